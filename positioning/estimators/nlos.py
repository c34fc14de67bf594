"""``nlos-map``: maximum a posteriori position under the physics of a band-limited ToA.

Each measurement's range error is a mixture (:mod:`positioning.model.noise`): a noise core at the
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

from dataclasses import dataclass, replace

import numpy as np

from ..model.noise import (
    LATE_MEAN_M,
    WIDE_PULSES,
    free_space_snr_db,
    late_mean_excess,
    link_sigma,
    mixture_nll,
    pulse_width_m,
    shares,
    shares_at_deficit,
)
from ..model.problem import Problem
from ..model.residuals import pseudorange_model
from ..model.tdoa import ranges, ranges_and_units
from .fixes import Fixes, Status, config_params
from .mixture_kernel import MixtureEStep, deepest_cells, grid_log_shares, numpy_is_libm
from .robust import REGION_MARGIN, REJECT_WEIGHT, candidates
from .solver import levenberg_marquardt

#: Grid starts are at least this many grid pitches apart (distinct basins).
SEPARATION_PITCHES = 2.0
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


def _grid_shares(links, idx: np.ndarray, R_h: np.ndarray, at: np.ndarray, G: int):
    """The mixture's shares at the grid's cells for epochs ``idx``: (p_wide, p_late, None)
    (A, G, N) in numpy, or (None, None, their logs (3, A, G, N)) compiled where that gives
    numpy's bits (:func:`~positioning.estimators.mixture_kernel.numpy_is_libm`). ``R_h``
    (H, G, N) the cells' ranges per device height, ``at`` (A,) each epoch's height."""
    fs = None
    if links is not None:
        links = links.take(idx)
        if links.snr_offset_db is not None and links.center_frequency_hz:
            fs = free_space_snr_db(links, R_h)  # (H, G, N)
    A, N = idx.size, R_h.shape[2]
    if numpy_is_libm():
        return None, None, grid_log_shares(fs, at, links, G, N)
    deficit = None
    if links is not None:
        links = replace(
            links,
            snr_db=links.snr_db[:, None, None, :],
            peak_ratio_db=links.peak_ratio_db[:, None, None, :],
            lobe_width=links.lobe_width[:, None, None, :],
        )
        if fs is not None:
            deficit = fs[at][:, :, None, :] - links.snr_db
    pw, pl = shares_at_deficit(links, deficit, np.ones((A, 1, 1, N), dtype=bool))
    return pw[:, :, 0], pl[:, :, 0], None


def grid_starts(prob: Problem, rows: np.ndarray, step_m: float, n_starts: int) -> np.ndarray:
    """(n_starts, E, dims+1) starts at the deepest distinct cells of the mixture NLL on a grid of
    the service area (NaN where there are fewer minima, or no area, or a 3D solve).

    The leave-one-out starts cannot represent two NLoS base stations among four; the likelihood
    over the whole area can (the SNR terms and the sign of the excess locate the device along the
    one remaining hyperbola). The clock term at a grid point is the best of the N values that
    make one base station's residual zero. Coarse to fine: at the grid's resolution the noise core
    is widened by half a pitch, so that a basin is not missed between grid points, and EM refines
    each start at the true scale. The starts are the deepest cells, each at least
    :data:`SEPARATION_PITCHES` pitches from the ones taken before (one per basin).
    """
    E, N = prob.rho.shape
    k = prob.dims + 1
    out = np.full((n_starts, E, k), np.nan)
    if prob.area is None or prob.height is None or n_starts <= 0:
        return out
    g = prob.area.grid(step_m)
    G = g.shape[0]
    sigma = np.sqrt(link_sigma(prob.links, (E, N)) ** 2 + (0.5 * step_m) ** 2)
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    chunk = max(1, 2_000_000 // max(G * N * N, 1))
    for a0 in range(0, E, chunk):
        idx = np.flatnonzero(rows[a0 : a0 + chunk]) + a0
        if idx.size == 0:
            continue
        A = idx.size
        # the cells' ranges and free-space SNRs once per device height (mostly one), not per
        # epoch: the same numbers, gathered
        heights, at = np.unique(prob.height[idx], return_inverse=True)
        xyz = np.empty((heights.size, G, 3))
        xyz[..., :2] = g[None]
        xyz[..., 2] = heights[:, None]
        R_h = np.linalg.norm(xyz[:, :, None, :] - prob.bs[None, None], axis=3)  # (H, G, N)
        R = R_h[at]  # (A, G, N)
        valid = prob.valid[idx][:, None, :]
        s = np.where(valid, prob.rho[idx][:, None, :] - R, 0.0)
        pw, pl, log_share = _grid_shares(prob.links, idx, R_h, at, G)
        # the deepest cells of the mixture NLL of the residuals s[n] - s[j] (beta from j), each
        # at least SEPARATION_PITCHES pitches from the ones taken before (compiled, with the
        # NLL computed only where a bound leaves a cell in contention: the grid was most of
        # nlos-map's time)
        pick, ref, ok, _ = deepest_cells(s, prob.valid[idx], sigma[idx], pw, pl, s_w,
                                         LATE_MEAN_M, g, SEPARATION_PITCHES * step_m, n_starts,
                                         log_share)  # fmt: skip
        ar = np.arange(A)
        for m in range(pick.shape[1]):
            th = np.column_stack([g[pick[:, m]], s[ar, pick[:, m], ref[:, m]]])
            out[m, idx[ok[:, m]]] = th[ok[:, m]]
    return out


class _EStep:
    """``em_fit``'s E-step (NLL, responsibilities, residuals) and M-step weights on the epochs
    of ``prob``: compiled (:class:`~positioning.estimators.mixture_kernel.MixtureEStep`) where
    that gives numpy's bits, else numpy (:func:`_nll`)."""

    def __init__(self, prob: Problem, sigma: np.ndarray, s_w: float) -> None:
        self.prob, self.sigma, self.s_w = prob, sigma, s_w
        self.kernel = None
        if numpy_is_libm():
            self.kernel = MixtureEStep(prob.rho, prob.valid, prob.links, sigma, s_w, LATE_MEAN_M)

    def at(self, idx: np.ndarray, theta: np.ndarray):
        """:func:`_nll` of epochs ``idx`` (A,) at ``theta`` (A, dims+1)."""
        if self.kernel is None:
            return _nll(self.prob.take(idx), theta, self.sigma[idx], self.s_w)
        p = self.prob.position(theta, idx)
        R = ranges(np.where(np.isfinite(p), p, 0.0), self.prob.bs)
        return self.kernel.at(idx, R, theta[:, self.prob.dims])

    def weights(self, idx: np.ndarray, r: np.ndarray, resp: np.ndarray):
        """The M-step's inverse-variance weights (A, N) and pseudo-ranges less the expected
        NLoS excess (A, N) from the E-step of epochs ``idx``."""
        if self.kernel is not None:
            return self.kernel.weights(idx, r, resp)
        sig, valid, s_w = self.sigma[idx], self.prob.valid[idx], self.s_w
        excess = late_mean_excess(r, sig)
        w = resp[0] / sig**2 + resp[1] / (sig**2 + s_w**2) + resp[2] / sig**2
        shift = resp[2] / sig**2 * excess / w
        return np.where(valid, w, 0.0), self.prob.rho[idx] - np.where(valid, shift, 0.0)


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
    estep = _EStep(prob, sigma_all, WIDE_PULSES * pulse_width_m(prob.links))
    theta = theta0.copy()
    iters = np.zeros(E, dtype=np.int64)
    weights = np.zeros((E, N))
    act = np.flatnonzero(rows & np.isfinite(theta0).all(axis=1))
    here = None  # (nll, resp, r) at theta[act], when the last iteration computed them
    for _ in range(max_iter):
        if act.size == 0:
            break
        # the E-step at an accepted M-step's end point is the NLL the test below computed there
        # (every term is per measurement: the same numbers for the smaller batch)
        nll0, resp, r = here if here is not None else estep.at(act, theta[act])
        W, rho_shifted = estep.weights(act, r, resp)
        # the M-step's problem: only its pseudo-ranges, validity and heights enter the model
        shifted = replace(prob, rho=rho_shifted, valid=prob.valid[act], links=None, memo=None,
                          height=None if prob.height is None else prob.height[act])  # fmt: skip
        th, _, _ = levenberg_marquardt(
            pseudorange_model(shifted), theta[act], W, tol=tol_m, max_iter=gn_max_iter
        )
        if prob.area is not None:  # the M-step stays on the floor
            th[:, :2] = prob.area.project(th[:, :2])
        step = np.linalg.norm(th - theta[act], axis=1)
        nll1, resp1, r1 = estep.at(act, np.nan_to_num(th))
        # a descent method: a step that does not lower the NLL (the shares move with the
        # position, so plain EM is not monotone here) ends the iteration where it is
        ok = np.isfinite(step) & (nll1.sum(axis=1) < nll0.sum(axis=1))
        theta[act[ok]] = th[ok]
        weights[act] = W
        iters[act] += 1
        go = ok & (step > tol_m)  # a finite step: th is finite there, nan_to_num kept it
        act = act[go]
        here = (nll1[go], resp1[:, go], r1[go])
    nll_e, _, _ = estep.at(np.arange(E), np.where(np.isfinite(theta), theta, 0.0))
    total = np.where(rows & np.isfinite(theta).all(axis=1), nll_e.sum(axis=1), np.inf)
    return theta, total, weights, iters


