"""Two-pulse refinement of a first lobe: when the lobe a receiver reports is not one pulse (paths
within a pulse width merged into it), fit it with two pulses at free delays and complex
amplitudes and report the earlier one where the fit determines it.

Two paths a fraction of a period ``T`` apart merge into one lobe whose top lies between them when
they are in phase (a late ToA) and *before the first* when they are in anti-phase (the difference
of two pulses is close to the pulse's derivative, whose first lobe leads): the early ToAs of the
lobe-top receivers on line-of-sight links (docs/channel.md, "Receiver study"). A receiver that
knows the pulse sees that such a lobe is not one pulse: the one-pulse fit leaves a residual far
above the noise.

Used by the tracer's ``search-back`` receiver (:mod:`raytrace.emulation.receivers.search_back`);
numpy beside the pulse, vectorised over rows (one row per link), the pulse fit compiled row by row
(numba, no fastmath; :func:`fit_pulses_numpy` is its numpy reference):

1. :func:`fit_pulses`: joint least-squares complex amplitudes and Gauss-Newton delays of ``K``
   pulses (eq. 2) on samples of a row (variable projection);
2. :func:`refine_lobe`: the samples from :data:`LEAD_T` before the reported lobe top to
   :data:`TAIL_T` after it, or after the strongest peak where that is within :data:`REACH_T`
   (a lobe that is the precursor of a merged peak is fitted with it), the profile's samples
   decimated to :data:`FIT_PER_T` per period, the cancelled lobes well outside (:data:`FAR_T`)
   removed. A lobe is not one pulse when the one-pulse fit leaves more than noise could,
   ``E_1 >= sigma_hat^2 (N - 1.5 + alpha kappa_n)``: the noise's own energy in ``N`` samples
   less the fit's 1.5 complex degrees of freedom, plus what a pulse-shaped excursion at the
   CFAR threshold adds (``alpha`` the CFAR factor, ``kappa_n`` the noise power a pulse collects
   from the profile's correlated noise, :func:`noise_gain`). Then the best two-pulse fit from a
   few starting pairs, and its earlier component replaces the lobe top where

   * both components are above the CFAR threshold ``gamma`` and within ``rho`` (the first
     lobe's relative threshold) of the stronger: paths, not noise;
   * the earlier is at least :data:`EARLY_RATIO` of the later (a weaker earlier path pulls
     the merged top late, not early);
   * they are at least :data:`MIN_SEPARATION_T` apart (closer, their amplitudes are not
     determined by the samples);
   * the earlier delay's standard error, from the fit's own residual (nonlinear least squares,
     :func:`delay_error`), is at most :data:`SE_MAX_T` periods: the early margin of a quarter
     period is five of them. A lobe made of three or more comparable paths within a fraction
     of ``T`` (dense multipath) leaves a residual that no two pulses explain; its two-pulse
     delays are then not determined.
3. Where no earlier component is accepted, the lobe top itself is tested against the fit that
   explains the lobe best: the two-pulse fit or, where that leaves more than noise could (the
   same residual test with ``N - 3``), a third pulse added at the largest residual sample
   (greedy, :data:`MAX_ORDER`) where it leaves less. If that fit is adequate (it explains the
   lobe into the noise, or its components are resolved, :data:`MIN_SEPARATION_T` apart) and
   its first component lies more than :data:`CONSISTENT_SE` standard errors and more than the
   early margin (:data:`LEAD_MIN_T`) after the lobe top, the lobe top is not a path (paths
   merged in anti-phase top before them all) and the first component is the ToA. The rule only
   ever moves a ToA later: an earlier component is reported only where step 2 accepts it.
4. A lobe :data:`REACH_T` to :data:`REACH_FAR_T` periods before the strongest peak may be that
   peak's sidelobe (a peak of paths merged in anti-phase has higher sidelobes than one pulse,
   and they can cross the first lobe's threshold). Where steps 2-3 on the lobe alone did not
   accept an earlier component, steps 2-3 run again on the lobe with the peak, and their result
   replaces the ToA only where it is later. (Fitting every lobe with a peak 3 T later instead
   lets a strong, separate later path take the fit's pair: C-band P10-BS1 of the bundled hall.)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np
import scipy.signal

from .pulse import TABLE_PER_T, pulse_at, raised_cosine

#: The fit's samples: from this many periods before the lobe top ...
LEAD_T = 1.25
#: ... to this many after it or after the strongest peak, ...
TAIL_T = 1.75
#: ... where the strongest peak is at most this many periods after the lobe top, ...
REACH_T = 2.0
#: ... or up to this many, in a second fit that may only move the ToA later (module docstring).
REACH_FAR_T = 3.0
#: ... this many per period (the profile's band is 1 / (1.25 T) wide: 3.2 samples per 1/B).
FIT_PER_T = 4
#: Cancelled lobes more than this many periods outside the fit's samples are removed before
#: the fit (their main lobes would bend its ends; those nearer are left to it: a cancelled
#: lobe is one pulse's estimate of what may be several, and removing it there would bend the
#: lobe itself).
FAR_T = 0.5
#: Two components closer than this (periods) are one: their amplitudes are not determined.
MIN_SEPARATION_T = 0.08
#: Largest standard error (periods) of the earlier component's delay (a fifth of the quarter
#: period that makes a ToA early).
SE_MAX_T = 0.05
#: The earlier component's amplitude over the later's, at least (-6 dB): an earlier path that
#: is weaker moves the merged lobe's top late, not early, and by less than their spacing; its
#: delay is the one the fit determines worst.
EARLY_RATIO = 0.5
#: The lobe top is replaced by the best fit's first component where it lies more than this many
#: of that component's standard errors before it.
CONSISTENT_SE = 3.0
#: ... and more than this many periods (the early margin: a lobe top less far before the
#: fit's first component is a fair estimate of a cluster the fit cannot resolve).
LEAD_MIN_T = 0.25
#: Most pulses of the best fit (greedy from the pair, :func:`_add_pulse`): with four the fit
#: explains the hall's dense lobes with spurious components again (C-band P23-BS4 early in 80 %
#: of epochs, 3 s static hall), as the previous study found for fits of 3-4 pulses from fixed
#: starts.
MAX_ORDER = 3
#: Starting pairs of the two-pulse fit, periods from the one-pulse fit's delay ...
STARTS_T = ((-0.5, 0.0), (0.0, 0.5), (-0.25, 0.25), (0.0, 0.75))
#: ... and from the strongest peak (the region's core end; also the lobe top with it): close
#: pairs too, from which an anti-phase pair a tenth of a period apart converges.
PEAK_STARTS_T = ((0.0, 0.5), (-0.06, 0.06), (0.24, 0.36), (-0.36, -0.24), (0.44, 0.56),
                 (-0.56, -0.44))  # fmt: skip
#: Gauss-Newton rounds of a fit, of which every start gets :data:`SCOUT_ROUNDS` and the best
#: start per row the rest; a step is clipped to :data:`STEP_T` periods.
ROUNDS = 8
SCOUT_ROUNDS = 4
STEP_T = 0.2
#: Ridge of the normal equations, relative to their diagonal.
_RIDGE = 1e-10


@lru_cache(maxsize=8)
def noise_correlation(roll_off: float, span: int, per_t: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Lags (periods, ``>= 0``) and the correlation coefficient of the delay profile's noise,
    whose spectrum is the pulse's squared (a white CFR estimate windowed by the pulse's
    spectrum): the pulse's autocorrelation ``(h * h)(x T) / (h * h)(0)``, on a grid of
    ``1 / per_t`` (numerical convolution of eq. 2 over ``+-span`` periods)."""
    x = np.arange(-span * per_t, span * per_t + 1) / per_t
    h = raised_cosine(x, roll_off)
    acf = scipy.signal.fftconvolve(h, h[::-1], mode="full")
    mid = acf.size // 2
    return np.arange(acf.size - mid) / per_t, acf[mid:] / acf[mid]


