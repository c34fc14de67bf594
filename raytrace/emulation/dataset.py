"""ToA datasets: the paper's static and semi-dynamic scenarios in both bands.

A dataset directory holds ``toa.csv`` (one row per epoch, point and base station) and
``meta.json`` (every parameter that produced it); the schema is in ``docs/dataset.md`` and is
read by :mod:`positioning.dataset`. For the semi-dynamic scenario it also holds
``forklifts.csv`` (the forklift poses of every epoch).

Measurements: :mod:`raytrace.emulation.measurement` (base station k transmits at ``k * delta``,
one device clock offset per epoch and point, the receiver's estimated delay)::

    toa_s = tx_offset_s + clock_offset_s + estimated propagation delay

Epochs: one per snapshot of the forklifts (``k / rate`` s, k = 0 .. duration * rate - 1) for
``semi-dynamic``; for ``static`` the scene never changes, so it is traced once and every epoch
draws its own clock offsets and estimation noise (the same number of epochs, so that the
statistics are comparable).

Reproducibility: the random numbers of epoch ``e`` come from
``numpy.random.SeedSequence([seed, e]).spawn(2)`` (clock offsets, then estimator noise;
:func:`raytrace.emulation.measurement.epoch_rngs`), so the files depend only on the inputs and the
seed, not on the number of worker processes.

Two ways in: :func:`make_datasets` traces a scene and writes its datasets;
:func:`write_dataset` (and :func:`dataset_files`) writes a dataset from measurements already made
with :meth:`DatasetConfig.model` (a sweep cell does this with the ToAs it positions). Both format
the files with the same code, so the two give the same bytes for the same inputs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import HallrayError, SceneError
from ..scene.io import load_scene
from ..scene.metadata import SceneMetadata
from ..scene.model import Scene
from ..scene.motion import FORKLIFT_CLEARANCE_M, snapshot_times
from ..solver.config import TraceConfig
from ..solver.incremental import Fleet, SnapshotTracer
from ..solver.paths import Paths
from .bands import Band, get_band
from .channel import LinkBudget, PulseShape
from .measurement import CLOCK_OFFSET_MAX_S, DELTA_S, Measurements, ToaModel
from .receivers import DEFAULT_TOA_METHOD, TOA_METHODS, FirstLobeSettings, PreparedLinks, Receiver

#: Version of the dataset schema (``meta.json`` ``schema_version``).
SCHEMA_VERSION = 2
#: Scenarios of the paper.
SCENARIOS = ("static", "semi-dynamic")
#: Bands of the paper (any band of :func:`raytrace.emulation.bands.get_band` works in the library).
PAPER_BANDS = ("c-band", "mmwave")
#: Header of ``toa.csv`` (the shared data contract).
COLUMNS = (
    "epoch",
    "time_s",
    "point",
    "bs",
    "toa_s",
    "x_true",
    "y_true",
    "z_true",
    "distance_m",
    "los",
    "first_kind",
    "snr_db",
    "peak_ratio_db",
    "lobe_width",
    "lobe_kind",
    "tx_offset_s",
    "clock_offset_s",
)
#: Sub-directories written by ``--all``.
ALL_DATASETS = tuple((s, b) for s in SCENARIOS for b in PAPER_BANDS)


# --------------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DatasetConfig:
    """Everything that defines a dataset besides the scene.

    Attributes
    ----------
    scenario : "static" or "semi-dynamic"
    band : str, band name (``c-band``, ``mmwave`` or a user band)
    duration_s : float, seconds of emulation (the paper: 60 s)
    rate_hz : float, snapshots (epochs) per second
    seed : int
    toa_method : ToA estimator, one of :data:`raytrace.emulation.receivers.TOA_METHODS`:
        "first-lobe" (default, the realistic receiver), "first-path" (ideal, the paper's eq. 3
        model), "peak" or "leading-edge"
    noise : bool, estimation noise on (False: no noise; ``first-path`` gives exact delays)
    delta_s : float, seconds between two base stations' transmissions
    clock_offset_max_s : float, device clock offsets are uniform in [0, this)
    budget : LinkBudget
    pulse : PulseShape
    first_lobe : FirstLobeSettings, settings of the first-lobe receiver
    trace : TraceConfig, the tracer limits
    clearance_m : float, forklift underside above the floor
    """

    scenario: str
    band: str
    duration_s: float = 60.0
    rate_hz: float = 10.0
    seed: int = 1
    toa_method: str = DEFAULT_TOA_METHOD
    noise: bool = True
    delta_s: float = DELTA_S
    clock_offset_max_s: float = CLOCK_OFFSET_MAX_S
    budget: LinkBudget = field(default_factory=LinkBudget)
    pulse: PulseShape = field(default_factory=PulseShape)
    first_lobe: FirstLobeSettings = field(default_factory=FirstLobeSettings)
    trace: TraceConfig = field(default_factory=TraceConfig)
    clearance_m: float = FORKLIFT_CLEARANCE_M

    def validate(self) -> Band:
        """Check the settings (one-line :class:`HallrayError`); return the band."""
        if self.scenario not in SCENARIOS:
            raise HallrayError(f"unknown scenario {self.scenario!r}; use {' or '.join(SCENARIOS)}")
        band = get_band(self.band)
        if self.toa_method not in TOA_METHODS:
            raise HallrayError(
                f"unknown ToA method {self.toa_method!r}; use one of {', '.join(TOA_METHODS)}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise HallrayError(f"seed must be an integer, got {self.seed!r}")
        if self.seed < 0:
            raise HallrayError(f"seed must be >= 0, got {self.seed}")
        snapshot_times(self.duration_s, self.rate_hz)  # raises on a bad duration or rate
        for name in ("delta_s", "clock_offset_max_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise HallrayError(f"{name} must be a finite number >= 0, got {v!r}")
        return band

    @property
    def times_s(self) -> np.ndarray:
        """Epoch times, seconds."""
        return snapshot_times(self.duration_s, self.rate_hz)

    def receiver(self) -> Receiver:
        """The dataset's ToA receiver (checks the settings first)."""
        band = self.validate()
        return Receiver(self.toa_method, band, budget=self.budget, pulse=self.pulse,
                        first_lobe=self.first_lobe)  # fmt: skip

    def model(self) -> ToaModel:
        """The measurement model of this dataset (receiver, seed, schedule, clock offsets)."""
        return ToaModel(
            self.receiver(), int(self.seed), bool(self.noise), self.delta_s,
            self.clock_offset_max_s,
        )  # fmt: skip


