"""The paper's estimators: reference-based least squares (eq. 7) and IRLS (Algorithm 1, eqs. 8-12).

Both are batched over epochs and return :class:`~positioning.estimators.fixes.Fixes`; their
settings are :class:`LsConfig` and :class:`IrlsConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.problem import Problem
from .eq7 import GRID_M, choose_reference, parse_reference, solve_eq7
from .fixes import Fixes, Status, config_params


def plausible(prob: Problem, xyz: np.ndarray, margin: float) -> np.ndarray:
    """(n,) bool: ``xyz`` lies within the base stations' horizontal bounding box grown on every
    side by ``margin`` times its diagonal.

    TDoA least squares can converge far outside the deployment, on a hyperbola asymptote or where
    the base stations look collinear from the device; such a fit is not a position estimate.
    """
    lo, hi = region_box(prob, margin)
    xy = xyz[:, :2]
    with np.errstate(invalid="ignore"):
        return np.all((xy >= lo) & (xy <= hi), axis=1)


def region_box(prob: Problem, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(2,), (2,) corners of the plausible region: the base stations' horizontal bounding box
    grown on every side by ``margin`` times its diagonal, metres."""
    lo = prob.bs[:, :2].min(axis=0)
    hi = prob.bs[:, :2].max(axis=0)
    grow = margin * float(np.linalg.norm(hi - lo))
    return lo - grow, hi + grow


#: Default cut-off of the Andrews weight (eq. 11), metres. See :func:`irls` for the reasoning.
U_MAX_M = 3.0
#: Default convergence threshold on the move of the weighted average (eq. 12), metres.
EPSILON_M = 1e-4
#: Default maximum number of reweighting iterations of Algorithm 1.
MAX_ITER = 100
#: Default Gauss-Newton step tolerance (m) and iteration limit of each least-squares solve.
LS_TOL_M = 1e-9
LS_MAX_ITER = 50


def andrews_weight(u: np.ndarray | float, u_max: float) -> np.ndarray:
    """Andrews sine weight of eq. 11: ``(u_max / (pi u)) sin(pi u / u_max)`` for ``u <= u_max``.

    Parameters
    ----------
    u : array of float, metres -- uncertainties ``u_e`` (eq. 10), non-negative
    u_max : float, metres -- cut-off; ``u > u_max`` (and NaN) gives weight 0

    Returns
    -------
    Weights in [0, 1], same shape as ``u``. At ``u = 0`` the weight is the limit 1; at
    ``u = u_max`` it is ``sin(pi) / pi = 0``, so the function is continuous at the cut-off.
    ``numpy.sinc(x) = sin(pi x) / (pi x)`` is exactly this form with ``x = u / u_max``.
    """
    u = np.asarray(u, dtype=float)
    w = np.sinc(u / u_max)
    return np.where(np.isfinite(u) & (u <= u_max), w, 0.0)


def uncertainties(prob: Problem, q: np.ndarray) -> np.ndarray:
    """Uncertainty ``u_e`` of every reference base station at positions ``q`` (eq. 10).

    ``u_e = 1/(N_e - 1) sum_{n != e} |dd_ne - (|q - b_n| - |q - b_e|)|`` over the received base
    stations (``N_e`` of them, the paper's N when none is missing). With pseudo-range residuals
    ``s_n = rho_n - |q - b_n|`` each term is ``|s_n - s_e|``.

    Parameters
    ----------
    prob : Problem
    q : (E, 3) float, metres -- the current weighted average ``Q_WA``

    Returns
    -------
    (E, N) float, metres; NaN for base stations not received.
    """
    R = np.linalg.norm(q[:, None, :] - prob.bs[None, :, :], axis=2)
    s = np.where(prob.valid, prob.rho - R, 0.0)
    diff = np.abs(s[:, :, None] - s[:, None, :])  # [E, e, n]
    both = prob.valid[:, :, None] & prob.valid[:, None, :]
    total = np.sum(np.where(both, diff, 0.0), axis=2)
    n_other = np.maximum(prob.n_valid - 1, 1)[:, None]
    return np.where(prob.valid, total / n_other, np.nan)


