"""Parameter sweeps of the whole pipeline over synthetic InF halls, locally or on a Dask cluster.

A sweep is a grid of *cells*; every cell runs::

    InF hall (raytrace.halls.inf)  ->  trace  ->  ToA per epoch (the measurement model of
    raytrace.emulation.measurement: schedule + device clock offset + the receiver's estimate)
    ->  positioning of every fix with every method (positioning.locate)  ->  errors and counts

and returns one small result (a JSON-able dict). Results are written one file per cell,
``OUT/cells/<key>.json``, atomically, where ``key`` is a hash of every parameter of the cell
(and :data:`PIPELINE_VERSION`): a rerun skips the cells whose file exists, so an interrupted sweep
resumes where it stopped. At the end (and on a partial run, over the finished cells)
``OUT/results.csv`` and ``OUT/results.md`` collect one row per cell: the parameters that vary, the
LoS and detected fractions, the mean and 90th-percentile 2D error of each method, timings.

Execution: in this process (``workers=1``), on a local process pool, or on a Dask distributed
cluster (``scheduler=ADDRESS``; needs ``dask[distributed]``, the optional extra ``cluster``). The
cells are independent and return their results to the driver, which writes the files: the
workers need hallray installed, not a shared file system.

The config format is in ``docs/sweep.md`` (example ``docs/sweep_example.yaml``).
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import HallrayError
from ..core.fileio import read_yaml, write_atomic
from ..emulation.receivers import DEFAULT_TOA_METHOD
from ..solver.config import TRACE_KEYS as TRACE_FIELDS
from ..solver.config import TraceConfig

if TYPE_CHECKING:  # the pipeline's modules load lazily (the driver of a cluster sweep needs few)
    from ..emulation.dataset import DatasetConfig
    from ..emulation.measurement import Measurements
    from ..scene.metadata import SceneMetadata
    from ..scene.model import Scene

#: Bumped when the pipeline's results change for the same parameters (old cell files are then
#: not reused: their keys differ).
PIPELINE_VERSION = 3
#: Seconds to wait for a Dask scheduler before giving up.
CONNECT_TIMEOUT_S = 10.0
#: Characters of the parameter hash used as a cell key.
KEY_LENGTH = 16
#: Parameters of a cell and their defaults. ``None`` = the generator's own default.
HALL_KEYS: dict[str, Any] = {
    "profile": None,  # required
    "seed": 0,
    "size": None,
    "density": None,
    "clutter_size": None,
    "clutter_height": None,
    "height_spread": 0.0,
    "bs_height": None,
    "bs_spacing": 20.0,
    "bs_grid": None,
    "n_points": 50,
    "ut_height": 1.5,
}
#: The tracer's limits and switches, with their defaults: the fields of TraceConfig.
TRACE_KEYS: dict[str, Any] = {k: getattr(TraceConfig(), k) for k in TRACE_FIELDS}
TOA_KEYS: dict[str, Any] = {
    "band": "c-band",
    "toa_method": DEFAULT_TOA_METHOD,
    "noise": True,
    "duration_s": 1.0,
    "rate_hz": 10.0,
    # NLoS injection for stress tests: each received ToA gets, with this probability, an extra
    # path length uniform in [0.5, 1.5] * inject_nlos_bias_m
    "inject_nlos_fraction": 0.0,
    "inject_nlos_bias_m": 0.0,
    # positioning in 2D with the device height known ("known") or in 3D ("free")
    "height": "known",
}
CELL_KEYS: dict[str, Any] = {**HALL_KEYS, **TRACE_KEYS, **TOA_KEYS}
#: Files of a cell's ToA dataset (``datasets: true``), written to ``OUT/datasets/<key>/``.
DATASET_FILES = ("toa.csv", "meta.json")
#: Positioning methods of a sweep unless the config says otherwise (the paper's two).
DEFAULT_METHODS = ("ls", "irls")
_TOP_KEYS = (
    "name",
    "description",
    "grid",
    "fixed",
    "methods",
    "method_params",
    "output",
    "datasets",
)


# --------------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------------


def _canonical(value: Any) -> Any:
    """JSON-stable form: tuples -> lists, numpy scalars -> Python, dict keys sorted on dump."""
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def cell_key(params: Mapping[str, Any], methods: Mapping[str, Mapping[str, Any]]) -> str:
    """Hash of everything that determines a cell's result (hex, :data:`KEY_LENGTH` chars)."""
    blob = json.dumps(
        {"v": PIPELINE_VERSION, "params": _canonical(params), "methods": _canonical(methods)},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(blob.encode("utf-8")).hexdigest()[:KEY_LENGTH]


@dataclass(frozen=True)
class Cell:
    """One point of the sweep grid.

    Attributes
    ----------
    index : int, position in grid order
    params : dict, every cell parameter (:data:`CELL_KEYS`), defaults filled in
    methods : dict, positioning method -> its parameters (validated, defaults filled in)
    key : str, :func:`cell_key` of params and methods
    """

    index: int
    params: dict[str, Any]
    methods: dict[str, dict[str, Any]]
    key: str
    datasets: bool = False

    def value(self, key: str) -> Any:
        """The cell's value of a grid key: a parameter, or ``<method>.<parameter>``."""
        if "." in key:
            m, p = key.split(".", 1)
            return self.methods[m][p]
        return self.params[key]

    def describe(self, keys: Sequence[str]) -> str:
        """``key=value, ...`` of the given grid keys (the cell's key if there are none)."""
        return ", ".join(f"{k}={self.value(k)}" for k in keys) or self.key

    def task(self) -> dict[str, Any]:
        """What a worker needs (plain data, picklable)."""
        return {
            "key": self.key,
            "params": self.params,
            "methods": self.methods,
            "datasets": self.datasets,
        }


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the grid, the fixed parameters and the positioning methods."""

    name: str
    grid: dict[str, list[Any]]
    fixed: dict[str, Any]
    methods: dict[str, dict[str, Any]]
    description: str = ""
    output: str | None = None
    source: str = ""
    datasets: bool = False

    def cells(self) -> list[Cell]:
        """Every combination of the grid values (the first grid key varies slowest)."""
        keys = list(self.grid)
        out = []
        for i, combo in enumerate(itertools.product(*(self.grid[k] for k in keys))):
            params = dict(CELL_KEYS)
            params.update(self.fixed)
            methods = {m: dict(p) for m, p in self.methods.items()}
            for k, v in zip(keys, combo):
                if "." in k:
                    m, p = k.split(".", 1)
                    methods[m][p] = v
                else:
                    params[k] = v
            methods = _resolve_methods(methods, self.source)
            params = _canonical(params)
            out.append(Cell(i, params, methods, cell_key(params, methods), self.datasets))
        return out

    @property
    def varying(self) -> list[str]:
        """Grid keys with more than one value (the table's parameter columns)."""
        return [k for k, v in self.grid.items() if len(v) > 1]


def _fail(source: str, msg: str) -> None:
    raise HallrayError(f"{source}: {msg}" if source else msg)


def _resolve_methods(
    methods: Mapping[str, Mapping[str, Any]], source: str
) -> dict[str, dict[str, Any]]:
    from positioning import PositioningError
    from positioning import resolve_params as resolve_method

    out = {}
    for m, p in methods.items():
        try:
            out[m] = _canonical(resolve_method(m, dict(p)))
        except PositioningError as exc:
            _fail(source, str(exc))
    return out


def _parse_methods(data: Mapping[str, Any], source: str) -> dict[str, dict[str, Any]]:
    """``methods`` and ``method_params``: method -> its fixed parameters (not yet resolved)."""
    from positioning import METHODS

    raw_methods = data.get("methods", list(DEFAULT_METHODS))
    if isinstance(raw_methods, str):
        raw_methods = [raw_methods]
    if not isinstance(raw_methods, list) or not raw_methods:
        _fail(source, f"methods: expected a non-empty list, got {raw_methods!r}")
    for m in raw_methods:
        if m not in METHODS:
            _fail(source, f"methods: unknown method {m!r} (known: {', '.join(METHODS)})")
    if len(set(raw_methods)) != len(raw_methods):
        _fail(source, "methods: listed twice")
    mparams = data.get("method_params") or {}
    if not isinstance(mparams, Mapping):
        _fail(source, "method_params: expected a mapping method -> {parameter: value}")
    for m, p in mparams.items():
        if m not in raw_methods:
            _fail(source, f"method_params: {m!r} is not in methods")
        if not isinstance(p, Mapping):
            _fail(source, f"method_params.{m}: expected a mapping")
    return {m: dict(mparams.get(m, {})) for m in raw_methods}


def _parse_grid_and_fixed(
    data: Mapping[str, Any], methods: Mapping[str, Any], source: str
) -> tuple[Mapping[str, Any], Mapping[str, Any]]:
    """``grid`` (parameter -> non-empty list of distinct values) and ``fixed`` (parameter ->
    value): known parameters (``<method>.<parameter>`` in grid), none in both, a profile."""
    grid = data.get("grid") or {}
    fixed = data.get("fixed") or {}
    if not isinstance(grid, Mapping) or not isinstance(fixed, Mapping):
        _fail(source, "grid and fixed must be mappings of parameter -> value(s)")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            _fail(source, f"grid.{k}: expected a non-empty list of values, got {v!r}")
        if len({json.dumps(_canonical(x), sort_keys=True) for x in v}) != len(v):
            _fail(source, f"grid.{k}: a value is listed twice")
    for where, block in (("grid", grid), ("fixed", fixed)):
        for k in block:
            if "." in k and where == "grid":
                m, p = k.split(".", 1)
                if m not in methods:
                    _fail(source, f"grid.{k}: method {m!r} is not in methods")
                continue
            if k not in CELL_KEYS:
                _fail(
                    source,
                    f"{where}.{k}: unknown parameter (known: {', '.join(CELL_KEYS)}, or "
                    "<method>.<parameter> in grid)",
                )
    both = sorted(set(grid) & set(fixed))
    if both:
        _fail(source, f"{both[0]!r} is in both grid and fixed")
    if "profile" not in grid and "profile" not in fixed:
        _fail(source, "give the profile (InF-SL, InF-DL, InF-SH, InF-DH) in grid or fixed")
    return grid, fixed


def _check_cells(cfg: SweepConfig) -> None:
    """Validate every cell (dry layout of its hall included); refuse identical cells."""
    seen: dict[str, int] = {}
    for cell in cfg.cells():
        try:
            validate_cell(cell.params)
        except HallrayError as exc:
            _fail(cfg.source, f"cell {cell.index} ({cell.describe(cfg.varying)}): {exc}")
        if cell.key in seen:
            _fail(cfg.source, f"cells {seen[cell.key]} and {cell.index} are identical")
        seen[cell.key] = cell.index


def parse_sweep_config(data: Any, *, source: str = "") -> SweepConfig:
    """Validate a sweep config given as a parsed YAML mapping (see ``docs/sweep.md``).

    Every cell is checked here (generator parameters, tracer limits, band, ToA method, positioning
    methods), so a bad cell fails before any work starts. Raises :class:`HallrayError` with a
    one-line message.
    """
    if not isinstance(data, Mapping):
        _fail(source, "a sweep config is a mapping with 'grid', 'fixed', 'methods', ...")
    for k in data:
        if k not in _TOP_KEYS:
            _fail(source, f"unknown key {k!r} (allowed: {', '.join(_TOP_KEYS)})")
    methods = _parse_methods(data, source)
    grid, fixed = _parse_grid_and_fixed(data, methods, source)
    name = data.get("name", Path(source).stem if source else "sweep")
    if not isinstance(name, str) or not name:
        _fail(source, f"name: expected a string, got {name!r}")
    output = data.get("output")
    if output is not None and not isinstance(output, str):
        _fail(source, f"output: expected a directory name, got {output!r}")
    datasets = data.get("datasets", False)
    if not isinstance(datasets, bool):
        _fail(source, f"datasets: expected true or false, got {datasets!r}")
    cfg = SweepConfig(
        name=name,
        grid={k: list(v) for k, v in grid.items()},
        fixed=dict(fixed),
        methods=methods,
        description=str(data.get("description", "")),
        output=output,
        source=source,
        datasets=datasets,
    )
    _check_cells(cfg)
    return cfg


def load_sweep_config(source: str | os.PathLike[str] | Mapping[str, Any]) -> SweepConfig:
    """Read and validate a sweep config file (YAML) or mapping; see :func:`parse_sweep_config`."""

    if isinstance(source, Mapping):
        return parse_sweep_config(source)
    path = Path(source)
    return parse_sweep_config(read_yaml(path, "sweep config"), source=str(path))


def _hall_kwargs(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: params[k] for k in HALL_KEYS if k not in ("profile", "size", "seed")}


def n_epochs(params: Mapping[str, Any]) -> int:
    """Epochs of a cell: ``floor(duration_s * rate_hz)``, as the dataset writer counts them."""
    from ..scene.motion import snapshot_times

    return len(snapshot_times(params["duration_s"], params["rate_hz"]))


def validate_cell(params: Mapping[str, Any]) -> None:
    """Check one cell's parameters without running it (one-line :class:`HallrayError`)."""
    from ..emulation.bands import get_band
    from ..emulation.receivers import TOA_METHODS
    from ..halls.inf import check_hall

    if params.get("profile") is None:
        raise HallrayError("no profile given")
    check_hall(params["profile"], params["size"], params["seed"], **_hall_kwargs(params))
    TraceConfig.from_mapping(params)  # one-line TraceInputError for a bad limit
    get_band(params["band"])
    if params["toa_method"] not in TOA_METHODS:
        raise HallrayError(
            f"unknown toa_method {params['toa_method']!r} (known: {', '.join(TOA_METHODS)})"
        )
    if not isinstance(params["noise"], bool):
        raise HallrayError(f"noise must be true or false, got {params['noise']!r}")
    for k in ("duration_s", "rate_hz", "inject_nlos_fraction", "inject_nlos_bias_m"):
        v = params[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise HallrayError(f"{k} must be a finite number >= 0, got {v!r}")
    if params["duration_s"] <= 0 or params["rate_hz"] <= 0:
        raise HallrayError("duration_s and rate_hz must be > 0")
    n_epochs(params)  # at least one epoch
    if params["inject_nlos_fraction"] > 1:
        raise HallrayError(
            f"inject_nlos_fraction must be in [0, 1], got {params['inject_nlos_fraction']!r}"
        )
    if params["height"] not in ("known", "free"):
        raise HallrayError(f"height must be 'known' or 'free', got {params['height']!r}")


# --------------------------------------------------------------------------------------------
# one cell
# --------------------------------------------------------------------------------------------


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
    from ..halls.inf import generate_hall, scene_from_spec, split_spec
    from ..halls.spec import parse_hall_spec
    from ..scene.metadata import SceneMetadata

    spec = generate_hall(
        params["profile"], params["size"], params["seed"], los_notes=False, **_hall_kwargs(params)
    )
    hall_dict, info = split_spec(spec)
    scene = scene_from_spec(parse_hall_spec(hall_dict))
    return CellHall(scene, SceneMetadata.from_scene(scene, require=True), info)


def cell_dataset_config(params: Mapping[str, Any]) -> DatasetConfig:
    """The :class:`raytrace.emulation.dataset.DatasetConfig` of a cell: static scenario, the
    cell's band, receiver, noise, epochs, seed and tracer limits. Its measurement model is the
    cell's, and its dataset is what ``make-dataset`` writes for the cell's hall."""
    from ..emulation.dataset import DatasetConfig

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
    from ..emulation.measurement import epoch_rngs

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
        m: np.asarray(locate(flat, bs_xyz, m, tx_offsets_s=tx_offset_s, height_m=h, **p))
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
    :func:`positioning.dataset.load_dataset`; ``CellData.dataset_max_diff_s`` is the largest
    difference between the file's ToAs and the in-memory ones (0 expected: a round trip).
    """
    from ..core.constants import C0
    from ..solver.tracer import trace

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

    from ..emulation.dataset import write_dataset

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

    from ..halls.inf import los_probability_3gpp

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


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------


def cell_path(out_dir: str | os.PathLike[str], key: str) -> Path:
    return Path(out_dir) / "cells" / f"{key}.json"


def dataset_dir(out_dir: str | os.PathLike[str], key: str) -> Path:
    return Path(out_dir) / "datasets" / key


def write_cell_result(out_dir: str | os.PathLike[str], result: Mapping[str, Any]) -> Path:
    """Write a cell's result atomically to ``OUT/cells/<key>.json`` (and, first, its dataset
    files to ``OUT/datasets/<key>/``, so a cell file implies complete dataset files)."""
    result = dict(result)
    files = result.pop("_files", None) or {}
    if files:
        d = dataset_dir(out_dir, result["key"])
        d.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            write_atomic(d / name, text.encode("utf-8"))
    path = cell_path(out_dir, result["key"])
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, (json.dumps(result, indent=1, sort_keys=True) + "\n").encode())
    return path


def read_cell_result(out_dir: str | os.PathLike[str], cell: Cell) -> dict[str, Any] | None:
    """The stored result of a cell, or None if absent, unreadable or not this cell's."""
    path = cell_path(out_dir, cell.key)
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(result, dict) or result.get("key") != cell.key:
        return None
    if result.get("params") != cell.params or result.get("methods") != cell.methods:
        return None
    if cell.datasets and not all(
        (dataset_dir(out_dir, cell.key) / n).is_file() for n in DATASET_FILES
    ):
        return None
    return result


def table_rows(
    config: SweepConfig, results: Mapping[str, Mapping[str, Any]]
) -> tuple[list[str], list[list[Any]]]:
    """Header and rows of the results table, one row per finished cell in grid order."""
    methods = list(config.methods)
    head = ["cell", *config.varying, "los_fraction", "los_fraction_3gpp", "detected_fraction"]
    for m in methods:
        head += [f"{m}_mean_m", f"{m}_median_m", f"{m}_p90_m", f"{m}_unsolved"]
    head += ["n_fixes", "generate_s", "trace_s", "toa_s", "locate_s", "total_s"]
    rows = []
    for cell in config.cells():
        res = results.get(cell.key)
        if res is None:
            continue
        row: list[Any] = [cell.key, *(cell.value(k) for k in config.varying)]
        st = res["stats"]
        row += [st["los_fraction"], st["los_fraction_3gpp"], st["detected_fraction"]]
        for m in methods:
            e = res["errors"][m]
            row += [e["mean_m"], e["median_m"], e["p90_m"], e["n_unsolved"]]
        t = res["timing_s"]
        row += [st["n_fixes"], t["generate"], t["trace"], t["toa"], t["locate"], t["total"]]
        rows.append(row)
    return head, rows


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    if isinstance(v, (list, tuple)):
        return "x".join(str(x) for x in v)
    return str(v)


def results_table_markdown(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Markdown of the sweep's results table (:func:`table_rows`: any header, one row per cell).

    Floats with 3 decimals (2 in the seconds columns, ``*_s``), lists as ``AxB`` (sizes,
    grids), None as ``-``. Not :func:`positioning.report.table_markdown`, which writes the
    paper's Table II (fixed columns: metric and dataset rows, the paper's values beside ours).
    """
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [_fmt(v, 2 if h.endswith("_s") else 3) for h, v in zip(head, row)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def results_table_csv(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """CSV of the sweep's results table: full precision, lists as ``AxB``, None empty (unlike
    :func:`positioning.report.table_csv`, Table II's fixed columns at 6 significant digits)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for row in rows:
        w.writerow(
            [
                "" if v is None else ("x".join(map(str, v)) if isinstance(v, list) else v)
                for v in row
            ]
        )
    return buf.getvalue()


def write_tables(
    out_dir: str | os.PathLike[str], config: SweepConfig, results: Mapping[str, Mapping[str, Any]]
) -> tuple[Path, Path]:
    """``OUT/results.csv`` and ``OUT/results.md`` (atomically) over the finished cells."""
    out = Path(out_dir)
    head, rows = table_rows(config, results)
    csv_path, md_path = out / "results.csv", out / "results.md"
    write_atomic(csv_path, results_table_csv(head, rows).encode())
    title = f"# Sweep {config.name}: {len(rows)} of {len(config.cells())} cells\n\n"
    if config.fixed:
        fixed = ", ".join(f"{k} = {_fmt(v)}" for k, v in config.fixed.items())
        title += f"Fixed: {fixed}. "
    title += "Methods: " + ", ".join(
        f"{m} ({', '.join(f'{k}={v}' for k, v in p.items())})" for m, p in config.methods.items()
    )
    title += ". Errors are 2D, in metres, over all fixes (epochs x points) of a cell.\n\n"
    write_atomic(md_path, (title + results_table_markdown(head, rows)).encode())
    return csv_path, md_path


# --------------------------------------------------------------------------------------------
# running
# --------------------------------------------------------------------------------------------


@dataclass
class SweepReport:
    """What :func:`run_sweep` did."""

    out_dir: Path
    n_cells: int
    computed: list[str]
    skipped: list[str]
    failed: dict[str, str]
    wall_s: float
    results: dict[str, dict[str, Any]]
    mode: str

    @property
    def cells_per_minute(self) -> float:
        return 60.0 * len(self.computed) / self.wall_s if self.wall_s > 0 else math.nan


def _execute_local(
    tasks: list[dict[str, Any]], workers: int
) -> Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]]:
    """Yield ``(task, result, error)`` as cells finish, in this process or on a process pool."""
    if not tasks:
        return
    if workers <= 1:
        for t in tasks:
            try:
                yield t, run_cell({**t, "threads": None}), None
            except HallrayError as exc:
                yield t, None, str(exc)
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from ..solver.parallel import cpu_count, process_context

    # forks of the preloaded fork server, never of this process: Embree's threads (alive here once
    # it has traced anything) do not survive a fork, and a child's first scene build could wait
    # for them forever (raytrace.solver.parallel)
    workers = min(workers, len(tasks), cpu_count())  # never more than usable cores or cells
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=process_context((__name__,)))
    futures: dict[Any, dict[str, Any]] = {}
    seen: set[Any] = set()
    try:
        futures = {pool.submit(run_cell, t): t for t in tasks}
        for fut in as_completed(futures):
            seen.add(fut)
            t = futures[fut]
            try:
                yield t, fut.result(), None
            except Exception as exc:  # a worker's error, reported per cell  # noqa: BLE001
                yield t, None, f"{type(exc).__name__}: {exc}".splitlines()[0]
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: stop the running cells now, keep finished ones
        done = [f for f in futures if f.done() and f not in seen and not f.cancelled()]
        _stop_pool(pool)
        for fut in done:
            if fut.exception() is None:
                yield futures[fut], fut.result(), None
        raise
    except BaseException:  # the consumer stopped (or failed): do not wait for running cells
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True, cancel_futures=True)