@lru_cache(maxsize=8)
def noise_gain(roll_off: float, span: int, per_t: int = FIT_PER_T) -> float:
    """``kappa_n = p^T R p / p^T p``: the noise power, in units of one sample's, that the
    projection on a pulse ``p`` sampled ``T / per_t`` apart collects from noise with the
    correlation ``R`` of :func:`noise_correlation` (white noise: 1; band-limited noise sampled
    above its rate: more)."""
    lags, rho = noise_correlation(float(roll_off), int(span))
    k = np.arange(-4 * per_t, 4 * per_t + 1) / per_t
    p = raised_cosine(k, roll_off)
    r = np.interp(np.abs(k[:, None] - k[None, :]), lags, rho)
    return float(p @ r @ p / (p @ p))


def _pulse_and_slope(lag: np.ndarray, period: float, table: tuple[np.ndarray, np.ndarray]):
    """``T h(lag)`` and its derivative in ``lag`` (1/s) from the pulse table (one look-up)."""
    value, step = table
    u = np.abs(lag) * (TABLE_PER_T / period)
    np.minimum(u, value.size - 2, out=u)
    i = u.astype(np.intp)
    d = step[i]
    return (u - i) * d + value[i], np.sign(lag) * d * (TABLE_PER_T / period)


@numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=False)
def _weighted_pulses(t, tau, w, scale, value, step):  # pragma: no cover - compiled
    """:func:`_pulse_and_slope` of ``t (R, N) - tau (R, K)`` times the weights ``w (R, N)``,
    component-major ``(K, R, N)``, each element computed once in registers (the fit's inner
    loop: in numpy eight array passes). numpy's arithmetic in its order, no ``fastmath`` (no
    fused multiply-add): bit for bit :func:`_pulse_and_slope`'s (tests/test_lobefit.py)."""
    r_n, n_n = t.shape
    k_n = tau.shape[1]
    top = float(value.size - 2)
    h = np.empty((k_n, r_n, n_n))
    slope = np.empty((k_n, r_n, n_n))
    for k in range(k_n):
        for r in range(r_n):
            tk = tau[r, k]
            for n in range(n_n):
                lag = t[r, n] - tk
                u = abs(lag) * scale
                if u > top:
                    u = top
                if u != u:  # NaN delays: NaN out (numpy would fail on the index)
                    h[k, r, n] = u
                    slope[k, r, n] = u
                    continue
                i = int(u)
                d = step[i]
                sg = 1.0 if lag > 0.0 else (-1.0 if lag < 0.0 else 0.0)
                h[k, r, n] = ((u - i) * d + value[i]) * w[r, n]
                slope[k, r, n] = sg * d * scale * w[r, n]
    return h, slope


