"""Bounded solve: a fix that left the service area is solved again inside it.

Every method first solves without bounds. Where its fix is outside the problem's
:class:`~positioning.model.area.ServiceArea` (or not finite), :func:`bounded_refit` minimises the
weighted pseudo-range least squares of that epoch::

    cost(p) = min_beta sum_n W_n (rho_n - |p - b_n| - beta)^2,      p_xy in the area

with ``W`` the method's own final measurement weights (equal weights for the methods that have
none), so the bounded fix is the method's fit where the unbounded one was not allowed.

The cost is not convex (TDoA least squares can have its optimum at infinity and local minima
inside), so the search is global first: the cost, with ``beta`` concentrated out, is evaluated on
a grid of the area (pitch :data:`GRID_STEP_M`), along its outline (:data:`OUTLINE_STEP_M`) and at
the projection of the unbounded fix; from the best grid point, the best outline point and the
projection, a projected Levenberg-Marquardt iteration (each step's horizontal position put back
into the area) refines, and the lowest final cost wins. ``test_bounded_fit_matches_grid`` checks
it against a brute-force 5 cm grid.
"""

from __future__ import annotations

import numpy as np

from ..model.problem import Problem
from ..model.residuals import pseudorange_model
from ..model.tdoa import ranges_and_units
from .solver import safe_solve

#: Pitch of the interior grid of the global search, metres (1 m: a cost basin of the LS problem
#: is at least a range resolution wide, c/B = 0.75-3 m).
GRID_STEP_M = 1.0
#: Spacing of the outline samples, metres.
OUTLINE_STEP_M = 0.25
#: Grid points evaluated at once (memory: chunk x epochs x N floats).
_CHUNK = 4096


