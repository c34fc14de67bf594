"""``nlos-map``: maximum a posteriori position under the physics of a band-limited ToA.

Each measurement's range error is a mixture (:mod:`positioning.noise`): a noise core at the
link's Cramér-Rao bound plus floor, a two-sided overlap shift of up to about a pulse width, and a
non-negative NLoS excess (NLoS only adds delay). The shares depend on what the receiver reports
(SNR against the free-space SNR at the candidate position, first-lobe width and level), so the
likelihood uses the SNR as a second, coarse range measurement.

Solve: for every hypothesis start (the least-squares fit of all received base stations and of
every leave-one-out subset), expectation-maximisation on the mixture: the E-step gives each
measurement's responsibilities and, for the late cause, the expected excess; the M-step is a
weighted least-squares fit of the pseudo-ranges less that expected excess. Each converged start
is scored by the total negative log-likelihood; starts that end outside the service area are
discarded (unless all do). ``estimate="map"`` returns the best; ``"mean"`` (default) the
posterior-weighted mean of the distinct local optima (weights ``exp(-NLL)``), which hedges
between two hypotheses the data cannot separate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .fixes import Status
from .noise import (
    WIDE_PULSES,
    late_mean_excess,
    link_sigma,
    mixture_nll,
    pulse_width_m,
    shares,
)
from .robust import REGION_MARGIN, REJECT_WEIGHT, _candidates
from .tdoa import Problem, levenberg_marquardt, pseudorange_model, ranges_and_units

#: Two local optima closer than this (m) are the same one (posterior mean).
SAME_OPTIMUM_M = 0.05


def _nll(prob: Problem, theta: np.ndarray, sigma: np.ndarray, s_w: float):
    """Per-measurement NLL (E, N), responsibilities (3, E, N), residuals (E, N) at ``theta``."""
    E = prob.n_epochs
    p = prob.position(theta, np.arange(E))
    R, _ = ranges_and_units(np.where(np.isfinite(p), p, 0.0), prob.bs, prob.dims)
    r = np.where(prob.valid, prob.rho - R - theta[:, prob.dims][:, None], 0.0)
    r = np.where(np.isfinite(r), r, 0.0)
    pw, pl = shares(prob.links, R, prob.valid)
    nll, resp = mixture_nll(r, sigma, pw, pl, s_w)
    return np.where(prob.valid, nll, 0.0), resp, r


def em_fit(
    prob: Problem,
    theta0: np.ndarray,
    rows: np.ndarray,
    *,
    tol_m: float,
    max_iter: int,
    gn_max_iter: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EM on the mixture from ``theta0`` (E, dims+1) on the epochs ``rows``.

    Returns theta (E, dims+1), total NLL (E,) (inf where not run), final inverse-variance
    weights (E, N) and iterations (E,).
    """
    E, N = prob.rho.shape
    sigma_all = link_sigma(prob.links, (E, N))
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    theta = theta0.copy()
    iters = np.zeros(E, dtype=np.int64)
    weights = np.zeros((E, N))
    act = np.flatnonzero(rows & np.isfinite(theta0).all(axis=1))
    for _ in range(max_iter):
        if act.size == 0:
            break
        sub = prob.take(act)
        sig = sigma_all[act]
        _, resp, r = _nll(sub, theta[act], sig, s_w)
        excess = late_mean_excess(r, sig)
        w = resp[0] / sig**2 + resp[1] / (sig**2 + s_w**2) + resp[2] / sig**2
        shift = resp[2] / sig**2 * excess / w
        W = np.where(sub.valid, w, 0.0)
        shifted = replace(sub, rho=sub.rho - np.where(sub.valid, shift, 0.0))
        th, _, _ = levenberg_marquardt(
            pseudorange_model(shifted), theta[act], W, tol=tol_m, max_iter=gn_max_iter
        )
        step = np.linalg.norm(th - theta[act], axis=1)
        ok = np.isfinite(step)
        theta[act[ok]] = th[ok]
        weights[act] = W
        iters[act] += 1
        act = act[ok & (step > tol_m)]
    nll_e, _, _ = _nll(prob, np.where(np.isfinite(theta), theta, 0.0), sigma_all, s_w)
    total = np.where(rows & np.isfinite(theta).all(axis=1), nll_e.sum(axis=1), np.inf)
    return theta, total, weights, iters


