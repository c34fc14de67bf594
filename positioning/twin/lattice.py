"""A fingerprint map as a lattice: the bias of every base station per node, the maps loaded
before (cached by path and modification time), and the re-synthesised ToA rasters kept with them.

The ``twin`` estimator (:mod:`positioning.twin.estimator`) needs the map's cells on a regular
square grid: :func:`load` builds the :class:`Lattice` of a map once (the bias ``c toa_s - |cell -
b_n|`` per node, holes filled from the nearest cell, and its 3 x 3 median), and keeps it with the
map read from a file, together with the ToA rasters (:class:`~positioning.twin.resynth.ToaRaster`)
re-synthesised on it. :func:`prepare` fills a raster up front.

A map whose base stations are not the dataset's (count or positions off by more than
:data:`BS_TOL_M`) is refused (:func:`check_bs`, :func:`check_dataset`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import PositioningError
from ..model.tdoa import C0
from .fingerprint import FingerprintMap, read_map
from .resynth import RASTER_STEP_M, PathMap, ToaRaster

#: Largest distance between a map's and the dataset's base station, metres.
BS_TOL_M = 0.01
#: The coarse match uses a sub-lattice of at most this many cells (speed).
COARSE_CELLS = 1200


@dataclass(frozen=True)
class Lattice:
    """A map's cells on a regular lattice with the bias per node (holes filled by the nearest
    cell), plus the coarse sub-lattice's cells."""

    x0: float
    y0: float
    step: float
    bias: np.ndarray  # (ny, nx, B) m, holes and undetected links filled from the nearest cell
    smooth: np.ndarray  # (ny, nx, B) m, median of each node's 3 x 3 neighbourhood of ``bias``
    coarse: np.ndarray  # (C,) indices of map cells of the coarse search
    pred: np.ndarray  # (N, B) c * toa_s, m (NaN: not detected)
    polygon: np.ndarray  # (V, 2) service area
    node_cell: np.ndarray  # (ny, nx) int, the map cell at each lattice node (-1: hole)
    #: re-synthesised ToA rasters by (paths, spacing, height in mm), kept with the loaded map
    rasters: dict = field(default_factory=dict, compare=False, repr=False)


#: Maps read from files kept loaded (with their lattices and rasters), least recently used
#: dropped first: a report over both bands alternates between two maps, and dropping one
#: dropped its ToA raster, re-synthesised again for the next dataset of that band.
MAX_MAPS = 4
_CACHE: dict[tuple[str, float], tuple[FingerprintMap, Lattice]] = {}


def load(fmap: FingerprintMap | str | Path) -> tuple[FingerprintMap, Lattice]:
    """The map (read and checked if a path; cached by path and mtime, at most
    :data:`MAX_MAPS`) and its lattice."""
    if isinstance(fmap, FingerprintMap):
        return fmap, _lattice(fmap)
    path = Path(fmap)
    try:
        key = (str(path.resolve()), path.stat().st_mtime)
    except OSError:
        key = None
    if key is not None and key in _CACHE:
        out = _CACHE.pop(key)
        _CACHE[key] = out  # last: the most recently used
        return out
    m = read_map(path)
    out = (m, _lattice(m, str(path)))
    if key is not None:
        for old in [k for k in _CACHE if k[0] == key[0]]:  # the file changed: its old map
            del _CACHE[old]
        while len(_CACHE) >= MAX_MAPS:
            del _CACHE[next(iter(_CACHE))]
        _CACHE[key] = out
    return out


