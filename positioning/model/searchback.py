"""Sidelobe-aware search-back on a sampled delay profile: successive cancellation of the strongest
lobes with the known pulse (CLEAN), then the earliest arrival that stands out of what is left.

Used by the tracer's ``search-back`` and ``super-res`` receivers
(:mod:`raytrace.emulation.receivers.search_back`, :mod:`raytrace.emulation.receivers.super_res`);
it lives beside the pulse in positioning's model floor so that the twin's receiver model
(:mod:`positioning.twin`) can run the same search (it does not yet). Pure numpy on windows of
samples, vectorised over rows (one row per link):

1. :func:`clean`: find the strongest sample of the residual, its lobe's top between samples
   (quartic, :func:`positioning.model.pulse.quartic_top`) and its complex value there, subtract
   that pulse (eq. 2) from the whole row, repeat for ``components`` lobes or until the residual
   is below ``floor``.
2. :func:`search_back`: before ``t_limit`` (the conventional first lobe's start less a guard),
   an arrival is declared where the residual, or a cancelled component, exceeds

       kappa sum_k |A_k| E(|t - tau_k| / T) + max(gamma + S(t), margin S(t))

   ``gamma`` the noise (CFAR) threshold, ``E`` the pulse's sidelobe envelope
   (:func:`positioning.model.pulse.envelope_table`; a component is tested against the stronger
   ones only), ``kappa`` the share of a cancelled lobe's sidelobes that the one-pulse model may
   miss (merged paths are not one pulse), and ``S(t)`` the sidelobe level of the lobes still in
   the residual, ``S(t)^2 = sum_l (|res(t_l)| E((t_l - t) / T))^2`` over its local maxima at
   least :data:`OWN_LOBE_T` later (their phases are unrelated). Noise and sidelobes add in
   amplitude: noise on a sidelobe crosses ``gamma + S`` at most at the CFAR's false-alarm
   rate; ``margin S`` covers merged lobes, whose sidelobes exceed the one-pulse envelope. The
   earliest such arrival is the first path; its ToA is the top of its lobe with the other
   components removed.
3. :func:`explained`: whether a lobe (the receiver's first lobe) is the cancelled lobes'
   sidelobe: not a component of its own, and what CLEAN leaves of it under that threshold.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from .pulse import QUARTIC, pulse_at, quartic_top

#: A residual lobe counts towards the sidelobe bound ``S(t)`` only from this many periods after t
#: (within it, the sample's own lobe).
OWN_LOBE_T = 0.75


def _value_at(y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Value at ``u`` of the quartic through the complex samples ``y (n, 5)`` at -2..2."""
    c = y @ QUARTIC.T
    return (((c[:, 4] * u + c[:, 3]) * u + c[:, 2]) * u + c[:, 1]) * u + c[:, 0]


