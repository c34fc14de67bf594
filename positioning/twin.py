"""``twin``: positioning against a ray-traced fingerprint map that knows where the NLoS biases are.

With 4 base stations in 2D a single epoch has one redundant measurement, so no residual test can
tell which base station is biased. The map (:mod:`positioning.fingerprint`, written by
``accuracy-map``) predicts, per grid cell and base station, the first-arrival ToA of the receiver
including its NLoS excess. The twin moves that bias from the unknowns into the model::

    rho_n = |p - b_n| + bias_n(p) + beta + e_n,       bias_n(p) = c toa_s[cell, n] - |cell - b_n|

(``rho_n`` the pseudo-range of :mod:`positioning.tdoa`, ``beta`` the clock offset times c).

1. **Prior.** The map-free ``fallback`` method (default ``nlos-aware``) gives a fix; only cells
   within ``prior_m`` of it are candidates (:func:`window_match`). A search of the whole map
   (:func:`coarse_match`, used where there is no prior) aliases: with three TDoAs and a rough
   bias field a far cell often matches as well as the right one.
2. **Match.** For every candidate cell the least-squares misfit of the measured pseudo-ranges to
   the predicted ones ``c toa_s`` with the offset free, ``min_beta sum_n (rho_n - c toa_s[c, n]
   - beta)^2``, batched over fixes and cells.
3. **Refine** the ``top`` best cells (:func:`refine_at_cells`): Gauss-Newton on ``(x, y, beta)``
   of the model above with the cell's own bias (``bias="cell"``) or the bias interpolated
   bilinearly from the median-smoothed lattice (``bias="interp"``), the position kept within
   :data:`REFINE_BOX` grid steps of the cell; the candidate with the smallest residual wins.
   With a map of schema version 2 (paths stored) the default ``bias="auto"`` refines the best
   of those again with the nearest cell's paths moved to the iterate and the receiver re-run on
   them (``bias="resynth"``, :mod:`positioning.resynth`), used where it fits within
   :data:`RESYNTH_M`; the re-synthesised ToAs come from a 5 cm raster filled around the visited
   cells on first use (``resynth_step``; :func:`prepare` fills all of it).
4. **Judge.** ``match_m`` = RMS residual of all received base stations at the refined fix
   (offset re-fitted); per base station ``nlos`` = the matched cell's bias exceeds
   :data:`NLOS_BIAS_M`.
5. **Fall back.** A fix with ``match_m > fallback_m`` does not fit the map (a stale map: forklifts
   that moved): it is replaced by the fallback method's fix and flagged ``MAP_MISMATCH``; the
   received base stations the map calls LoS are reported ``stale``.
6. **Bound.** Every fix is moved into the map's service area (``meta["service_area"]``, else the
   cells' bounding box) if it lies outside.

Measured choices (``docs/positioning.md``): the first-lobe receiver's bias on the bundled hall is
rough between 0.5 m cells, so ``bias="cell"`` is used with a v1 map (not ``interp``).

The map is checked on load (:func:`positioning.fingerprint.read_map`, one-line errors); a map
whose base stations are not the dataset's (count or positions off by more than
:data:`BS_TOL_M`) is refused.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import PositioningError
from .fingerprint import FingerprintMap, read_map
from .fixes import Status
from .irls import irls
from .resynth import RASTER_STEP_M, PathMap, ToaRaster, normal_step, refine_resynth
from .tdoa import C0, Problem

#: Largest distance between a map's and the dataset's base station, metres.
BS_TOL_M = 0.01
#: The coarse match uses a sub-lattice of at most this many cells (speed).
COARSE_CELLS = 1200
#: :func:`window_match` groups the fixes by window centre when there are at least this many
#: fixes per centre on average (matrix products per group; else one gather per fix).
WINDOW_GROUP = 4
#: A map bias above this (m) marks the base station as NLoS at the fix.
NLOS_BIAS_M = 0.25
#: Default threshold on match_m (m) above which a fix falls back to the map-free method.
FALLBACK_M = 0.6
#: Default search radius around the map-free fix (m) and candidate cells refined per fix.
PRIOR_M = 4.0
#: Default search radius with ``bias="resynth"`` (m): the re-synthesised fit rejects the far
#: cells that alias with the cell-held one, so the window can hold the right cell even where the
#: map-free prior is 10 m off (mmWave P21, P23; docs/positioning.md).
RESYNTH_PRIOR_M = 15.0
TOP = 3
#: Gauss-Newton iterations of the refinement.
REFINE_ITER = 5
#: The refined fix stays within this many grid steps of its cell centre (per coordinate).
REFINE_BOX = 1.0
#: ``bias="resynth"``: largest RMS residual (m) of the re-synthesised solution that is used.
RESYNTH_M = 0.3
#: ``bias="resynth"``: best cell-held solutions refined again with re-synthesised paths.
RESYNTH_TOP = 3
#: ``bias="resynth"``: fixes re-synthesised per block (bounds memory: about 60 MB per block
#: with 16 paths per link; all 13 800 fixes of a 60 s dataset at once took 10 GB).
RESYNTH_CHUNK = 256
#: The same with the ToA raster (``resynth_step > 0``): only (fixes x top x 25, B) values per
#: block, so blocks are larger (fewer passes of numpy's per-call overhead).
RASTER_CHUNK = 4096
#: ``bias="resynth"``: half-width (m) of the 5 x 5 grid the Gauss-Newton start is chosen from.
SEARCH_M = 0.3


@dataclass(frozen=True)
class _Lattice:
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


_CACHE: dict[tuple[str, float], tuple[FingerprintMap, _Lattice]] = {}


def load(fmap: FingerprintMap | str | Path) -> tuple[FingerprintMap, _Lattice]:
    """The map (read and checked if a path; cached by path and mtime) and its lattice."""
    if isinstance(fmap, FingerprintMap):
        return fmap, _lattice(fmap)
    path = Path(fmap)
    try:
        key = (str(path.resolve()), path.stat().st_mtime)
    except OSError:
        key = None
    if key is not None and key in _CACHE:
        return _CACHE[key]
    m = read_map(path)
    out = (m, _lattice(m, str(path)))
    if key is not None:
        _CACHE.clear()
        _CACHE[key] = out
    return out


def _lattice(m: FingerprintMap, name: str = "fingerprint map") -> _Lattice:
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
    return _Lattice(
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


# ----------------------------------------------------------------------------------------------
# stage 1: coarse match over cells


def coarse_match(
    prob: Problem,
    lat: _Lattice,
    cells: np.ndarray,
    cell_xy: np.ndarray,
    *,
    prior_xy: np.ndarray | None = None,
    prior_m: float = 0.0,
    top: int = 1,
    chunk: int = 1024,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``top`` best cells (indices into the map's cells) among ``cells`` for every fix.

    Least-squares misfit with a free offset, ``sum (rho - pred)^2 - (sum (rho - pred))^2 / n``,
    expanded into matrix products, per pattern of received base stations (a cell whose
    prediction misses a received base station is not a candidate for that pattern). With
    ``prior_m > 0`` only cells within ``prior_m`` of ``prior_xy`` (E, 2) are candidates (fixes
    without a finite prior search all cells).

    Returns (E, top) cell indices (-1: none) and (E, top) misfits, m^2.
    """
    E = prob.n_epochs
    best = np.full((E, top), -1, dtype=np.int64)
    best_cost = np.full((E, top), np.inf)
    pred = lat.pred[cells]  # (C, B)
    cxy = cell_xy[cells]
    patterns, inv = np.unique(prob.valid, axis=0, return_inverse=True)
    inv = inv.ravel()
    for k, pat in enumerate(patterns):
        if pat.sum() < prob.min_bs:
            continue
        ok = np.isfinite(pred[:, pat]).all(axis=1)
        if ok.sum() < top:
            continue
        M = pred[np.ix_(ok, pat)]  # (C', n)
        n = int(pat.sum())
        ms = M.sum(axis=1)
        m2 = np.sum(M * M, axis=1) - ms**2 / n  # (C',)
        rows = np.flatnonzero(inv == k)
        for s in range(0, rows.size, chunk):
            r = rows[s : s + chunk]
            rho = prob.rho[np.ix_(r, pat)]
            rs = rho.sum(axis=1)
            r2 = np.sum(rho * rho, axis=1) - rs**2 / n
            cost = r2[:, None] + m2[None, :] - 2.0 * (rho @ M.T - rs[:, None] * ms[None, :] / n)
            if prior_m > 0 and prior_xy is not None:
                pr = prior_xy[r]
                d2 = (pr[:, :1] - cxy[ok, 0][None]) ** 2 + (pr[:, 1:2] - cxy[ok, 1][None]) ** 2
                far = d2 > prior_m**2
                far &= np.isfinite(pr).all(axis=1)[:, None]
                cost = np.where(far, np.inf, cost)
            part = np.argpartition(cost, top - 1, axis=1)[:, :top]
            pc = np.take_along_axis(cost, part, axis=1)
            order = np.argsort(pc, axis=1)
            best[r] = cells[ok][np.take_along_axis(part, order, axis=1)]
            best_cost[r] = np.take_along_axis(pc, order, axis=1)
    best[~np.isfinite(best_cost)] = -1
    return best, best_cost