# --------------------------------------------------------------------------------------------
# files of one dataset
# --------------------------------------------------------------------------------------------


def _num(values: np.ndarray, fmt: str) -> list[str]:
    """CSV texts of floats in ``fmt``: empty for NaN."""
    return [format(v, fmt) if math.isfinite(v) else "" for v in values.ravel().tolist()]


def _toa_csv(inputs: SceneMetadata, times_s: np.ndarray, m: Measurements) -> str:
    """``toa.csv``: header and one row per (epoch, point, base station), in that order.

    Floats are written with ``repr`` (shortest round trip), SNR and lobe figures with fixed
    decimals; an undetected link has an empty ``toa_s``.
    """
    return "".join(_toa_csv_blocks(inputs, times_s, m))


#: Epochs formatted per block of ``toa.csv`` text (memory: one block, not the whole file).
CSV_BLOCK_EPOCHS = 100


def _toa_csv_blocks(inputs: SceneMetadata, times_s: np.ndarray, m: Measurements) -> Iterator[str]:
    """The text of ``toa.csv`` (:func:`_toa_csv`) in blocks of :data:`CSV_BLOCK_EPOCHS` epochs,
    so that a writer streams it."""
    n_e, n_p, n_b = m.toa_s.shape
    yield ",".join(COLUMNS) + "\n"
    # the texts of what repeats (per point, base station, link), then one join a row
    point_xyz = [",".join(map(repr, p)) for p in inputs.point_xyz.tolist()]
    dist = np.linalg.norm(inputs.bs_xyz[None, :, :] - inputs.point_xyz[:, None, :], axis=2)
    dist_txt = [[repr(d) for d in row] for row in dist.tolist()]
    tx_txt = [repr(t) for t in m.tx_offset_s.tolist()]
    for e0 in range(0, n_e, CSV_BLOCK_EPOCHS):
        sl = slice(e0, min(n_e, e0 + CSV_BLOCK_EPOCHS))
        ep = m.epochs[sl]
        epoch = [f"{e},{t!r}" for e, t in zip(ep.tolist(), times_s[ep].tolist())]
        clock_txt = [[repr(c) for c in row] for row in m.clock_offset_s[sl].tolist()]
        det = m.detected[sl].ravel().tolist()
        toa = [repr(t) if d else "" for t, d in zip(m.toa_s[sl].ravel().tolist(), det)]
        los = m.los[sl].ravel().astype(np.int64).tolist()
        snr, ratio = _num(m.snr_db[sl], ".3f"), _num(m.peak_ratio_db[sl], ".3f")
        width = _num(m.lobe_width[sl], ".4f")
        first, lobe = m.first_kind[sl].ravel().tolist(), m.lobe_kind[sl].ravel().tolist()
        lines = []
        i = 0
        for e in range(len(epoch)):  # formatting only; the numbers are in the arrays
            for p in range(n_p):
                for b in range(n_b):
                    lines.append(
                        f"{epoch[e]},{inputs.point_names[p]},{inputs.bs_names[b]},{toa[i]},"
                        f"{point_xyz[p]},{dist_txt[p][b]},{los[i]},{first[i]},{snr[i]},"
                        f"{ratio[i]},{width[i]},{lobe[i]},{tx_txt[b]},{clock_txt[e][p]}\n"
                    )
                    i += 1
        yield "".join(lines)


