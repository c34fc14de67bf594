"""The batched least-squares machinery every estimator uses.

All solvers are batched over epochs: arrays carry a leading epoch axis ``E`` and Gauss-Newton with
Levenberg-Marquardt damping runs on all unfinished epochs at once (no Python loop per epoch).
Missing measurements (NaN ToA) enter with weight 0.

* :func:`levenberg_marquardt`: weighted nonlinear least squares of a residual function of
  :mod:`positioning.model.residuals`, batched over epochs;
* :func:`linear_start`: the closed-form start (spherical intersection, Chan / Fang);
* :func:`solve_tdoa` and :func:`solve_pseudorange`: the two ready-made solves (eq. 7 against a
  reference; the pseudo-range model with measurement weights), returning a :class:`Solution`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.problem import Problem
from ..model.residuals import ModelFun, pseudorange_model, tdoa_model
from ..model.tdoa import ranges_and_units

#: Condition number of the normal matrix above which a fix is flagged ``ILL_CONDITIONED``.
COND_LIMIT = 1e10

# Relative threshold for a singular normal matrix in the closed-form start.
_SINGULAR_REL = 1e-12


def safe_solve(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched ``solve(A, b)``: singular matrices give NaN rows instead of raising for the batch.

    Parameters
    ----------
    A : (A, k, k) float, normal matrices; b : (A, k, m) float, right-hand sides

    Returns
    -------
    x : (A, k, m) float (NaN where singular); singular : (A,) bool -- a matrix is singular when
    its determinant is not above ``1e-12`` times its mean diagonal to the power ``k`` (or that
    mean is not positive).
    """
    k = A.shape[-1]
    scale = np.trace(A, axis1=1, axis2=2) / k
    det = np.linalg.det(A)
    bad = ~np.isfinite(det) | ~(np.abs(det) > _SINGULAR_REL * np.abs(scale) ** k) | (scale <= 0)
    A_safe = np.where(bad[:, None, None], np.eye(k)[None], A)
    x = np.linalg.solve(A_safe, b)
    x[bad] = np.nan
    return x, bad