def concentrated_cost(prob: Problem, xyz: np.ndarray, idx: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(A,) ``min_beta sum_n W_n (rho_n - |p - b_n| - beta)^2`` at positions ``xyz`` (A, 3) of
    epochs ``idx`` (A,) with weights ``W`` (A, N); the minimising beta is the weighted mean."""
    R, _ = ranges_and_units(xyz, prob.bs, 3)
    s = np.where(W > 0, prob.rho[idx] - R, 0.0)
    wsum = np.maximum(W.sum(axis=1), 1e-300)
    beta = np.sum(W * s, axis=1) / wsum
    return np.sum(W * (s - beta[:, None]) ** 2, axis=1)


def _z_start(prob: Problem, idx: np.ndarray, xyz0: np.ndarray) -> np.ndarray:
    """(A,) device heights to start from: known (2D), else the unbounded z if it is within the
    base stations' heights +- 10 m, else their mean height."""
    if prob.height is not None:
        return prob.height[idx]
    z0 = xyz0[:, 2]
    zb = prob.bs[:, 2]
    ok = np.isfinite(z0) & (z0 >= zb.min() - 10.0) & (z0 <= zb.max() + 10.0)
    return np.where(ok, z0, zb.mean())


def _best_of(prob: Problem, idx: np.ndarray, W: np.ndarray, z: np.ndarray, pts: np.ndarray):
    """(A, 2) the point of ``pts`` (G, 2) of lowest cost for each epoch, and (A,) that cost."""
    A = idx.size
    best = np.full(A, np.inf)
    arg = np.zeros((A, 2))
    for g0 in range(0, pts.shape[0], max(_CHUNK // max(A, 1), 16)):
        g = pts[g0 : g0 + max(_CHUNK // max(A, 1), 16)]
        G = g.shape[0]
        xyz = np.empty((A, G, 3))
        xyz[..., :2] = g[None]
        xyz[..., 2] = z[:, None]
        c = concentrated_cost(
            prob, xyz.reshape(-1, 3), np.repeat(idx, G), np.repeat(W, G, axis=0)
        ).reshape(A, G)
        k = np.argmin(c, axis=1)
        ck = c[np.arange(A), k]
        better = ck < best
        best = np.where(better, ck, best)
        arg[better] = g[k[better]]
    return arg, best


def projected_lm(
    prob: Problem, idx: np.ndarray, theta0: np.ndarray, W: np.ndarray, *, tol: float, max_iter: int
) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the pseudo-range model with each trial point's horizontal position
    projected into the service area (a step is kept only if it lowers the cost).

    Parameters
    ----------
    idx : (A,) epochs; theta0 : (A, dims+1) start inside the area; W : (A, N) weights

    Returns
    -------
    theta (A, dims+1) and cost (A,) at the end.
    """
    area = prob.area
    assert area is not None
    fun = pseudorange_model(prob)
    dims = prob.dims
    k = dims + 1
    theta = theta0.copy()
    r, J = fun(theta, idx)
    cost = np.sum(W * r * r, axis=1)
    lam = np.full(idx.size, 1e-3)
    act = np.arange(idx.size)
    diag = np.arange(k)
    for _ in range(max_iter):
        if act.size == 0:
            break
        Wa = W[act]
        JW = J[act] * Wa[..., None]
        A = np.matmul(JW.transpose(0, 2, 1), J[act])
        g = np.matmul(JW.transpose(0, 2, 1), r[act][..., None])
        A[:, diag, diag] += lam[act, None] * A[:, diag, diag] + 1e-12
        delta, _ = safe_solve(A, g)
        delta = np.where(np.isfinite(delta[..., 0]), delta[..., 0], 0.0)
        th = theta[act] + delta
        th[:, :2] = area.project(th[:, :2])
        r_new, J_new = fun(th, idx[act])
        c_new = np.sum(Wa * r_new * r_new, axis=1)
        ok = c_new <= cost[act]
        step = np.linalg.norm(th - theta[act], axis=1)
        sel = act[ok]
        theta[sel], r[sel], J[sel], cost[sel] = th[ok], r_new[ok], J_new[ok], c_new[ok]
        lam[act] = np.where(ok, np.maximum(lam[act] * 0.1, 1e-12), np.minimum(lam[act] * 10, 1e12))
        act = act[~((step <= tol) | (lam[act] >= 1e12))]
    return theta, cost


def bounded_refit(
    prob: Problem,
    idx: np.ndarray,
    xyz0: np.ndarray,
    W: np.ndarray,
    *,
    tol: float = 1e-6,
    max_iter: int = 60,
) -> tuple[np.ndarray, np.ndarray]:
    """Best weighted pseudo-range fit inside the service area for epochs ``idx``.

    Parameters
    ----------
    prob : Problem with ``area`` set
    idx : (A,) int -- epochs to re-solve
    xyz0 : (A, 3) float, metres -- their unbounded fixes (may be NaN)
    W : (A, N) float -- measurement weights (0 = unused; missing ToAs are excluded anyway)

    Returns
    -------
    xyz : (A, 3) float, metres, horizontally inside the area; cost : (A,) float, m^2
    """
    area = prob.area
    if area is None:
        raise ValueError("bounded_refit needs a problem with a service area")
    A = idx.size
    if A == 0:
        return np.empty((0, 3)), np.empty(0)
    W = np.where(prob.valid[idx], W, 0.0)
    # no usable weight left (a method that weighted everything out): all received alike
    W = np.where((W > 0).sum(axis=1, keepdims=True) >= prob.min_bs, W, prob.valid[idx] * 1.0)
    z = _z_start(prob, idx, xyz0)
    starts = [
        area.project(np.where(np.isfinite(xyz0[:, :2]), xyz0[:, :2], area.polygon[0])),
        _best_of(prob, idx, W, z, area.grid(GRID_STEP_M))[0],
        _best_of(prob, idx, W, z, area.outline(OUTLINE_STEP_M))[0],
    ]
    best_cost = np.full(A, np.inf)
    best = np.full((A, 3), np.nan)
    for xy in starts:
        xyz = np.column_stack([xy, z])
        R, _ = ranges_and_units(xyz, prob.bs, 3)
        s = np.where(W > 0, prob.rho[idx] - R, 0.0)
        beta = np.sum(W * s, axis=1) / np.maximum(W.sum(axis=1), 1e-300)
        theta0 = np.column_stack([xyz[:, : prob.dims], beta])
        theta, _ = projected_lm(prob, idx, theta0, W, tol=tol, max_iter=max_iter)
        pos = prob.position(theta, idx)
        cost = concentrated_cost(prob, pos, idx, W)  # beta at its exact best
        better = cost < best_cost
        best_cost = np.where(better, cost, best_cost)
        best[better] = pos[better]
    return best, best_cost
