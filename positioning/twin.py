"""``twin``: positioning against a ray-traced fingerprint map that knows where the NLoS biases are.

With 4 base stations in 2D a single epoch has one redundant measurement, so no residual test can
tell which base station is biased. The map (:mod:`positioning.fingerprint`, written by
``accuracy-map``) predicts, per grid cell and base station, the first-arrival ToA of the receiver
including its NLoS excess. The twin moves that bias from the unknowns into the model::

    rho_n = |p - b_n| + bias_n(p) + beta + e_n,       bias_n(p) = c toa_s[cell, n] - |cell - b_n|

(``rho_n`` the pseudo-range of :mod:`positioning.tdoa`, ``beta`` the clock offset times c).

1. **Match.** On the map's cells (a coarse sub-lattice of at most :data:`COARSE_CELLS` cells),
   the least-squares misfit of the measured pseudo-ranges to the predicted ones ``c toa_s`` with
   the offset ``beta`` free, ``min_beta sum_n (rho_n - c toa_s[c, n] - beta)^2``, for every fix
   and cell at once (matrix products per pattern of received base stations).
2. **Refine** from the best cell: Gauss-Newton on ``(x, y, beta)`` of the model above with
   ``bias_n(p)`` interpolated bilinearly between cells, and the one-sided robust weights of
   ``nlos-aware`` on the residuals (a base station *later* than the map predicts by more than
   ``k sigma_m`` is down-weighted as ``(k sigma_m / r)^2``: moving forklifts only add delay).
3. **Judge.** ``match_m`` = RMS residual of all received base stations at the solution (offset
   re-fitted); per base station ``nlos`` = the map's bias there exceeds :data:`NLOS_BIAS_M` or
   the link was down-weighted (weight below 0.5, ``stale``).
4. **Fall back.** A fix with ``match_m > fallback_m`` does not fit the map (a stale map: forklifts
   that moved): it is replaced by the map-free ``fallback`` method's fix (default ``irls``) and
   flagged ``MAP_MISMATCH``.
5. **Bound.** Every fix is moved into the map's service area (``meta["service_area"]``, else the
   cells' bounding box) if it lies outside.

The map is checked on load (:func:`positioning.fingerprint.read_map`, one-line errors); a map
whose base stations are not the dataset's (count or positions off by more than
:data:`BS_TOL_M`) is refused.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import PositioningError
from .fingerprint import FingerprintMap, read_map
from .fixes import Status
from .irls import irls
from .tdoa import C0, Problem

#: Largest distance between a map's and the dataset's base station, metres.
BS_TOL_M = 0.01
#: The coarse match uses a sub-lattice of at most this many cells (speed).
COARSE_CELLS = 1200
#: A map bias above this (m) marks the base station as NLoS at the fix.
NLOS_BIAS_M = 0.25
#: Defaults: ranging noise (m), one-sided loss knee (in sigma), fallback threshold on match_m (m).
SIGMA_M = 0.15
NLOS_K = 3.0
FALLBACK_M = 0.6
#: Gauss-Newton iterations of the refinement (each re-interpolates the bias).
REFINE_ITER = 8


@dataclass(frozen=True)
class _Lattice:
    """A map's cells on a regular lattice with the bias per node (holes filled by the nearest
    cell), plus the coarse sub-lattice's cells."""

    x0: float
    y0: float
    step: float
    bias: np.ndarray  # (ny, nx, B) m, holes and undetected links filled from the nearest cell
    coarse: np.ndarray  # (C,) indices of map cells of the coarse search
    pred: np.ndarray  # (N, B) c * toa_s, m (NaN: not detected)
    polygon: np.ndarray  # (V, 2) service area


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
    stride = max(1, int(np.ceil(np.sqrt(m.n_cells / COARSE_CELLS))))
    coarse = np.flatnonzero((ix % stride == 0) & (iy % stride == 0))
    return _Lattice(float(xs[0]), float(ys[0]), step, bias, coarse, pred, _service_polygon(m, step))


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


# ----------------------------------------------------------------------------------------------
# stage 1: coarse match over cells