def _ridge(a: np.ndarray) -> np.ndarray:
    """``a (R, K, K)`` plus :data:`_RIDGE` times its largest diagonal element (keeps two
    components that meet on one delay solvable)."""
    k = a.shape[-1]
    diag = a[:, np.arange(k), np.arange(k)]
    ridge = _RIDGE * np.maximum(np.abs(diag).max(axis=1, initial=0.0), 1e-300)
    out = a + 0.0  # a + ridge * I: off the diagonal + 0.0 (a -0.0 becomes +0.0, as there)
    out[:, np.arange(k), np.arange(k)] = diag + ridge[:, None]
    return out


def _solve(a: np.ndarray, b: np.ndarray, ridged: bool = False) -> np.ndarray:
    """Batched ``a x = b`` (``a (R, K, K)`` real symmetric, ``b (R, K)`` real or complex) with
    the ridge (``ridged``: ``a`` has it already, :func:`_ridge`); K <= 2 in closed form (the
    common case, much faster than a batched LAPACK call)."""
    if not ridged:
        a = _ridge(a)
    if a.shape[-1] == 1:
        return b / a[:, :, 0]
    if a.shape[-1] == 2:
        det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        x0 = (a[:, 1, 1] * b[:, 0] - a[:, 0, 1] * b[:, 1]) / det
        x1 = (a[:, 0, 0] * b[:, 1] - a[:, 1, 0] * b[:, 0]) / det
        return np.stack([x0, x1], axis=1)
    return np.linalg.solve(a, b[..., None])[..., 0]