def _stop_pool(pool: Any) -> None:
    """Cancel a process pool's pending cells and terminate its running ones at once (waiting
    for them is what made Ctrl-C take tens of seconds)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=5)


#: glibc ``mallopt`` settings for Dask workers (see :func:`tune_malloc`): large temporaries from
#: the heap below 32 MiB, heap top trimmed beyond 128 MiB.
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 128 * 1024 * 1024


def tune_malloc() -> bool:
    """Undo the allocator setting Dask's nanny gives its workers, which halves the tracer's speed.

    Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (to return memory to the OS
    quickly). Setting it switches off glibc's dynamic mmap threshold, so every numpy temporary
    above 128 KiB becomes a fresh ``mmap`` whose pages fault in again: a trace took 2.3x as long
    in a Dask worker as in a plain process. This sets ``M_MMAP_THRESHOLD`` and
    ``M_TRIM_THRESHOLD`` through ``mallopt`` (glibc only; elsewhere it does nothing).

    Returns
    -------
    bool, whether the settings were applied
    """
    import ctypes
    import ctypes.util

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(
        mallopt(m_mmap_threshold, MMAP_THRESHOLD_BYTES)
        and mallopt(m_trim_threshold, TRIM_THRESHOLD_BYTES)
    )


def _connect_dask(scheduler: Any) -> tuple[Any, bool]:
    """``(client, own)`` for a scheduler address or an existing ``distributed.Client``."""
    try:
        from distributed import Client
    except ImportError:
        raise HallrayError(
            "--scheduler needs dask.distributed: pip install 'hallray[cluster]' "
            "(or 'dask[distributed]')"
        ) from None
    if isinstance(scheduler, Client):
        return scheduler, False
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s"), True
    except (OSError, TimeoutError, ValueError) as exc:
        raise HallrayError(
            f"cannot connect to the Dask scheduler {scheduler!r}: {str(exc).splitlines()[0]}"
        ) from None


def _execute_dask(
    tasks: list[dict[str, Any]], client: Any, own: bool
) -> Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]]:
    """The same on a Dask distributed cluster; closes the client if ``own``."""
    from distributed import as_completed

    try:
        if not tasks:
            return
        client.run(tune_malloc)  # see tune_malloc: the workers' allocator setting costs 2x
        futures = client.map(
            run_cell, tasks, key=[f"hallray-cell-{t['key']}" for t in tasks], pure=False
        )
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        for fut in as_completed(futures):
            t = by_key[fut.key]
            try:
                yield t, fut.result(), None
            except Exception as exc:  # noqa: BLE001 -- a worker's error, reported per cell
                yield t, None, f"{type(exc).__name__}: {exc}".splitlines()[0]
            finally:
                fut.release()
    finally:
        if own:
            client.close()


def _output_dir(cfg: SweepConfig, out_dir: str | os.PathLike[str] | None) -> Path:
    """The sweep's output directory (:func:`default_output` if not given), checked."""
    out = Path(out_dir) if out_dir is not None else default_output(cfg)
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output {out} exists and is not a directory")
    if not out.parent.is_dir():
        raise HallrayError(f"cannot create {out}: directory {out.parent} does not exist")
    return out