def window_match(
    prob: Problem,
    lat: _Lattice,
    prior_xy: np.ndarray,
    radius_m: float,
    top: int = 1,
    chunk: int = 512,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``top`` best cells within ``radius_m`` of ``prior_xy`` (E, 2) for every fix: the
    misfit of :func:`coarse_match` evaluated on the lattice window around the prior only
    (about ``pi (radius / step)^2`` nodes per fix instead of the whole map).

    Returns (E, top) cell indices (-1: none) and (E, top) misfits, m^2.
    """
    E = prob.n_epochs
    ny, nx = lat.node_cell.shape
    w = int(np.ceil(radius_m / lat.step))
    off = np.arange(-w, w + 1)
    dy, dx = np.meshgrid(off, off, indexing="ij")
    keep = (dx**2 + dy**2) * lat.step**2 <= radius_m**2 + 1e-9
    dx, dy = dx[keep], dy[keep]
    # node predictions padded by w on every side (NaN outside the map and in holes)
    node_pred = np.full((ny + 2 * w, nx + 2 * w, prob.n_bs), np.nan)
    node_pred[w : w + ny, w : w + nx] = np.where(
        (lat.node_cell >= 0)[..., None], lat.pred[np.maximum(lat.node_cell, 0)], np.nan
    )
    node_cell = np.full((ny + 2 * w, nx + 2 * w), -1, dtype=np.int64)
    node_cell[w : w + ny, w : w + nx] = lat.node_cell
    flat_pred = node_pred.reshape(-1, prob.n_bs)
    rel = dy * (nx + 2 * w) + dx  # (W,) flat offsets
    pr = np.where(np.isfinite(prior_xy), prior_xy, 0.0)
    ci = np.clip(np.rint((pr[:, 0] - lat.x0) / lat.step).astype(np.int64), 0, nx - 1) + w
    cj = np.clip(np.rint((pr[:, 1] - lat.y0) / lat.step).astype(np.int64), 0, ny - 1) + w
    centre = cj * (nx + 2 * w) + ci
    top = min(top, rel.size)
    best = np.full((E, top), -1, dtype=np.int64)
    best_cost = np.full((E, top), np.inf)
    n = np.maximum(prob.valid.sum(axis=1), 1)
    # the offset-free misfit does not change with a common shift of a fix's pseudo-ranges:
    # centring them keeps the expanded sums below well conditioned (rho holds the clock offset)
    mean = np.sum(np.where(prob.valid, prob.rho, 0.0), axis=1) / n
    rho = np.where(prob.valid, prob.rho - mean[:, None], 0.0)
    groups, inv = np.unique(centre, return_inverse=True)
    if groups.size * WINDOW_GROUP <= E:
        # fixes share window centres (a device stays near a node for many epochs): per centre
        # the misfit of all its fixes against all window nodes is four small matrix products
        order = np.argsort(inv, kind="stable")
        bounds = np.searchsorted(inv[order], np.arange(groups.size + 1))
        V = prob.valid.astype(float)
        B = prob.n_bs
        # per node: sum of the predictions and their spread term (inf where one is missing)
        fin = np.where(np.isfinite(flat_pred), flat_pred, 0.0)
        node_sum = fin.sum(axis=1)
        node_term = np.where(np.isfinite(flat_pred).all(axis=1),
                             np.sum(fin * fin, axis=1) - node_sum**2 / B, np.inf)  # fmt: skip
        rr = np.sum(rho * rho, axis=1)
        rs = rho.sum(axis=1)
        for g, c in enumerate(groups):
            r_ = order[bounds[g] : bounds[g + 1]]
            idx = c + rel  # (W,)
            P = fin[idx]  # (W, B), 0 where missing
            Vg = V[r_]
            if Vg.all():
                # every base station received (the common case): the fix and node terms
                # separate, one matrix product remains
                fix = rr[r_] - rs[r_] ** 2 / B
                cost = fix[:, None] + node_term[idx][None, :] - 2.0 * (rho[r_] @ P.T)
                cost += (2.0 / B) * rs[r_, None] * node_sum[idx][None, :]
            else:
                s1 = rs[r_, None] - Vg @ P.T  # (g, W) sum of residuals
                s2 = rr[r_, None] - 2.0 * (rho[r_] @ P.T) + Vg @ (P * P).T
                cost = s2 - s1 * s1 / n[r_, None]
                miss = ~np.isfinite(flat_pred[idx])
                cost = np.where((Vg @ miss.T) > 0, np.inf, cost)
            part = np.argpartition(cost, top - 1, axis=1)[:, :top]
            pc = np.take_along_axis(cost, part, axis=1)
            o = np.argsort(pc, axis=1)
            best[r_] = node_cell.ravel()[idx[np.take_along_axis(part, o, axis=1)]]
            best_cost[r_] = np.take_along_axis(pc, o, axis=1)
        return np.where(np.isfinite(best_cost), best, -1), best_cost
    for s in range(0, E, chunk):
        r_ = slice(s, min(s + chunk, E))
        idx = centre[r_, None] + rel[None, :]  # (c, W)
        res = rho[r_, None, :] - flat_pred[idx]  # (c, W, B), NaN: no cell / no prediction
        res = np.where(prob.valid[r_, None, :], res, 0.0)
        sq = np.einsum("cwb,cwb->cw", res, res)
        cost = sq - res.sum(axis=2) ** 2 / n[r_, None]
        cost = np.where(np.isfinite(cost), cost, np.inf)
        part = np.argpartition(cost, top - 1, axis=1)[:, :top]
        pc = np.take_along_axis(cost, part, axis=1)
        order = np.argsort(pc, axis=1)
        part = np.take_along_axis(part, order, axis=1)
        best[r_] = node_cell.ravel()[np.take_along_axis(idx, part, axis=1)]
        best_cost[r_] = np.take_along_axis(pc, order, axis=1)
    return np.where(np.isfinite(best_cost), best, -1), best_cost


def refine_at_cells(
    prob: Problem,
    lat: _Lattice,
    cell_xy: np.ndarray,
    cand: np.ndarray,
    *,
    iters: int = REFINE_ITER,
    mode: str = "cell",
) -> tuple[np.ndarray, np.ndarray]:
    """Refine each candidate cell: Gauss-Newton on (x, y, beta) of the biased model, the
    position kept within :data:`REFINE_BOX` grid steps of the cell centre.

    Parameters
    ----------
    cand : (E, K) cell indices (-1: none)
    mode : ``"cell"`` -- the cell's own bias held fixed; ``"interp"`` -- the bias interpolated
        bilinearly at the current position from the median-smoothed lattice (re-evaluated every
        iteration)

    Returns
    -------
    xy (E, K, 2) m; residual RMS about the offset (E, K) m (inf where no candidate).
    """
    E, K = cand.shape
    flat = cand.ravel()
    ok = flat >= 0
    c = np.maximum(flat, 0)
    rep = np.repeat(np.arange(E), K)
    rho = prob.rho[rep]
    valid = prob.valid[rep]
    h = prob.height[rep]
    centre = cell_xy[c]
    cbias = lat.pred[c] - np.linalg.norm(
        np.column_stack([centre, h])[:, None, :] - prob.bs[None], axis=2
    )
    obs = np.where(valid, rho - cbias, 0.0)
    use = (valid & np.isfinite(cbias)).astype(float)
    xy = centre.copy()
    half = lat.step * REFINE_BOX
    for _ in range(iters):
        if mode == "interp":
            obs = np.where(valid, rho - interp_bias(lat, xy, smooth=True), 0.0)
        p = np.column_stack([xy, h])
        diff = p[:, None, :] - prob.bs[None]
        R = np.linalg.norm(diff, axis=2)
        U = diff[..., :2] / np.maximum(R, 1e-12)[..., None]
        s = obs - R
        beta = np.sum(use * s, axis=1) / np.maximum(use.sum(axis=1), 1)
        r = (s - beta[:, None]) * use
        Uc = (
            U
            - (np.sum(use[..., None] * U, axis=1) / np.maximum(use.sum(axis=1), 1)[:, None])[
                :, None
            ]
        )
        Uc = Uc * use[..., None]
        delta = normal_step(Uc, r, 1e-9)
        xy = np.clip(xy + np.where(np.isfinite(delta), delta, 0.0), centre - half, centre + half)
    if mode == "interp":
        obs = np.where(valid, rho - interp_bias(lat, xy, smooth=True), 0.0)
    p = np.column_stack([xy, h])
    s = obs - np.linalg.norm(p[:, None, :] - prob.bs[None], axis=2)
    rms = match_quality(np.where(use > 0, s, np.nan), use > 0)
    rms = np.where(ok & np.isfinite(rms), rms, np.inf)
    return xy.reshape(E, K, 2), rms.reshape(E, K)


def prepare(
    map: FingerprintMap | str | Path,  # noqa: A002 - the CLI's name for it
    height_m: float,
    *,
    paths: int | None = None,
    resynth_step: float = RASTER_STEP_M,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Re-synthesise a version-2 map's whole ToA raster at device height ``height_m`` now, so
    that :func:`twin` answers every later fix with look-ups only (a server that must run at
    full speed from its first fix; by default the raster fills lazily around the fixes).

    The raster is kept with the map loaded from ``map`` (a path: cached by path and mtime).
    Returns the receiver runs (links) spent; ``progress(done, total)`` is called per batch of
    tiles.
    """
    fmap, lat = load(map)
    if not fmap.has_paths:
        raise PositioningError("twin: prepare needs a map with paths (schema version 2)")
    if not (np.isfinite(resynth_step) and resynth_step > 0):
        raise PositioningError(f"twin: resynth_step must be > 0 m, got {resynth_step!r}")
    if not np.isfinite(height_m):
        raise PositioningError(f"twin: prepare needs a finite device height, got {height_m!r}")
    r = _raster(lat, PathMap.from_map(fmap, paths), paths, resynth_step,
                int(np.rint(float(height_m) * 1000.0)))  # fmt: skip
    before = r.links
    r.fill(progress=progress)
    return r.links - before


#: Re-synthesised ToA rasters kept per loaded map (one per number of paths, spacing and device
#: height): beyond this, the least recently used is dropped (a filled raster of the hall at
#: 5 cm is about 30 MB, and a long-running service may see devices at many heights).
MAX_RASTERS = 8


def _raster(lat: _Lattice, pmap: PathMap, paths: int | None, h: float, h_mm: int) -> ToaRaster:
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


# ----------------------------------------------------------------------------------------------
# bias interpolation


def nearest_cell(lat: _Lattice, xy: np.ndarray) -> np.ndarray:
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


def interp_bias(lat: _Lattice, xy: np.ndarray, smooth: bool = False) -> np.ndarray:
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


def match_quality(s: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(E,) RMS of the offset-free residuals ``s`` (E, B) of all received base stations about
    their mean (the least-squares offset), metres; NaN where fewer than two."""
    n = valid.sum(axis=1)
    mean = np.nansum(np.where(valid, s, 0.0), axis=1) / np.maximum(n, 1)
    d = np.where(valid, s - mean[:, None], 0.0)
    with np.errstate(invalid="ignore"):
        return np.where(n >= 2, np.sqrt(np.sum(d * d, axis=1) / np.maximum(n - 1, 1)), np.nan)


# ----------------------------------------------------------------------------------------------
# service area


def clamp_to_polygon(xy: np.ndarray, poly: np.ndarray, inset: float = 1e-6) -> tuple:
    """Points outside the polygon moved to the nearest boundary point (``inset`` m inside
    along the move). Returns (xy (A, 2), moved (A,) bool)."""
    from matplotlib.path import Path as MplPath

    fin = np.isfinite(xy).all(axis=1)
    inside = np.ones(len(xy), dtype=bool)
    if fin.any():
        inside[fin] = MplPath(poly).contains_points(xy[fin], radius=1e-9)
    out = fin & ~inside
    if not out.any():
        return xy, out
    q = xy[out]
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(
        np.einsum("avk,vk->av", q[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=1), 0.0, 1.0
    )
    near = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(near - q[:, None, :], axis=2)
    j = np.argmin(d, axis=1)
    foot = near[np.arange(len(q)), j]
    centre = poly.mean(axis=0)
    nudge = centre - foot
    nudge /= np.maximum(np.linalg.norm(nudge, axis=1, keepdims=True), 1e-12)
    res = xy.copy()
    res[out] = foot + inset * nudge
    return res, out


# ----------------------------------------------------------------------------------------------
# the method


def twin(
    prob: Problem,
    *,
    map: FingerprintMap | str | Path,  # noqa: A002 - the CLI's name for it
    fallback: Callable[[Problem], dict[str, np.ndarray]] | None = None,
    fallback_m: float = FALLBACK_M,
    prior_m: float | None = None,
    top: int = TOP,
    bias: str = "auto",
    paths: int | None = None,
    fd_jacobian: bool = True,
    resynth_m: float = RESYNTH_M,
    cells: str = "nearest",
    resynth_top: int = RESYNTH_TOP,
    search_m: float = SEARCH_M,
    resynth_step: float = RASTER_STEP_M,
) -> dict[str, np.ndarray]:
    """The twin estimator (module docstring). 2D only: the map is at one device height.

    Parameters
    ----------
    prob : Problem (2D: ``height`` known)
    map : FingerprintMap or path of a map file
    fallback : ``fallback(sub_problem) -> dict`` (``xyz``, ``status``), the map-free method
        that gives the search prior and the fix where the map does not fit
        (:func:`positioning.locate` binds the ``fallback`` method name, default ``irls``);
        None: :func:`positioning.irls.irls`
    fallback_m : float, m -- ``match_m`` above which a fix falls back
    prior_m : float or None, m -- only cells within this distance of the fallback fix are
        candidates (0: the whole map; None: :data:`RESYNTH_PRIOR_M` with ``bias="resynth"``,
        else :data:`PRIOR_M`)
    top : int -- candidate cells refined per fix
    bias : ``"cell"`` or ``"interp"``, the bias model of the refinement
        (:func:`refine_at_cells`); ``"resynth"`` (a map of schema version 2 only): then
        Gauss-Newton with the nearest cell's paths moved to the iterate and the receiver re-run
        on them (:func:`positioning.resynth.refine_resynth`); ``"auto"`` (default):
        ``"resynth"`` for a map with paths, else ``"cell"``
    paths : int or None, the strongest paths per cell and base station the re-synthesis uses
        (None or 0: all the map stores)
    fd_jacobian : bool, ``resynth`` only: Jacobian with the bias gradient by finite
        differences (default; False: the geometric Jacobian,
        :func:`positioning.resynth.refine_resynth`)
    resynth_m : float, m, ``resynth`` only: the re-synthesised solution is used when its RMS
        residual is at most this, else the cell-held one
    cells : ``"own"`` -- each candidate's paths are moved from its own cell;
        ``"nearest"`` (default) -- from the cell nearest to the iterate (switching as it moves)
    resynth_top : int, ``resynth`` only: how many of the best cell-held solutions are refined
        again with re-synthesised paths
    search_m : float, m, ``resynth`` only: > 0 starts Gauss-Newton from the best point of a
        5 x 5 grid spanning +-search_m around the cell-held solution (default 0.3 m; 0: from the
        cell-held solution itself)
    resynth_step : float, m, ``resynth`` only: the re-synthesised ToAs are sampled on a raster
        of this spacing around the visited cells and interpolated bilinearly
        (:class:`positioning.resynth.ToaRaster`, kept with a map loaded from a file, so later
        fixes near the same cells cost only look-ups; default 0.05 m); 0: the receiver is re-run
        at every iterate (exact, about 90x slower)

    Returns
    -------
    dict with ``xyz`` (E, 3), ``status`` (E,), ``iterations`` (E,), ``weights`` (E, N) (1 used,
    0 not received), ``nlos`` (E, N) bool, ``stale`` (E, N) bool, ``match_m`` (E,) m,
    ``fallback`` (E,) bool.
    """
    if map is None:
        raise PositioningError("method 'twin' needs a fingerprint map (--map MAP)")
    if prob.height is None:
        raise PositioningError("twin solves in 2D only (the map is at one height): drop --3d")
    fmap, lat = load(map)
    check_bs(fmap, prob.bs)
    if bias == "auto":
        bias = "resynth" if fmap.has_paths else "cell"
    if bias not in ("cell", "interp", "resynth"):
        raise PositioningError(f"twin: unknown bias model {bias!r} (cell, interp, resynth, auto)")
    if bias == "resynth" and not fmap.has_paths:
        raise PositioningError("twin: bias=resynth needs a map with paths (schema version 2)")
    if prior_m is None:
        prior_m = RESYNTH_PRIOR_M if bias == "resynth" else PRIOR_M
    E, B = prob.rho.shape
    rows = np.flatnonzero(prob.solvable)
    status = np.where(prob.solvable, 0, int(Status.UNSOLVED)).astype(np.int64)
    xyz = np.full((E, 3), np.nan)
    match = np.full(E, np.nan)
    nlos = np.zeros((E, B), dtype=bool)
    stale = np.zeros((E, B), dtype=bool)
    bad = np.zeros(E, dtype=bool)
    if rows.size:
        sub = prob.take(rows)
        fb = (fallback or irls)(sub)
        cell_xy = fmap.cell_xyz[:, :2]
        prior = fb["xyz"][:, :2]
        if prior_m > 0:
            cand, _ = window_match(sub, lat, prior, prior_m, top)
            # no prior (fallback unsolved) or nothing near it: the whole map
            lost = ~np.isfinite(prior).all(axis=1) | (cand[:, 0] < 0)
            if lost.any():
                cand[lost], _ = coarse_match(
                    sub.take(np.flatnonzero(lost)), lat, lat.coarse, cell_xy, top=top
                )
        else:
            cand, _ = coarse_match(sub, lat, lat.coarse, cell_xy, top=top)
        xy_k, rms_k = refine_at_cells(sub, lat, cell_xy, cand,
                                      mode="cell" if bias == "resynth" else bias)  # fmt: skip
        if bias == "resynth":
            # the resynth_top best cell-held solutions are refined again with re-synthesised
            # paths
            n_r = min(int(resynth_top), cand.shape[1])
            best = np.argsort(rms_k, axis=1, kind="stable")[:, :n_r]
            c_r = np.where(np.isfinite(np.take_along_axis(rms_k, best, axis=1)),
                           np.take_along_axis(cand, best, axis=1), -1)  # fmt: skip
            s_r = np.take_along_axis(xy_k, best[..., None], axis=1)
            rep = np.repeat(np.arange(rows.size), n_r)
            pmap = PathMap.from_map(fmap, paths)
            near = (lambda xy: nearest_cell(lat, xy)) if cells == "nearest" else None
            s_flat, c_flat = s_r.reshape(-1, 2), c_r.ravel()
            xy_f, rms_f = np.empty_like(s_flat), np.empty(rep.size)
            h_mm = np.rint(sub.height[rep] * 1000.0).astype(np.int64)
            use_raster = resynth_step > 0 and cells == "nearest"
            # per device height (one raster each), in blocks of fixes: without the raster the
            # start grid holds (fixes x top x 25, B, K) path arrays
            for hv in np.unique(h_mm) if use_raster else [None]:
                idx = np.flatnonzero(h_mm == hv) if use_raster else np.arange(rep.size)
                raster = _raster(lat, pmap, paths, resynth_step, hv) if use_raster else None
                chunk = (RASTER_CHUNK if use_raster else RESYNTH_CHUNK) * n_r
                for c0 in range(0, idx.size, chunk):
                    b = idx[c0 : c0 + chunk]
                    xy_f[b], rms_f[b] = refine_resynth(
                        sub.rho[rep[b]], sub.valid[rep[b]], sub.height[rep[b]], sub.bs, pmap,
                        near, s_flat[b], c_flat[b], lat.step * (REFINE_BOX + 0.5),
                        fd_jacobian=fd_jacobian, search_m=search_m, raster=raster,
                    )  # fmt: skip
            # the re-synthesised solution wins where it fits within resynth_m; where the
            # nearest cell's paths do not explain the measurements (a path appears or vanishes
            # between cell and device) the cell-held solution is kept
            rms_f = rms_f.reshape(-1, n_r)
            fits = np.min(rms_f, axis=1) <= resynth_m
            xy_k = np.where(fits[:, None, None], xy_f.reshape(-1, n_r, 2), s_r)
            rms_k = np.where(fits[:, None], rms_f, np.take_along_axis(rms_k, best, axis=1))
            cand = np.take_along_axis(cand, best, axis=1)
        k = np.argmin(rms_k, axis=1)
        ar = np.arange(rows.size)
        xy, m, cell = xy_k[ar, k], rms_k[ar, k], cand[ar, k]
        m = np.where(np.isfinite(m), m, np.nan)
        cbias = lat.pred[np.maximum(cell, 0)] - np.linalg.norm(
            fmap.cell_xyz[np.maximum(cell, 0)][:, None, :] - prob.bs[None], axis=2
        )
        worse = ~(m <= fallback_m)
        xyz[rows] = np.column_stack([xy, sub.height])
        xyz[rows[worse]] = fb["xyz"][worse]
        status[rows[worse]] |= np.asarray(fb["status"], np.int64)[worse] | int(Status.MAP_MISMATCH)
        match[rows] = m
        nlos[rows] = sub.valid & (cell >= 0)[:, None] & (cbias > NLOS_BIAS_M)
        stale[rows] = sub.valid & worse[:, None] & ~nlos[rows]
        bad[rows] = worse
    xyz[:, :2], _ = clamp_to_polygon(xyz[:, :2], lat.polygon)
    return {
        "xyz": xyz,
        "status": status,
        "iterations": np.where(prob.solvable, 1, 0),
        "weights": prob.valid.astype(float),
        "nlos": nlos,
        "stale": stale,
        "match_m": match,
        "fallback": bad,
    }
