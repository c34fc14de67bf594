"""The accuracy map of a hall: per grid cell, what the base stations' signals and a positioning
method give a device there, predicted by the twin.

A grid of cells covers the floor (the scene's floor outline inside its walls, else the hall size
of its metadata, else its bounding box), at device height, without the cells inside solids. The
grid's origin is shifted within one step so that every cell centre lies at least ``clearance_m``
(horizontally) from every test point of the scene's metadata: a map used as a fingerprint then
never contains the evaluation points themselves (:func:`grid_offset`).

Per cell and base station the map holds the line-of-sight flag, the first arrival's kind and
excess delay, the receiver's noiseless ToA and, over ``draws`` noise epochs of the one
measurement model (:class:`raytrace.emulation.measurement.ToaModel`), the ToA spread and the
detected fraction; per cell the GDOP of the TDoA fix and, per positioning method
(:func:`positioning.locate`, 2D with the device height known), the p90 and mean 2D error and
the share of draws with a fix. The result is a :class:`positioning.fingerprint.FingerprintMap`
(schema ``hallray-accuracy-map`` v1), written only through :func:`positioning.fingerprint.write_map`.

Work is split into chunks of cells (:func:`raytrace.solver.parallel.receiver_chunks`); each chunk
is traced, measured and positioned on its own, in this process or on worker processes
(:class:`raytrace.solver.parallel.ScenePool`), so memory is bounded by one chunk. A chunk's noise
streams come from ``SeedSequence([seed, first cell of the chunk])``: the map depends on the seed
and the chunk size, not on the number of workers. See docs/accuracy_map.md.
"""

from __future__ import annotations

import csv
import io
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from positioning.twin.fingerprint import FingerprintMap, write_map

from ..core.constants import C0
from ..core.errors import HallrayError
from ..core.fileio import write_atomic
from ..emulation.bands import get_band
from ..emulation.measurement import ToaModel, emulate_toa, prepare_links
from ..emulation.receivers import DEFAULT_TOA_METHOD, TOA_METHODS, Receiver
from ..scene.metadata import SceneMetadata
from ..scene.model import Scene
from ..solver.config import TraceConfig
from ..solver.parallel import (
    CHUNK_LINKS,
    ScenePool,
    receiver_chunks,
    resolve_workers,
)
from ..solver.paths import Paths

#: Most links per chunk of cells (a chunk is traced whole: its candidate arrays in memory at once).
MAX_CHUNK_LINKS = 999
#: The CSV companion of map.npz: its schema name and version (first line of the file).
CSV_SCHEMA, CSV_VERSION = "hallray-accuracy-map-csv", 1
#: Most cells a map may have unless the caller raises it (a 1 m grid of the hall has ~1700).
MAX_CELLS = 20000
DEFAULT_STEP_M = 2.0
DEFAULT_DRAWS = 100
DEFAULT_CLEARANCE_M = 0.25
DEFAULT_SEED = 1
#: The paper's two positioning methods.
DEFAULT_METHODS = ("ls", "irls")
#: Device height when neither the caller nor the scene's test points give one, m.
FALLBACK_HEIGHT_M = 1.5
#: Candidate grid offsets per axis and step searched for the clearance rule.
OFFSET_CANDIDATES = 64
#: Paths stored per cell and base station (schema v2; 0: a v1 map without paths).
DEFAULT_PATHS = 16