def _done_and_todo(
    cells: Sequence[Cell], out: Path, limit: int | None
) -> tuple[dict[str, dict[str, Any]], list[Cell]]:
    """Stored results of the finished cells, and the cells to compute (at most ``limit``)."""
    results: dict[str, dict[str, Any]] = {}
    todo: list[Cell] = []
    for cell in cells:
        res = read_cell_result(out, cell)
        if res is None:
            todo.append(cell)
        else:
            results[cell.key] = res
    if limit is not None:
        todo = todo[: max(0, int(limit))]
    return results, todo


def _collect(
    runner: Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]],
    out: Path,
    results: dict[str, dict[str, Any]],
    computed: list[str],
    failed: dict[str, str],
    tick: Callable[[int], None],
) -> None:
    """Write each finished cell (:func:`write_cell_result`), add it to ``results`` and its key
    to ``computed`` (a failure to ``failed``, key -> error) as it comes, then call ``tick(cells
    finished or failed)``: an interruption leaves them telling what was done."""
    for task, result, error in runner:
        if result is not None:
            write_cell_result(out, result)
            result.pop("_files", None)
            results[task["key"]] = result
            computed.append(task["key"])
        else:
            failed[task["key"]] = error or "unknown error"
        tick(len(computed) + len(failed))


def _write_summary(
    out: Path,
    cfg: SweepConfig,
    results: Mapping[str, Any],
    last_run: Mapping[str, Any],
) -> None:
    """``OUT/sweep.json``: the config, every cell's key and state, what the last run did."""
    cells = cfg.cells()
    summary = {
        "name": cfg.name,
        "description": cfg.description,
        "source": cfg.source,
        "grid": _canonical(cfg.grid),
        "fixed": _canonical(cfg.fixed),
        "methods": cfg.methods,
        "pipeline_version": PIPELINE_VERSION,
        "datasets": cfg.datasets,
        "n_cells": len(cells),
        "n_finished": len(results),
        "last_run": dict(last_run),
        "cells": [{"index": c.index, "key": c.key, "done": c.key in results} for c in cells],
    }
    write_atomic(out / "sweep.json", (json.dumps(summary, indent=1) + "\n").encode())