def _summary(m: Measurements) -> dict[str, Any]:
    """``meta.json`` ``summary``: rows and the detected / LoS / first-path LoS fractions."""
    rows, det, los, first_los = (int(v) for v in m.counts())
    return {
        "rows": rows,
        "detected_fraction": det / rows if rows else 0.0,
        "los_fraction": los / rows if rows else 0.0,
        "first_path_los_fraction": first_los / rows if rows else 0.0,
    }


def _hall_width_depth(block: Mapping[str, Any]) -> tuple[float, float] | None:
    """Width (x) and depth (y) of ``hall.size`` in the scene metadata, metres, if stated."""
    hall = block.get("hall") if isinstance(block, Mapping) else None
    try:
        w, d = (float(v) for v in hall["size"][:2])  # type: ignore[index]
    except (TypeError, KeyError, ValueError, IndexError):
        return None
    return w, d


def _hall_xy(block: Mapping[str, Any], scene: Scene) -> list[list[float]]:
    """``meta.json`` ``hall_xy``: the hall interior from the metadata, else the scene bounds."""
    wd = _hall_width_depth(block)
    if wd is not None:
        return [[0.0, 0.0], [wd[0], wd[1]]]
    lo, hi = scene.bounds
    return [[float(lo[0]), float(lo[1])], [float(hi[0]), float(hi[1])]]


def service_area(scene: Scene, meta: Mapping[str, Any]) -> dict[str, Any] | None:
    """The dataset's service area: where a device can be, as positioning bounds its fixes.

    The scene's floor outline inside its walls (:meth:`Scene.floor_outline`); for a scene without
    a floor, the hall size of its metadata; otherwise None.
    """
    ring = scene.floor_outline()
    if ring is not None:
        src = "floor outline of the scene inside its walls"
        return {"polygon": [[float(x), float(y)] for x, y in ring], "source": src}
    wd = _hall_width_depth(meta)
    if wd is None:
        return None
    w, d = wd
    return {"polygon": [[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]], "source": "hall size"}