def nlos_map(
    prob: Problem,
    *,
    estimate: str = "mean",
    max_drop: int = 1,
    tol_m: float = 1e-4,
    max_iter: int = 30,
    gn_max_iter: int = 5,
    region_margin: float = REGION_MARGIN,
) -> dict[str, np.ndarray]:
    """Physics-aware robust estimator (see the module docstring).

    Parameters
    ----------
    estimate : "mean" (posterior mean of the distinct local optima, default) or "map" (the best).
    max_drop : most base stations left out in a start hypothesis (default 1).
    tol_m, max_iter, gn_max_iter : EM step tolerance (m), EM iterations, LM steps per M-step.
    region_margin : leave-one-out starts outside the base stations' box grown by this fraction
        of its diagonal are not used.

    Returns
    -------
    dict with ``xyz`` (E, 3), ``status``, ``iterations``, ``weights`` (E, N) (the measurement's
    final core-plus-wide responsibility, 0..1: low = treated as NLoS), ``fit_weights``.
    """
    if estimate not in ("map", "mean"):
        raise ValueError(f"unknown estimate {estimate!r}")
    E, N = prob.rho.shape
    rows = prob.solvable
    fits, scores, wts, its, ills = [], [], [], [], []
    for _, sub, s in _candidates(prob, rows, max_drop, region_margin):
        th, total, W, it = em_fit(
            prob, s.theta, sub, tol_m=tol_m, max_iter=max_iter, gn_max_iter=gn_max_iter
        )
        fits.append(th)
        scores.append(total)
        wts.append(W)
        its.append(it)
        ills.append(s.ill)
    H = len(fits)
    if H == 0:  # no epoch has enough base stations
        return {
            "xyz": np.full((E, 3), np.nan),
            "status": np.full(E, int(Status.UNSOLVED), dtype=np.int64),
            "iterations": np.zeros(E, dtype=np.int64),
            "weights": np.zeros((E, N)),
        }
    theta = np.stack(fits)  # (H, E, k)
    score = np.stack(scores)  # (H, E)
    xyz_h = np.stack([prob.position(np.nan_to_num(t), np.arange(E)) for t in fits])
    if prob.area is not None:
        inside = np.stack([prob.area.contains(x[:, :2]) for x in xyz_h])
        any_in = (inside & np.isfinite(score)).any(axis=0)
        score = np.where(inside | ~any_in[None], score, np.inf)
    best = np.argmin(score, axis=0)
    ar = np.arange(E)
    xyz = xyz_h[best, ar].copy()
    if estimate == "mean" and H > 1:
        # distinct optima only: a hypothesis whose fit repeats a better one's adds nothing
        order = np.argsort(score, axis=0)
        keep = np.zeros((H, E), dtype=bool)
        for j in range(H):
            h = order[j]
            fin = np.isfinite(score[h, ar])
            dup = np.zeros(E, dtype=bool)
            for i in range(j):
                g = order[i]
                near = np.linalg.norm(xyz_h[h, ar, :2] - xyz_h[g, ar, :2], axis=1) < SAME_OPTIMUM_M
                dup |= keep[g, ar] & near
            keep[h, ar] = fin & ~dup
        top = score[best, ar]
        lw = np.where(keep, -(score - np.where(np.isfinite(top), top, 0.0)[None]), -np.inf)
        w = np.exp(lw)
        w /= np.maximum(w.sum(axis=0), 1e-300)
        xyz = np.einsum("he,hej->ej", w, np.nan_to_num(xyz_h))
        if prob.height is not None:
            xyz[:, 2] = prob.height  # known, not averaged (exactly)
    W = np.stack(wts)[best, ar]
    sigma = link_sigma(prob.links, (E, N))
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    _, resp, _ = _nll(prob, np.nan_to_num(theta[best, ar]), sigma, s_w)
    trust = np.where(prob.valid, resp[0] + resp[1], 0.0)
    status = np.where(rows & np.stack(ills)[best, ar], int(Status.ILL_CONDITIONED), 0)
    rejected = (prob.valid & (trust < REJECT_WEIGHT)).any(axis=1)
    status |= np.where(rows & rejected, int(Status.OUTLIER_REJECTED), 0)
    status |= np.where(rows, 0, int(Status.UNSOLVED))
    xyz[~rows] = np.nan
    return {
        "xyz": xyz,
        "status": status,
        "iterations": np.stack(its)[best, ar],
        "weights": np.where(rows[:, None], trust, 0.0),
        "fit_weights": W,
    }
