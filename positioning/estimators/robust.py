"""Estimators beyond the paper that remove the influence of NLoS base stations.

All three work on the reference-free pseudo-range model (see :mod:`positioning.model.tdoa`)::

    rho_n = c (toa_n - delta_n) = |p - b_n| + beta + c e_n,     beta = c * (device clock offset)

which is equivalent to TDoA (``beta`` is a nuisance unknown that absorbs the clock offset) but
treats every base station alike: no reference whose error leaks into every equation. With ``k =
dims + 1`` unknowns and ``N`` received base stations the redundancy is ``N - k``. A single outlier
can be *detected* with redundancy 1 and *identified* from residuals only with redundancy 2 or more
(with redundancy 1 every residual vector is a multiple of the same parity vector, whichever base
station is biased). In 2D (known height) that is N >= 5, in 3D N >= 6.

* ``m-estimator``: Tukey biweight (or Huber) M-estimator by iteratively reweighted least squares,
  robust scale from the MAD of the residuals.
* ``subset``: fault detection and exclusion: chi-square test of the residuals; if it fails, solve
  every leave-one-out subset and drop the base station whose removal leaves the most consistent
  set; repeat while the test fails and the outlier is identifiable.
* ``nlos-aware``: uses that NLoS only ever adds delay. The residuals ``rho_n - |p - b_n| - beta``
  of LoS base stations are noise, those of NLoS base stations noise plus a non-negative excess.
  The loss is quadratic for negative residuals (a ToA can never be early by more than noise) and
  only logarithmic for large positive ones. Candidate solutions (all base stations, every subset
  with one -- optionally more -- base station left out) are scored with this loss over *all*
  received base stations and the best one is refined by IRLS. This still works with redundancy 1
  (4 base stations in 2D), where residual consistency alone cannot tell which one is biased: a
  wrong hypothesis usually needs a base station to be *early* and is rejected.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.stats import chi2

from ..model.problem import Problem
from ..model.residuals import pseudorange_model, pseudorange_residuals
from .fixes import Fixes, Status, config_params
from .irls import plausible
from .solver import Solution, levenberg_marquardt, solve_pseudorange

#: Tukey biweight tuning constant (95 % efficiency under Gaussian noise).
TUKEY_C = 4.685
#: Huber tuning constant (95 % efficiency under Gaussian noise).
HUBER_C = 1.345
#: MAD -> standard deviation for Gaussian noise.
MAD_TO_SIGMA = 1.4826
#: A measurement whose final robust weight is below this counts as rejected (status flag).
REJECT_WEIGHT = 0.1
#: Default noise scale (1 sigma of a pseudo-range, m) used by ``subset`` and ``nlos-aware``.
SIGMA_M = 0.1
#: Default lower bound of the MAD scale of the ``m-estimator`` (m).
SCALE_FLOOR_M = 0.05
#: Default growth of the plausible region around the base stations (fraction of their diagonal).
REGION_MARGIN = 1.0
#: Default one-sided quadratic range of ``nlos-aware``, in units of sigma.
NLOS_K = 2.0


def _median_abs(r: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(A,) median of ``|r|`` over the valid entries of each row (NaN if none)."""
    a = np.sort(np.where(valid, np.abs(r), np.inf), axis=1)
    n = valid.sum(axis=1)
    ar = np.arange(a.shape[0])
    lo = a[ar, np.maximum((n - 1) // 2, 0)]
    hi = a[ar, np.maximum(n // 2, 0)]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def robust_weights(z: np.ndarray, loss: str, c: float) -> np.ndarray:
    """IRLS weights ``psi(z) / z`` of standardised residuals ``z``.

    ``tukey``: ``(1 - (z/c)^2)^2`` for ``|z| < c``, else 0. ``huber``: ``min(1, c / |z|)``.
    """
    az = np.abs(z)
    if loss == "tukey":
        return np.where(az < c, (1.0 - (az / c) ** 2) ** 2, 0.0)
    if loss == "huber":
        return np.minimum(1.0, c / np.maximum(az, 1e-300))
    raise ValueError(f"unknown loss {loss!r}")


def _irls_loop(
    prob: Problem,
    theta: np.ndarray,
    rows: np.ndarray,
    weight_fn,
    *,
    tol_m: float,
    max_iter: int,
    gn_max_iter: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Generic batched IRLS on the pseudo-range model.

    ``weight_fn(r (A, N), valid (A, N), idx (A,)) -> w (A, N)`` gives the weights from the current
    residuals; each iteration solves the weighted problem (a few LM steps) from the current
    estimate and stops when the estimate moved less than ``tol_m``.

    Returns theta (E, k), weights (E, N), iterations (E,), converged (E,).
    """
    E, N = prob.rho.shape
    fun = pseudorange_model(prob)
    weights = np.where(prob.valid & rows[:, None], 1.0, 0.0)
    iterations = np.zeros(E, dtype=np.int64)
    converged = np.zeros(E, dtype=bool)
    act = np.flatnonzero(rows & np.isfinite(theta).all(axis=1))
    theta = theta.copy()
    for _ in range(max_iter):
        if act.size == 0:
            break
        r = pseudorange_residuals(_rows(prob, act), theta[act])
        w = weight_fn(r, prob.valid[act], act)
        W = np.zeros((E, N))
        W[act] = w
        th0 = np.full_like(theta, np.nan)
        th0[act] = theta[act]
        th, _, _ = levenberg_marquardt(fun, th0, W, tol=tol_m, max_iter=gn_max_iter)
        step = np.linalg.norm(th[act] - theta[act], axis=1)
        ok = np.isfinite(step)
        theta[act[ok]] = th[act[ok]]
        weights[act] = w
        iterations[act] += 1
        done = ~ok | (step <= tol_m)
        converged[act[done & ok]] = True
        act = act[~done]
    return theta, weights, iterations, converged


def _rows(prob: Problem, idx: np.ndarray) -> Problem:
    return Problem(
        rho=prob.rho[idx],
        valid=prob.valid[idx],
        bs=prob.bs,
        height=None if prob.height is None else prob.height[idx],
    )


def _finish(
    prob: Problem,
    theta: np.ndarray,
    rows: np.ndarray,
    status: np.ndarray,
    iterations: np.ndarray,
    weights: np.ndarray,
    method: str,
    config: object,
) -> Fixes:
    """The :class:`Fixes` of a robust estimator: ``NO_REDUNDANCY`` and ``UNSOLVED`` flagged,
    unsolved epochs NaN with zero weights."""
    k = prob.dims + 1
    status = status | np.where(rows & (prob.n_valid <= k), int(Status.NO_REDUNDANCY), 0)
    status |= np.where(rows, 0, int(Status.UNSOLVED))
    xyz = prob.position(theta, np.arange(prob.n_epochs)).copy()
    xyz[~rows] = np.nan
    weights = np.where(rows[:, None], weights, 0.0)
    return Fixes(
        xyz=xyz,
        status=status,
        iterations=iterations,
        weights=weights,
        n_used=prob.n_valid,
        method=method,
        params=config_params(config),
    )


def candidates(
    prob: Problem, rows: np.ndarray, max_drop: int, margin: float
) -> Iterator[tuple[tuple[int, ...], np.ndarray, Solution]]:
    """The hypothesis fits the robust estimators start from (``m-estimator``, ``nlos-aware``,
    ``nlos-map``): the least-squares pseudo-range fit of all received base stations and of every
    subset leaving out 1..``max_drop`` of them with at least ``dims + 1`` remaining.

    Parameters
    ----------
    prob : Problem
    rows : (E,) bool, the epochs to solve
    max_drop : int, most base stations left out
    margin : float, the plausible region's growth (:func:`~positioning.estimators.irls.plausible`)

    Yields
    ------
    ``(drop, sub, solution)``: the left-out base stations (a tuple of indices, empty for the fit of
    all), ``sub`` (E,) bool, the epochs where the hypothesis applies (for a proper subset also: its
    fit is plausible), and the :class:`~positioning.estimators.solver.Solution`.
    """
    if prob.memo is not None:  # m-estimator, nlos-aware and nlos-map fit the same ones
        key = ("candidates", np.asarray(rows, bool).tobytes(), int(max_drop), float(margin))
        yield from prob.memo.get(prob, key, lambda: list(_candidates(prob, rows, max_drop, margin)))
        return
    yield from _candidates(prob, rows, max_drop, margin)


def _candidates(
    prob: Problem, rows: np.ndarray, max_drop: int, margin: float
) -> Iterator[tuple[tuple[int, ...], np.ndarray, Solution]]:
    """:func:`candidates`, computed."""
    E, N = prob.rho.shape
    k = prob.dims + 1
    valid = prob.valid & rows[:, None]
    subsets: list[tuple[int, ...]] = [()]
    for m in range(1, max(int(max_drop), 0) + 1):
        subsets += list(combinations(range(N), m))
    for drop in subsets:
        use = valid.copy()
        use[:, list(drop)] = False
        sub = rows & valid[:, list(drop)].all(axis=1) & (use.sum(axis=1) >= k)
        if not sub.any():
            continue
        s = solve_pseudorange(prob, use.astype(float), sub, tol=1e-9, max_iter=50)
        if drop:
            sub = sub & plausible(prob, s.xyz, margin)
        yield drop, sub, s


@dataclass(frozen=True)
class MEstimatorConfig:
    """Settings of the ``m-estimator`` (:func:`m_estimator`).

    Attributes
    ----------
    loss : "tukey" (default, redescending: gross outliers get weight 0) or "huber".
    c : tuning constant in units of the scale (default 4.685 Tukey, 1.345 Huber; 95 % efficiency).
    scale_floor_m : lower bound of the scale, metres (default 0.05 m), so that noise-free or very
        clean data is not cut at a vanishing scale.
    tol_m, max_iter, gn_max_iter : IRLS step tolerance (m), reweightings, LM steps per reweighting.
    region_margin : float -- leave-one-out starts outside the :func:`plausible` region (base
        stations' bounding box grown by this fraction of its diagonal, default 1) are discarded.
    """

    loss: str = "tukey"
    c: float | None = None
    scale_floor_m: float = SCALE_FLOOR_M
    tol_m: float = 1e-6
    max_iter: int = 50
    gn_max_iter: int = 10
    region_margin: float = REGION_MARGIN


def m_estimator(prob: Problem, config: MEstimatorConfig = MEstimatorConfig()) -> Fixes:
    """Reference-free robust MM-estimator on the pseudo-range residuals.

    1. High-breakdown start (least median of squares over candidate fits): the least-squares
       pseudo-range fit with all received base stations and every leave-one-out fit; the one with
       the smallest median squared residual over *all* received base stations wins.
    2. Robust scale from that start, Rousseeuw's LMS scale
       ``s = 1.4826 (1 + 5 / (N - k)) sqrt(median r^2)``, floored at ``scale_floor_m``.
    3. M-step: iteratively reweighted least squares with Tukey biweight (or Huber) weights
       ``w(r / s)`` at that fixed scale, from the start, until the estimate moves less than
       ``tol_m``. If Tukey leaves fewer than ``k`` measurements with non-zero weight in an epoch,
       that epoch uses Huber weights for the iteration.

    The start makes it robust to a high-leverage outlier that plain LS residuals would hide; the
    M-step keeps the efficiency of least squares on clean data (all weights near 1). No noise level
    has to be given. With fewer than two spare measurements (``N <= dims + 2``, e.g. 4 base
    stations in 2D) residuals cannot identify an outlier: the epoch gets the least-squares fit,
    flagged ``NO_REDUNDANCY``.
    """
    loss = config.loss
    if loss not in ("tukey", "huber"):
        raise ValueError(f"unknown loss {loss!r}")
    cc = float(config.c) if config.c is not None else (TUKEY_C if loss == "tukey" else HUBER_C)
    E, N = prob.rho.shape
    k = prob.dims + 1
    rows = prob.solvable
    valid = prob.valid & rows[:, None]
    n = valid.sum(axis=1)
    robust_rows = rows & (n >= k + 2)
    best = np.full(E, np.inf)
    theta = np.full((E, k), np.nan)
    ill = np.zeros(E, dtype=bool)
    for drop, sub, s in candidates(prob, rows, 1, config.region_margin):
        if drop:
            sub = sub & robust_rows
        r = pseudorange_residuals(prob, s.theta)
        med = _median_abs(np.where(valid, r, np.inf), valid)
        med = np.where(sub & np.isfinite(med), med, np.inf)
        better = med < best
        best = np.where(better, med, best)
        theta[better] = s.theta[better]
        ill[better] = s.ill[better]
    scale = MAD_TO_SIGMA * (1.0 + 5.0 / np.maximum(n - k, 1)) * best
    scale = np.maximum(np.where(np.isfinite(scale), scale, 0.0), config.scale_floor_m)

    def weight_fn(r: np.ndarray, valid_: np.ndarray, idx: np.ndarray) -> np.ndarray:
        z = np.where(valid_, r, 0.0) / scale[idx, None]
        w = robust_weights(z, loss, cc) * valid_
        few = (w > 0).sum(axis=1) < k
        if few.any():
            w[few] = robust_weights(z[few], "huber", HUBER_C) * valid_[few]
        return w

    theta, weights, iterations, converged = _irls_loop(
        prob,
        theta,
        robust_rows,
        weight_fn,
        tol_m=config.tol_m,
        max_iter=config.max_iter,
        gn_max_iter=config.gn_max_iter,
    )
    weights = np.where(robust_rows[:, None], weights, valid.astype(float))
    converged |= rows & ~robust_rows
    status = np.where(rows & ~converged, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & ill, int(Status.ILL_CONDITIONED), 0)
    status |= np.where(rows & ~robust_rows, int(Status.NO_REDUNDANCY), 0)
    rejected = (valid & (weights < REJECT_WEIGHT)).any(axis=1)
    status |= np.where(rows & rejected, int(Status.OUTLIER_REJECTED), 0)
    return _finish(prob, theta, rows, status, iterations, weights, "m-estimator", config)


def _sse(prob: Problem, theta: np.ndarray, use: np.ndarray) -> np.ndarray:
    r = pseudorange_residuals(prob, theta)
    return np.sum(np.where(use & np.isfinite(r), r, 0.0) ** 2, axis=1)


@dataclass(frozen=True)
class SubsetConfig:
    """Settings of ``subset`` (:func:`subset`).

    Attributes
    ----------
    sigma_m : float, metres -- 1-sigma pseudo-range noise of LoS measurements (default 0.1 m).
    alpha : float -- false-alarm probability of the test (default 0.01).
    max_drop : int or None -- most base stations to drop (None: as many as identifiable).
    tol_m, max_iter : Gauss-Newton/LM settings.
    region_margin : float -- leave-one-out fits outside the :func:`plausible` region are not
        candidates (default 1).
    """

    sigma_m: float = SIGMA_M
    alpha: float = 0.01
    max_drop: int | None = None
    tol_m: float = 1e-9
    max_iter: int = 50
    region_margin: float = REGION_MARGIN


def subset(prob: Problem, config: SubsetConfig = SubsetConfig()) -> Fixes:
    """Subset-consistency search (fault detection and exclusion), reference-free.

    1. Least-squares pseudo-range fit with all received base stations.
    2. Consistency test: ``SSE / sigma_m^2 <= chi2.ppf(1 - alpha, N - k)`` (``k = dims + 1``).
    3. If it fails and the redundancy ``N - k >= 2``: fit every leave-one-out subset, drop the base
       station whose removal gives the smallest SSE (best explains the rest), re-test; repeat while
       the test fails, the redundancy allows identification and fewer than ``max_drop`` are
       dropped.

    With redundancy 1 (N = 4 in 2D, 5 in 3D) every leave-one-out subset is exactly determined and
    fits with zero residual, so an inconsistency can be detected but not attributed: the
    all-base-station fit is returned, flagged ``INCONSISTENT`` (use ``nlos-aware`` there). A set
    still failing after the last possible drop is flagged ``INCONSISTENT`` as well.

    ``iterations`` are the LM iterations of the final fit; ``weights`` 1 for used, 0 for dropped.
    """
    E, N = prob.rho.shape
    k = prob.dims + 1
    rows = prob.solvable
    use = prob.valid & rows[:, None]
    sol = solve_pseudorange(prob, use.astype(float), rows, tol=config.tol_m,
                            max_iter=config.max_iter)  # fmt: skip
    theta, iters, conv, ill = (
        sol.theta.copy(),
        sol.iterations.copy(),
        sol.converged.copy(),
        sol.ill.copy(),
    )
    sse = _sse(prob, theta, use)
    n_drop = np.zeros(E, dtype=np.int64)
    limit = N if config.max_drop is None else int(config.max_drop)
    inconsistent = np.zeros(E, dtype=bool)

    def failing(sse_: np.ndarray, use_: np.ndarray) -> np.ndarray:
        dof = use_.sum(axis=1) - k
        thr = config.sigma_m**2 * chi2.ppf(1.0 - config.alpha, np.maximum(dof, 1))
        return rows & (dof >= 1) & (sse_ > thr)

    fail = failing(sse, use)
    for _ in range(N):
        dof = use.sum(axis=1) - k
        cand = fail & (dof >= 2) & (n_drop < limit)
        inconsistent |= fail & ~cand
        if not cand.any():
            break
        best_sse, best_j, best = _best_drop(prob, use, cand, config)
        upd = cand & (best_j >= 0)
        use[upd, best_j[upd]] = False
        theta[upd], iters[upd], conv[upd], ill[upd] = (b[upd] for b in best)
        sse[upd] = best_sse[upd]
        n_drop[upd] += 1
        fail = failing(sse, use) & upd
    status = np.where(rows & ~conv, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & ill, int(Status.ILL_CONDITIONED), 0)
    status |= np.where(rows & (n_drop > 0), int(Status.OUTLIER_REJECTED), 0)
    status |= np.where(rows & inconsistent, int(Status.INCONSISTENT), 0)
    status |= np.where(rows & (prob.n_valid < k + 2), int(Status.NO_REDUNDANCY), 0)
    return _finish(prob, theta, rows, status, iters, use.astype(float), "subset", config)


def _best_drop(
    prob: Problem, use: np.ndarray, cand: np.ndarray, config: SubsetConfig
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """One step of :func:`subset` on the epochs ``cand`` (E,): fit every leave-one-out subset of
    the base stations in ``use`` (E, N) and keep, per epoch, the plausible one of smallest SSE.

    Returns its SSE (E,) (inf: none), the dropped base station (E,) (-1: none) and its fit
    (theta (E, k), iterations, converged, ill-conditioned)."""
    E, N = use.shape
    best_sse = np.full(E, np.inf)
    best_j = np.full(E, -1)
    best = (
        np.full((E, prob.dims + 1), np.nan),
        np.zeros(E, np.int64),
        np.zeros(E, bool),
        np.zeros(E, bool),
    )
    for j in range(N):
        sub = cand & use[:, j]
        if not sub.any():
            continue
        use_j = use.copy()
        use_j[:, j] = False
        s = solve_pseudorange(prob, use_j.astype(float), sub, tol=config.tol_m,
                              max_iter=config.max_iter)  # fmt: skip
        sub = sub & plausible(prob, s.xyz, config.region_margin)
        e_j = np.where(sub, _sse(prob, s.theta, use_j), np.inf)
        better = e_j < best_sse
        best_sse = np.where(better, e_j, best_sse)
        best_j = np.where(better, j, best_j)
        best[0][better] = s.theta[better]
        best[1][better] = s.iterations[better]
        best[2][better] = s.converged[better]
        best[3][better] = s.ill[better]
    return best_sse, best_j, best


def nlos_loss(z: np.ndarray, k: float) -> np.ndarray:
    """One-sided NLoS loss of standardised residuals ``z = r / sigma``.

    ``z^2 / 2`` for ``z <= k`` (negative residuals, i.e. early arrivals, are only noise and are
    never forgiven); ``k^2 / 2 + k^2 ln(z / k)`` for ``z > k`` (a late arrival may be NLoS: its
    influence ``psi = k^2 / z`` redescends). Continuous with continuous derivative at ``k``.
    """
    zz = np.maximum(z, k)
    return np.where(z <= k, 0.5 * z * z, 0.5 * k * k + k * k * np.log(zz / k))


def nlos_weights(z: np.ndarray, k: float) -> np.ndarray:
    """IRLS weights ``psi(z) / z`` of :func:`nlos_loss`: 1 for ``z <= k``, ``(k / z)^2`` above."""
    return np.where(z <= k, 1.0, (k / np.maximum(z, k)) ** 2)


@dataclass(frozen=True)
class NlosAwareConfig:
    """Settings of ``nlos-aware`` (:func:`nlos_aware`).

    Attributes
    ----------
    sigma_m : float, metres -- 1-sigma pseudo-range noise of LoS measurements (default 0.1 m).
    k : float -- quadratic range of the loss in units of sigma (default 2).
    max_drop : int -- most base stations left out in a hypothesis (default 1).
    tol_m, max_iter, gn_max_iter : IRLS step tolerance, reweightings, LM steps per reweighting.
    region_margin : float -- subset hypotheses whose fit is outside the :func:`plausible` region
        are not candidates (default 1).
    """

    sigma_m: float = SIGMA_M
    k: float = NLOS_K
    max_drop: int = 1
    tol_m: float = 1e-6
    max_iter: int = 50
    gn_max_iter: int = 10
    region_margin: float = REGION_MARGIN


def nlos_aware(prob: Problem, config: NlosAwareConfig = NlosAwareConfig()) -> Fixes:
    """NLoS-aware estimator: hypotheses from subsets, one-sided robust loss, IRLS refinement.

    1. Candidates: the least-squares pseudo-range fit with all received base stations and with
       every subset leaving out 1..``max_drop`` of them (as long as ``k = dims + 1`` remain).
    2. Each candidate is scored by ``sum_n nlos_loss((rho_n - |p - b_n| - beta) / sigma_m)`` over
       all received base stations; the lowest score wins.
    3. IRLS with :func:`nlos_weights` from the winner.

    Why it helps where residuals alone cannot: with one NLoS base station among four (2D), the
    leave-one-out fits are all exact, but any hypothesis that blames the wrong base station
    predicts a *negative* excess delay for the one left out in about half of the cases, which the
    quadratic side of the loss rejects; among the remaining hypotheses the loss (increasing with
    the excess) prefers the one needing the smallest total NLoS excess. When the geometry is
    symmetric two hypotheses can fit equally well; then the data cannot decide and either may be
    picked.
    """
    sigma_m, k = config.sigma_m, config.k
    E, N = prob.rho.shape
    kk = prob.dims + 1
    rows = prob.solvable
    valid = prob.valid & rows[:, None]
    best_score = np.full(E, np.inf)
    theta = np.full((E, kk), np.nan)
    ill = np.zeros(E, dtype=bool)
    for _, sub, s in candidates(prob, rows, config.max_drop, config.region_margin):
        z = pseudorange_residuals(prob, s.theta) / sigma_m
        score = np.sum(np.where(valid, nlos_loss(np.where(valid, z, 0.0), k), 0.0), axis=1)
        score = np.where(sub & np.isfinite(score), score, np.inf)
        better = score < best_score
        best_score = np.where(better, score, best_score)
        theta[better] = s.theta[better]
        ill[better] = s.ill[better]

    def weight_fn(r: np.ndarray, valid_: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return nlos_weights(np.where(valid_, r, 0.0) / sigma_m, k) * valid_

    theta, weights, iterations, converged = _irls_loop(
        prob, theta, rows, weight_fn, tol_m=config.tol_m, max_iter=config.max_iter,
        gn_max_iter=config.gn_max_iter,
    )  # fmt: skip
    status = np.where(rows & ~converged, int(Status.NOT_CONVERGED), 0)
    status |= np.where(rows & ill, int(Status.ILL_CONDITIONED), 0)
    rejected = (prob.valid & (weights < REJECT_WEIGHT)).any(axis=1)
    status |= np.where(rows & rejected, int(Status.OUTLIER_REJECTED), 0)
    return _finish(prob, theta, rows, status, iterations, weights, "nlos-aware", config)