@dataclass(frozen=True)
class MapSettings:
    """What an accuracy map is computed with (validated by :meth:`check`).

    Attributes
    ----------
    step_m : float, m, grid step in x and y
    height_m : float or None, m, device height (None: the median height of the scene's test
        points, else :data:`FALLBACK_HEIGHT_M`)
    band : str, band name (:func:`raytrace.emulation.bands.get_band`)
    receiver : str, ToA receiver (:data:`raytrace.emulation.receivers.TOA_METHODS`)
    methods : tuple of str, positioning methods (:func:`positioning.method_names`)
    draws : int, noise epochs per cell (K)
    seed : int, root of the noise streams
    clearance_m : float, m, least horizontal distance of a cell centre from a test point
    max_cells : int, refuse grids with more cells
    trace : TraceConfig, the tracer's limits
    chunk_links : int, links per chunk of cells
    paths : int, strongest paths stored per cell and base station (schema v2, for the twin's
        re-synthesis); 0: a version-1 map without paths
    """

    step_m: float = DEFAULT_STEP_M
    height_m: float | None = None
    band: str = "c-band"
    receiver: str = DEFAULT_TOA_METHOD
    methods: tuple[str, ...] = DEFAULT_METHODS
    draws: int = DEFAULT_DRAWS
    seed: int = DEFAULT_SEED
    clearance_m: float = DEFAULT_CLEARANCE_M
    max_cells: int = MAX_CELLS
    trace: TraceConfig = field(default_factory=TraceConfig)
    chunk_links: int = CHUNK_LINKS
    paths: int = DEFAULT_PATHS

    def check(self) -> None:
        """Raise a one-line :class:`HallrayError` for a bad setting (before any tracing)."""
        from positioning import method_names

        if not (np.isfinite(self.step_m) and self.step_m > 0):
            raise HallrayError(f"--step must be a positive number of metres, got {self.step_m}")
        if not (np.isfinite(self.clearance_m) and self.clearance_m >= 0):
            raise HallrayError(f"--clearance must be >= 0 m, got {self.clearance_m}")
        if self.height_m is not None and not np.isfinite(self.height_m):
            raise HallrayError(f"--height must be a finite number of metres, got {self.height_m}")
        get_band(self.band)  # HallrayError naming the known bands
        if self.receiver not in TOA_METHODS:
            raise HallrayError(
                f"unknown receiver {self.receiver!r}; known: {', '.join(TOA_METHODS)}"
            )
        known = method_names()
        bad = [m for m in self.methods if m not in known]
        if bad or not self.methods:
            raise HallrayError(
                f"unknown positioning method {bad[0] if bad else '(none)'!r}; known: {', '.join(known)}"
            )
        for name, v, lo, hi in (("--draws", self.draws, 1, None),
                                ("--paths", self.paths, 0, None),
                                ("--max-cells", self.max_cells, 1, None),
                                ("chunk_links", self.chunk_links, 1, MAX_CHUNK_LINKS)):  # fmt: skip
            if (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo
                    or (hi is not None and v > hi)):  # fmt: skip
                raise HallrayError(f"{name} must be an integer in [{lo}, {hi or 'inf'}], got {v!r}")


# --------------------------------------------------------------------------------------------
# the grid
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MapGrid:
    """The cells of a map.

    Attributes
    ----------
    cell_xyz : (N, 3) float, m, cell centres (z = device height)
    ij : (N, 2) int, lattice indices: ``cell_xy = origin_xy + ij * step_m``
    origin_xy : (2,) float, m, centre of lattice cell (0, 0)
    step_m : float, m
    shape : (2,) int, lattice size in x and y
    area_xy : (K, 2) float, m, polygon the cells lie in
    test_names : list of str; test_xyz : (P, 3) float, m, the scene's test points
    test_distance_m : (P,) float, m, horizontal distance of each test point to its nearest cell
    """

    cell_xyz: np.ndarray
    ij: np.ndarray
    origin_xy: np.ndarray
    step_m: float
    shape: tuple[int, int]
    area_xy: np.ndarray
    test_names: list[str]
    test_xyz: np.ndarray
    test_distance_m: np.ndarray

    def raster(self, values: np.ndarray) -> np.ndarray:
        """(nx, ny) float: per-cell ``values`` (N,) on the lattice, NaN where there is no cell."""
        out = np.full(self.shape, np.nan)
        out[self.ij[:, 0], self.ij[:, 1]] = values
        return out


def area_polygon(scene: Scene, block: dict[str, Any]) -> np.ndarray:
    """(K, 2) float, m: where cells may lie (the dataset's service area, else the bounding box)."""
    from ..emulation.dataset import service_area

    area = service_area(scene, block)
    if area is not None:
        return np.asarray(area["polygon"], dtype=float)
    (x0, y0, _), (x1, y1, _) = scene.bounds
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def lattice_distance(points_xy: np.ndarray, offset_xy: np.ndarray, step_m: float) -> np.ndarray:
    """(..., P) float, m: horizontal distance of each point to the nearest node of the infinite
    lattice ``offset_xy + step_m * Z^2`` (``offset_xy`` (..., 2) broadcasts over candidates)."""
    d = np.mod(points_xy - offset_xy[..., None, :], step_m)
    d = np.minimum(d, step_m - d)
    return np.hypot(d[..., 0], d[..., 1])


def grid_offset(
    lo_xy: np.ndarray, step_m: float, test_xy: np.ndarray, clearance_m: float
) -> np.ndarray:
    """(2,) float, m: the offset of the first cell centre from ``lo_xy`` in ``[0, step)^2``.

    Among :data:`OFFSET_CANDIDATES`^2 offsets, the one closest to the centred lattice (offset
    ``step / 2``: cells that tile the area from its corner) whose every node is at least
    ``clearance_m`` from every test point. Raises :class:`HallrayError` when none is.
    """
    half = 0.5 * step_m
    if len(test_xy) == 0:
        return np.array([half, half])
    u = np.arange(OFFSET_CANDIDATES) * (step_m / OFFSET_CANDIDATES)
    cand = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    cand = cand[np.argsort(np.hypot(*(cand - half).T), kind="stable")]
    dist = lattice_distance(np.asarray(test_xy)[:, :2], np.asarray(lo_xy) + cand, step_m)
    ok = dist.min(axis=1) >= clearance_m
    if not ok.any():
        raise HallrayError(
            f"no grid origin keeps every cell {clearance_m:g} m from the test points with "
            f"--step {step_m:g} m (largest possible: {dist.min(axis=1).max():.3f} m); lower "
            "--clearance or change --step"
        )
    return cand[int(np.argmax(ok))]