def _obstacles_2d(meta: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The scene's obstacle footprints, each with a ``polygon`` [[x, y], ...] (the positioning
    package's plots read that key) besides the scene metadata's own ``xy``."""
    out = []
    for o in meta.get("obstacles_2d") or []:
        if isinstance(o, Mapping) and "xy" in o:
            out.append({**o, "polygon": o["xy"]})
    return out


def _meta(
    cfg: DatasetConfig,
    band: Band,
    scene: Scene,
    inputs: SceneMetadata,
    m: Measurements,
    scene_name: str,
) -> dict[str, Any]:
    """``meta.json``: every parameter that produced the dataset (schema in docs/dataset.md)."""
    from ..core.version import __version__

    routes = (
        [dataclasses.asdict(r) for r in inputs.routes] if cfg.scenario == "semi-dynamic" else []
    )
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario": cfg.scenario,
        "band": band.name,
        "band_parameters": {
            "center_frequency_hz": band.center_frequency_hz,
            "bandwidth_hz": band.bandwidth_hz,
            "subcarrier_spacing_hz": band.subcarrier_spacing_hz,
        },
        "seed": int(cfg.seed),
        "version": __version__,
        "scene": scene_name,
        "scene_sha256": scene.content_hash(),
        "duration_s": float(cfg.duration_s),
        "rate_hz": float(cfg.rate_hz),
        "n_epochs": len(m.epochs),
        "epoch_time_s": "epoch / rate_hz",
        "toa_method": cfg.toa_method,
        "noise": bool(cfg.noise),
        "delta_s": float(cfg.delta_s),
        "schedule_s": {n: float(o) for n, o in zip(inputs.bs_names, m.tx_offset_s)},
        "clock_offset": {
            "distribution": "uniform",
            "low_s": 0.0,
            "high_s": float(cfg.clock_offset_max_s),
            "per": "epoch and point",
        },
        "random_streams": "numpy SeedSequence([seed, epoch]).spawn(2): clock offsets, noise",
        "toa_model": "toa_s = tx_offset_s + clock_offset_s + estimated propagation delay",
        "link_budget": dataclasses.asdict(cfg.budget),
        "pulse": dataclasses.asdict(cfg.pulse),
        "first_lobe": dataclasses.asdict(cfg.first_lobe),
        "trace": dataclasses.asdict(cfg.trace),
        "forklifts": {"clearance_m": float(cfg.clearance_m), "routes": routes},
        "base_stations": [
            {"name": n, "xyz": [float(v) for v in p]}
            for n, p in zip(inputs.bs_names, inputs.bs_xyz)
        ],
        "points": [
            {"name": n, "xyz": [float(v) for v in p]}
            for n, p in zip(inputs.point_names, inputs.point_xyz)
        ],
        "hall_xy": _hall_xy(inputs.block, scene),
        "service_area": service_area(scene, inputs.block),
        "area_of_interest": inputs.block.get("area_of_interest"),
        "obstacles_2d": _obstacles_2d(inputs.block),
        "columns": list(COLUMNS),
        "summary": _summary(m),
    }


def _forklift_csv(fleet: Fleet, times: np.ndarray) -> str:
    lines = ["epoch,time_s,forklift,x,y,z,heading_rad\n"]
    for e, t in enumerate(times):
        centre, yaw = fleet.poses(float(t))
        for name, c, h in zip(fleet.names, centre, yaw):
            lines.append(
                f"{e},{float(t)!r},{name},{float(c[0])!r},{float(c[1])!r},{float(c[2])!r},"
                f"{float(h)!r}\n"
            )
    return "".join(lines)


def _scene_name(scene: Scene) -> str:
    """``meta.json`` ``scene``: the scene file's name."""
    return Path(scene.source).name or "scene"


def dataset_files(
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    inputs: SceneMetadata | None = None,
    fleet: Fleet | None = None,
) -> dict[str, str]:
    """The files of one dataset: file name -> text.

    Parameters
    ----------
    scene : Scene, with base stations and points in its metadata (their order is the rows')
    cfg : DatasetConfig
    measured : Measurements of every epoch of ``cfg`` (0 .. n - 1, in order), made by
        ``cfg.model()`` on the scene's paths: (n_epochs, points, base stations)
    inputs : SceneMetadata of the scene, optional (read from the scene otherwise)
    fleet : Fleet, the forklifts (semi-dynamic only: ``forklifts.csv``)

    Returns
    -------
    dict: ``toa.csv``, ``meta.json`` and, for semi-dynamic, ``forklifts.csv``
    """
    parts = _dataset_parts(scene, cfg, measured, inputs=inputs, fleet=fleet)
    return {k: v if isinstance(v, str) else "".join(v) for k, v in parts.items()}


def _dataset_parts(
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    inputs: SceneMetadata | None = None,
    fleet: Fleet | None = None,
) -> dict[str, str | Iterable[str]]:
    """:func:`dataset_files` with ``toa.csv`` as an iterable of text blocks (streamed)."""
    band = cfg.validate()
    inputs = inputs if inputs is not None else SceneMetadata.from_scene(scene, require=True)
    times = cfg.times_s
    shape = (len(times), len(inputs.point_names), len(inputs.bs_names))
    if measured.toa_s.shape != shape:
        raise HallrayError(
            f"measurements of shape {measured.toa_s.shape} do not fit the dataset's "
            f"(epochs, points, base stations) = {shape}"
        )
    if not np.array_equal(measured.epochs, np.arange(len(times))):
        raise HallrayError("a dataset's measurements are of its epochs 0 .. n - 1, in order")
    if (cfg.scenario == "semi-dynamic") != (fleet is not None):
        raise HallrayError("a semi-dynamic dataset needs its forklift fleet, a static one none")
    meta = _meta(cfg, band, scene, inputs, measured, _scene_name(scene))
    files = {
        "toa.csv": _toa_csv_blocks(inputs, times, measured),
        "meta.json": json.dumps(meta, indent=1, sort_keys=False) + "\n",
    }
    if fleet is not None:
        files["forklifts.csv"] = _forklift_csv(fleet, times)
    return files


def _write_files(directory: Path, files: Mapping[str, str | Iterable[str]]) -> None:
    """Write each file's text (or text blocks, streamed) into ``directory``, inside a staged
    directory (whole or not at all)."""
    directory.mkdir(exist_ok=True)
    for name, text in files.items():
        with (directory / name).open("w", encoding="utf-8", newline="") as fh:
            for block in [text] if isinstance(text, str) else text:
                fh.write(block)


def write_dataset(
    out_dir: str | os.PathLike[str],
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    fleet: Fleet | None = None,
    force: bool = False,
) -> Path:
    """Write one dataset from measurements already made (:func:`dataset_files`) to ``out_dir``.

    The files are those :func:`make_dataset` writes for the same scene and configuration (the
    same formatting code). Written to a temporary directory beside ``out_dir`` and renamed when
    complete; ``force`` replaces a non-empty ``out_dir``.

    Returns
    -------
    Path, the dataset directory
    """
    files = dataset_files(scene, cfg, measured, fleet=fleet)
    out = Path(out_dir)
    tmp = _prepare_output(out, force)
    try:
        _write_files(tmp, files)
        _commit_output(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _prepare_output(out: Path, force: bool) -> Path:
    """Check the output directory and create the temporary one beside it."""
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise HallrayError(f"output directory {out} is not empty (use --force to replace it)")
    parent = out.resolve().parent
    if not parent.is_dir():
        raise HallrayError(f"parent directory of {out} does not exist")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    umask = os.umask(0o022)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700: a dataset is for others to read too
    return tmp


def _commit_output(tmp: Path, out: Path) -> None:
    """Move the finished temporary directory to ``out`` (replacing it)."""
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=tmp.parent))
        os.rename(out, old / "previous")
        os.rename(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, out)


