"""One cell of a sweep: its InF hall, one trace, the ToAs of its measurement model (with the
NLoS injection of stress tests), every fix with every method (:func:`simulate_cell`), reduced
to a JSON-able result (:func:`run_cell`, what the workers call).
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...solver.config import TraceConfig
from .config import DATASET_FILES, PIPELINE_VERSION, hall_kwargs

if TYPE_CHECKING:  # the pipeline's modules load lazily (the driver of a cluster sweep needs few)
    from ...emulation.dataset.config import DatasetConfig
    from ...emulation.measurement import Measurements
    from ...scene.metadata import SceneMetadata
    from ...scene.model import Scene


@dataclass
class CellData:
    """Arrays of one cell's pipeline run (for tests and analyses; :func:`run_cell` reduces them).

    Attributes
    ----------
    bs_xyz : (B, 3) float, m; point_xyz : (N, 3) float, m
    distance_m : (B, N) float, 3D BS-point distance, m
    los : (B, N) bool, the link has a line-of-sight path
    propagation_toa_s : (E, N, B) float, s, estimated propagation delay (no schedule, no clock,
        no injected NLoS); NaN where not detected
    sigma_s : (B, N) float, s, eq. 3 standard deviation of the first detectable path (NaN if none)
    injected_m : (E, N, B) float, m, extra path length injected as NLoS (0 where none)
    toa_s : (E, N, B) float, s, the measured ToA: schedule + clock offset + delay + injection
    tx_offset_s : (B,) float, s; clock_offset_s : (E, N) float, s
    fixes : dict method -> (E * N, 3) float, m, estimated positions (fix order: epoch-major)
    true_xyz : (E * N, 3) float, m
    k_3gpp_m : float; n_clutter : int; achieved_density : float; n_paths : int
    timing_s : dict stage -> seconds
    dataset_max_diff_s : float, s, see :func:`simulate_cell` (NaN when no dataset was written)
    """

    bs_xyz: np.ndarray
    point_xyz: np.ndarray
    distance_m: np.ndarray
    los: np.ndarray
    propagation_toa_s: np.ndarray
    sigma_s: np.ndarray
    injected_m: np.ndarray
    toa_s: np.ndarray
    tx_offset_s: np.ndarray
    clock_offset_s: np.ndarray
    fixes: dict[str, np.ndarray]
    true_xyz: np.ndarray
    k_3gpp_m: float
    n_clutter: int
    achieved_density: float
    n_paths: int
    timing_s: dict[str, float] = field(default_factory=dict)
    dataset_max_diff_s: float = math.nan

    def errors_2d(self, method: str) -> np.ndarray:
        """(E * N,) float, m, horizontal error of each fix (NaN where unsolved)."""
        from positioning import error_2d

        return error_2d(self.fixes[method], self.true_xyz)


@dataclass(frozen=True)
class CellHall:
    """A cell's synthetic hall, built in memory.

    Attributes
    ----------
    scene : Scene, with base stations and points in its metadata
    inputs : SceneMetadata, the scene's base stations and points (names, (n, 3) float m)
    info : dict, the generator's ``_inf`` block (3GPP ``k_subsce_m``, clutter count, density)
    """

    scene: Scene
    inputs: SceneMetadata
    info: dict[str, Any]


def cell_hall(params: Mapping[str, Any]) -> CellHall:
    """The hall of a cell: ``generate_hall(profile, size, seed, ...)`` as a scene."""
    from ...halls.inf.generator import generate_hall, split_spec
    from ...halls.inf.los import scene_from_spec
    from ...halls.spec.parse import parse_hall_spec
    from ...scene.metadata import SceneMetadata

    spec = generate_hall(
        params["profile"], params["size"], params["seed"], los_notes=False, **hall_kwargs(params)
    )
    hall_dict, info = split_spec(spec)
    scene = scene_from_spec(parse_hall_spec(hall_dict))
    return CellHall(scene, SceneMetadata.from_scene(scene, require=True), info)


def cell_dataset_config(params: Mapping[str, Any]) -> DatasetConfig:
    """The :class:`raytrace.emulation.dataset.DatasetConfig` of a cell: static scenario, the
    cell's band, receiver, noise, epochs, seed and tracer limits. Its measurement model is the
    cell's, and its dataset is what ``make-dataset`` writes for the cell's hall."""
    from ...emulation.dataset.config import DatasetConfig

    return DatasetConfig(
        "static",
        params["band"],
        duration_s=float(params["duration_s"]),
        rate_hz=float(params["rate_hz"]),
        seed=int(params["seed"]),
        toa_method=params["toa_method"],
        noise=bool(params["noise"]),
        trace=TraceConfig.from_mapping(params),
    )


#: Stream of an epoch's :func:`raytrace.emulation.measurement.epoch_rngs` for the NLoS injection
#: (after the measurement model's clock-offset and noise streams).
NLOS_STREAM = 2


def inject_nlos(delay_s: np.ndarray, seed: int, fraction: float, bias_m: float) -> np.ndarray:
    """Extra path lengths of the NLoS stress test (:data:`TOA_KEYS` ``inject_nlos_*``).

    Each received ToA gets, with probability ``fraction``, an extra path length uniform in
    ``[0.5, 1.5] * bias_m``; epoch ``e`` draws from its stream :data:`NLOS_STREAM`.

    Parameters
    ----------
    delay_s : (E, N, B) float, s, estimated propagation delays, NaN where not received
    seed : int; fraction : float in [0, 1]; bias_m : float, m

    Returns
    -------
    (E, N, B) float, m, 0 where nothing is injected
    """
    from ...emulation.measurement import epoch_rngs

    injected = np.zeros(delay_s.shape)
    if fraction <= 0 or bias_m <= 0:
        return injected
    shape = delay_s.shape[1:]
    for e in range(delay_s.shape[0]):  # one stream per epoch, as the measurement model's
        rng = epoch_rngs(seed, e, NLOS_STREAM + 1)[NLOS_STREAM]
        hit = rng.random(shape) < fraction
        extra = bias_m * rng.uniform(0.5, 1.5, shape)
        injected[e] = np.where(hit & np.isfinite(delay_s[e]), extra, 0.0)
    return injected


def _locate_fixes(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    point_xyz: np.ndarray,
    tx_offset_s: np.ndarray,
    methods: Mapping[str, Mapping[str, Any]],
    height: str,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every fix (epoch-major) with every method: ``(fixes, true_xyz)``, (E * N, 3) m each.

    ``height`` "known": 2D fixes with the device height known; "free": 3D fixes.
    """
    from positioning import locate

    n_e, n_p, n_b = toa_s.shape
    flat = toa_s.reshape(n_e * n_p, n_b)
    true_xyz = np.tile(point_xyz, (n_e, 1))
    h = true_xyz[:, 2] if height == "known" else None
    fixes = {
        # every cell's fixes, whatever its geometry (the sweep's table shows it)
        m: np.asarray(locate(flat, bs_xyz, m, tx_offsets_s=tx_offset_s, height_m=h, checks=False,
                             **p))  # fmt: skip
        for m, p in methods.items()
    }
    return fixes, true_xyz