def _height_range(scene: Scene, block: dict[str, Any]) -> tuple[float, float]:
    """(floor, ceiling) heights of the hall, m."""
    from ..halls.scan import floor_level

    # a scene without a floor (floor_outline None) is open below: its bottom is the floor
    floor = floor_level(scene) if scene.floor_outline() is not None else float(scene.bounds[0, 2])
    top = float(scene.bounds[1, 2])
    size = SceneMetadata.from_metadata({"hallray": block}).hall_size
    if size is not None:
        top = min(top, floor + size[2])
    return floor, top


def device_height(scene: Scene, settings: MapSettings, test_xyz: np.ndarray) -> float:
    """The map's device height, m, checked against the hall's floor and ceiling."""
    block = SceneMetadata.from_scene(scene).block
    h = settings.height_m
    if h is None:
        h = float(np.median(test_xyz[:, 2])) if len(test_xyz) else FALLBACK_HEIGHT_M
    floor, top = _height_range(scene, block)
    if not floor < h < top:
        raise HallrayError(
            f"--height {h:g} m is outside the hall (floor {floor:.2f} m, ceiling {top:.2f} m)"
        )
    return float(h)


def make_grid(
    scene: Scene,
    settings: MapSettings,
    test_names: Sequence[str],
    test_xyz: np.ndarray,
    area_xy: np.ndarray | None = None,
) -> MapGrid:
    """The cells: a lattice over the area at device height, outside solids (module docstring).

    Raises :class:`HallrayError` when the step gives no cell or more than ``max_cells``.
    """
    import shapely

    block = SceneMetadata.from_scene(scene).block
    area = area_polygon(scene, block) if area_xy is None else np.asarray(area_xy, dtype=float)
    h = device_height(scene, settings, test_xyz)
    step = float(settings.step_m)
    lo, hi = area.min(axis=0), area.max(axis=0)
    n_lattice = np.floor((hi - lo) / step).astype(np.int64) + 1
    if int(np.prod(n_lattice.astype(float))) > 4 * settings.max_cells:  # before allocating it
        raise HallrayError(
            f"--step {step:g} m gives about {int(np.prod(n_lattice.astype(float)))} cells, more "
            f"than the limit of {settings.max_cells} (raise --step or --max-cells)"
        )
    origin = lo + grid_offset(lo, step, test_xyz, settings.clearance_m)
    nx, ny = (int(n) for n in np.floor((hi - origin) / step).astype(np.int64) + 1)
    ij = np.stack(np.meshgrid(np.arange(max(nx, 0)), np.arange(max(ny, 0)), indexing="ij"),
                  axis=-1).reshape(-1, 2)  # fmt: skip
    xy = origin + ij * step
    poly = shapely.Polygon(area)
    keep = shapely.contains_xy(poly, xy[:, 0], xy[:, 1]) if len(xy) else np.zeros(0, bool)
    ij, xy = ij[keep], xy[keep]
    xyz = np.column_stack([xy, np.full(len(xy), h)])
    if len(xyz):
        free = scene.inside_solid(xyz) < 0
        ij, xyz = ij[free], xyz[free]
    if len(xyz) == 0:
        raise HallrayError(f"--step {step:g} m at height {h:g} m gives no cell on the floor")
    if len(xyz) > settings.max_cells:
        raise HallrayError(
            f"--step {step:g} m gives {len(xyz)} cells, more than the limit of "
            f"{settings.max_cells} (raise --step or --max-cells)"
        )
    test_xyz = np.asarray(test_xyz, dtype=float).reshape(-1, 3)
    dist = (np.hypot(*(test_xyz[:, None, :2] - xyz[None, :, :2]).transpose(2, 0, 1)).min(axis=1)
            if len(test_xyz) else np.zeros(0))  # fmt: skip
    return MapGrid(xyz, ij, origin, step, (max(nx, 1), max(ny, 1)), area, list(test_names),
                   test_xyz, dist)  # fmt: skip


# --------------------------------------------------------------------------------------------
# per-cell quantities
# --------------------------------------------------------------------------------------------