def _starts(
    prob: Problem, rows: np.ndarray, max_drop: int, margin: float, grid_m: float, n_grid: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(epochs, theta0 (E, k), ill-conditioned (E,)) of every start: the hypothesis fits of
    :func:`positioning.estimators.robust.candidates`, then the grid starts."""
    E = prob.n_epochs
    starts = [(sub, s.theta, s.ill) for _, sub, s in candidates(prob, rows, max_drop, margin)]
    if grid_m > 0 and starts:
        for th0 in grid_starts(prob, rows, grid_m, n_grid):
            ok = rows & np.isfinite(th0).all(axis=1)
            if ok.any():
                starts.append((ok, th0, np.zeros(E, dtype=bool)))
    return starts


def posterior_mean(
    prob: Problem, xyz_h: np.ndarray, score: np.ndarray, best: np.ndarray
) -> np.ndarray:
    """(E, 3) mean of the distinct end points ``xyz_h`` (H, E, 3), weighted by ``exp(-NLL)``
    (``score`` (H, E); ``best`` (E,) the lowest). An end point within :data:`SAME_OPTIMUM_M` of
    a better one is the same optimum and is counted once."""
    H, E = score.shape
    ar = np.arange(E)
    order = np.argsort(score, axis=0)
    keep = np.zeros((H, E), dtype=bool)
    for j in range(H):
        h = order[j]
        dup = np.zeros(E, dtype=bool)
        for i in range(j):
            g = order[i]
            near = np.linalg.norm(xyz_h[h, ar, :2] - xyz_h[g, ar, :2], axis=1) < SAME_OPTIMUM_M
            dup |= keep[g, ar] & near
        keep[h, ar] = np.isfinite(score[h, ar]) & ~dup
    top = score[best, ar]
    lw = np.where(keep, -(score - np.where(np.isfinite(top), top, 0.0)[None]), -np.inf)
    w = np.exp(lw)
    w /= np.maximum(w.sum(axis=0), 1e-300)
    xyz = np.einsum("he,hej->ej", w, np.nan_to_num(xyz_h))
    if prob.height is not None:
        xyz[:, 2] = prob.height  # known, not averaged (exactly)
    return xyz


@dataclass(frozen=True)
class NlosMapConfig:
    """Settings of ``nlos-map`` (:func:`nlos_map`).

    Attributes
    ----------
    estimate : "mean" (posterior mean of the distinct local optima, default) or "map" (the best).
    max_drop : most base stations left out in a start hypothesis (default 1).
    grid_m : pitch (m) of the likelihood grid over the service area that gives one more start
        (2D with an area only; 0 = none). Default 2 m: the likelihood's basins are at least a
        pulse width (0.9-3.7 m) wide.
    n_grid_starts : the deepest local minima of the grid used as starts (default 3).
    tol_m, max_iter, gn_max_iter : EM step tolerance (m), EM iterations, LM steps per M-step.
    region_margin : leave-one-out starts outside the base stations' box grown by this fraction
        of its diagonal are not used.
    """

    estimate: str = "mean"
    max_drop: int = 1
    grid_m: float = 2.0
    n_grid_starts: int = 3
    tol_m: float = 1e-4
    max_iter: int = 30
    gn_max_iter: int = 5
    region_margin: float = REGION_MARGIN


def nlos_map(prob: Problem, config: NlosMapConfig = NlosMapConfig()) -> Fixes:
    """Physics-aware robust estimator (see the module docstring).

    Returns
    -------
    :class:`Fixes` of method ``nlos-map``: ``weights`` (E, N) the measurement's final
    core-plus-wide responsibility, 0..1 (low = treated as NLoS); ``fit_weights`` (E, N) the
    final inverse-variance weights of the best start's EM (for the bounded re-solve).
    """
    if config.estimate not in ("map", "mean"):
        raise ValueError(f"unknown estimate {config.estimate!r}")
    E, N = prob.rho.shape
    rows = prob.solvable
    starts = _starts(prob, rows, config.max_drop, config.region_margin, config.grid_m,
                     config.n_grid_starts)  # fmt: skip
    fits, scores, wts, its, ills = [], [], [], [], []
    for sub, th0, ill in starts:
        th, total, W, it = em_fit(
            prob, th0, sub, tol_m=config.tol_m, max_iter=config.max_iter,
            gn_max_iter=config.gn_max_iter,
        )  # fmt: skip
        fits.append(th)
        scores.append(total)
        wts.append(W)
        its.append(it)
        ills.append(ill)
    H = len(fits)
    if H == 0:  # no epoch has enough base stations
        return Fixes(
            xyz=np.full((E, 3), np.nan),
            status=np.full(E, int(Status.UNSOLVED), dtype=np.int64),
            iterations=np.zeros(E, dtype=np.int64),
            weights=np.zeros((E, N)),
            n_used=prob.n_valid,
            method="nlos-map",
            params=config_params(config),
        )
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
    if config.estimate == "mean" and H > 1:
        xyz = posterior_mean(prob, xyz_h, score, best)
    W = np.stack(wts)[best, ar]
    estep = _EStep(prob, link_sigma(prob.links, (E, N)), WIDE_PULSES * pulse_width_m(prob.links))
    _, resp, _ = estep.at(ar, np.nan_to_num(theta[best, ar]))
    trust = np.where(prob.valid, resp[0] + resp[1], 0.0)
    status = np.where(rows & np.stack(ills)[best, ar], int(Status.ILL_CONDITIONED), 0)
    rejected = (prob.valid & (trust < REJECT_WEIGHT)).any(axis=1)
    status |= np.where(rows & rejected, int(Status.OUTLIER_REJECTED), 0)
    status |= np.where(rows, 0, int(Status.UNSOLVED))
    xyz[~rows] = np.nan
    return Fixes(
        xyz=xyz,
        status=status,
        iterations=np.stack(its)[best, ar],
        weights=np.where(rows[:, None], trust, 0.0),
        n_used=prob.n_valid,
        method="nlos-map",
        params=config_params(config),
        fit_weights=W,
    )