def simulate_cell(
    params: Mapping[str, Any],
    methods: Mapping[str, Mapping[str, Any]],
    *,
    threads: int | None = 1,
    dataset_dir: str | os.PathLike[str] | None = None,
) -> CellData:
    """Run the pipeline of one cell and keep the arrays (see :class:`CellData`).

    Hall (:func:`cell_hall`), one trace of the static scene, the measurement model of the cell's
    dataset config (:func:`cell_dataset_config`, :class:`raytrace.emulation.measurement.ToaModel`:
    schedule, clock offsets and estimation noise from ``epoch_rngs(seed, e)``), the NLoS
    injection (:func:`inject_nlos`), then every fix with every method.

    With ``dataset_dir``, the cell's ToA dataset (before injection) is also written there by
    :func:`raytrace.emulation.dataset.write_dataset` from these measurements (the files
    ``make-dataset`` writes for this hall and settings) and read back with
    :func:`positioning.io.dataset.load_dataset`; ``CellData.dataset_max_diff_s`` is the largest
    difference between the file's ToAs and the in-memory ones (0 expected: a round trip).
    """
    from ...core.constants import C0
    from ...solver.tracer import trace

    t0 = time.perf_counter()
    hall = cell_hall(params)
    bs, pts = hall.inputs.bs_xyz, hall.inputs.point_xyz
    t1 = time.perf_counter()
    cfg = cell_dataset_config(params)
    model = cfg.model()
    paths = trace(hall.scene, bs, pts, model.receiver.band.center_frequency_hz, cfg.trace,
                  threads=threads)  # fmt: skip
    t2 = time.perf_counter()
    measured = model.measure(paths, range(len(cfg.times_s)))  # the scene is static
    injected = inject_nlos(
        measured.delay_s,
        cfg.seed,
        float(params["inject_nlos_fraction"]),
        float(params["inject_nlos_bias_m"]),
    )
    toa = measured.toa_s + injected / C0
    t3 = time.perf_counter()
    fixes, true_xyz = _locate_fixes(toa, bs, pts, measured.tx_offset_s, methods, params["height"])
    t4 = time.perf_counter()
    timing = {"generate": t1 - t0, "trace": t2 - t1, "toa": t3 - t2, "locate": t4 - t3}
    diff = math.nan
    if dataset_dir is not None:
        diff = _write_dataset(dataset_dir, hall, cfg, measured)
        timing["dataset"] = time.perf_counter() - t4
    return CellData(
        bs_xyz=bs,
        point_xyz=pts,
        distance_m=np.linalg.norm(bs[:, None, :] - pts[None, :, :], axis=2),
        los=measured.los[0].T,
        propagation_toa_s=measured.delay_s,
        sigma_s=measured.sigma_s[0].T,
        injected_m=injected,
        toa_s=toa,
        tx_offset_s=measured.tx_offset_s,
        clock_offset_s=measured.clock_offset_s,
        fixes=fixes,
        true_xyz=true_xyz,
        k_3gpp_m=float(hall.info["k_subsce_m"]),
        n_clutter=int(hall.info["n_clutter"]),
        achieved_density=float(hall.info["achieved_density"]),
        n_paths=int(paths.n_paths),
        timing_s=timing,
        dataset_max_diff_s=diff,
    )