# --------------------------------------------------------------------------------------------
# the epochs of one scenario (in-process or in worker processes)
# --------------------------------------------------------------------------------------------

_WORKER: dict[str, Any] = {}


@dataclass
class _Group:
    """Datasets of one scenario (one measurement model each) computed in one pass over the
    epochs from one trace per snapshot."""

    scenario: str
    models: list[ToaModel]
    times_s: np.ndarray
    tracer: SnapshotTracer
    #: index of each dataset's carrier in the tracer's frequencies (receivers share a trace)
    freq_index: list[int]
    #: static scene: each dataset's receiver work on its paths, done once
    prepared: list[PreparedLinks] | None = None

    def paths_of(self, paths: Sequence[Paths], k: int) -> Paths:
        """The paths of dataset ``k`` among the tracer's per-frequency ``paths``."""
        return paths[self.freq_index[k]]

    @property
    def static(self) -> bool:
        return self.scenario != "semi-dynamic"


def _group_state(g: _Group) -> dict[str, Any]:
    tr = g.tracer
    return {
        "scenario": g.scenario,
        "models": g.models,
        "times_s": g.times_s,
        "scene": dataclasses.replace(tr.scene),  # a copy without the Embree scene and caches
        "tx": tr.tx,
        "rx": tr.rx,
        "routes": tr.fleet.routes,
        "frequencies_hz": tr.frequencies_hz,
        "settings": tr.settings,
        "clearance_m": tr.fleet.clearance_m,
        "static_paths": tr.static_paths,
        "freq_index": g.freq_index,
    }