def run_sweep(
    config: SweepConfig | str | os.PathLike[str] | Mapping[str, Any],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool | Callable[[int, int], None] = False,
    limit: int | None = None,
) -> SweepReport:
    """Run (or resume) a sweep; write one file per cell and the results tables.

    Parameters
    ----------
    config : SweepConfig, a config file or a mapping
    out_dir : output directory (default: the config's ``output``, else ``<config stem>-sweep``
        beside the config file, else ``sweep-<name>``)
    workers : processes of the local pool (default: the cores this process may use; 1 = in
        this process)
    scheduler : Dask scheduler address (``tcp://host:8786``) or a ``distributed.Client``; when
        given, cells run on that cluster and ``workers`` is ignored
    progress : True for a tqdm bar on stderr, or a callable ``(done, total)``
    limit : compute at most this many missing cells (then stop, as if interrupted)

    Returns
    -------
    SweepReport
    """
    cfg = config if isinstance(config, SweepConfig) else load_sweep_config(config)
    out = _output_dir(cfg, out_dir)
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int) or workers < 1
    ):
        raise HallrayError(f"workers must be an integer >= 1, got {workers!r}")
    cells = cfg.cells()
    results, todo = _done_and_todo(cells, out, limit)
    skipped = list(results)
    # connect before writing anything: an unreachable scheduler leaves no output behind
    dask_client = _connect_dask(scheduler) if scheduler is not None and todo else None
    out.mkdir(exist_ok=True)
    from ..solver.parallel import cpu_count

    n_workers = workers if workers is not None else cpu_count()
    mode = "dask" if scheduler is not None else ("local" if n_workers <= 1 else f"pool:{n_workers}")
    tasks = [c.task() for c in todo]
    bar = None
    if progress is True and tasks:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), desc=f"sweep {cfg.name}", unit="cell", file=sys.stderr)

    def tick(n_done: int) -> None:
        if bar is not None:
            bar.update(1)
        elif callable(progress):
            progress(n_done, len(tasks))

    t0 = time.perf_counter()
    runner = (
        _execute_dask(tasks, *dask_client)
        if dask_client is not None
        else _execute_local(tasks, n_workers)
    )
    computed: list[str] = []
    failed: dict[str, str] = {}
    try:
        _collect(runner, out, results, computed, failed, tick)
    finally:
        if bar is not None:
            bar.close()
        wall = time.perf_counter() - t0
        write_tables(out, cfg, results)
        last_run = {
            "mode": mode,
            "computed": len(computed),
            "skipped": len(skipped),
            "failed": failed,
            "wall_s": wall,
        }
        _write_summary(out, cfg, results, last_run)
    return SweepReport(out, len(cells), computed, skipped, failed, wall, results, mode)


def default_output(cfg: SweepConfig) -> Path:
    """Where a sweep writes when no ``-o`` is given (see :func:`run_sweep`)."""
    if cfg.output:
        base = Path(cfg.source).parent if cfg.source else Path.cwd()
        return base / cfg.output
    if cfg.source:
        src = Path(cfg.source)
        return src.parent / f"{src.stem}-sweep"
    return Path.cwd() / f"sweep-{cfg.name}"