@dataclass(frozen=True)
class LsConfig:
    """Settings of the paper's LS (:func:`least_squares`).

    Attributes
    ----------
    reference : str, int or None
        Reference base station of each epoch (:mod:`positioning.estimators.eq7`): ``first``
        (None, the default: the first received base station), ``random`` (drawn per epoch with
        ``seed``: the paper's "random base station as a reference"), ``strongest`` (highest
        reported SNR among lone-looking first lobes) or ``fixed:N`` (an index N alone means the
        same). If a fixed reference is not received in an epoch, that epoch falls back to its
        first received base station and is flagged ``REFERENCE_FALLBACK``.
    seed : int -- seed of the ``random`` reference
    tol_m : float, m -- Gauss-Newton/LM step tolerance
    max_iter : int -- Gauss-Newton/LM iteration limit
    grid_m : float, m -- pitch of the grid over the service area whose deepest cells, besides the
        closed-form start, start the descents (the lowest minimum of eq. 7 inside the area is
        kept); 0: the closed-form start alone
    """

    reference: str | int | None = None
    seed: int = 0
    tol_m: float = LS_TOL_M
    max_iter: int = LS_MAX_ITER
    grid_m: float = GRID_M


def least_squares(prob: Problem, config: LsConfig = LsConfig()) -> Fixes:
    """The paper's LS (eqs. 5-7): signed TDoAs against one reference base station, the lowest
    minimum of eq. 7 inside the service area (:func:`positioning.estimators.eq7.solve_eq7`).

    Returns
    -------
    :class:`Fixes` of method ``ls``: ``weights`` (E, N) 1 for a received base station of a solved
    epoch, else 0.
    """
    E = prob.n_epochs
    rows = prob.solvable
    status = np.zeros(E, dtype=np.int64)
    ref, fallback = choose_reference(
        prob, parse_reference(config.reference, prob.n_bs), config.seed
    )
    status |= np.where(rows & fallback, int(Status.REFERENCE_FALLBACK), 0)
    sol = solve_eq7(
        prob, ref, rows, tol=config.tol_m, max_iter=config.max_iter, grid_m=config.grid_m
    )
    status |= np.where(rows & ~sol.converged, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & sol.ill, int(Status.ILL_CONDITIONED), 0)
    status |= np.where(rows, 0, int(Status.UNSOLVED))
    return Fixes(
        xyz=sol.xyz,
        status=status,
        iterations=sol.iterations,
        weights=prob.valid.astype(float) * rows[:, None],
        n_used=prob.n_valid,
        method="ls",
        params=config_params(config),
    )


@dataclass(frozen=True)
class IrlsConfig:
    """Settings of IRLS (:func:`irls`, the paper's Algorithm 1).

    Attributes
    ----------
    u_max : float, metres
        Cut-off of eq. 11 (default 3 m). ``u_e`` is a mean absolute TDoA misfit. With LoS noise
        of standard deviation ``sigma`` per range it is about ``1.13 sigma`` (mean of ``|N(0,
        2 sigma^2)|``), i.e. centimetres to a few decimetres at 400/100 MHz, where the weight stays
        above 0.99. An NLoS excess ``b`` on the reference gives ``u_e ~ b`` (all terms of eq. 10
        carry it) but only ``~ b / (N - 1)`` for the other references. 3 m (the range resolution
        ``c / B`` at 100 MHz) therefore rejects a reference with a metre-scale NLoS bias (weight
        0.39 at 1.5 m, 0 from 3 m) while a bias up to about ``(N - 1) u_max`` (9 m with 4 base
        stations) does not drive every weight to zero.
    epsilon : float, metres
        Threshold on ``S`` of eq. 12 (default 1e-4 m: three orders of magnitude below the ranging
        errors of either band, while the reweighting, a fixed-point iteration that converges only
        linearly, needs about twice as many iterations for 1e-6 m).
    max_iter : int
        Maximum reweighting iterations (default 100; typically fewer than 10 are needed).
    ls_tol_m, ls_max_iter : Gauss-Newton/LM settings of the N least-squares solves.
    ls_grid_m : float, m, grid pitch of the N least-squares solves (as ``grid_m`` of
        :class:`LsConfig`); 0 (default): each from its closed-form start alone, as before the
        search existed (the guard already drops estimates outside the plausible region)
    region_margin : float, plausible region of the per-reference estimates (default 1: the
        base stations' box grown by one diagonal on every side)
    guard : bool
        True (``irls``): only converged, plausible per-reference estimates are averaged (the
        guards of :func:`irls`). False (``irls-paper``): Algorithm 1 as written, every
        per-reference estimate averaged (all-zero weights keep the previous average, as eq. 9
        cannot divide by zero).
    """

    u_max: float = U_MAX_M
    epsilon: float = EPSILON_M
    max_iter: int = MAX_ITER
    ls_tol_m: float = LS_TOL_M
    ls_max_iter: int = LS_MAX_ITER
    ls_grid_m: float = 0.0
    region_margin: float = 1.0
    guard: bool = True