def _lattice(m: FingerprintMap, name: str = "fingerprint map") -> Lattice:
    from scipy.ndimage import distance_transform_edt

    xy = m.cell_xyz[:, :2]
    xs, ys = np.unique(np.round(xy[:, 0], 6)), np.unique(np.round(xy[:, 1], 6))
    steps = np.concatenate([np.diff(xs), np.diff(ys)])
    step = float(steps.min()) if steps.size else 1.0
    ix = np.rint((xy[:, 0] - xs[0]) / step).astype(int)
    iy = np.rint((xy[:, 1] - ys[0]) / step).astype(int)
    on = np.abs(xs[0] + ix * step - xy[:, 0]) + np.abs(ys[0] + iy * step - xy[:, 1])
    if steps.size == 0 or np.max(on) > 1e-3 * step:
        raise PositioningError(f"{name}: the twin needs the cells on a regular square grid")
    pred = C0 * m.toa_s
    dist = np.linalg.norm(m.cell_xyz[:, None, :] - m.bs_xyz[None, :, :], axis=2)
    cell_bias = pred - dist
    ny, nx = iy.max() + 1, ix.max() + 1
    bias = np.full((ny, nx, m.n_bs), np.nan)
    bias[iy, ix] = cell_bias
    for b in range(m.n_bs):  # fill holes and undetected links from the nearest known node
        miss = ~np.isfinite(bias[..., b])
        if miss.all():
            bias[..., b] = 0.0
        elif miss.any():
            _, (jy, jx) = distance_transform_edt(miss, return_indices=True)
            bias[..., b] = bias[jy, jx, b]
    raw = np.full((ny, nx, m.n_bs), np.nan)
    raw[iy, ix] = cell_bias
    pad = np.pad(raw, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
    stack = np.stack([pad[dy : dy + ny, dx : dx + nx] for dy in range(3) for dx in range(3)])
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            smooth = np.nanmedian(stack, axis=0)
    smooth = np.where(np.isfinite(smooth), smooth, bias)
    stride = max(1, int(np.ceil(np.sqrt(m.n_cells / COARSE_CELLS))))
    coarse = np.flatnonzero((ix % stride == 0) & (iy % stride == 0))
    node_cell = np.full((ny, nx), -1, dtype=np.int64)
    node_cell[iy, ix] = np.arange(m.n_cells)
    return Lattice(
        float(xs[0]), float(ys[0]), step, bias, smooth, coarse, pred,
        _service_polygon(m, step), node_cell,
    )  # fmt: skip


def _service_polygon(m: FingerprintMap, step: float) -> np.ndarray:
    """(V, 2) service area from the map's meta (a list of [x, y] or ``{"polygon": ...}``), else
    the cells' bounding box grown by half a step."""
    sa = m.meta.get("service_area")
    if isinstance(sa, dict):
        sa = sa.get("polygon")
    try:
        poly = np.asarray(sa, dtype=float)
        if poly.ndim == 2 and poly.shape[0] >= 3 and poly.shape[1] == 2 and np.isfinite(poly).all():
            return poly
    except (TypeError, ValueError):
        pass
    lo = m.cell_xyz[:, :2].min(axis=0) - step / 2
    hi = m.cell_xyz[:, :2].max(axis=0) + step / 2
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


def check_bs(m: FingerprintMap, bs_xyz: np.ndarray) -> None:
    """Refuse a map whose base stations are not ``bs_xyz`` (count, or a position off by more
    than :data:`BS_TOL_M`)."""
    if m.n_bs != len(bs_xyz):
        raise PositioningError(
            f"map has {m.n_bs} base stations but the data has {len(bs_xyz)}: not this site's map"
        )
    off = np.linalg.norm(m.bs_xyz - bs_xyz, axis=1)
    if off.max() > BS_TOL_M:
        j = int(np.argmax(off))
        raise PositioningError(
            f"map base station {j} ({m.bs_names[j]}) is {off[j]:.3f} m from the data's: "
            "not this site's map"
        )


def check_dataset(
    map_path: FingerprintMap | str | Path,
    bs_xyz: np.ndarray,
    bs_names: list[str] | None = None,
    band: str | None = None,
) -> None:
    """Refuse a map that is not the dataset's: base stations (positions, names when given) or
    band (when both name one) differ. One-line :class:`PositioningError`."""
    fmap, _ = load(map_path)
    check_bs(fmap, np.asarray(bs_xyz, dtype=float))
    if bs_names is not None and [str(n) for n in fmap.bs_names] != list(bs_names):
        raise PositioningError(
            f"map base stations {', '.join(map(str, fmap.bs_names))} are not the dataset's "
            f"{', '.join(bs_names)}: not this site's map"
        )
    mb = fmap.meta.get("band")
    if band not in (None, "unknown") and mb is not None and str(mb) != str(band):
        raise PositioningError(f"map is for band {mb!r} but the dataset is {band!r}")


def prepare(
    fingerprint_map: FingerprintMap | str | Path,
    height_m: float,
    *,
    paths: int | None = None,
    resynth_step: float = RASTER_STEP_M,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Re-synthesise a version-2 map's whole ToA raster at device height ``height_m`` now, so
    that :func:`~positioning.twin.estimator.twin` answers every later fix with look-ups only (a
    server that must run at full speed from its first fix; by default the raster fills lazily
    around the fixes).

    The raster is kept with the map loaded from ``fingerprint_map`` (a path: cached by path and
    mtime).
    Returns the receiver runs (links) spent; ``progress(done, total)`` is called per batch of
    tiles.
    """
    fmap, lat = load(fingerprint_map)
    if not fmap.has_paths:
        raise PositioningError("twin: prepare needs a map with paths (schema version 2)")
    if not (np.isfinite(resynth_step) and resynth_step > 0):
        raise PositioningError(f"twin: resynth_step must be > 0 m, got {resynth_step!r}")
    if not np.isfinite(height_m):
        raise PositioningError(f"twin: prepare needs a finite device height, got {height_m!r}")
    r = raster_for(lat, PathMap.from_map(fmap, paths), paths, resynth_step,
                int(np.rint(float(height_m) * 1000.0)))  # fmt: skip
    before = r.links
    r.fill(progress=progress)
    return r.links - before


#: Re-synthesised ToA rasters kept per loaded map (one per number of paths, spacing and device
#: height): beyond this, the least recently used is dropped (a filled raster of the hall at
#: 5 cm is about 30 MB, and a long-running service may see devices at many heights).
MAX_RASTERS = 8


def raster_for(lat: Lattice, pmap: PathMap, paths: int | None, h: float, h_mm: int) -> ToaRaster:
    """The lattice's re-synthesised ToA raster for ``paths``, spacing ``h`` (m), device height
    ``h_mm`` (mm), created on first use (at most :data:`MAX_RASTERS` kept, least recently used
    dropped first)."""
    key = (int(paths or 0), float(h), int(h_mm))
    raster = lat.rasters.pop(key, None)
    if raster is None:
        raster = ToaRaster(pmap, lat.node_cell, lat.x0, lat.y0, lat.step, h_mm / 1000.0, h)
        while len(lat.rasters) >= MAX_RASTERS:
            lat.rasters.pop(next(iter(lat.rasters)))
    lat.rasters[key] = raster  # last: the most recently used
    return raster


def nearest_cell(lat: Lattice, xy: np.ndarray) -> np.ndarray:
    """(A,) int: the map cell at the lattice node nearest to each ``xy`` (A, 2); -1 where that
    node is a hole or off the lattice."""
    ny, nx = lat.node_cell.shape
    fin = np.isfinite(xy).all(axis=1)
    p = np.where(fin[:, None], xy, 0.0)
    i = np.rint((p[:, 0] - lat.x0) / lat.step).astype(np.int64)
    j = np.rint((p[:, 1] - lat.y0) / lat.step).astype(np.int64)
    on = fin & (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
    out = np.full(len(xy), -1, dtype=np.int64)
    out[on] = lat.node_cell[j[on], i[on]]
    return out


def interp_bias(lat: Lattice, xy: np.ndarray, smooth: bool = False) -> np.ndarray:
    """(A, B) bias at ``xy`` (A, 2), bilinear between lattice nodes (clamped at the edges), of
    the raw or the median-smoothed node biases."""
    ny, nx, _ = lat.bias.shape
    u = np.clip((xy[:, 0] - lat.x0) / lat.step, 0.0, nx - 1.000001)
    v = np.clip((xy[:, 1] - lat.y0) / lat.step, 0.0, ny - 1.000001)
    u = np.where(np.isfinite(u), u, 0.0)
    v = np.where(np.isfinite(v), v, 0.0)
    i, j = u.astype(int), v.astype(int)
    i1, j1 = np.minimum(i + 1, nx - 1), np.minimum(j + 1, ny - 1)
    fu, fv = (u - i)[:, None], (v - j)[:, None]
    b = lat.smooth if smooth else lat.bias
    return (
        (1 - fu) * (1 - fv) * b[j, i]
        + fu * (1 - fv) * b[j, i1]
        + (1 - fu) * fv * b[j1, i]
        + fu * fv * b[j1, i1]
    )