def _solve_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched ``a x = b`` for a matrix ``b (R, K, J)`` (column by column, :func:`_solve`; ``a``
    with its ridge already)."""
    return np.stack([_solve(a, b[:, :, j], ridged=True) for j in range(b.shape[2])], axis=2)


def _cross(x: np.ndarray, y: np.ndarray, symmetric: bool = False) -> np.ndarray:
    """``[r, i, j] = x_i[r] . y_j[r]`` of component-major ``(K, R, N)`` arrays, each sum along the
    contiguous last axis (``symmetric``: ``x`` is ``y``, the lower triangle mirrored: a product
    and its mirror are the same numbers summed in the same order)."""
    k = x.shape[0]
    g = np.empty((x.shape[1], k, k))
    for i in range(k):
        for j in range(i if symmetric else 0, k):
            g[:, i, j] = np.einsum("rn,rn->r", x[i], y[j])
            if symmetric:
                g[:, j, i] = g[:, i, j]
    return g


_JIT = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)


@numba.njit(inline="always", **_JIT)
def _solve_small(a, b, x):  # pragma: no cover - compiled
    """``a x = b`` for a small ``a (K, K)`` (Gaussian elimination with partial pivoting; ``a``
    and ``b`` are overwritten)."""
    k_n = b.size
    for c in range(k_n):
        p = c
        for i in range(c + 1, k_n):
            if abs(a[i, c]) > abs(a[p, c]):
                p = i
        if p != c:
            for j in range(k_n):
                a[c, j], a[p, j] = a[p, j], a[c, j]
            b[c], b[p] = b[p], b[c]
        for i in range(c + 1, k_n):
            f = a[i, c] / a[c, c]
            for j in range(c, k_n):
                a[i, j] -= f * a[c, j]
            b[i] -= f * b[c]
    for c in range(k_n - 1, -1, -1):
        acc = b[c]
        for j in range(c + 1, k_n):
            acc -= a[c, j] * x[j]
        x[c] = acc / a[c, c]


@numba.njit(inline="always", **_JIT)
def _add_ridge(a, ridge):  # pragma: no cover - compiled
    """:func:`_ridge` of one matrix, in place."""
    top = 0.0
    for i in range(a.shape[0]):
        top = max(top, abs(a[i, i]))
    add = ridge * max(top, 1e-300)
    for i in range(a.shape[0]):
        a[i, i] += add


@numba.njit(**_JIT)
def _fit_kernel(sr, si, t, w, tau0, rounds, period, scale, value, step, step_max, ridge):  # pragma: no cover - compiled
    """:func:`fit_pulses`, row by row in registers (long kernel: one Gauss-Newton round is one
    pass over the row's samples per sum, and splitting it would allocate per round).

    ``sr, si, t, w (R, N)``: the weighted samples' real and imaginary parts, times, weights;
    ``tau0 (R, K)`` starting delays. Returns ``tau (R, K)``, ``amp_re, amp_im (R, K)``,
    ``energy (R,)``."""
    r_n, n_n = t.shape
    k_n = tau0.shape[1]
    tau = tau0.copy()
    a_re, a_im, energy = np.empty((r_n, k_n)), np.empty((r_n, k_n)), np.empty(r_n)
    h, sl = np.empty((k_n, n_n)), np.empty((k_n, n_n))
    er, ei = np.empty(n_n), np.empty(n_n)
    hh, m, hs, x = np.empty((k_n, k_n)), np.empty((k_n, k_n)), np.empty((k_n, k_n)), np.empty(k_n)
    proj, jj = np.empty((k_n, k_n)), np.empty((k_n, k_n))
    b, je, ar, ai = np.empty(k_n), np.empty(k_n), np.empty(k_n), np.empty(k_n)
    top = float(value.size - 2)
    for r in range(r_n):
        for it in range(rounds + 1):
            for k in range(k_n):
                for n in range(n_n):
                    lag = t[r, n] - tau[r, k]
                    u = min(abs(lag) * scale, top)
                    if u != u:
                        h[k, n] = u
                        sl[k, n] = u
                        continue
                    i = int(u)
                    d = step[i]
                    sg = 1.0 if lag > 0.0 else (-1.0 if lag < 0.0 else 0.0)
                    h[k, n] = ((u - i) * d + value[i]) * w[r, n]
                    sl[k, n] = sg * d * scale * w[r, n]
            for i in range(k_n):
                for j in range(k_n):
                    acc = 0.0
                    for n in range(n_n):
                        acc += h[i, n] * h[j, n]
                    hh[i, j] = acc
            _add_ridge(hh, ridge)
            for part in range(2):  # the amplitudes: real, then imaginary part
                src = sr if part == 0 else si
                for i in range(k_n):
                    acc = 0.0
                    for n in range(n_n):
                        acc += h[i, n] * src[r, n]
                    b[i] = acc
                m[:, :] = hh
                _solve_small(m, b, ar if part == 0 else ai)
            for n in range(n_n):
                vr, vi = sr[r, n], si[r, n]
                for k in range(k_n):
                    vr -= h[k, n] * ar[k]
                    vi -= h[k, n] * ai[k]
                er[n], ei[n] = vr, vi
            if it == rounds:
                break
            # Gauss-Newton with the amplitudes projected out (fit_pulses): s'_k less its
            # projection on the pulses, J^H J and J^H e
            for j in range(k_n):
                for k in range(k_n):
                    acc = 0.0
                    for n in range(n_n):
                        acc += h[j, n] * sl[k, n]
                    hs[j, k] = acc
            for k in range(k_n):  # proj[:, k] = hh^-1 hs[:, k]
                m[:, :] = hh
                b[:] = hs[:, k]
                _solve_small(m, b, x)
                proj[:, k] = x
            for i in range(k_n):
                for j in range(k_n):
                    acc = 0.0
                    for n in range(n_n):
                        acc += sl[i, n] * sl[j, n]
                    for q in range(k_n):
                        acc -= hs[q, i] * proj[q, j]
                    jj[i, j] = acc * (ar[i] * ar[j] + ai[i] * ai[j])
                sre, sie = 0.0, 0.0
                for n in range(n_n):
                    sre += sl[i, n] * er[n]
                    sie += sl[i, n] * ei[n]
                je[i] = -(ar[i] * sre + ai[i] * sie)
            _add_ridge(jj, ridge)
            _solve_small(jj, je, x)
            for k in range(k_n):
                tau[r, k] += min(max(x[k], -step_max), step_max)
        acc = 0.0
        for n in range(n_n):
            acc += er[n] * er[n] + ei[n] * ei[n]
        energy[r] = acc
        a_re[r, :] = ar
        a_im[r, :] = ai
    return tau, a_re, a_im, energy


def fit_pulses(
    s: np.ndarray,
    t: np.ndarray,
    valid: np.ndarray,
    tau: np.ndarray,
    period: float,
    table: tuple[np.ndarray, np.ndarray],
    rounds: int = ROUNDS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares fit of ``K`` pulses to each row: ``s ~ sum_k a_k T h(t - tau_k)``, compiled
    row by row (:func:`_fit_kernel`; :func:`fit_pulses_numpy` is the same fit in array passes).

    Parameters
    ----------
    s : (R, N) complex, 1/s, the samples; t : (R, N) float, s, their times
    valid : (R, N) bool, samples that count
    tau : (R, K) float, s, starting delays
    period : float, s, T; table : :func:`positioning.model.pulse.pulse_table`
    rounds : int, Gauss-Newton rounds on the delays (each step clipped to :data:`STEP_T`
        periods), the amplitudes solved jointly by least squares at every round

    Returns
    -------
    tau : (R, K) float, s; amp : (R, K) complex, 1/s (the pulses' peak values); energy : (R,)
    float, ``sum |s - model|^2`` over the valid samples
    """
    w = valid.astype(float)
    tk, a_re, a_im, energy = _fit_kernel(
        np.ascontiguousarray(s.real * w), np.ascontiguousarray(s.imag * w),
        np.ascontiguousarray(t, dtype=float), w, np.ascontiguousarray(tau, dtype=float),
        int(rounds), float(period), TABLE_PER_T / period, table[0], table[1],
        STEP_T * period, _RIDGE)  # fmt: skip
    return tk, a_re + 1j * a_im, energy


def fit_pulses_numpy(
    s: np.ndarray,
    t: np.ndarray,
    valid: np.ndarray,
    tau: np.ndarray,
    period: float,
    table: tuple[np.ndarray, np.ndarray],
    rounds: int = ROUNDS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`fit_pulses` in numpy array passes, with its parameters and returns: the
    reference its compiled kernel is tested against (the same arithmetic but the order of the
    sums)."""
    w = valid.astype(float)
    sr, si = s.real * w, s.imag * w
    t = np.ascontiguousarray(t, dtype=float)
    value, slope_table = table
    scale = TABLE_PER_T / period
    for it in range(rounds + 1):
        # component-major (K, R, N): every product and sum runs over contiguous rows
        h, slope = _weighted_pulses(t, tau, w, scale, value, slope_table)
        hh = _ridge(_cross(h, h, symmetric=True))
        br = np.einsum("krn,rn->rk", h, sr)
        bi = np.einsum("krn,rn->rk", h, si)
        amp = _solve(hh, br + 1j * bi, ridged=True)
        er = sr - np.einsum("krn,rk->rn", h, amp.real)
        ei = si - np.einsum("krn,rk->rn", h, amp.imag)
        if it == rounds:
            break
        # Gauss-Newton on the delays with the amplitudes projected out (variable projection,
        # Kaufman's step): J_k = -a_k s'_k, s'_k the slope less its projection on the pulses,
        # J^H J = Re(conj(a_k) a_j) s'_k . s'_j, J^H e = -Re(conj(a_k) s_k . e) (e is orthogonal
        # to the pulses already)
        hs = _cross(h, slope)  # [r, j, k] = h_j . s_k
        ss = _cross(slope, slope, symmetric=True) - np.swapaxes(hs, 1, 2) @ _solve_matrix(hh, hs)
        jj = ss * np.real(np.conj(amp)[:, :, None] * amp[:, None, :])
        je = -(amp.real * np.einsum("krn,rn->rk", slope, er)
               + amp.imag * np.einsum("krn,rn->rk", slope, ei))  # fmt: skip
        step = _solve(jj, je)
        tau = tau + np.clip(step, -STEP_T * period, STEP_T * period)
    return tau, amp, np.sum(er**2 + ei**2, axis=1)


def delay_error(
    t: np.ndarray,
    valid: np.ndarray,
    tau: np.ndarray,
    amp: np.ndarray,
    energy: np.ndarray,
    period: float,
    table: tuple[np.ndarray, np.ndarray],
    kappa_n: float,
) -> np.ndarray:
    """(R, K) float, s: standard errors of fitted delays from the fit's own residual (nonlinear
    least squares, ``s^2 (J^T J)^-1`` over the real parameters ``Re a_k, Im a_k, tau_k``; ``s^2``
    the residual's power per degree of freedom times ``kappa_n``, the samples' correlation).
    Noise alone makes it the delays' Cramer-Rao scale; a model that does not explain the lobe
    (more paths than pulses) makes it large where the delay is not determined."""
    k = tau.shape[1]
    w = valid.astype(float)
    h, slope = _pulse_and_slope(t[:, :, None] - tau[:, None, :], period, table)
    h *= w[:, :, None]
    d = -slope * w[:, :, None] * amp[:, None, :]
    jc = np.concatenate([h, 1j * h, d], axis=2)  # (R, N, 3K)
    jr = np.concatenate([jc.real, jc.imag], axis=1)
    inv = np.linalg.inv(_ridge(np.swapaxes(jr, 1, 2) @ jr))
    s2 = kappa_n * energy / np.maximum(valid.sum(axis=1) - 1.5 * k, 1.0)  # complex samples
    var = np.einsum("rkk->rk", inv)[:, 2 * k :] * (0.5 * s2[:, None])
    return np.sqrt(np.maximum(var, 0.0))


@dataclass(frozen=True)
class LobeFit:
    """What :func:`refine_lobe` fitted to each row (``(M,)`` or ``(M, 2)`` arrays).

    Attributes
    ----------
    one_pulse : bool, the one-pulse fit explains the lobe (no two-pulse fit was needed)
    tau : (M, 2) float, s, the two-pulse fit's delays, earlier first (NaN: not fitted)
    amp : (M, 2) complex, 1/s, their amplitudes
    delay_se : (M, 2) float, s, their standard errors (:func:`delay_error`)
    applied : bool, a fitted component replaced the lobe top (the two-pulse fit's earlier one,
        or ``moved``)
    moved : bool, a later fitted component replaced the lobe top: the best fit's first one, the
        lobe top not consistent with it (step 3), or the fit with a farther peak's (step 4)
    order : int, pulses of the best fit (1: one pulse explained the lobe; 2; 3)
    """

    one_pulse: np.ndarray
    tau: np.ndarray
    amp: np.ndarray
    delay_se: np.ndarray
    applied: np.ndarray
    moved: np.ndarray
    order: np.ndarray


def _fit_region(sig, n_samples, t0, dt, period, oversampling, table, toa, until, comp_tau, comp_amp,
                reach_t=REACH_T):
    """Samples of the fit (decimated, the cancelled lobes outside the region removed): ``s, t,
    valid`` (M, N) and the region's core end ``hi`` (M,)."""
    m, w = sig.shape
    hi = np.where(np.isfinite(until) & (until > toa) & (until - toa <= reach_t * period), until, toa)
    step = max(1, oversampling // FIT_PER_T)
    span = (hi - toa) + (LEAD_T + TAIL_T) * period
    n_fit = int(np.ceil(np.max(span) / (step * dt))) + 1
    start = np.rint((toa - LEAD_T * period - t0) / dt).astype(np.int64)
    idx = start[:, None] + step * np.arange(n_fit)[None, :]
    t = t0[:, None] + idx * dt
    valid = (idx >= 0) & (idx < np.asarray(n_samples)[:, None]) & (t <= (hi + TAIL_T * period)[:, None])
    idx = np.clip(idx, 0, w - 1)
    t = t0[:, None] + idx * dt
    s = np.take_along_axis(sig, idx, axis=1)
    near_lo, near_hi = toa - (LEAD_T + FAR_T) * period, hi + (TAIL_T + FAR_T) * period
    far = np.isfinite(comp_tau) & ((comp_tau < near_lo[:, None]) | (comp_tau > near_hi[:, None]))
    for k in range(comp_tau.shape[1]):
        r = np.flatnonzero(far[:, k])
        s[r] -= comp_amp[r, k, None] * pulse_at(t[r] - comp_tau[r, k, None], period, table)
    return s, t, valid, hi


def _best_pair(s, t, valid, toa, hi, tau1, period, table):
    """The two-pulse fit of least residual from the starting pairs of :data:`STARTS_T` around
    the one-pulse fit's delay ``tau1`` (M,), of :data:`PEAK_STARTS_T` around the strongest peak
    ``hi`` and the lobe top with it: ``tau, amp, energy``. All starts of all rows are one batched
    fit of :data:`SCOUT_ROUNDS` rounds; the best of each row goes on to :data:`ROUNDS`."""
    m = s.shape[0]
    off, off_hi = period * np.array(STARTS_T), period * np.array(PEAK_STARTS_T)  # (S, 2)
    starts = np.concatenate([tau1[:, None, None] + off[None], hi[:, None, None] + off_hi[None],
                             np.column_stack([toa, hi])[:, None, :]], axis=1)  # fmt: skip
    n_s = starts.shape[1]
    rep = np.repeat(np.arange(m), n_s)
    # every start a few rounds, then the best of each row to convergence
    tk, ak, ek = fit_pulses(s[rep], t[rep], valid[rep], starts.reshape(-1, 2), period, table,
                            SCOUT_ROUNDS)  # fmt: skip
    ek = np.where(np.all(np.isfinite(tk), axis=1), ek, np.inf).reshape(m, n_s)
    best = np.argmin(ek, axis=1)
    tk, ak, ek = fit_pulses(s, t, valid, tk[np.arange(m) * n_s + best], period, table,
                            ROUNDS - SCOUT_ROUNDS)  # fmt: skip
    return tk, ak, ek


def _sorted_fit(t, valid, tk, ak, ek, period, table, kappa_n):
    """A fit's components in order of delay with their standard errors (:func:`delay_error`;
    inf where the fit failed): ``tau, amp, se`` (R, K)."""
    ok = np.all(np.isfinite(tk), axis=1)
    se = np.full(tk.shape, np.inf)
    se[ok] = delay_error(t[ok], valid[ok], tk[ok], ak[ok], ek[ok], period, table, kappa_n)
    order = np.argsort(np.where(ok[:, None], tk, 0.0), axis=1)
    return (np.take_along_axis(tk, order, axis=1), np.take_along_axis(ak, order, axis=1),
            np.take_along_axis(se, order, axis=1))  # fmt: skip


def _determined(tau, amp, se, gamma, rho, period):
    """(R,) bool: the earliest of sorted components ``tau, amp, se (R, K)`` is a path the fit
    determines (module docstring: the first two above the CFAR threshold ``gamma (R,)`` and within
    ``rho`` of the strongest, apart, the earlier's delay to :data:`SE_MAX_T`, not much weaker)."""
    mag = np.abs(amp)
    two = mag[:, :2]
    return (
        np.all(np.isfinite(se[:, :2]), axis=1)
        & np.all(two >= gamma[:, None], axis=1)
        & np.all(two >= rho * mag.max(axis=1, keepdims=True), axis=1)
        & (tau[:, 1] - tau[:, 0] >= MIN_SEPARATION_T * period)
        & (se[:, 0] <= SE_MAX_T * period)
        & (mag[:, 0] >= EARLY_RATIO * mag[:, 1])
    )


def _explained(energy, valid, k, sigma2, alpha, kappa_n):
    """(R,) bool: ``k`` pulses leave no more than noise could (the residual test of the module
    docstring: ``E_k < sigma_hat^2 (N - 1.5 k + alpha kappa_n)``)."""
    dof = np.maximum(valid.sum(axis=1) - 1.5 * k, 1.0)
    return energy < sigma2 * (dof + alpha * kappa_n)


def _add_pulse(s, t, valid, tk, ak, period, table):
    """Fit of ``K + 1`` pulses from the ``K`` of ``tk, ak`` and one more at the largest sample of
    their residual (greedy order increase, as CLEAN's): ``tau, amp, energy``."""
    model = np.einsum("rkn,rk->rn", pulse_at(t[:, None, :] - tk[:, :, None], period, table), ak)
    res = np.where(valid, np.abs(s - model), -1.0)
    new = np.take_along_axis(t, np.argmax(res, axis=1)[:, None], axis=1)
    return fit_pulses(s, t, valid, np.concatenate([tk, new], axis=1), period, table)


def _best_model(s, t, valid, tk, ak, ek, open_, sigma2, alpha, kappa_n, period, table):
    """The fit that explains rows best: the two-pulse fit ``tk, ak, ek`` or, where that leaves
    more than noise and the row is ``open_`` (its earlier component not accepted), one pulse more
    at a time (:func:`_add_pulse`, up to :data:`MAX_ORDER`) while it leaves less. Returns ``order`` (R,) int, the first component's
    delay, standard error and the fitted profile's magnitude there (R,) float, and ``adequate``
    (R,) bool: the fit explains the lobe into the noise (:func:`_explained`) or its components
    are resolved (at least :data:`MIN_SEPARATION_T` apart: a closer pair is one pulse and its
    derivative, its delays set by the model's conditioning, not by the samples)."""
    tau, amp, se = _sorted_fit(t, valid, tk, ak, ek, period, table, kappa_n)
    order = np.full(tk.shape[0], 2)
    explained = _explained(ek, valid, 2, sigma2, alpha, kappa_n)
    resolved = tau[:, 1] - tau[:, 0] >= MIN_SEPARATION_T * period
    first, first_se = tau[:, 0].copy(), se[:, 0].copy()
    first_peak = np.abs(np.einsum("rk,rk->r", amp, pulse_at(first[:, None] - tau, period, table)))
    q = np.flatnonzero(open_ & ~explained)
    tq, aq, eq = tk[q], ak[q], ek[q]
    for k in range(3, MAX_ORDER + 1):
        if not q.size:
            break
        t3, a3, e3 = _add_pulse(s[q], t[q], valid[q], tq, aq, period, table)
        tau3, amp3, se3 = _sorted_fit(t[q], valid[q], t3, a3, e3, period, table, kappa_n)
        better = np.isfinite(se3[:, 0]) & (e3 < eq)
        q, tau3, amp3, se3, e3 = q[better], tau3[better], amp3[better], se3[better], e3[better]
        tq, aq, eq = t3[better], a3[better], e3
        order[q] = k
        first[q], first_se[q] = tau3[:, 0], se3[:, 0]
        lag = first[q, None] - tau3
        first_peak[q] = np.abs(np.einsum("rk,rk->r", amp3, pulse_at(lag, period, table)))
        explained[q] = _explained(e3, valid[q], k, sigma2[q], alpha, kappa_n)
        resolved[q] = np.all(np.diff(tau3, axis=1) >= MIN_SEPARATION_T * period, axis=1)
        q, tq, aq, eq = q[~explained[q]], tq[~explained[q]], aq[~explained[q]], eq[~explained[q]]
    return order, first, first_se, first_peak, explained | resolved


def refine_lobe(
    sig: np.ndarray,
    n_samples: np.ndarray,
    t0: np.ndarray,
    dt: float,
    period: float,
    oversampling: int,
    table: tuple[np.ndarray, np.ndarray],
    toa: np.ndarray,
    until: np.ndarray,
    comp_tau: np.ndarray,
    comp_amp: np.ndarray,
    gamma: np.ndarray,
    sigma2: np.ndarray,
    alpha: float,
    rho: float,
    kappa_n: float,
) -> tuple[np.ndarray, np.ndarray, LobeFit]:
    """The earlier of two pulses fitted to the lobe at ``toa``, where the lobe is not one pulse
    and the fit determines it; else the first component of the best fit where the lobe top is
    inconsistent with it; a later result of the fit with a peak up to :data:`REACH_FAR_T` later
    (module docstring, steps 2-4).

    Parameters
    ----------
    sig : (M, W) complex, 1/s, the noisy delay profile on ``t0 + k dt`` (rows zero-padded)
    n_samples : (M,) int; t0 : (M,) float, s; dt, period : float, s
    oversampling : int, samples per period of ``sig``
    table : the pulse table (:func:`positioning.model.pulse.pulse_table`)
    toa : (M,) float, s, the reported lobe top of each row
    until : (M,) float, s, the strongest peak's time (the fit covers it where it is at most
        :data:`REACH_T` periods later; NaN: the lobe alone)
    comp_tau, comp_amp : (M, K) the cancelled lobes (:func:`positioning.model.searchback.clean`;
        NaN / 0: none), removed where outside the fit's region
    gamma : (M,) float, 1/s, CFAR threshold; sigma2 : (M,) float, the noise power estimate
    alpha : float, CFAR power factor; rho : float, relative threshold (amplitude ratio)
    kappa_n : float, :func:`noise_gain`

    Returns
    -------
    toa : (M,) float, s, the earlier component's delay where the refinement applies, else the
    input; peak : (M,) float, 1/s, that component's amplitude (a moved lobe top: the fitted
    profile's magnitude there; NaN where unchanged); LobeFit
    """
    until = np.asarray(until, dtype=float)
    args = (dt, period, oversampling, table)
    out, peak, fit = _refine(sig, n_samples, t0, *args, toa, until, comp_tau, comp_amp, gamma, sigma2,
                             alpha, rho, kappa_n, REACH_T)  # fmt: skip
    # a lobe up to REACH_FAR_T before the strongest peak may be that peak's sidelobe (a peak of
    # paths merged in anti-phase has higher sidelobes than one pulse): where the lobe alone gave
    # nothing, its top is tested against the fit of the lobe with the peak (step 3 only)
    lead = until - np.asarray(toa, dtype=float)
    far = np.flatnonzero((~fit.applied | fit.moved) & (lead > REACH_T * period)
                         & (lead <= REACH_FAR_T * period))  # fmt: skip
    if far.size:
        o2, p2, f2 = _refine(sig[far], n_samples[far], t0[far], *args, np.asarray(toa, float)[far],
                             until[far], comp_tau[far], comp_amp[far], gamma[far], sigma2[far],
                             alpha, rho, kappa_n, REACH_FAR_T)  # fmt: skip
        later = f2.applied & (o2 > out[far])
        r = far[later]
        out[r], peak[r] = o2[later], p2[later]
        fit.applied[r] = fit.moved[r] = True
        fit.order[r] = f2.order[later]
    return out, peak, fit


def _refine(sig, n_samples, t0, dt, period, oversampling, table, toa, until, comp_tau, comp_amp,
            gamma, sigma2, alpha, rho, kappa_n, reach_t):
    """:func:`refine_lobe` with the fit's reach ``reach_t`` (periods)."""
    m = sig.shape[0]
    toa = np.asarray(toa, dtype=float)
    out, peak = toa.copy(), np.full(m, np.nan)
    tau2, amp2, se2 = np.full((m, 2), np.nan), np.zeros((m, 2), complex), np.full((m, 2), np.nan)
    one = np.ones(m, dtype=bool)
    applied, moved = np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)
    order = np.ones(m, dtype=np.int64)
    if m:
        s, t, valid, hi = _fit_region(sig, n_samples, t0, dt, period, oversampling, table, toa,
                                      np.asarray(until, float), comp_tau, comp_amp, reach_t)  # fmt: skip
        tau1, _, e1 = fit_pulses(s, t, valid, toa[:, None].copy(), period, table)
        one = _explained(e1, valid, 1, sigma2, alpha, kappa_n)
        r = np.flatnonzero(~one)
        if r.size:
            tk, ak, ek = _best_pair(s[r], t[r], valid[r], toa[r], hi[r], tau1[r, 0], period, table)
            tau2[r], amp2[r], se2[r] = _sorted_fit(t[r], valid[r], tk, ak, ek, period, table, kappa_n)
            applied[r] = _determined(tau2[r], amp2[r], se2[r], gamma[r], rho, period)
            # the lobe top where the fit that explains the lobe best has no path near it
            order[r], first, first_se, first_peak, adequate = _best_model(
                s[r], t[r], valid[r], tk, ak, ek, ~applied[r], sigma2[r], alpha, kappa_n, period,
                table)  # fmt: skip
            lead = first - toa[r]
            moved[r] = (~applied[r] & adequate & (lead > CONSISTENT_SE * first_se)
                        & (lead > LEAD_MIN_T * period))  # fmt: skip
            out[r[moved[r]]] = first[moved[r]]
            peak[r[moved[r]]] = first_peak[moved[r]]
        out[applied] = tau2[applied, 0]
        peak[applied] = np.abs(amp2[applied, 0])
        applied |= moved
    return out, peak, LobeFit(one, tau2, amp2, se2, applied, moved, order)