def irls(prob: Problem, config: IrlsConfig = IrlsConfig()) -> Fixes:
    """IRLS positioning, the paper's Algorithm 1.

    1. Every received base station ``e`` is the reference once: N position estimates ``q_e`` by
       the least squares of eq. 7 (:func:`least_squares` machinery).
    2. ``Q_WA`` = their average with equal weights (eq. 8, first iteration).
    3. Repeat: uncertainties ``u_e`` at ``Q_WA`` (eq. 10); weights ``w_e`` = Andrews sine of
       ``u_e`` (eq. 11); normalise (eq. 9); new ``Q_WA`` = weighted average of the ``q_e`` (eq. 8);
       stop when it moved by ``S <= epsilon`` (eq. 12).

    Guards the paper leaves open:

    * **All weights zero** (every ``u_e > u_max``): eq. 9 would divide by zero. The epoch keeps the
      previous ``Q_WA`` (at the first reweighting, the equal-weight average), stops iterating and
      is flagged ``ALL_WEIGHTS_ZERO``; the reported weights are the (all zero) eq. 11 weights.
    * **No convergence** within ``max_iter``: the last ``Q_WA`` is returned, flagged
      ``NOT_CONVERGED`` (also set when one of the N least-squares solves did not converge).
    * **A per-reference least squares that did not converge** (it typically runs off to infinity
      along a hyperbola asymptote when the TDoAs are inconsistent, e.g. an NLoS excess beyond
      the baseline): that estimate gets weight 0 throughout, unless no reference converged, and
      the epoch is flagged ``NOT_CONVERGED``. So does an estimate that converged outside the
      plausible region (the base stations' horizontal box grown by ``region_margin`` times its
      diagonal): a far point on an asymptote passes eq. 10, which tests reference ``e``'s
      measurements at ``Q_WA`` and not ``q_e`` itself, and would drag the average away. If no
      estimate converged inside the region, the plausible ones are averaged; if none is
      plausible, the average is clamped into the region (and flagged ``NOT_CONVERGED``).
    * **Missing ToAs**: only received base stations serve as references and enter eq. 10 (whose
      ``1/(N-1)`` becomes ``1/(N_e-1)``); epochs with fewer than ``dims + 1`` received base
      stations are ``UNSOLVED`` (NaN).

    The per-reference guard above (converged and plausible estimates only) is this
    implementation's, not the paper's: ``irls-paper`` (``guard=False``) is Algorithm 1 as written,
    every per-reference estimate averaged whatever its solve did (the all-zero-weights rule
    stays, as eq. 9 cannot divide by zero). Both are in Table II of ``reproduce-paper``.

    Returns
    -------
    :class:`Fixes` of method ``irls``: ``weights`` (E, N) the normalised eq. 9 weights of the
    estimate referenced to each base station; ``extra["estimates"]`` (E, N, 3) the N
    per-reference positions ``q_e`` (NaN where not received).
    """
    rows = prob.solvable
    q, conv, ill = reference_estimates(prob, rows, config)
    if config.guard:
        usable, ls_bad, nowhere = _usable_estimates(prob, q, conv, rows, config.region_margin)
    else:  # Algorithm 1 as written: every estimate, whatever its solve did
        usable = np.isfinite(q).all(axis=2)
        ls_bad = rows & (usable & ~conv).any(axis=1)
        nowhere = np.zeros(prob.n_epochs, dtype=bool)
    Q, w_norm, iterations, zero_w, converged = reweight(prob, q, usable, rows, config)
    if nowhere.any():
        lo, hi = region_box(prob, config.region_margin)
        Q[nowhere, :2] = np.clip(Q[nowhere, :2], lo, hi)
    status = np.zeros(prob.n_epochs, dtype=np.int64)
    status |= np.where(rows & zero_w, int(Status.ALL_WEIGHTS_ZERO), 0)
    status |= np.where(rows & ~zero_w & ~converged, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & ls_bad, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & ill, int(Status.ILL_CONDITIONED), 0)
    status |= np.where(rows, 0, int(Status.UNSOLVED))
    Q[~rows] = np.nan
    w_norm[~rows] = 0.0
    return Fixes(
        xyz=Q,
        status=status,
        iterations=iterations,
        weights=w_norm,
        n_used=prob.n_valid,
        method="irls",
        params=config_params(config),
        extra={"estimates": q},
    )


