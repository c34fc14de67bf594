"""ToA datasets: the paper's static and semi-dynamic scenarios in both bands.

A dataset directory holds ``toa.csv`` (one row per epoch, point and base station) and
``meta.json`` (every parameter that produced it); the schema is in ``docs/dataset.md`` and is
read by :mod:`positioning.dataset`. For the semi-dynamic scenario it also holds
``forklifts.csv`` (the forklift poses of every epoch).

Time model: base station k (in the scene's order) transmits its PRS at ``k * delta`` (delta =
10 ms) after the start of each positioning epoch; the device measures the time of arrival with
its own clock, which is off by an unknown ``clock_offset_s`` (one draw per epoch and point, the
same for all base stations of that fix). So a measured ToA is::

    toa_s = tx_offset_s + clock_offset_s + estimated propagation delay

Epochs: one per snapshot of the forklifts (``k / rate`` s, k = 0 .. duration * rate - 1) for
``semi-dynamic``; for ``static`` the scene never changes, so it is traced once and every epoch
draws its own clock offsets and estimation noise (the same number of epochs, so that the
statistics are comparable).

Reproducibility: the random numbers of epoch ``e`` come from
``numpy.random.SeedSequence([seed, e]).spawn(2)`` (clock offsets, then estimator noise), so the
files depend only on the inputs and the seed, not on the number of worker processes.
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
from collections.abc import Callable, Iterable, Mapping, Sequence
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
from ..solver.incremental import SnapshotTracer
from ..solver.paths import Paths
from .bands import Band, get_band
from .channel import LinkBudget, PulseShape
from .receivers import (
    DEFAULT_TOA_METHOD,
    TOA_METHODS,
    FirstLobeSettings,
    PreparedLinks,
    Receiver,
)

#: Version of the dataset schema (``meta.json`` ``schema_version``).
SCHEMA_VERSION = 2
#: Scenarios of the paper.
SCENARIOS = ("static", "semi-dynamic")
#: Bands of the paper (any band of :func:`raytrace.emulation.bands.get_band` works in the library).
PAPER_BANDS = ("c-band", "mmwave")
#: Period between two base stations' transmissions, s (paper, section II).
DELTA_S = 0.01
#: The device clock offset of a fix is drawn uniformly from [0, CLOCK_OFFSET_MAX_S), s.
CLOCK_OFFSET_MAX_S = 1e-3
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
# paths -> per-link ToA
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinkToA:
    """Per-link ToA of one epoch (L = transmitters x receivers, link = tx * R + rx).

    Attributes
    ----------
    toa_s : (L,) float, seconds, estimated propagation delay (no schedule, no clock offset);
        NaN where not detected
    detected : (L,) bool
    snr_db : (L,) float, dB, SNR before processing gain (measured on the first lobe by
        ``first-lobe``, the first detectable path's otherwise; NaN if none)
    sigma_s : (L,) float, seconds, eq. 3 standard deviation at that SNR (NaN if none)
    first_path : (L,) int, index of the first detectable path into the paths, -1 if none
    first_kind : (L,) str, its interaction sequence ("LoS", "R", "TD", ...; "" if none)
    los : (L,) bool, the link has an unobstructed line-of-sight path (detectable or not)
    peak_ratio_db : (L,) float, dB, ``first-lobe``: first lobe's peak over the strongest (NaN else)
    lobe_width : (L,) float, ``first-lobe``: first lobe's half-amplitude width over an isolated
        pulse's (NaN else)
    lobe_kind : (L,) str, kind of the path that dominates the measured lobe (``first-path``: the
        first path's kind; "" if none or not known)
    """

    toa_s: np.ndarray
    detected: np.ndarray
    snr_db: np.ndarray
    sigma_s: np.ndarray
    first_path: np.ndarray
    first_kind: np.ndarray
    los: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    lobe_kind: np.ndarray


def _kinds(paths: Paths, index: np.ndarray) -> np.ndarray:
    """Kind labels of the paths ``index`` (-1: "")."""
    kind = np.full(index.size, "", dtype=object)
    has = index >= 0
    if has.any():
        kind[has] = paths.select(index[has]).kind_label
    return kind.astype(str)


def prepare_links(paths: Paths, receiver: Receiver) -> PreparedLinks:
    """The receiver's path-only work for ``paths`` (reusable by every epoch of a snapshot)."""
    return receiver.prepare(paths.link, paths.delay_s, paths.gain, paths.n_links)


def emulate_toa(
    paths: Paths,
    band: Band | str,
    *,
    method: str = DEFAULT_TOA_METHOD,
    budget: LinkBudget | None = None,
    pulse: PulseShape | None = None,
    first_lobe: FirstLobeSettings | None = None,
    rng: np.random.Generator | None = None,
    noise: bool = True,
    receiver: Receiver | None = None,
    prepared: PreparedLinks | None = None,
) -> LinkToA:
    """Times of arrival of every link of ``paths`` (:class:`raytrace.emulation.receivers.Receiver`) with
    the first path's kind and the link's line-of-sight flag.

    Parameters
    ----------
    paths : Paths
    band : Band or band name
    method, budget, pulse, first_lobe, rng, noise : as in :func:`raytrace.emulation.receivers.estimate_toa`
    receiver : Receiver, optional, used instead of ``band, method, budget, pulse, first_lobe``
    prepared : PreparedLinks, optional, ``prepare_links(paths, receiver)`` done before (a scene
        that does not change between epochs)

    Returns
    -------
    LinkToA
    """
    rx = receiver or Receiver(method, band, budget=budget, pulse=pulse, first_lobe=first_lobe)
    prep = prepared if prepared is not None else prepare_links(paths, rx)
    est = rx.measure(prep, rng, noise=noise)
    n = paths.n_links
    first = np.asarray(est.first_path, dtype=np.int64)
    los = np.bincount(paths.link[paths.los], minlength=n) > 0
    return LinkToA(
        toa_s=np.asarray(est.toa_s, dtype=float),
        detected=np.asarray(est.detected, dtype=bool),
        snr_db=np.asarray(est.snr_db, dtype=float),
        sigma_s=np.asarray(est.sigma_s, dtype=float),
        first_path=first,
        first_kind=_kinds(paths, first),
        los=los,
        peak_ratio_db=np.asarray(est.peak_ratio_db, dtype=float),
        lobe_width=np.asarray(est.lobe_width, dtype=float),
        lobe_kind=_kinds(paths, np.asarray(est.lobe_path, dtype=np.int64)),
    )


def epoch_rngs(seed: int, epoch: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The two random streams of an epoch: (clock offsets, estimator noise)."""
    a, b = np.random.SeedSequence([int(seed), int(epoch)]).spawn(2)
    return np.random.default_rng(a), np.random.default_rng(b)


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
    toa_method : ToA estimator, one of :data:`raytrace.emulation.receivers.TOA_METHODS`: "first-lobe"
        (default, the realistic receiver), "first-path" (ideal, the paper's eq. 3 model),
        "peak" or "leading-edge"
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


# --------------------------------------------------------------------------------------------
# one epoch -> rows
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Fixed:
    """Per-dataset constants shared by all epochs (picklable, sent to workers)."""

    cfg: DatasetConfig
    band: Band
    bs_names: list[str]
    point_names: list[str]
    bs_xyz: np.ndarray
    point_xyz: np.ndarray

    @property
    def tx_offset_s(self) -> np.ndarray:
        return np.arange(len(self.bs_names)) * self.cfg.delta_s

    def receiver(self) -> Receiver:
        """The dataset's ToA receiver."""
        c = self.cfg
        return Receiver(c.toa_method, self.band, budget=c.budget, pulse=c.pulse,
                        first_lobe=c.first_lobe)  # fmt: skip


def _num(value: float, fmt: str) -> str:
    """CSV text of a float: empty for NaN."""
    return format(float(value), fmt) if math.isfinite(value) else ""


def _epoch_rows(
    fx: _Fixed, epoch: int, t_s: float, paths: Paths, prepared: PreparedLinks | None = None
) -> tuple[str, np.ndarray]:
    """CSV rows of one epoch (point-major, then base station) and its counters
    ``[rows, detected, los, first path LoS]``."""
    clock_rng, noise_rng = epoch_rngs(fx.cfg.seed, epoch)
    n_b, n_p = len(fx.bs_names), len(fx.point_names)
    clock = clock_rng.uniform(0.0, fx.cfg.clock_offset_max_s, n_p) if n_p else np.zeros(0)
    est = emulate_toa(
        paths, fx.band, receiver=fx.receiver(), prepared=prepared, rng=noise_rng,
        noise=fx.cfg.noise,
    )  # fmt: skip
    # link = bs * n_points + point; rows run over points, then base stations
    link = (np.arange(n_b)[None, :] * n_p + np.arange(n_p)[:, None]).reshape(-1)
    b_idx = np.tile(np.arange(n_b), n_p)
    p_idx = np.repeat(np.arange(n_p), n_b)
    tx_off = fx.tx_offset_s[b_idx]
    toa = tx_off + clock[p_idx] + est.toa_s[link]
    dist = np.linalg.norm(fx.bs_xyz[b_idx] - fx.point_xyz[p_idx], axis=1)
    t_txt = repr(float(t_s))
    lines = []
    for i in range(len(link)):  # formatting only: ~100 rows per epoch
        j = link[i]
        p = fx.point_xyz[p_idx[i]]
        det = bool(est.detected[j])
        lines.append(
            f"{epoch},{t_txt},{fx.point_names[p_idx[i]]},{fx.bs_names[b_idx[i]]},"
            f"{repr(float(toa[i])) if det else ''},"
            f"{float(p[0])!r},{float(p[1])!r},{float(p[2])!r},{float(dist[i])!r},"
            f"{int(est.los[j])},{est.first_kind[j]},{_num(est.snr_db[j], '.3f')},"
            f"{_num(est.peak_ratio_db[j], '.3f')},{_num(est.lobe_width[j], '.4f')},"
            f"{est.lobe_kind[j]},{float(tx_off[i])!r},{float(clock[p_idx[i]])!r}\n"
        )
    det = est.detected[link]
    counts = np.array(
        [
            len(link),
            int(det.sum()),
            int(est.los[link].sum()),
            int((det & (est.first_kind[link] == "LoS")).sum()),
        ]
    )
    return "".join(lines), counts


# --------------------------------------------------------------------------------------------
# snapshot work (in-process or in worker processes)
# --------------------------------------------------------------------------------------------

_WORKER: dict[str, Any] = {}


@dataclass
class _Group:
    """Datasets of one scenario (one per band) computed in one pass over the epochs."""

    scenario: str
    fixed: list[_Fixed]
    times_s: np.ndarray
    tracer: SnapshotTracer
    #: index of each dataset's carrier in the tracer's frequencies (receivers share a trace)
    freq_index: list[int] = field(default_factory=list)
    #: static scene: each dataset's receiver work on its paths, done once
    prepared: list[PreparedLinks] | None = None

    def paths_of(self, paths: Sequence[Paths], k: int) -> Paths:
        """The paths of dataset ``k`` among the tracer's per-frequency ``paths``."""
        return paths[self.freq_index[k] if self.freq_index else k]


def _group_state(g: _Group) -> dict[str, Any]:
    tr = g.tracer
    return {
        "scenario": g.scenario,
        "fixed": g.fixed,
        "times_s": g.times_s,
        "scene": dataclasses.replace(tr.scene, _embree=None),
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
    scene._build_embree()
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
        state["scenario"], state["fixed"], state["times_s"], tracer, state["freq_index"]
    )


def _run_epochs(g: _Group, epochs: Sequence[int]) -> tuple[list[list[str]], np.ndarray, dict]:
    """Rows of the given epochs for every dataset of the group.

    Returns
    -------
    text : per dataset, per epoch, the CSV rows
    counts : (n_datasets, 4) int, rows / detected / LoS / first path LoS
    stats : the tracer's stage timings of this call
    """
    tr = g.tracer
    tr.stats = {}
    text: list[list[str]] = [[] for _ in g.fixed]
    counts = np.zeros((len(g.fixed), 4), dtype=np.int64)
    static = g.scenario != "semi-dynamic"
    if static and g.prepared is None:
        g.prepared = [
            prepare_links(g.paths_of(tr.static_paths, k), fx.receiver())
            for k, fx in enumerate(g.fixed)
        ]
    for e in epochs:
        t = float(g.times_s[e])
        paths = tr.static_paths if static else tr.paths_at(t)
        for k, fx in enumerate(g.fixed):
            prep = g.prepared[k] if static and g.prepared is not None else None
            rows, c = _epoch_rows(fx, int(e), t, g.paths_of(paths, k), prep)
            text[k].append(rows)
            counts[k] += c
    return text, counts, dict(tr.stats)


def _run_chunk(epochs: Sequence[int]) -> tuple[list[list[str]], np.ndarray, dict]:
    return _run_epochs(_WORKER["group"], epochs)


def _chunks(n: int, size: int) -> list[list[int]]:
    return [list(range(i, min(n, i + size))) for i in range(0, n, size)]


def _compute_group(
    g: _Group, workers: int, progress: Callable[[int], None] | None
) -> tuple[list[str], np.ndarray, dict]:
    """All epochs of a group: CSV bodies per dataset, counters, summed stage timings."""
    n = len(g.times_s)
    bodies: list[list[str]] = [[] for _ in g.fixed]
    counts = np.zeros((len(g.fixed), 4), dtype=np.int64)
    stats: dict[str, float] = {}

    def collect(res: tuple[list[list[str]], np.ndarray, dict], n_done: int) -> None:
        text, c, st = res
        for k in range(len(g.fixed)):
            bodies[k].extend(text[k])
        counts[:] += c
        for key, v in st.items():
            stats[key] = stats.get(key, 0.0) + v
        if progress is not None:
            progress(n_done)

    # static epochs with the first-path or first-lobe receiver cost milliseconds: no processes
    cheap = g.scenario == "static" and all(
        fx.cfg.toa_method in ("first-path", "first-lobe") for fx in g.fixed
    )
    if workers <= 1 or cheap or n < 2:
        for chunk in _chunks(n, 10):
            collect(_run_epochs(g, chunk), len(chunk))
    else:
        import multiprocessing

        size = max(1, min(25, n // (4 * workers)))
        chunks = _chunks(n, size)
        # spawn, not fork: Embree's and the tracer's threads do not survive a fork
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            max_workers=workers,
            mp_context=ctx,
            initializer=_init_worker,
            initargs=(_group_state(g),),
        ) as pool:
            # map keeps the order of the chunks: the files do not depend on the worker count
            for chunk, res in zip(chunks, pool.map(_run_chunk, chunks)):
                collect(res, len(chunk))
    return ["".join(b) for b in bodies], counts, stats


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------


def _hall_xy(meta: Mapping[str, Any], scene: Scene) -> list[list[float]]:
    hall = meta.get("hall") if isinstance(meta, Mapping) else None
    try:
        size = [float(v) for v in hall["size"]]  # type: ignore[index]
        return [[0.0, 0.0], [size[0], size[1]]]
    except (TypeError, KeyError, ValueError, IndexError):
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
    hall = meta.get("hall") if isinstance(meta, Mapping) else None
    try:
        w, d = (float(v) for v in hall["size"][:2])  # type: ignore[index]
    except (TypeError, KeyError, ValueError, IndexError):
        return None
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
    fx: _Fixed,
    scene: Scene,
    inputs: SceneMetadata,
    times: np.ndarray,
    counts: np.ndarray,
    scene_name: str,
) -> dict[str, Any]:
    from ..core.version import __version__

    cfg = fx.cfg
    rows, det, los, first_los = (int(v) for v in counts)
    routes = (
        [dataclasses.asdict(r) for r in inputs.routes] if cfg.scenario == "semi-dynamic" else []
    )
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario": cfg.scenario,
        "band": fx.band.name,
        "band_parameters": {
            "center_frequency_hz": fx.band.center_frequency_hz,
            "bandwidth_hz": fx.band.bandwidth_hz,
            "subcarrier_spacing_hz": fx.band.subcarrier_spacing_hz,
        },
        "seed": int(cfg.seed),
        "version": __version__,
        "scene": scene_name,
        "scene_sha256": scene.content_hash(),
        "duration_s": float(cfg.duration_s),
        "rate_hz": float(cfg.rate_hz),
        "n_epochs": len(times),
        "epoch_time_s": "epoch / rate_hz",
        "toa_method": cfg.toa_method,
        "noise": bool(cfg.noise),
        "delta_s": float(cfg.delta_s),
        "schedule_s": {n: float(o) for n, o in zip(fx.bs_names, fx.tx_offset_s)},
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
            {"name": n, "xyz": [float(v) for v in p]} for n, p in zip(fx.bs_names, fx.bs_xyz)
        ],
        "points": [
            {"name": n, "xyz": [float(v) for v in p]} for n, p in zip(fx.point_names, fx.point_xyz)
        ],
        "hall_xy": _hall_xy(inputs.block, scene),
        "service_area": service_area(scene, inputs.block),
        "area_of_interest": inputs.block.get("area_of_interest"),
        "obstacles_2d": _obstacles_2d(inputs.block),
        "columns": list(COLUMNS),
        "summary": {
            "rows": rows,
            "detected_fraction": det / rows if rows else 0.0,
            "los_fraction": los / rows if rows else 0.0,
            "first_path_los_fraction": first_los / rows if rows else 0.0,
        },
    }


def _forklift_csv(tracer: SnapshotTracer, times: np.ndarray) -> str:
    lines = ["epoch,time_s,forklift,x,y,z,heading_rad\n"]
    for e, t in enumerate(times):
        centre, yaw = tracer.fleet.poses(float(t))
        for name, c, h in zip(tracer.fleet.names, centre, yaw):
            lines.append(
                f"{e},{float(t)!r},{name},{float(c[0])!r},{float(c[1])!r},{float(c[2])!r},"
                f"{float(h)!r}\n"
            )
    return "".join(lines)


def _prepare_output(out: Path, force: bool) -> Path:
    """Check the output directory and create the temporary one beside it."""
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise HallrayError(f"output directory {out} is not empty (use --force to replace it)")
    parent = out.resolve().parent
    if not parent.is_dir():
        raise HallrayError(f"parent directory of {out} does not exist")
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))


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
# public API
# --------------------------------------------------------------------------------------------


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

    Returns
    -------
    list of dict, one summary per dataset (directory, rows, fractions, timings)
    """
    methods = [toa_method] if isinstance(toa_method, str) else list(dict.fromkeys(toa_method))
    if not methods:
        raise HallrayError("no ToA receiver requested")
    triples = list(dict.fromkeys((str(s), str(b), m) for s, b in datasets for m in methods))
    if not triples:
        raise HallrayError("no dataset requested")
    if not subdirectories and len(triples) != 1:
        raise HallrayError("several datasets need subdirectories")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise HallrayError(f"workers must be an integer >= 1, got {workers!r}")
    budget = budget or LinkBudget()
    settings = trace_settings or TraceConfig()
    lobe = first_lobe or FirstLobeSettings()
    configs = [
        DatasetConfig(
            s,
            b,
            duration_s,
            rate_hz,
            seed,
            m,
            noise,
            budget=budget,
            first_lobe=lobe,
            trace=settings,
        )
        for s, b, m in triples
    ]
    bands = [c.validate() for c in configs]
    t_start = time.perf_counter()
    if isinstance(scene, Scene):
        sc, scene_name = scene, Path(scene.source).name or "scene"
    else:
        sc = load_scene(scene)
        scene_name = Path(sc.source).name
    inputs = SceneMetadata.from_scene(sc, require=True)
    if any(c.scenario == "semi-dynamic" for c in configs) and not inputs.routes:
        raise SceneError("the semi-dynamic scenario needs forklift routes in the scene metadata")
    out = Path(out_dir)
    tmp = _prepare_output(out, force)
    committed = False
    summaries: list[dict[str, Any]] = []
    # the static scene's paths per carrier, traced once for both scenarios
    static_cache: dict[float, Paths] = {}
    try:
        for scenario in SCENARIOS:
            idx = [i for i, c in enumerate(configs) if c.scenario == scenario]
            if not idx:
                continue
            t0 = time.perf_counter()
            times = configs[idx[0]].times_s
            fixed = [
                _Fixed(
                    configs[i],
                    bands[i],
                    inputs.bs_names,
                    inputs.point_names,
                    inputs.bs_xyz,
                    inputs.point_xyz,
                )
                for i in idx
            ]
            routes = inputs.routes if scenario == "semi-dynamic" else []
            carriers = [bands[i].center_frequency_hz for i in idx]
            freqs = list(dict.fromkeys(carriers))
            known = [static_cache.get(f) for f in freqs]
            tracer = SnapshotTracer(
                sc,
                inputs.bs_xyz,
                inputs.point_xyz,
                routes,
                freqs,
                settings,
                static_paths=None if any(p is None for p in known) else known,
            )
            static_cache.update(zip(freqs, tracer.static_paths))
            tracer.check_clear(times, inputs.bs_names, inputs.point_names)
            t_static = time.perf_counter() - t0
            group = _Group(scenario, fixed, times, tracer, [freqs.index(f) for f in carriers])
            bar = None
            if progress:
                from tqdm import tqdm

                names = ", ".join(dict.fromkeys(bands[i].name for i in idx))
                bar = tqdm(
                    total=len(times), desc=f"{scenario} ({names})", unit="epoch", file=sys.stderr
                )
            try:
                bodies, counts, stats = _compute_group(
                    group, workers, bar.update if bar is not None else None
                )
            finally:
                if bar is not None:
                    bar.close()
            for k, i in enumerate(idx):
                cfg = configs[i]
                name = f"{cfg.scenario}-{bands[i].name}"
                if cfg.toa_method != methods[0]:
                    name += f"-{cfg.toa_method}"
                d = tmp / name if subdirectories else tmp
                d.mkdir(exist_ok=True)
                header = ",".join(COLUMNS) + "\n"
                (d / "toa.csv").write_text(header + bodies[k], encoding="utf-8")
                meta = _meta(fixed[k], sc, inputs, times, counts[k], scene_name)
                (d / "meta.json").write_text(
                    json.dumps(meta, indent=1, sort_keys=False) + "\n", encoding="utf-8"
                )
                if scenario == "semi-dynamic":
                    (d / "forklifts.csv").write_text(_forklift_csv(tracer, times), encoding="utf-8")
                summaries.append(
                    {
                        "directory": str(out / d.relative_to(tmp)),
                        "scenario": cfg.scenario,
                        "band": bands[i].name,
                        "toa_method": cfg.toa_method,
                        "epochs": len(times),
                        **meta["summary"],
                        "static_trace_s": t_static,
                        "group_seconds": time.perf_counter() - t0,
                        "stage_seconds": stats,
                    }
                )
        _commit_output(tmp, out)
        committed = True
    finally:
        if not committed:
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