def gdop_2d(cell_xyz: np.ndarray, bs_xyz: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Horizontal GDOP of the TDoA fix with the device height known, per cell.

    The ToAs ``t_b = |p - b| / c + offset`` have the unknowns (x, y, offset); with the Jacobian
    rows ``h_b = [(p - b)_x / |p - b|, (p - b)_y / |p - b|, 1]`` of the used base stations,
    ``GDOP = sqrt(trace of the (x, y) block of (H^T H)^-1)``: the RMS 2D error per metre of
    i.i.d. range noise (c times the ToA standard deviation). Eliminating the offset is the same
    as TDoA with a full difference covariance.

    Parameters
    ----------
    cell_xyz : (N, 3) float, m
    bs_xyz : (B, 3) float, m
    use : (N, B) bool, optional, base stations received at each cell (default all)

    Returns
    -------
    (N,) float, dimensionless; NaN with fewer than 3 base stations or a singular geometry
    """
    d = np.asarray(cell_xyz, float)[:, None, :] - np.asarray(bs_xyz, float)[None, :, :]
    r = np.linalg.norm(d, axis=2)
    rows = np.concatenate([d[:, :, :2] / r[:, :, None], np.ones(r.shape + (1,))], axis=2)
    w = np.ones(r.shape) if use is None else np.asarray(use, dtype=float)
    g = np.einsum("nb,nbi,nbj->nij", w, rows, rows)
    out = np.full(len(g), np.nan)
    ok = w.sum(axis=1) >= 3
    if ok.any():
        cond = np.linalg.cond(g[ok])
        sub = np.flatnonzero(ok)[cond < 1e12]
        if len(sub):
            inv = np.linalg.inv(g[sub])
            out[sub] = np.sqrt(inv[:, 0, 0] + inv[:, 1, 1])
    return out


def _excess_m(paths: Paths, first: np.ndarray) -> np.ndarray:
    """(L,) float, m: first path's delay x c minus the straight distance (NaN without one)."""
    n_rx = len(paths.rx)
    link = np.arange(paths.n_links)
    dist = np.linalg.norm(paths.tx[link // n_rx] - paths.rx[link % n_rx], axis=1)
    out = np.full(paths.n_links, np.nan)
    has = first >= 0
    out[has] = C0 * paths.delay_s[first[has]] - dist[has]
    return out


def last_segment_dirs(paths: Paths) -> np.ndarray:
    """(P, 3) float: unit vector of each path's last segment, from its last interaction (or the
    transmitter) towards the receiver (the gradient of its length in the receiver position)."""
    n_int = (paths.interaction != 0).sum(axis=1)
    start = paths.tx[paths.tx_index].copy()
    idx = np.flatnonzero(n_int > 0)
    start[idx] = paths.points[idx, n_int[idx] - 1]
    d = paths.rx[paths.rx_index] - start
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def wave_radius(paths: Paths) -> np.ndarray:
    """(P,) float, m: radius of each path's wavefront at the receiver: the unfolded length (its
    image source) for line of sight, reflections and penetrations; the distance from the last
    diffraction point for a diffracted path (its edge source)."""
    from ..solver.paths import DIFFRACTION

    out = C0 * paths.delay_s
    dif = paths.interaction == DIFFRACTION
    rows = np.flatnonzero(dif.any(axis=1))
    if rows.size:
        last = dif.shape[1] - 1 - np.argmax(dif[rows, ::-1], axis=1)
        out[rows] = np.linalg.norm(paths.rx[paths.rx_index[rows]] - paths.points[rows, last], axis=1)
    return out


def path_table(paths: Paths, k: int) -> dict[str, np.ndarray]:
    """The ``k`` strongest paths of every link as the schema-v2 arrays (n cells, B, k).

    Links are ``tx * n + rx`` (base stations are the transmitters, cells the receivers); slots
    without a path have delay NaN, gain 0, direction NaN and radius NaN.
    """
    n_b, n_c = len(paths.tx), len(paths.rx)
    out = {
        "path_delay_s": np.full((n_b, n_c, k), np.nan),
        "path_gain": np.zeros((n_b, n_c, k), dtype=complex),
        "path_dir": np.full((n_b, n_c, k, 3), np.nan),
        "path_radius_m": np.full((n_b, n_c, k), np.nan),
    }
    if paths.n_paths and k > 0:
        order = np.lexsort((-np.abs(paths.gain), paths.link))
        link = paths.link[order]
        rank = np.arange(order.size) - np.searchsorted(link, link, side="left")
        sel = order[rank < k]
        rank = rank[rank < k]
        b, c = paths.tx_index[sel], paths.rx_index[sel]
        out["path_delay_s"][b, c, rank] = paths.delay_s[sel]
        out["path_gain"][b, c, rank] = paths.gain[sel]
        out["path_dir"][b, c, rank] = last_segment_dirs(paths.select(sel))
        out["path_radius_m"][b, c, rank] = wave_radius(paths.select(sel))
    return {key: np.swapaxes(v, 0, 1) for key, v in out.items()}


def receiver_model_meta(receiver: Receiver) -> dict[str, Any]:
    """The settings the twin's copy of the noiseless first-lobe receiver
    (:class:`positioning.lobe.LobeReceiver`) needs, as the map's ``meta["receiver_model"]``."""
    from ..emulation import receivers as rx_mod
    from ..emulation.receivers import cfar_factor

    band, budget, pulse, fl = receiver.band, receiver.budget, receiver.pulse, receiver.first_lobe
    return {
        "frequency_hz": float(band.center_frequency_hz),
        "period_s": float(pulse.period_s(band)),
        "roll_off": float(pulse.roll_off),
        "oversampling": int(pulse.oversampling),
        "span": int(pulse.span),
        "noise_std": float(budget.correlator_noise_std(band, pulse)),
        "alpha": float(cfar_factor(budget.false_alarm_probability, fl.cfar_cells)),
        "rho": float(fl.rho),
        "negligible_db": float(rx_mod.NEGLIGIBLE_DB),
        "min_crossing": float(rx_mod.MIN_CROSSING),
        "sure_crossing": float(rx_mod.SURE_CROSSING),
        "post_t": int(rx_mod.POST_T),
        "top_paths": int(rx_mod.TOP_PATHS),
    }


def stored_paths(settings: MapSettings) -> int:
    """Paths stored per link: ``settings.paths`` for the first-lobe receiver (the one the twin's
    re-synthesis models), 0 for the others."""
    return int(settings.paths) if settings.receiver == "first-lobe" else 0


def chunk_seed(seed: int, first_cell: int) -> int:
    """Seed of the noise streams of the chunk starting at ``first_cell`` (module docstring)."""
    return int(np.random.SeedSequence([int(seed), int(first_cell)]).generate_state(1)[0])


def measure_cells(
    paths: Paths, receiver: Receiver, seed: int, draws: int, methods: Sequence[str],
    n_paths: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Per-cell quantities of a chunk: the paths of B base stations (tx) to n cells (rx).

    Returns
    -------
    dict with ``los, first_kind, excess_m, toa_s, toa_std_s, detected_fraction`` (n, B),
    ``gdop`` (n,), ``err_p90_m, err_mean_m, availability`` (M, n), with ``n_paths > 0`` the
    :func:`path_table` arrays, and ``time_s`` (dict)
    """
    from positioning import locate

    t0 = time.perf_counter()
    n_b, n_c = len(paths.tx), len(paths.rx)
    prep = prepare_links(paths, receiver)
    clean = emulate_toa(paths, receiver.band, receiver=receiver, prepared=prep, noise=False)

    def cells(a: np.ndarray) -> np.ndarray:  # link = bs * n + cell -> (n, B)
        return a.reshape(n_b, n_c).T

    out: dict[str, Any] = {
        "los": cells(clean.los),
        "first_kind": cells(clean.first_kind),
        "excess_m": cells(_excess_m(paths, clean.first_path)),
        "toa_s": cells(np.where(clean.detected, clean.toa_s, np.nan)),
    }
    out["gdop"] = gdop_2d(paths.rx, paths.tx, np.isfinite(out["toa_s"]))
    if n_paths > 0:
        out.update(path_table(paths, n_paths))
    meas = ToaModel(receiver, seed).measure(paths, range(draws), prepared=prep)
    t1 = time.perf_counter()
    out["detected_fraction"] = meas.detected.mean(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN cells give NaN, as documented
        out["toa_std_s"] = np.nanstd(meas.delay_s, axis=0)
        flat = meas.toa_s.reshape(draws * n_c, n_b)
        height = np.tile(paths.rx[:, 2], draws)
        true_xy = np.tile(paths.rx[:, :2], (draws, 1))
        stats = []
        for m in methods:
            fix = np.asarray(
                locate(flat, paths.tx, m, tx_offsets_s=meas.tx_offset_s, height_m=height)
            )
            err = np.hypot(*(fix[:, :2] - true_xy).T).reshape(draws, n_c)
            stats.append((np.nanpercentile(err, 90, axis=0), np.nanmean(err, axis=0),
                          np.isfinite(err).mean(axis=0)))  # fmt: skip
    for k, key in enumerate(("err_p90_m", "err_mean_m", "availability")):
        out[key] = np.array([s[k] for s in stats]).reshape(len(methods), n_c)
    out["time_s"] = {"measure": t1 - t0, "locate": time.perf_counter() - t1}
    return out


def _chunk_job(scene: Scene, job: tuple) -> dict[str, Any]:
    """Trace, measure and position one chunk of cells (in a worker or in this process)."""
    from ..solver.tracer import trace

    tx, cells, first, settings, receiver, threads = job
    t0 = time.perf_counter()
    # a job's trace stays in its process, on threads (raytrace.solver.parallel.in_job)
    paths = trace(scene, tx, cells, receiver.band.center_frequency_hz, settings.trace,
                  threads=threads)  # fmt: skip
    t1 = time.perf_counter()
    out = measure_cells(paths, receiver, chunk_seed(settings.seed, first), settings.draws,
                        settings.methods, stored_paths(settings))  # fmt: skip
    out["time_s"]["trace"] = t1 - t0
    out["n_paths"] = paths.n_paths
    return out


# --------------------------------------------------------------------------------------------
# the map
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AccuracyMap:
    """A computed map: the schema's arrays (:attr:`fmap`) and the grid they lie on."""

    fmap: FingerprintMap
    grid: MapGrid


def compute_map(
    scene: Scene,
    settings: MapSettings,
    *,
    scene_name: str = "",
    bs_xyz: np.ndarray | None = None,
    bs_names: Sequence[str] | None = None,
    area_xy: np.ndarray | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool | Callable[[int], None] = False,
) -> AccuracyMap:
    """The accuracy map of ``scene`` (module docstring).

    Parameters
    ----------
    scene : Scene
    settings : MapSettings
    scene_name : str, recorded in the meta
    bs_xyz : (B, 3) float, m, optional, base stations (default: the scene's metadata)
    bs_names : sequence of str, optional (default BS1, BS2, ... for given positions)
    area_xy : (K, 2) float, m, optional, polygon for the cells (default :func:`area_polygon`)
    workers : int, optional, processes (default every core, at most one per chunk; 1: this one)
    scheduler : Dask scheduler address or ``distributed.Client``, optional: the chunks run on
        that cluster instead (as :func:`raytrace.studies.sweep.run_sweep`'s cells; the scene is
        sent to every worker once)
    progress : bool or callable, a tqdm bar over the cells, or a callback with cells done

    Returns
    -------
    AccuracyMap
    """
    t_start = time.perf_counter()
    settings.check()
    inputs = SceneMetadata.from_scene(scene)
    if bs_xyz is None:
        bs_xyz, bs_names = inputs.bs_xyz, inputs.bs_names
    bs_xyz = np.asarray(bs_xyz, dtype=float).reshape(-1, 3)
    if len(bs_xyz) == 0:
        raise HallrayError("the scene has no base stations (metadata['hallray']['base_stations'])")
    names = list(bs_names) if bs_names is not None else [f"BS{i + 1}" for i in range(len(bs_xyz))]
    grid = make_grid(scene, settings, inputs.point_names, inputs.point_xyz, area_xy)
    band = get_band(settings.band)
    receiver = Receiver(settings.receiver, band)
    chunks = receiver_chunks(len(bs_xyz), len(grid.cell_xyz), settings.chunk_links)
    n_workers = resolve_workers(workers, len(chunks))
    threads = 1 if n_workers > 1 or scheduler is not None else None
    jobs = [(bs_xyz, grid.cell_xyz[c.start : c.stop], c.start, settings, receiver, threads)
            for c in chunks]  # fmt: skip
    if scheduler is not None:
        parts = _run_chunks_dask(scene, jobs, chunks, scheduler, progress)
        n_workers = 0  # recorded as "dask"
    else:
        parts = _run_chunks(scene, jobs, chunks, n_workers, progress)
    arrays = _join(parts, len(settings.methods))
    timing = {k: float(sum(p["time_s"][k] for p in parts)) for k in ("trace", "measure", "locate")}
    timing["total_wall"] = time.perf_counter() - t_start
    meta = _meta(scene, scene_name, settings, band, grid, n_workers, timing,
                 sum(p["n_paths"] for p in parts))  # fmt: skip
    if stored_paths(settings) > 0:
        meta["receiver_model"] = receiver_model_meta(receiver)
    fmap = FingerprintMap(
        cell_xyz=grid.cell_xyz, bs_xyz=bs_xyz, bs_names=np.array(names, dtype=str),
        methods=np.array(settings.methods, dtype=str), meta=meta, **arrays,
    )  # fmt: skip
    return AccuracyMap(fmap, grid)


def _run_chunks(
    scene: Scene, jobs: list[tuple], chunks: list[range], n_workers: int,
    progress: bool | Callable[[int], None],
) -> list[dict[str, Any]]:  # fmt: skip
    """Every chunk's result, in chunk order, with a progress bar over the cells."""
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=chunks[-1].stop, desc="accuracy map", unit="cell")
    parts = []
    try:
        with ScenePool(scene, n_workers, preload=(__name__,)) as pool:
            for chunk, part in zip(chunks, pool.map(_chunk_job, jobs)):
                parts.append(part)
                if bar is not None:
                    bar.update(len(chunk))
                elif callable(progress):
                    progress(len(chunk))
    finally:
        if bar is not None:
            bar.close()
    return parts


def _run_chunks_dask(
    scene: Scene, jobs: list[tuple], chunks: list[range], scheduler: Any,
    progress: bool | Callable[[int], None],
) -> list[dict[str, Any]]:  # fmt: skip
    """:func:`_run_chunks` on a Dask cluster (the sweep's connection and allocator settings)."""
    from .sweep import _connect_dask, tune_malloc

    client, own = _connect_dask(scheduler)
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=chunks[-1].stop, desc="accuracy map (dask)", unit="cell")
    try:
        client.run(tune_malloc)
        scene_f = client.scatter(scene, broadcast=True)
        futures = client.map(_chunk_job, [scene_f] * len(jobs), jobs, pure=False)
        parts = []
        for chunk, fut in zip(chunks, futures):
            parts.append(fut.result())
            if bar is not None:
                bar.update(len(chunk))
            elif callable(progress):
                progress(len(chunk))
        return parts
    finally:
        if bar is not None:
            bar.close()
        if own:
            client.close()


def _join(parts: list[dict[str, Any]], n_methods: int) -> dict[str, np.ndarray]:
    """The chunks' arrays joined along the cell axis."""
    out: dict[str, np.ndarray] = {}
    for key in ("los", "first_kind", "excess_m", "toa_s", "toa_std_s", "detected_fraction",
                "gdop"):  # fmt: skip
        out[key] = np.concatenate([p[key] for p in parts])
    for key in ("err_p90_m", "err_mean_m", "availability"):
        out[key] = np.concatenate([p[key].reshape(n_methods, -1) for p in parts], axis=1)
    if "path_delay_s" in parts[0]:
        for key in ("path_delay_s", "path_gain", "path_dir", "path_radius_m"):
            out[key] = np.concatenate([p[key] for p in parts])
    out["los"] = out["los"].astype(bool)
    out["first_kind"] = out["first_kind"].astype(str)
    return out


def _meta(
    scene: Scene, scene_name: str, settings: MapSettings, band: Any, grid: MapGrid,
    n_workers: int, timing: dict[str, float], n_paths: int,
) -> dict[str, Any]:  # fmt: skip
    """The map's ``meta_json`` (docs/accuracy_map.md)."""
    from ..core.version import __version__

    return {
        "band": band.name,
        "frequency_hz": band.center_frequency_hz,
        "bandwidth_hz": band.bandwidth_hz,
        "receiver": settings.receiver,
        "step_m": settings.step_m,
        "height_m": float(grid.cell_xyz[0, 2]),
        "scene": scene_name,
        "scene_sha256": scene.content_hash(),
        "draws": settings.draws,
        "seed": settings.seed,
        "paths_per_link": stored_paths(settings),
        "noise_streams": "chunk c: ToaModel seed SeedSequence([seed, first cell of c]); "
        "epochs 0..draws-1",
        "chunk_links": settings.chunk_links,
        "clearance_m": settings.clearance_m,
        "service_area": grid.area_xy.tolist(),
        "grid": {
            "origin_xy": grid.origin_xy.tolist(),
            "step_m": grid.step_m,
            "shape": list(grid.shape),
            "cell_ij": "round((cell_xy - origin_xy) / step_m)",
        },
        "test_points": [
            {"name": n, "xyz": p.tolist(), "nearest_cell_m": float(d)}
            for n, p, d in zip(grid.test_names, grid.test_xyz, grid.test_distance_m)
        ],
        "positioning": "positioning.locate, 2D with the device height known, default parameters",
        "gdop": "horizontal, base stations the noiseless receiver detects (NaN below 3)",
        "trace": asdict(settings.trace),
        "version": __version__,
        "workers": n_workers if n_workers else "dask",
        "n_paths": int(n_paths),
        "timing_s": timing,
    }


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------


def csv_columns(bs_names: Sequence[str], methods: Sequence[str]) -> list[str]:
    """Columns of map.csv (one row per cell; docs/accuracy_map.md)."""
    head = ["cell", "i", "j", "x_m", "y_m", "z_m", "n_los", "gdop"]
    for b in bs_names:
        head += [f"{b}:{k}" for k in ("los", "first_kind", "excess_m", "toa_s", "toa_std_s",
                                      "detected_fraction")]  # fmt: skip
    for m in methods:
        head += [f"{m}:{k}" for k in ("err_p90_m", "err_mean_m", "availability")]
    return head


def map_csv(amap: AccuracyMap) -> bytes:
    """map.csv: a ``# hallray-accuracy-map-csv v1 ...`` line, the header, one row per cell."""
    f, g = amap.fmap, amap.grid
    buf = io.StringIO()
    buf.write(f"# {CSV_SCHEMA} v{CSV_VERSION}; one row per cell; units SI (m, s); "
              "columns BS:quantity per base station, METHOD:quantity per method; "
              "see docs/accuracy_map.md\n")  # fmt: skip
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_columns(list(f.bs_names), list(f.methods)))
    n_los = f.n_los()
    for n in range(f.n_cells):
        row: list[Any] = [n, *g.ij[n].tolist(), *(f"{v:.4f}" for v in f.cell_xyz[n]),
                          int(n_los[n]), _num(f.gdop[n])]  # fmt: skip
        for b in range(f.n_bs):
            row += [int(f.los[n, b]), f.first_kind[n, b], _num(f.excess_m[n, b]),
                    _num(f.toa_s[n, b], 12), _num(f.toa_std_s[n, b], 12),
                    _num(f.detected_fraction[n, b])]  # fmt: skip
        for m in range(len(f.methods)):
            row += [_num(f.err_p90_m[m, n]), _num(f.err_mean_m[m, n]), _num(f.availability[m, n])]
        w.writerow(row)
    return buf.getvalue().encode("utf-8")


def _num(v: float, digits: int = 6) -> str:
    """A number for the CSV, ``nan`` for NaN."""
    return "nan" if not np.isfinite(v) else f"{float(v):.{digits}g}"


def check_output(out_dir: str | Path, force: bool) -> None:
    """Refuse, before any work, an output path :func:`write_outputs` would refuse."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise HallrayError(f"output directory {out} is not empty (use --force to replace it)")
    if not out.resolve().parent.is_dir():
        raise HallrayError(f"parent directory of {out} does not exist")


def write_outputs(
    out_dir: str | Path, scene: Scene, amap: AccuracyMap, *, force: bool = False,
    pictures: bool = True,
) -> list[Path]:  # fmt: skip
    """Write DIR/map.npz (:func:`positioning.fingerprint.write_map`), DIR/map.csv and the PNG
    heatmaps into a temporary directory beside ``out_dir``, renamed when complete (no partial
    output). Returns the files' final paths."""
    import shutil

    from hallray.safe_output import commit_dir

    from ..emulation.dataset import _prepare_output

    out = Path(out_dir)
    tmp = _prepare_output(out, force)
    committed = False
    try:
        write_map(tmp / "map.npz", amap.fmap)
        write_atomic(tmp / "map.csv", map_csv(amap))
        names = ["map.npz", "map.csv"]
        if pictures:
            for name, png in map_pictures(scene, amap):
                write_atomic(tmp / name, png)
                names.append(name)
        commit_dir(tmp, out)
        committed = True
    finally:
        if not committed:
            shutil.rmtree(tmp, ignore_errors=True)
    return [out / n for n in names]


#: Lower end of the error pictures' log colour scale, m.
ERR_FLOOR_M = 0.01
#: Pictures of a map: (file, quantity, colour-bar label, colour map, discrete).
PICTURES = (
    ("n_los.png", "n_los", "base stations in line of sight", "viridis", True),
    (
        "n_detected.png",
        "n_detected",
        "base stations detected (noiseless receiver)",
        "viridis",
        True,
    ),
    ("gdop.png", "gdop", "GDOP (2D, TDoA)", "magma_r", False),
    (
        "excess_worst_m.png",
        "excess_worst",
        "largest first-arrival excess delay over BS, m",
        "inferno_r",
        False,
    ),
)


def map_pictures(scene: Scene, amap: AccuracyMap) -> list[tuple[str, bytes]]:
    """The map's PNG heatmaps: :data:`PICTURES`, then ``err_p90_<method>.png`` and
    ``availability_<method>.png`` per method."""
    from ..viz.heatmap import footprints, heatmap_png

    f, g = amap.fmap, amap.grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # cells with no arrival at all
        per_cell = {
            "n_los": f.n_los().astype(float),
            "n_detected": np.isfinite(f.toa_s).sum(axis=1).astype(float),
            "gdop": np.where(np.isfinite(f.gdop), f.gdop, np.nan),
            "excess_worst": np.nanmax(f.excess_m, axis=1),
        }
    jobs = [(name, per_cell[key], label, cmap, disc, 0.0 if disc else None,
             float(f.n_bs) if disc else None, False)
            for name, key, label, cmap, disc in PICTURES]  # fmt: skip
    for k, m in enumerate(f.methods):
        err = f.err_p90_m[k]  # centimetres to tens of metres: a log scale from 1 cm
        top = float(np.nanmax(err)) if np.isfinite(err).any() else 1.0
        jobs.append((f"err_p90_{m}.png", err, f"p90 2D error, {m}, m (log scale)", "turbo",
                     False, ERR_FLOOR_M, max(top, 10 * ERR_FLOOR_M), True))  # fmt: skip
        jobs.append((f"availability_{m}.png", f.availability[k],
                     f"share of draws with a fix, {m}", "cividis", False, 0.0, 1.0, False))  # fmt: skip
    outlines = footprints(scene)
    pts = np.asarray(g.test_xyz, dtype=float).reshape(-1, 3)[:, :2]
    meta = f.meta
    sub = (f"{meta.get('scene', '')} {meta.get('band', '')}, receiver {meta.get('receiver', '')}, "
           f"step {g.step_m:g} m, h {meta.get('height_m', 0):g} m")  # fmt: skip
    out = []
    for name, vals, label, cmap, disc, vmin, vmax, log in jobs:
        png = heatmap_png(scene, g.raster(vals), g.origin_xy, g.step_m, title=f"{label}\n{sub}",
                          label=label, bs_xyz=f.bs_xyz, bs_names=list(f.bs_names), points_xy=pts,
                          cmap=cmap, vmin=vmin, vmax=vmax, discrete=disc, log=log,
                          outlines=outlines)  # fmt: skip
        out.append((name, png))
    return out