def _init_worker(state: dict[str, Any]) -> None:
    scene = state["scene"]
    scene.build_embree()
    tracer = SnapshotTracer(
        scene,
        state["tx"],
        state["rx"],
        state["routes"],
        state["frequencies_hz"],
        state["settings"],
        clearance_m=state["clearance_m"],
        static_paths=state["static_paths"],
        threads=1,
    )
    _WORKER["group"] = _Group(
        state["scenario"], state["models"], state["times_s"], tracer, state["freq_index"]
    )


def _run_epochs(g: _Group, epochs: Sequence[int]) -> tuple[list[Measurements], dict]:
    """Measurements of the given epochs for every dataset of the group, and the tracer's stage
    timings of this call."""
    tr = g.tracer
    tr.stats = {}
    if g.static:
        if g.prepared is None:
            g.prepared = [m.prepare(g.paths_of(tr.static_paths, k)) for k, m in enumerate(g.models)]
        out = [
            m.measure(g.paths_of(tr.static_paths, k), epochs, g.prepared[k])
            for k, m in enumerate(g.models)
        ]
        return out, dict(tr.stats)
    parts: list[list[Measurements]] = [[] for _ in g.models]
    for e in epochs:
        paths = tr.paths_at(float(g.times_s[e]))  # one trace of the snapshot for all datasets
        for k, m in enumerate(g.models):
            parts[k].append(m.measure(g.paths_of(paths, k), [e]))
    return [Measurements.concatenate(p) for p in parts], dict(tr.stats)


def _run_chunk(epochs: Sequence[int]) -> tuple[list[Measurements], dict]:
    return _run_epochs(_WORKER["group"], epochs)


def _chunks(n: int, size: int) -> list[list[int]]:
    return [list(range(i, min(n, i + size))) for i in range(0, n, size)]


