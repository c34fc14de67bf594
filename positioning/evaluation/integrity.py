"""Integrity figures of a fix: normalised chi-square and horizontal protection level (HPL).

For every method's fix, from the measurements alone (no truth):

* ``chi2n = SSE / (n - k)`` with ``SSE = sum_n (r_n / sigma_n)^2`` the pseudo-range residuals at
  the fix (the clock term at its weighted best) over the noise core ``sigma_n`` of
  :func:`positioning.model.noise.link_sigma`; ``n - k`` the redundancy (NaN without one). About 1
  for consistent LoS measurements.
* ``HPL``: the fix could be wrong because any one base station is biased (NLoS or overlap). Each
  fault hypothesis ``h`` -- none, or base station j excluded -- has its own least-squares fit
  ``p_h`` with horizontal standard deviation ``sigma_h`` (the largest eigenvalue of its
  horizontal covariance, noise core). A hypothesis is *plausible* if its fit is inside the
  service area, its own residuals pass a chi-square test at :data:`P_CONSISTENT`, and the
  excluded measurement is not early beyond noise (:data:`K_SIGMA` sigma; the two-sided overlap
  spread for a narrow lobe), since NLoS only adds delay. Then::

      HPL = max over plausible h of ( |p_fix - p_h| + K_SIGMA sigma_h )

  It bounds the horizontal error whenever at most one base station is faulty and the noise stays
  within ``K_SIGMA`` sigma. With no plausible hypothesis HPL is infinite (the data cannot vouch
  for any position). Two or more faulty base stations are not covered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..estimators.fixes import Status
from ..estimators.solver import solve_pseudorange
from ..model.noise import NARROW_LOBE, WIDE_PULSES, link_sigma, pulse_width_m
from ..model.problem import Problem
from ..model.residuals import pseudorange_model
from ..model.tdoa import ranges_and_units

#: Multiplier of the standard deviations (noise of the excluded measurement, fit's horizontal
#: spread): 3 sigma, a 0.3 % two-sided miss per Gaussian figure.
K_SIGMA = 3.0
#: Consistency test of a hypothesis's residuals: chi-square quantile.
P_CONSISTENT = 0.999
#: Default alert limit of the command-line tools, metres (the paper's worst setups' p90 error).
ALERT_LIMIT_M = 2.0


def _residuals(prob: Problem, xyz: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(E, N) pseudo-range residuals at ``xyz`` with the clock term at its weighted best."""
    R, _ = ranges_and_units(np.nan_to_num(xyz), prob.bs, 3)
    s = np.where(prob.valid, prob.rho - R, 0.0)
    beta = np.sum(W * s, axis=1) / np.maximum(W.sum(axis=1), 1e-300)
    return np.where(prob.valid, s - beta[:, None], 0.0)


def _horizontal_sigma(prob: Problem, theta: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(E,) sqrt of the largest eigenvalue of the horizontal covariance of a fit, metres."""
    ok = np.isfinite(theta).all(axis=1)
    out = np.full(theta.shape[0], np.inf)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    _, J = pseudorange_model(prob)(theta[idx], idx)
    JW = J * W[idx][..., None]
    A = np.matmul(JW.transpose(0, 2, 1), J)
    A += 1e-12 * np.eye(A.shape[-1])
    try:
        cov = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return out
    ev = np.linalg.eigvalsh(cov[:, :2, :2])
    out[idx] = np.sqrt(np.maximum(ev[:, -1], 0.0))
    return out


@dataclass(frozen=True)
class Hypothesis:
    """One fault hypothesis's least-squares fit (see the module docstring): what of the HPL does
    not depend on the fix.

    Attributes
    ----------
    fit : (E, 3) float, metres, the hypothesis's fit
    ok : (E,) bool, plausible (solved, converged, inside the area, consistent, not early)
    sigma_h : (E,) float, metres, its horizontal standard deviation
    """

    fit: np.ndarray
    ok: np.ndarray
    sigma_h: np.ndarray


def hypotheses(prob: Problem, rows: np.ndarray) -> list[Hypothesis]:
    """The fits of every fault hypothesis (none, then each base station excluded) on the epochs
    ``rows`` (E,) bool; a hypothesis no epoch can take is left out."""
    E, N = prob.rho.shape
    k = prob.dims + 1
    sigma = link_sigma(prob.links, (E, N))
    W0 = np.where(prob.valid, 1.0 / sigma**2, 0.0)
    s_wide = np.sqrt(sigma**2 + (WIDE_PULSES * pulse_width_m(prob.links)) ** 2)
    narrow = prob.links is not None and prob.links.lobe_width is not None
    early_tol = K_SIGMA * (
        np.where(prob.links.lobe_width < NARROW_LOBE, s_wide, sigma) if narrow else sigma
    )
    out = []
    for j in range(-1, N):
        use = prob.valid.copy()
        if j >= 0:
            use[:, j] = False
        sub = rows & (use.sum(axis=1) >= k) & (j < 0 or prob.valid[:, max(j, 0)])
        if not np.any(sub):
            continue
        W = np.where(use, W0, 0.0)
        sol = solve_pseudorange(prob, W, sub, tol=1e-6, max_iter=30)
        fit = sol.xyz
        ok = sub & sol.converged & np.isfinite(fit).all(axis=1)
        if prob.area is not None:
            ok &= prob.area.contains(fit[:, :2])
        rh = _residuals(prob, fit, W)
        dof = use.sum(axis=1) - k
        sse = np.sum(W * rh * rh, axis=1)
        ok &= (dof < 1) | (sse <= chi2.ppf(P_CONSISTENT, np.maximum(dof, 1)))
        if j >= 0:
            ok &= rh[:, j] >= -early_tol[:, j]
        out.append(Hypothesis(fit, ok, _horizontal_sigma(prob, sol.theta, W)))
    return out


def integrity(prob: Problem, xyz: np.ndarray, status: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """HPL (E,) and chi2n (E,) of fixes ``xyz`` (E, 3) (see the module docstring).

    NaN for unsolved fixes; chi2n NaN without redundancy. The hypotheses depend on the
    measurements alone: with a memo (:meth:`~positioning.model.problem.Problem.with_memo`) they
    are fitted once per set of epochs for every method's fixes.
    """
    E, N = prob.rho.shape
    k = prob.dims + 1
    solved = ((status & int(Status.UNSOLVED)) == 0) & np.isfinite(xyz).all(axis=1)
    sigma = link_sigma(prob.links, (E, N))
    W0 = np.where(prob.valid, 1.0 / sigma**2, 0.0)
    n = prob.n_valid
    r = _residuals(prob, xyz, W0)
    with np.errstate(invalid="ignore", divide="ignore"):
        chi2n = np.where(solved & (n > k), np.sum(W0 * r * r, axis=1) / (n - k), np.nan)
    rows = solved & prob.solvable
    if prob.memo is not None:
        key = ("integrity hypotheses", rows.tobytes())
        hyps = prob.memo.get(prob, key, lambda: hypotheses(prob, rows))
    else:
        hyps = hypotheses(prob, rows)
    hpl = np.full(E, -np.inf)
    for h in hyps:
        d = np.linalg.norm(np.nan_to_num(h.fit[:, :2] - xyz[:, :2]), axis=1)
        hpl = np.where(h.ok, np.maximum(hpl, d + K_SIGMA * h.sigma_h), hpl)
    hpl = np.where(np.isfinite(hpl), hpl, np.inf)
    hpl = np.where(solved, hpl, np.nan)
    return hpl, chi2n