def clean(
    sig: np.ndarray,
    n_samples: np.ndarray,
    t0: np.ndarray,
    dt: float,
    period: float,
    table: tuple[np.ndarray, np.ndarray],
    floor: np.ndarray,
    components: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Successive cancellation of the ``components`` strongest lobes of each row.

    Parameters
    ----------
    sig : (M, W) complex, 1/s, the delay profile on ``t0 + k dt`` (rows zero-padded)
    n_samples : (M,) int, samples of each row inside its window
    t0 : (M,) float, s; dt, period : float, s (sample spacing, pulse period T)
    table : the pulse table (:func:`positioning.model.pulse.pulse_table`)
    floor : (M,) float, 1/s, a lobe below it is left in the residual
    components : int, most lobes cancelled per row

    Returns
    -------
    tau : (M, components) float, s, cancelled lobes' times (NaN: none)
    amp : (M, components) complex, 1/s, their complex peak values (0: none)
    res : (M, W) complex, the residual
    """
    res = np.array(sig, dtype=complex, copy=True)
    m, w = res.shape
    tau = np.full((m, components), np.nan)
    amp = np.zeros((m, components), dtype=complex)
    if m == 0 or w < 5:
        return tau, amp, res
    idx = np.arange(w)
    valid = (idx[None, :] >= 2) & (idx[None, :] < np.asarray(n_samples)[:, None] - 2)
    rows = np.arange(m)
    five = np.arange(-2, 3)
    for k in range(components):
        mag = np.where(valid, np.abs(res), -1.0)
        i = np.argmax(mag, axis=1)
        live = mag[rows, i] >= floor
        if not live.any():
            break
        r, i = rows[live], i[live]
        y = res[r[:, None], i[:, None] + five[None, :]]
        u, _ = quartic_top(np.abs(y))
        a = _value_at(y, u)
        tk = t0[r] + (i + u) * dt
        lag = t0[r, None] + idx[None, :] * dt - tk[:, None]
        res[r] -= a[:, None] * pulse_at(lag, period, table)
        tau[r, k], amp[r, k] = tk, a
    return tau, amp, res


def lobe_bound(
    mag: np.ndarray, n_samples: np.ndarray, dt: float, period: float, env: tuple
) -> np.ndarray:
    """(M, W) sidelobe level ``S(t) = sqrt(sum_l (mag_l E((t_l - t) / T))^2)`` of the local
    maxima ``l`` of ``mag (M, W)`` at least :data:`OWN_LOBE_T` periods later than ``t`` (their
    sidelobes add with unrelated phases: in power; one correlation with the squared envelope per
    row). ``env``: :func:`positioning.model.pulse.envelope_table`."""
    m, w = mag.shape
    if m == 0 or w < 3:
        return np.zeros((m, w))
    inside = np.arange(w)[None, :] < np.asarray(n_samples)[:, None]
    peaks = np.zeros((m, w))
    top = (mag[:, 1:-1] >= mag[:, :-2]) & (mag[:, 1:-1] > mag[:, 2:]) & inside[:, 1:-1]
    peaks[:, 1:-1] = np.where(top, mag[:, 1:-1] ** 2, 0.0)
    x, e = env
    n_k = min(w, int(np.ceil(x[-1] * period / dt)) + 1)
    j = np.arange(n_k)
    kernel = np.where(j * dt >= OWN_LOBE_T * period, np.interp(j * dt / period, x, e, right=0.0), 0.0)
    kernel = kernel**2
    # S[t] = sum_j peaks[t + j] kernel[j]: a correlation, i.e. convolution with the reversed kernel
    full = scipy.signal.fftconvolve(peaks, kernel[::-1][None, :], mode="full", axes=1)
    return np.sqrt(np.maximum(full[:, n_k - 1 : n_k - 1 + w], 0.0))


def _over_sidelobes(gamma: np.ndarray, s: np.ndarray, margin: float) -> np.ndarray:
    """Level a sample must reach over the residual's sidelobe bound ``s``: ``max(gamma + s,
    margin s)``. A sidelobe of at most ``s`` plus noise exceeds ``gamma + s`` no more often than
    noise alone exceeds ``gamma`` (the CFAR's design); a merged lobe's sidelobes exceed the
    one-pulse bound, by up to ``margin`` (model error, in proportion to the lobe: the hall's
    C-band merged clusters reach 1.4 times it). Adding the two (``gamma + margin s``, before
    issue 38's third round) raised the threshold of a weak lobe among weak lobes, where ``s`` is
    below the noise threshold, by twice their sidelobes."""
    return np.maximum(gamma + s, margin * s)


def _envelope(lag_t: np.ndarray, env: tuple) -> np.ndarray:
    x, e = env
    return np.interp(np.abs(lag_t), x, e, right=0.0)


def explained(
    sig: np.ndarray,
    res: np.ndarray,
    n_samples: np.ndarray,
    t0: np.ndarray,
    dt: float,
    period: float,
    tau: np.ndarray,
    amp: np.ndarray,
    gamma: np.ndarray,
    t_at: np.ndarray,
    kappa: float,
    margin: float,
    env: tuple,
) -> np.ndarray:
    """Whether the lobe at ``t_at`` is the cancelled lobes' sidelobe: no cancelled component within
    :data:`OWN_LOBE_T` periods of it (it was not cancelled as a lobe of its own), the lobe no
    more than ``margin`` times their summed sidelobe envelope there, and the residual there under :func:`search_back`'s threshold ``kappa sum_k |A_k| E + max(gamma + S, margin S)``
    (what CLEAN's pulses leave of it is no more than their model error, the residual's sidelobes
    and noise: it was made by the later lobes' sidelobes, e.g. several comparable merged lobes
    whose sidelobes add up to -10 dB of the strongest, 1.3-1.7 T before it).

    Parameters
    ----------
    sig : (M, W) complex, 1/s, the delay profile :func:`clean` took
    res, n_samples, t0, dt, period, tau, amp, gamma, kappa, margin, env : as :func:`search_back`
    t_at : (M,) float, s, the lobe's top (NaN: none)

    Returns
    -------
    (M,) bool, True where the lobe is explained by the cancelled lobes
    """
    m, w = res.shape
    if m == 0 or w < 5:
        return np.zeros(m, dtype=bool)
    n_samples = np.asarray(n_samples)
    rows = np.arange(m)
    ok = np.isfinite(t_at)
    at = np.where(ok, t_at, t0)
    i = np.clip(np.rint((at - t0) / dt).astype(np.int64), 0, np.maximum(n_samples - 1, 0))
    mag = np.abs(res)
    have = np.isfinite(tau)
    lag = np.where(have, (tau - at[:, None]) / period, np.inf)
    own = np.any(np.abs(lag) < OWN_LOBE_T, axis=1)
    g = np.sum(np.where(have, np.abs(amp) * _envelope(lag, env), 0.0), axis=1)
    # S at the one sample: the residual's local maxima at least OWN_LOBE_T periods later
    idx = np.arange(w)[None, :]
    top = np.zeros((m, w), dtype=bool)
    top[:, 1:-1] = (mag[:, 1:-1] >= mag[:, :-2]) & (mag[:, 1:-1] > mag[:, 2:])
    top &= idx < n_samples[:, None]
    lag_l = (idx - i[:, None]) * dt / period
    s = np.sqrt(np.sum(np.where(top & (lag_l >= OWN_LOBE_T), (mag * _envelope(lag_l, env)) ** 2, 0.0),
                       axis=1))  # fmt: skip
    thr = kappa * g + _over_sidelobes(gamma, s, margin)
    # and their sidelobes can make it: a lobe over ``margin`` times their summed envelope (the
    # bound merged lobes may exceed) is a path CLEAN's pulses overlapped, not their sidelobe
    reach = np.abs(sig[rows, i]) <= margin * g
    return ok & ~own & reach & (mag[rows, i] < thr)


def _first_lobe_top(mag: np.ndarray, ok: np.ndarray, n_samples: np.ndarray):
    """First sample where ``ok (M, W)`` and the top of its lobe in ``mag``: (has, top, u, peak)."""
    m, w = mag.shape
    idx = np.arange(w)[None, :]
    has = ok.any(axis=1)
    cross = np.argmax(ok, axis=1)
    falling = np.zeros_like(ok)
    falling[:, :-1] = mag[:, 1:] < mag[:, :-1]
    inside = idx < n_samples[:, None] - 2
    top = np.argmax(falling & (idx >= cross[:, None]) & inside, axis=1)
    has &= (top >= 2) & (top <= n_samples - 3)
    k5 = np.clip(top[:, None] + np.arange(-2, 3)[None, :], 0, max(w - 1, 0))
    u, peak = quartic_top(np.take_along_axis(mag, k5, axis=1))
    return has, top, u, peak


def search_back(
    res: np.ndarray,
    n_samples: np.ndarray,
    t0: np.ndarray,
    dt: float,
    period: float,
    tau: np.ndarray,
    amp: np.ndarray,
    gamma: np.ndarray,
    t_limit: np.ndarray,
    kappa: float,
    margin: float,
    env: tuple,
    table: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """The earliest arrival before ``t_limit`` that stands out of the cancelled lobes' sidelobes,
    the residual's and the noise (module docstring).

    Parameters
    ----------
    res, n_samples, t0, dt, period : the residual rows of :func:`clean` and their sampling
    tau, amp : (M, K) the cancelled lobes (:func:`clean`)
    gamma : (M,) float, 1/s, noise threshold (CFAR)
    t_limit : (M,) float, s, search only before this time
    kappa : float, weight of the cancelled lobes' sidelobes
    margin : float, a sample must reach this many times the residual's sidelobe bound
        (:func:`_over_sidelobes`)
    env : :func:`positioning.model.pulse.envelope_table`; table : the pulse table

    Returns
    -------
    toa : (M,) float, s, top of the earliest detected lobe; NaN where nothing stands out
    peak : (M,) float, 1/s, its magnitude there
    """
    m, w = res.shape
    toa = np.full(m, np.nan)
    peak = np.full(m, np.nan)
    if m == 0 or w < 5:
        return toa, peak
    n_samples = np.asarray(n_samples)
    mag_a = np.abs(amp)
    have = np.isfinite(tau)
    tau0 = np.where(have, tau, 0.0)
    t = t0[:, None] + np.arange(w)[None, :] * dt
    mag = np.abs(res)
    s_res = lobe_bound(mag, n_samples, dt, period, env)
    g = np.zeros((m, w))
    for k in range(tau.shape[1]):  # the cancelled lobes' sidelobe envelope (K is small)
        g += mag_a[:, k, None] * _envelope((t - tau0[:, k, None]) / period, env)
    thr = kappa * g + _over_sidelobes(gamma[:, None], s_res, margin)
    inside = np.arange(w)[None, :] < n_samples[:, None]
    ok = (mag >= thr) & (t < t_limit[:, None]) & inside
    ok[:, :2] = False
    has, top, u, pk = _first_lobe_top(mag, ok, n_samples)
    toa[has] = t0[has] + (top[has] + u[has]) * dt
    peak[has] = pk[has]
    # cancelled components: each against the stronger ones, the residual's bound and the noise
    stronger = mag_a[:, None, :] > mag_a[:, :, None]  # [m, k, j]: j stronger than k
    lag = (tau0[:, :, None] - tau0[:, None, :]) / period
    guard = np.sum(np.where(stronger & have[:, None, :], mag_a[:, None, :] * _envelope(lag, env), 0.0),
                   axis=2)  # fmt: skip
    near = np.clip(np.rint((tau0 - t0[:, None]) / dt).astype(np.int64), 0, w - 1)
    s_at = np.take_along_axis(s_res, near, axis=1)
    over = kappa * guard + _over_sidelobes(gamma[:, None], s_at, margin)
    acc = have & (mag_a >= over) & (tau0 < t_limit[:, None])
    t_comp = np.where(acc, tau0, np.inf)
    k_first = np.argmin(t_comp, axis=1)
    earlier = np.isfinite(t_comp[np.arange(m), k_first]) & ~(toa <= t_comp[np.arange(m), k_first])
    r = np.flatnonzero(earlier)
    if r.size:
        # the component's own lobe, the other components removed: its top between samples
        k = k_first[r]
        tk, ak = tau0[r, k], amp[r, k]
        i0 = np.clip(np.rint((tk - t0[r]) / dt).astype(np.int64), 2, np.maximum(n_samples[r] - 3, 2))
        i5 = i0[:, None] + np.arange(-2, 3)[None, :]
        iso = res[r[:, None], i5] + ak[:, None] * pulse_at(t[r[:, None], i5] - tk[:, None], period,
                                                           table)  # fmt: skip
        u, pk = quartic_top(np.abs(iso))
        toa[r] = t0[r] + (i0 + u) * dt
        peak[r] = pk
    return toa, peak