def _compute_group(
    g: _Group, workers: int, progress: Callable[[int], None] | None
) -> tuple[list[Measurements], dict]:
    """All epochs of a group: the measurements of each dataset, summed stage timings."""
    n = len(g.times_s)
    parts: list[list[Measurements]] = [[] for _ in g.models]
    stats: dict[str, float] = {}

    def collect(res: tuple[list[Measurements], dict], n_done: int) -> None:
        measured, st = res
        for k, m in enumerate(measured):
            parts[k].append(m)
        for key, v in st.items():
            stats[key] = stats.get(key, 0.0) + v
        if progress is not None:
            progress(n_done)

    # static epochs with the first-path or first-lobe receiver cost milliseconds: no processes
    cheap = g.static and all(m.receiver.method in ("first-path", "first-lobe") for m in g.models)
    if workers <= 1 or cheap or n < 2:
        for chunk in _chunks(n, 10):
            collect(_run_epochs(g, chunk), len(chunk))
    else:
        size = max(1, min(25, n // (4 * workers)))
        chunks = _chunks(n, size)
        from ..solver.parallel import process_context, resolve_workers

        workers = resolve_workers(workers, len(chunks))  # never more than the cores, the chunks
        # forks of the preloaded fork server, never of this process: Embree's and the tracer's
        # threads do not survive a fork (raytrace.solver.parallel)
        ctx = process_context((__name__,))
        with ProcessPoolExecutor(
            max_workers=workers,
            mp_context=ctx,
            initializer=_init_worker,
            initargs=(_group_state(g),),
        ) as pool:
            # map keeps the order of the chunks: the files do not depend on the worker count
            for chunk, res in zip(chunks, pool.map(_run_chunk, chunks)):
                collect(res, len(chunk))
    return [Measurements.concatenate(p) for p in parts], stats


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def _dataset_configs(
    datasets: Iterable[tuple[str, str]],
    methods: Sequence[str],
    **settings: Any,
) -> list[DatasetConfig]:
    """One config per requested (scenario, band, receiver), in request order, duplicates
    dropped; each validated (one-line :class:`HallrayError`)."""
    triples = list(dict.fromkeys((str(s), str(b), m) for s, b in datasets for m in methods))
    if not triples:
        raise HallrayError("no dataset requested")
    configs = [
        DatasetConfig(s, b, toa_method=m, **settings)  # type: ignore[arg-type]
        for s, b, m in triples
    ]
    for c in configs:
        c.validate()
    return configs


def _open_scene(scene: str | os.PathLike[str] | Scene) -> Scene:
    return scene if isinstance(scene, Scene) else load_scene(scene)


def _scenario_group(
    scenario: str,
    configs: Sequence[DatasetConfig],
    scene: Scene,
    inputs: SceneMetadata,
    static_cache: dict[float, Paths],
) -> _Group:
    """The tracer and measurement models of one scenario's datasets (the static scene's paths
    per carrier come from ``static_cache`` when another scenario traced them; new ones are
    added to it)."""
    routes = inputs.routes if scenario == "semi-dynamic" else []
    carriers = [get_band(c.band).center_frequency_hz for c in configs]
    freqs = list(dict.fromkeys(carriers))
    known = [static_cache.get(f) for f in freqs]
    tracer = SnapshotTracer(
        scene,
        inputs.bs_xyz,
        inputs.point_xyz,
        routes,
        freqs,
        configs[0].trace,
        clearance_m=configs[0].clearance_m,
        static_paths=None if any(p is None for p in known) else known,
    )
    static_cache.update(zip(freqs, tracer.static_paths))
    times = configs[0].times_s
    tracer.check_clear(times, inputs.bs_names, inputs.point_names)
    models = [c.model() for c in configs]
    return _Group(scenario, models, times, tracer, [freqs.index(f) for f in carriers])


def _measure_with_progress(
    g: _Group, workers: int, progress: bool
) -> tuple[list[Measurements], dict]:
    """:func:`_compute_group`, with a tqdm bar on stderr if ``progress``."""
    if not progress:
        return _compute_group(g, workers, None)
    from tqdm import tqdm

    names = ", ".join(dict.fromkeys(m.receiver.band.name for m in g.models))
    with tqdm(
        total=len(g.times_s), desc=f"{g.scenario} ({names})", unit="epoch", file=sys.stderr
    ) as bar:
        return _compute_group(g, workers, bar.update)


def make_datasets(
    out_dir: str | os.PathLike[str],
    datasets: Iterable[tuple[str, str]],
    *,
    scene: str | os.PathLike[str] | Scene = "hall",
    duration_s: float = 60.0,
    rate_hz: float = 10.0,
    seed: int = 1,
    toa_method: str | Sequence[str] = DEFAULT_TOA_METHOD,
    noise: bool = True,
    workers: int = 1,
    force: bool = False,
    progress: bool = False,
    budget: LinkBudget | None = None,
    first_lobe: FirstLobeSettings | None = None,
    trace_settings: TraceConfig | None = None,
    subdirectories: bool = True,
    staging: bool = True,
) -> list[dict[str, Any]]:
    """Write several ToA datasets, sharing the traces between them.

    All datasets of one scenario are computed in one pass over the epochs (one geometric trace
    per snapshot for all bands). Everything is written to a temporary directory beside
    ``out_dir`` and renamed to ``out_dir`` only when complete.

    Parameters
    ----------
    out_dir : path, the output directory (must not exist or be empty, unless ``force``)
    datasets : (scenario, band) pairs
    scene : scene file, bundled name or Scene; must carry base stations and points (and routes
        for semi-dynamic) in its ``metadata["hallray"]``
    duration_s, rate_hz, seed, noise : see :class:`DatasetConfig`
    toa_method : str or sequence of str, the receiver (:class:`DatasetConfig`); with several, each
        (scenario, band) is written for each receiver from the same traces, the first receiver's
        in ``<scenario>-<band>``, the others' in ``<scenario>-<band>-<receiver>``
    workers : int, processes for the snapshots (the files do not depend on it)
    force : bool, replace a non-empty ``out_dir``
    progress : bool, tqdm progress bars on stderr
    budget : LinkBudget, optional
    first_lobe : FirstLobeSettings, optional, settings of the first-lobe receiver
    trace_settings : TraceConfig, optional, the tracer limits
    subdirectories : bool, each dataset in ``out_dir/<scenario>-<band>`` (True) or, for a
        single dataset, directly in ``out_dir``
    staging : bool, build in a temporary directory and rename it (True), or write straight into
        ``out_dir``, an empty directory the caller stages itself (False: the command-line tools,
        through :mod:`positioning.output`)

    Returns
    -------
    list of dict, one summary per dataset (directory, rows, fractions, timings)
    """
    methods = [toa_method] if isinstance(toa_method, str) else list(dict.fromkeys(toa_method))
    if not methods:
        raise HallrayError("no ToA receiver requested")
    configs = _dataset_configs(
        datasets, methods, duration_s=duration_s, rate_hz=rate_hz, seed=seed, noise=noise,
        budget=budget or LinkBudget(), first_lobe=first_lobe or FirstLobeSettings(),
        trace=trace_settings or TraceConfig(),
    )  # fmt: skip
    if not subdirectories and len(configs) != 1:
        raise HallrayError("several datasets need subdirectories")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise HallrayError(f"workers must be an integer >= 1, got {workers!r}")
    t_start = time.perf_counter()
    sc = _open_scene(scene)
    inputs = SceneMetadata.from_scene(sc, require=True)
    if any(c.scenario == "semi-dynamic" for c in configs) and not inputs.routes:
        raise SceneError("the semi-dynamic scenario needs forklift routes in the scene metadata")
    out = Path(out_dir)
    if staging:
        tmp = _prepare_output(out, force)
    elif not out.is_dir() or any(out.iterdir()):
        raise HallrayError(f"unstaged output {out} must be an empty directory")
    else:
        tmp = out
    committed = False
    summaries: list[dict[str, Any]] = []
    # the static scene's paths per carrier, traced once for both scenarios
    static_cache: dict[float, Paths] = {}
    try:
        for scenario in SCENARIOS:
            group = [c for c in configs if c.scenario == scenario]
            if not group:
                continue
            t0 = time.perf_counter()
            g = _scenario_group(scenario, group, sc, inputs, static_cache)
            t_static = time.perf_counter() - t0
            measured, stats = _measure_with_progress(g, workers, progress)
            fleet = g.tracer.fleet if scenario == "semi-dynamic" else None
            for cfg, m in zip(group, measured):
                name = f"{cfg.scenario}-{get_band(cfg.band).name}"
                if cfg.toa_method != methods[0]:
                    name += f"-{cfg.toa_method}"
                d = tmp / name if subdirectories else tmp
                _write_files(d, _dataset_parts(sc, cfg, m, inputs=inputs, fleet=fleet))
                summaries.append(
                    {
                        "directory": str(out / d.relative_to(tmp)),
                        "scenario": cfg.scenario,
                        "band": get_band(cfg.band).name,
                        "toa_method": cfg.toa_method,
                        "epochs": len(g.times_s),
                        **_summary(m),
                        "static_trace_s": t_static,
                        "group_seconds": time.perf_counter() - t0,
                        "stage_seconds": stats,
                    }
                )
        if staging:
            _commit_output(tmp, out)
        committed = True
    finally:
        if not committed and staging:
            shutil.rmtree(tmp, ignore_errors=True)
    for s in summaries:
        s["total_seconds"] = time.perf_counter() - t_start
    return summaries


def make_dataset(
    out_dir: str | os.PathLike[str],
    scenario: str,
    band: str,
    **kwargs: Any,
) -> dict[str, Any]:
    """Write one ToA dataset (``toa.csv``, ``meta.json``) to ``out_dir``.

    Keyword arguments are those of :func:`make_datasets` (scene, duration_s, rate_hz, seed,
    toa_method, noise, workers, force, progress, budget, trace_settings).

    Returns
    -------
    dict, the dataset's summary: directory, epochs, rows, detected / LoS fractions, timings
    """
    return make_datasets(out_dir, [(scenario, band)], subdirectories=False, **kwargs)[0]
