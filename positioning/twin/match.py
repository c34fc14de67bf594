"""The twin's match of the measured pseudo-ranges to a fingerprint map's cells, and the
refinement of the best cells with their bias held (or interpolated).

* :func:`window_match`: the best cells within a radius of a prior fix (the map-free method's);
* :func:`coarse_match`: the best cells of the whole map (where there is no prior);
* :func:`refine_at_cells`: Gauss-Newton on ``(x, y, beta)`` of the biased model
  ``rho_n = |p - b_n| + bias_n + beta`` at each candidate cell, the position kept near the cell.

The misfit of a cell is the least-squares misfit with a free clock offset,
``min_beta sum_n (rho_n - c toa_s[cell, n] - beta)^2``.
"""

from __future__ import annotations

import numpy as np

from ..model.problem import Problem
from .lattice import Lattice, interp_bias
from .resynth import normal_step

#: :func:`window_match` groups the fixes by window centre when there are at least this many
#: fixes per centre on average (matrix products per group; else one gather per fix).
WINDOW_GROUP = 4
#: Gauss-Newton iterations of the refinement.
REFINE_ITER = 5
#: The refined fix stays within this many grid steps of its cell centre (per coordinate).
REFINE_BOX = 1.0


def coarse_match(
    prob: Problem,
    lat: Lattice,
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
    lat: Lattice,
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
    lat: Lattice,
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


def match_quality(s: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(E,) RMS of the offset-free residuals ``s`` (E, B) of all received base stations about
    their mean (the least-squares offset), metres; NaN where fewer than two."""
    n = valid.sum(axis=1)
    mean = np.nansum(np.where(valid, s, 0.0), axis=1) / np.maximum(n, 1)
    d = np.where(valid, s - mean[:, None], 0.0)
    with np.errstate(invalid="ignore"):
        return np.where(n >= 2, np.sqrt(np.sum(d * d, axis=1) / np.maximum(n - 1, 1)), np.nan)