def levenberg_marquardt(
    fun: ModelFun,
    theta0: np.ndarray,
    W: np.ndarray,
    *,
    tol: float,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched weighted nonlinear least squares ``min sum_n W_n r_n(theta)^2`` per epoch.

    Gauss-Newton steps ``(J^T W J + lambda diag(J^T W J)) delta = J^T W r`` with Marquardt
    damping: ``lambda`` starts at 1e-3, shrinks 10x after a step that lowers the cost (so near the
    solution the iteration is Gauss-Newton, quadratically convergent) and grows 10x after a step
    that does not (which is then rejected). Epochs leave the batch once a step is shorter than
    ``tol``, so late epochs do not cost the finished ones anything.

    Parameters
    ----------
    fun : ``fun(theta (A, k), idx (A,)) -> (r (A, M), J (A, M, k))``, residual = obs - model
    theta0 : (E, k) float -- start; rows with NaN are skipped (left NaN)
    W : (E, M) float -- non-negative weights (0 = unused)
    tol : float -- step-length tolerance, same unit as theta (m)
    max_iter : int

    Returns
    -------
    theta : (E, k) float; iterations : (E,) int; converged : (E,) bool
    """
    E, k = theta0.shape
    theta = theta0.copy()
    iterations = np.zeros(E, dtype=np.int64)
    converged = np.zeros(E, dtype=bool)
    act = np.flatnonzero(np.isfinite(theta0).all(axis=1))
    if act.size == 0 or max_iter <= 0:
        return theta, iterations, converged
    r, J = fun(theta[act], act)
    Wa = W[act]
    cost = np.sum(Wa * r * r, axis=1)
    lam = np.full(act.size, 1e-3)
    diag = np.arange(k)
    for _ in range(max_iter):
        JW = J * Wa[..., None]
        A = np.matmul(JW.transpose(0, 2, 1), J)
        g = np.matmul(JW.transpose(0, 2, 1), r[..., None])
        # Marquardt scaling plus a tiny absolute term so an all-zero row/column stays solvable.
        A[:, diag, diag] += lam[:, None] * A[:, diag, diag] + 1e-12
        delta, _ = safe_solve(A, g)
        delta = delta[..., 0]
        delta = np.where(np.isfinite(delta), delta, 0.0)
        th_new = theta[act] + delta
        r_new, J_new = fun(th_new, act)
        cost_new = np.sum(Wa * r_new * r_new, axis=1)
        ok = cost_new <= cost
        sel = act[ok]
        theta[sel] = th_new[ok]
        r[ok], J[ok], cost[ok] = r_new[ok], J_new[ok], cost_new[ok]
        lam = np.where(ok, np.maximum(lam * 0.1, 1e-12), np.minimum(lam * 10.0, 1e12))
        iterations[act] += 1
        # A rejected step shorter than tol means no nearby point is better: converged as well.
        done = np.linalg.norm(delta, axis=1) <= tol
        converged[act[done]] = True
        keep = ~done
        if not keep.any():
            break
        act, r, J, Wa, cost, lam = act[keep], r[keep], J[keep], Wa[keep], cost[keep], lam[keep]
    return theta, iterations, converged


def ill_conditioned(fun: ModelFun, theta: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(E,) bool: normal matrix ``J^T W J`` at ``theta`` has condition number above COND_LIMIT."""
    E = theta.shape[0]
    out = np.zeros(E, dtype=bool)
    idx = np.flatnonzero(np.isfinite(theta).all(axis=1))
    if idx.size == 0:
        return out
    _, J = fun(theta[idx], idx)
    JW = J * W[idx][..., None]
    A = np.matmul(JW.transpose(0, 2, 1), J)
    ev = np.linalg.eigvalsh(A)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = ev[:, -1] / ev[:, 0]
    out[idx] = ~(np.abs(cond) <= COND_LIMIT) | (ev[:, 0] <= 0)
    return out


def first_valid(mask: np.ndarray) -> np.ndarray:
    """(E,) index of the first True per row (0 for an all-False row)."""
    return np.argmax(mask, axis=1)


def linear_start(prob: Problem, W: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Closed-form starting positions from the linearised TDoA equations (spherical intersection).

    With ``r_e = |p - b_e|`` unknown and ``dd_n = rho_n - rho_e``, squaring
    ``|p - b_n| = dd_n + r_e`` and subtracting the same for ``e`` gives equations linear in ``p``
    for a given ``r_e``::

        2 (b_n - b_e) . p = |b_n|^2 - |b_e|^2 - dd_n^2 - 2 dd_n r_e

    (with the known height moved to the right in 2D). Their weighted least-squares solution is
    ``p(r_e) = a + r_e c``; putting it into ``|p(r_e) - b_e| = r_e`` gives a quadratic in ``r_e``
    (Chan / Fang). Of its non-negative roots the one with the smaller TDoA residual is taken (ties,
    as in an exactly determined set, go to the one nearer the base stations' centroid). Where the
    linear system is singular (e.g. collinear base stations) or no root exists, the start is the
    centroid of the received base stations.

    Parameters
    ----------
    prob : Problem
    W : (E, N) -- weights; a base station takes part where ``W > 0`` and it is received
    ref : (E,) int -- reference base station per epoch (must be received)

    Returns
    -------
    (E, 3) float, metres (z = height in 2D).
    """
    E, N = prob.rho.shape
    dims = prob.dims
    ar = np.arange(E)
    bs = prob.bs
    use = (W > 0) & prob.valid
    Wm = (use & (np.arange(N)[None, :] != ref[:, None])).astype(float)
    rho = np.where(prob.valid, prob.rho, 0.0)
    d = rho - rho[ar, ref][:, None]
    be = bs[ref]
    G = 2.0 * (bs[None, :, :dims] - be[:, None, :dims])
    g0 = np.sum(bs**2, axis=1)[None, :] - np.sum(be**2, axis=1)[:, None] - d**2
    if prob.height is not None:
        g0 = g0 - 2.0 * (bs[None, :, 2] - be[:, None, 2]) * prob.height[:, None]
    g1 = -2.0 * d
    Gw = G * Wm[..., None]
    A = np.matmul(Gw.transpose(0, 2, 1), G)
    rhs = np.matmul(Gw.transpose(0, 2, 1), np.stack([g0, g1], axis=2))
    sol, bad = safe_solve(A, rhs)
    a, c = sol[..., 0], sol[..., 1]
    D = a - be[:, :dims]
    hz2 = 0.0 if prob.height is None else (prob.height - be[:, 2]) ** 2
    qa = np.sum(c * c, axis=1) - 1.0
    qb = 2.0 * np.sum(D * c, axis=1)
    qc = np.sum(D * D, axis=1) + hz2
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (qb + np.where(qb >= 0, sq, -sq))
        r1 = np.where(np.abs(qa) > 1e-12, q / qa, -qc / qb)
        r2 = np.where(np.abs(qa) > 1e-12, qc / q, np.nan)
        # No real root (noise): the vertex of the parabola is the least-violating r_e.
        vertex = np.maximum(-qb / (2.0 * qa), 0.0)
    r1 = np.where(disc < 0, vertex, r1)
    r2 = np.where(disc < 0, np.nan, r2)

    cent = _centroid(prob, use)

    def candidate(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ok = np.isfinite(r) & (r >= -1e-9)
        xy = a + r[:, None] * c
        p = _embed(prob, xy, ar)
        R, _ = ranges_and_units(p, bs, dims)
        res = d - (R - R[ar, ref][:, None])
        sse = np.sum(Wm * np.where(np.isfinite(res), res, 0.0) ** 2, axis=1)
        sse = np.where(ok & np.isfinite(p).all(axis=1), sse, np.inf)
        return p, sse

    p1, s1 = candidate(r1)
    p2, s2 = candidate(r2)
    with np.errstate(invalid="ignore"):
        tie = np.abs(s1 - s2) <= 1e-9 * (1.0 + np.minimum(s1, s2))
    closer2 = np.linalg.norm((p2 - cent)[:, :2], axis=1) < np.linalg.norm(
        (p1 - cent)[:, :2], axis=1
    )
    pick2 = np.where(tie & np.isfinite(s1), closer2, s2 < s1)
    p = np.where(pick2[:, None], p2, p1)
    fail = bad | ~np.isfinite(np.minimum(s1, s2)) | ~np.isfinite(p).all(axis=1)
    return np.where(fail[:, None], cent, p)


def _embed(prob: Problem, xy: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(A, 3) positions from (A, dims) coordinates (adds the known height in 2D)."""
    if prob.height is None:
        return xy[:, :3]
    return np.column_stack([xy[:, 0], xy[:, 1], prob.height[idx]])


def _centroid(prob: Problem, use: np.ndarray) -> np.ndarray:
    """(E, 3) centroid of the used base stations (height replaced by the known one in 2D)."""
    w = use.astype(float)
    n = np.maximum(w.sum(axis=1), 1.0)
    cent = (w @ prob.bs) / n[:, None]
    if prob.height is not None:
        cent[:, 2] = prob.height
    return cent


@dataclass(frozen=True)
class Solution:
    """Batched solver output (E epochs)."""

    theta: np.ndarray  # (E, k) unknowns (x, y[, z][, beta]); NaN where not solved
    xyz: np.ndarray  # (E, 3) positions, metres
    iterations: np.ndarray  # (E,) int
    converged: np.ndarray  # (E,) bool
    ill: np.ndarray  # (E,) bool, ILL_CONDITIONED


def solve_tdoa(
    prob: Problem,
    ref: np.ndarray,
    rows: np.ndarray,
    *,
    tol: float,
    max_iter: int,
) -> Solution:
    """Least squares of eq. 7 with reference ``ref`` (E,) on the epochs where ``rows`` (E,) is True.

    The start is :func:`linear_start`; the solve is :func:`levenberg_marquardt`.
    """
    fun, W = tdoa_model(prob, ref)
    start = linear_start(prob, W + (np.arange(prob.n_bs)[None, :] == ref[:, None]), ref)
    theta0 = np.where(rows[:, None], start[:, : prob.dims], np.nan)
    theta, it, conv = levenberg_marquardt(fun, theta0, W, tol=tol, max_iter=max_iter)
    ill = ill_conditioned(fun, theta, W)
    xyz = np.where(rows[:, None], _embed(prob, theta, np.arange(prob.n_epochs)), np.nan)
    return Solution(theta=theta, xyz=xyz, iterations=it, converged=conv, ill=ill)


def pseudorange_start(prob: Problem, W: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(E, dims+1) closed-form start ``(x, y[, z], beta)`` using the base stations with ``W > 0``.

    Position from :func:`linear_start` referenced to the first used base station, ``beta`` the
    weighted mean of ``rho_n - |p - b_n|``. NaN rows where ``rows`` is False.
    """
    use = (W > 0) & prob.valid
    ref = first_valid(use)
    p = linear_start(prob, use.astype(float), ref)
    R, _ = ranges_and_units(p, prob.bs, prob.dims)
    w = np.where(use, W, 0.0)
    beta = np.sum(w * np.where(use, prob.rho - R, 0.0), axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    theta = np.column_stack([p[:, : prob.dims], beta])
    return np.where(rows[:, None], theta, np.nan)


def solve_pseudorange(
    prob: Problem,
    W: np.ndarray,
    rows: np.ndarray,
    *,
    tol: float,
    max_iter: int,
    theta0: np.ndarray | None = None,
) -> Solution:
    """Weighted least squares of the pseudo-range model on the epochs where ``rows`` is True.

    Parameters
    ----------
    W : (E, N) float -- measurement weights (0 = excluded); missing ToAs are excluded anyway.
    theta0 : (E, dims+1) float, optional -- start (default :func:`pseudorange_start`).
    """
    W = np.where(prob.valid, W, 0.0)
    fun = pseudorange_model(prob)
    if theta0 is None:
        theta0 = pseudorange_start(prob, W, rows)
    theta0 = np.where(rows[:, None], theta0, np.nan)
    theta, it, conv = levenberg_marquardt(fun, theta0, W, tol=tol, max_iter=max_iter)
    ill = ill_conditioned(fun, theta, W)
    xyz = _embed(prob, theta, np.arange(prob.n_epochs))
    return Solution(theta=theta, xyz=xyz, iterations=it, converged=conv, ill=ill)