def reference_estimates(
    prob: Problem, rows: np.ndarray, config: IrlsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1 of Algorithm 1: the least squares of eq. 7 with every received base station the
    reference once, on the epochs ``rows`` (E,).

    Returns
    -------
    q : (E, N, 3) float, m, the per-reference positions (NaN where not received or not solved);
    converged : (E, N) bool; ill : (E,) bool, some solve was ill-conditioned
    """
    E, N = prob.rho.shape
    q = np.full((E, N, 3), np.nan)
    conv = np.zeros((E, N), dtype=bool)
    ill = np.zeros(E, dtype=bool)
    for e in range(N):
        sub = rows & prob.valid[:, e]
        if not sub.any():
            continue
        sol = solve_eq7(prob, np.full(E, e), sub, tol=config.ls_tol_m,
                        max_iter=config.ls_max_iter, grid_m=config.ls_grid_m)  # fmt: skip
        q[sub, e] = sol.xyz[sub]
        conv[:, e] = sub & sol.converged
        ill |= sub & sol.ill
    return q, conv, ill


def _usable_estimates(
    prob: Problem, q: np.ndarray, conv: np.ndarray, rows: np.ndarray, region_margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which per-reference estimates take part (E, N), the epochs with an estimate that did not
    converge (E,) and those without a plausible one (E,; their average is clamped)."""
    E, N = conv.shape
    has_q = np.isfinite(q).all(axis=2)
    # A per-reference LS that did not converge has usually run off along a hyperbola asymptote
    # (an inconsistent TDoA set has its LS optimum at infinity); it takes no part unless no
    # reference converged at all.
    # A solve can also converge to a far-away point on an asymptote; eq. 10 judges reference e's
    # measurements at Q_WA, not q_e itself, so such an estimate could keep a large weight and
    # drag the average away. Estimates outside the plausible region (the base stations' box
    # grown by region_margin times its diagonal) count as not converged.
    far = np.zeros((E, N), dtype=bool)
    for e in range(N):
        ok_e = has_q[:, e]
        far[ok_e, e] = ~plausible(prob, q[ok_e, e], region_margin)
    conv = conv & ~far
    ls_bad = rows & (has_q & ~conv).any(axis=1)
    usable = has_q & conv
    plaus = has_q & ~far
    # nothing converged inside the region: the plausible ones; nothing plausible: all of them,
    # and the result is clamped into the region
    nowhere = rows & ~plaus.any(axis=1)
    has_q = np.where(
        usable.any(axis=1)[:, None], usable, np.where(plaus.any(axis=1)[:, None], plaus, has_q)
    )
    return has_q, ls_bad, nowhere


def reweight(
    prob: Problem, q: np.ndarray, has_q: np.ndarray, rows: np.ndarray, config: IrlsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2 and 3 of Algorithm 1: the weighted average of the per-reference estimates ``q``
    (E, N, 3) where ``has_q`` (E, N), reweighted by eqs. 9-11 until it moves by at most
    ``epsilon`` (eq. 12).

    Returns
    -------
    Q : (E, 3) float, m, the weighted average ``Q_WA``; w_norm : (E, N) float, the normalised
    weights; iterations : (E,) int; all_zero : (E,) bool, every weight zero (the average before
    is kept); converged : (E,) bool
    """
    E = prob.n_epochs
    q0 = np.where(has_q[..., None], q, 0.0)
    w_norm = has_q / np.maximum(has_q.sum(axis=1), 1)[:, None]
    w0 = has_q.astype(float)  # equal weights at iteration 0
    Q = np.sum(w0[..., None] * q0, axis=1) / np.maximum(np.sum(w0, axis=1), 1e-300)[:, None]
    iterations = np.zeros(E, dtype=np.int64)
    act = np.flatnonzero(rows)
    zero_w = np.zeros(E, dtype=bool)
    converged = np.zeros(E, dtype=bool)
    for _ in range(config.max_iter):
        if act.size == 0:
            break
        sub = prob.take(act)
        u = uncertainties(sub, Q[act])
        w = andrews_weight(u, config.u_max) * has_q[act]
        wsum = w.sum(axis=1)
        iterations[act] += 1
        dead = wsum <= 0.0
        zero_w[act[dead]] = True
        w_norm[act[dead]] = 0.0
        live = act[~dead]
        wl = w[~dead] / wsum[~dead, None]
        Q_new = np.sum(wl[..., None] * q0[live], axis=1)
        S = np.linalg.norm(Q_new - Q[live], axis=1)
        Q[live] = Q_new
        w_norm[live] = wl
        done = S <= config.epsilon
        converged[live[done]] = True
        act = live[~done]
    return Q, w_norm, iterations, zero_w, converged