def coarse_match(prob: Problem, lat: _Lattice, cells: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """(E,) index (into the map's cells) of the best cell among ``cells`` for every fix.

    Least-squares misfit with a free offset, ``sum w (rho - pred)^2 - (sum w (rho - pred))^2 /
    sum w``, expanded into matrix products, per pattern of received base stations (a cell whose
    prediction misses a received base station is not a candidate for that pattern).
    """
    E = prob.n_epochs
    best = np.full(E, -1, dtype=np.int64)
    pred = lat.pred[cells]  # (C, B)
    patterns, inv = np.unique(prob.valid, axis=0, return_inverse=True)
    inv = inv.ravel()
    for k, pat in enumerate(patterns):
        if pat.sum() < prob.min_bs:
            continue
        ok = np.isfinite(pred[:, pat]).all(axis=1)
        if not ok.any():
            continue
        M = pred[np.ix_(ok, pat)]  # (C', n)
        n = int(pat.sum())
        m2 = np.sum(M * M, axis=1) - M.sum(axis=1) ** 2 / n  # (C',)
        ms = M.sum(axis=1)
        rows = np.flatnonzero(inv == k)
        for s in range(0, rows.size, chunk):
            r = rows[s : s + chunk]
            rho = prob.rho[np.ix_(r, pat)]
            rs = rho.sum(axis=1)
            # cost = |rho|^2 - 2 rho.M + |M|^2 - (rs - ms)^2 / n; the |rho|^2 and rs^2 terms are
            # the same for every cell and are left out of the argmin
            cost = m2[None, :] - 2.0 * (rho @ M.T) + (2.0 / n) * rs[:, None] * ms[None, :]
            best[r] = cells[ok][np.argmin(cost, axis=1)]
    return best


# ----------------------------------------------------------------------------------------------
# stage 2: refinement with the interpolated bias


def interp_bias(lat: _Lattice, xy: np.ndarray) -> np.ndarray:
    """(A, B) bias at ``xy`` (A, 2), bilinear between lattice nodes (clamped at the edges)."""
    ny, nx, _ = lat.bias.shape
    u = np.clip((xy[:, 0] - lat.x0) / lat.step, 0.0, nx - 1.000001)
    v = np.clip((xy[:, 1] - lat.y0) / lat.step, 0.0, ny - 1.000001)
    u = np.where(np.isfinite(u), u, 0.0)
    v = np.where(np.isfinite(v), v, 0.0)
    i, j = u.astype(int), v.astype(int)
    i1, j1 = np.minimum(i + 1, nx - 1), np.minimum(j + 1, ny - 1)
    fu, fv = (u - i)[:, None], (v - j)[:, None]
    b = lat.bias
    return (
        (1 - fu) * (1 - fv) * b[j, i]
        + fu * (1 - fv) * b[j, i1]
        + (1 - fu) * fv * b[j1, i]
        + fu * fv * b[j1, i1]
    )


def _residuals(prob: Problem, lat: _Lattice, xy: np.ndarray, idx: np.ndarray):
    """Residuals without offset ``rho - |p - b| - bias(p)`` (A, B) and d|p - b|/d(x, y)."""
    p = np.column_stack([xy, prob.height[idx]])
    diff = p[:, None, :] - prob.bs[None, :, :]
    R = np.linalg.norm(diff, axis=2)
    U = diff[..., :2] / np.maximum(R, 1e-12)[..., None]
    s = prob.rho[idx] - R - interp_bias(lat, xy)
    return s, U


def refine(
    prob: Problem, lat: _Lattice, xy0: np.ndarray, *, sigma_m: float, k: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust Gauss-Newton of the biased model from ``xy0`` (E, 2).

    Returns xy (E, 2), the robust weights (E, B) and the offset-free residuals (E, B).
    """
    E, B = prob.rho.shape
    idx = np.arange(E)
    xy = xy0.copy()
    valid = prob.valid
    w = valid.astype(float)
    for _ in range(REFINE_ITER):
        s, U = _residuals(prob, lat, xy, idx)
        s = np.where(valid, s, 0.0)
        beta = _wmean(s, w)
        r = s - beta[:, None]
        # one-sided weights (nlos-aware's loss on the map residual): late beyond k sigma only
        z = r / sigma_m
        w = np.where(valid, np.where(z > k, (k / np.maximum(z, k)) ** 2, 1.0), 0.0)
        # Gauss-Newton on (x, y, beta): J = d pred / d theta = [U, 1] (bias gradient neglected)
        J = np.concatenate([U, np.ones((E, B, 1))], axis=2)
        JW = J * w[..., None]
        A = JW.transpose(0, 2, 1) @ J + 1e-9 * np.eye(3)
        g = JW.transpose(0, 2, 1) @ r[..., None]
        delta = np.linalg.solve(A, g)[..., 0]
        step = np.clip(delta[:, :2], -2.0, 2.0)  # a bias jump must not throw the fix away
        xy = xy + np.where(np.isfinite(step), step, 0.0)
    s, _ = _residuals(prob, lat, xy, idx)
    s = np.where(valid, s, np.nan)
    return xy, w, s


def _wmean(s: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.sum(w * s, axis=1) / np.maximum(np.sum(w, axis=1), 1e-300)


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
    sigma_m: float = SIGMA_M,
    k: float = NLOS_K,
) -> dict[str, np.ndarray]:
    """The twin estimator (module docstring). 2D only: the map is at one device height.

    Parameters
    ----------
    prob : Problem (2D: ``height`` known)
    map : FingerprintMap or path of a map file
    fallback : ``fallback(sub_problem) -> dict`` (``xyz``, ``status``), the map-free method for
        fixes that do not fit the map (:func:`positioning.locate` binds the ``fallback`` method
        name, default ``irls``); None: :func:`positioning.irls.irls`
    fallback_m : float, m -- ``match_m`` above which a fix falls back (default 0.6 m)
    sigma_m : float, m -- ranging noise of the one-sided loss (default 0.15 m)
    k : float -- knee of the one-sided loss in units of ``sigma_m`` (default 3)

    Returns
    -------
    dict with ``xyz`` (E, 3), ``status`` (E,), ``iterations`` (E,), ``weights`` (E, N) (robust
    weight per base station), ``nlos`` (E, N) bool, ``stale`` (E, N) bool, ``match_m`` (E,) m,
    ``fallback`` (E,) bool.
    """
    if map is None:
        raise PositioningError("method 'twin' needs a fingerprint map (--map MAP)")
    if prob.height is None:
        raise PositioningError("twin solves in 2D only (the map is at one height): drop --3d")
    fmap, lat = load(map)
    check_bs(fmap, prob.bs)
    E, B = prob.rho.shape
    rows = prob.solvable
    status = np.where(rows, 0, int(Status.UNSOLVED)).astype(np.int64)
    cell = coarse_match(prob, lat, lat.coarse)
    found = rows & (cell >= 0)
    xy0 = np.where(found[:, None], fmap.cell_xyz[np.maximum(cell, 0), :2], np.nan)
    sub = _take(prob, np.flatnonzero(found))
    xy = np.full((E, 2), np.nan)
    w = np.zeros((E, B))
    s = np.full((E, B), np.nan)
    if sub.n_epochs:
        xy[found], w[found], s[found] = refine(sub, lat, xy0[found], sigma_m=sigma_m, k=k)
    match = np.where(found, match_quality(s, prob.valid), np.nan)
    bias = np.where(found[:, None], interp_bias(lat, np.nan_to_num(xy)), np.nan)
    stale = found[:, None] & prob.valid & (w < 0.5)
    nlos = found[:, None] & prob.valid & ((bias > NLOS_BIAS_M) | stale)
    bad = rows & ~(match <= fallback_m)
    xyz = np.column_stack([xy, np.where(np.isfinite(xy[:, 0]), prob.height, np.nan)])
    if bad.any():
        fb = (fallback or irls)(_take(prob, np.flatnonzero(bad)))
        xyz[bad] = fb["xyz"]
        status[bad] |= np.asarray(fb["status"], dtype=np.int64) | int(Status.MAP_MISMATCH)
    xyz[:, :2], _ = clamp_to_polygon(xyz[:, :2], lat.polygon)
    xyz[~rows] = np.nan
    return {
        "xyz": xyz,
        "status": status,
        "iterations": np.where(found, REFINE_ITER, 0),
        "weights": w,
        "nlos": nlos,
        "stale": stale,
        "match_m": match,
        "fallback": bad,
    }


def _take(prob: Problem, idx: np.ndarray) -> Problem:
    return Problem(
        rho=prob.rho[idx],
        valid=prob.valid[idx],
        bs=prob.bs,
        height=None if prob.height is None else prob.height[idx],
    )