def _write_dataset(
    out: str | os.PathLike[str], hall: CellHall, cfg: DatasetConfig, measured: Measurements
) -> float:
    """Write the cell's dataset from its measurements; return max |file ToA - measured ToA| (s),
    inf if the file's detected ToAs are not the measured ones."""
    from positioning.io.dataset import load_dataset

    from ...emulation.dataset.files import write_dataset

    write_dataset(out, hall.scene, cfg, measured, force=True)
    ds = load_dataset(out)
    col = {name: i for i, name in enumerate(hall.inputs.point_names)}
    mine = measured.toa_s[ds.epoch, [col[p] for p in ds.point]]  # (F, B), the dataset's fix order
    if not np.array_equal(np.isfinite(mine), np.isfinite(ds.toa_s)):
        return math.inf
    both = np.isfinite(mine)
    return float(np.max(np.abs(mine[both] - ds.toa_s[both]), initial=0.0))


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def run_cell(task: Mapping[str, Any]) -> dict[str, Any]:
    """Run one cell (``Cell.task()``) and return its JSON-able result.

    This is the function the local pool and the Dask workers call. It writes nothing the driver
    sees: with ``datasets`` the dataset is written to a temporary directory of the worker and its
    files come back in the result (``"_files"``), which :func:`write_cell_result` writes.
    """
    import tempfile

    from positioning import summarize

    from ...halls.inf.params import los_probability_3gpp

    t0 = time.perf_counter()
    params, methods = task["params"], task["methods"]
    files: dict[str, str] = {}
    # one tracer thread in pool and cluster workers (no oversubscription); all cores in process
    with tempfile.TemporaryDirectory(prefix="hallray-cell-") as tmp:
        ds_dir = Path(tmp) / "dataset" if task.get("datasets") else None
        data = simulate_cell(params, methods, threads=task.get("threads", 1), dataset_dir=ds_dir)
        if ds_dir is not None:
            files = {n: (ds_dir / n).read_text(encoding="utf-8") for n in DATASET_FILES}
    errors = {}
    for m in methods:
        s = summarize(data.errors_2d(m))
        errors[m] = {k: (_finite(v) if isinstance(v, float) else v) for k, v in s.items()}
    d2d = np.hypot(*(data.bs_xyz[:, None, :2] - data.point_xyz[None, :, :2]).transpose(2, 0, 1))
    timing = dict(data.timing_s)
    timing["total"] = time.perf_counter() - t0
    received = np.isfinite(data.propagation_toa_s)
    return {
        "key": task["key"],
        "pipeline_version": PIPELINE_VERSION,
        "params": dict(params),
        "methods": {m: dict(p) for m, p in methods.items()},
        "stats": {
            "n_bs": int(len(data.bs_xyz)),
            "n_points": int(len(data.point_xyz)),
            "n_epochs": int(data.toa_s.shape[0]),
            "n_fixes": int(data.true_xyz.shape[0]),
            "n_clutter": data.n_clutter,
            "achieved_density": data.achieved_density,
            "n_paths": data.n_paths,
            "los_fraction": float(np.mean(data.los)),
            "los_fraction_3gpp": float(np.mean(los_probability_3gpp(d2d, data.k_3gpp_m))),
            "detected_fraction": float(np.mean(received)),
            "injected_fraction": float(np.mean(data.injected_m > 0)),
            "dataset_max_diff_s": _finite(data.dataset_max_diff_s),
        },
        "errors": errors,
        "timing_s": timing,
        "host": platform.node(),
        **({"_files": files} if files else {}),
    }
