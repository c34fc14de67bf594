"""The first-lobe receiver: the ToA a 5G positioning receiver measures, evaluated in a window.

What the receiver does (eqs. 1-2 of the paper; details, defaults and their reasons in
``docs/channel.md``):

1. **Correlator output.** ``r(t) = sum_j A_j h(t - tau_j) + n(t)``: every path of the link
   convolved with the raised cosine of eq. 2, plus correlator noise (complex Gaussian with the
   pulse's spectrum, per-sample std ``sigma_n`` from the link budget, see
   :meth:`raytrace.emulation.channel.LinkBudget.correlator_noise_std`).
2. **Noise threshold (CA-CFAR).** The receiver does not know ``sigma_n``: it averages ``|r|^2``
   over ``M`` noise-only reference cells, ``sigma_hat^2 = sigma_n^2 G / M`` with
   ``G ~ Gamma(M, 1)``, and compares ``|r|^2`` with ``alpha sigma_hat^2``,
   ``alpha = M (P_fa^(-1/M) - 1)``, which keeps the false-alarm probability per cell at
   ``P_fa`` exactly (cell-averaging CFAR with a square-law detector, Richards, *Fundamentals of
   Radar Signal Processing*, 2nd ed., eq. 7.33). ``M -> inf`` is the known-noise threshold
   ``-ln P_fa``.
3. **Relative threshold.** ``|r| >= rho * max_t |r(t)|`` (``rho`` = ``relative_threshold_db``,
   default -12 dB, above the pulse's first sidelobe at -14.3 dB), so that the strongest path's
   own precursor ringing is not taken for an earlier path.
4. **First lobe.** The first sample above both thresholds marks the first detected path; the
   ToA is the top of the lobe that holds it, refined between samples by a quartic through the
   five samples around the top (bias below 1e-5 T at 8 samples per T).

Paths that overlap the first one within a pulse width move that lobe's top: the bias the paper
adds to its emulated MPCs, smaller at wider bandwidths.

Speed: the response is evaluated only in a window from a few T before the earliest path that
could cross the threshold to shortly after the first path (or the strongest peak) that must
cross it, and only with the paths that reach into it above a negligible level. The noiseless part
depends on the paths alone (:func:`prepare_first_lobe`, once per snapshot: once per dataset for
a static scene); each epoch adds its own noise and thresholds (:func:`measure_first_lobe`).
Link-epochs whose lobe does not fit the window (rare) are measured again on the link's whole
response with fresh noise.

Observables besides the ToA, as a receiver has them: the SNR of the first lobe from its peak and
the noise estimate, the lobe's peak relative to the strongest peak (``peak_ratio_db``) and its
half-amplitude width relative to an isolated pulse's (``lobe_width``); NLoS and overlapping paths
show as weak or broadened first lobes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from positioning.model.pulse import (
    TABLE_PER_T,
    envelope_table,
    precursor_extent_t,
    pulse_at,
    pulse_table,
    quartic_top,
)

from ...core.constants import linear_power_to_db
from ...core.errors import HallrayError
from ...core.jit import carray, kernel
from ..bands import Band
from ..channel.budget import LinkBudget
from ..channel.cir import DiscreteCIR
from ..channel.pulse import PulseShape, raised_cosine
from ..channel.response import concat_ranges, correlator_noise

#: Paths are dropped from the window evaluation when their peak is this far below the noise std
#: (dB): their whole contribution stays under 1 % of the noise.
NEGLIGIBLE_DB = -40.0
#: Strongest paths per link around which the strongest peak of the response is searched.
TOP_PATHS = 4
#: A path whose own peak is this many times the threshold crosses it (the window ends after it).
SURE_CROSSING = 2.0
#: A path whose own peak is below this fraction of the threshold cannot cross it alone (the
#: window starts at the earliest path above it).
MIN_CROSSING = 0.1
#: Window margin after the lobe that must contain the detection, in pulse periods T.
POST_T = 2
#: Samples beyond the sampled noise window kept free so that the circular FFT noise has the
#: stationary correlation inside the window (correlation at 8 T: below -40 dB).
NOISE_GUARD_T = 8


@dataclass(frozen=True)
class FirstLobeSettings:
    """Settings of the first-lobe receiver.

    Parameters
    ----------
    relative_threshold_db : float, dB
        Detection threshold relative to the strongest peak of ``|r|`` (default -12 dB: 2.3 dB
        above the first sidelobe of the beta = 0.25 pulse, -14.3 dB, so a strong path's own
        precursor is not detected as an earlier path; a first path more than 12 dB below the
        strongest is missed, as in receivers with this rule).
    cfar_cells : int or None
        Noise-only reference cells of the cell-averaging CFAR (default 64, T apart: 0.8 us at
        100 MHz, a small part of a PRS search window). None: the receiver knows the noise power.
    """

    relative_threshold_db: float = -12.0
    cfar_cells: int | None = 64

    def __post_init__(self) -> None:
        r = self.relative_threshold_db
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not (-60.0 <= r < 0.0):
            raise HallrayError(
                f"first-lobe relative_threshold_db must be a number in [-60, 0) dB, got {r!r}"
            )
        m = self.cfar_cells
        if m is not None and (isinstance(m, bool) or not isinstance(m, int) or m < 1):
            raise HallrayError(f"first-lobe cfar_cells must be an integer >= 1 or None, got {m!r}")

    @property
    def rho(self) -> float:
        """Relative threshold as an amplitude ratio."""
        return float(10.0 ** (self.relative_threshold_db / 20.0))


def cfar_factor(false_alarm_probability: float, cells: int | None) -> float:
    """Power threshold factor ``alpha`` of a cell-averaging CFAR, ``|r|^2 >= alpha sigma_hat^2``.

    ``alpha = M (P_fa^(-1/M) - 1)`` for ``M`` reference cells (Richards eq. 7.33, exponential
    noise power); ``-ln P_fa`` for ``M = None`` (noise power known), the limit ``M -> inf``.
    """
    pfa = float(false_alarm_probability)
    if cells is None:
        return -math.log(pfa)
    return float(cells * math.expm1(-math.log(pfa) / cells))


@dataclass(frozen=True)
class WindowOptions:
    """How a plan's windows and noise differ from the first-lobe receiver's own (the receivers on
    the PRS channel frequency response reuse its windows, :mod:`.search_back`).

    Attributes
    ----------
    noise_std : float or None, 1/s, per-sample noise std of the delay profile (None: the
        correlator noise of the link budget, :meth:`LinkBudget.correlator_noise_std`)
    noise_power : int, the noise spectrum is the pulse's to this power (1: correlator output;
        2: a white CFR estimate windowed by the pulse's spectrum)
    window_rho : float or None, relative level (amplitude ratio to the strongest peak) down to
        which a path may start the window (None: the detection threshold ``rho``)
    to_peak : bool, every window runs to :data:`POST_T` periods after the strongest peak (the
        strongest lobes are in it), not just after the first path that must cross
    """

    noise_std: float | None = None
    noise_power: int = 1
    window_rho: float | None = None
    to_peak: bool = False


@lru_cache(maxsize=32)
def isolated_half_width_t(roll_off: float) -> float:
    """Half-amplitude full width of the raised cosine, in T (1.22 T for beta = 0.25)."""
    half = brentq(lambda t: raised_cosine(t, 1.0, roll_off) - 0.5, 0.0, 1.0, xtol=1e-14)
    return 2.0 * float(half)


def _response(
    delay: np.ndarray,
    gain: np.ndarray,
    t: np.ndarray,
    half_width: float,
    period: float,
    table: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """``s(t) = sum_j A_j h(t - tau_j)`` of one link at times ``t`` (n,), complex: the paths
    within ``half_width`` of ``[t.min(), t.max()]`` (``delay`` sorted), as one matrix product."""
    a = np.searchsorted(delay, t.min() - half_width, side="left")
    b = np.searchsorted(delay, t.max() + half_width, side="right")
    if b <= a:
        return np.zeros(t.size, dtype=complex)
    # pulse_at(t[None, :] - delay[a:b, None], period, table) in one pass (the same bits)
    h = np.empty((b - a, t.size))
    value, step = table
    pulse_matrix_kernel(carray(t), carray(delay[a:b]), TABLE_PER_T / period, value, step, h)
    g = gain[a:b] / period
    ri = np.stack([g.real, g.imag]) @ h  # two real products, no complex copy of h
    return ri[0] + 1j * ri[1]


@kernel("void(f8[::1], f8[::1], f8, f8[::1], f8[::1], f8[:, ::1])")
def pulse_matrix_kernel(t, delay, scale, value, step, out):
    """``out[j, k] = T h(t[k] - delay[j])``: :func:`positioning.model.pulse.pulse_at` of the lag
    matrix (``scale = TABLE_PER_T / period``, ``value, step`` its table) with its operations in
    its order (abs, scale, clip to the table, linear interpolation), so its very bits, without
    the lag matrix and the six temporaries numpy makes of it."""
    top = float(value.size - 2)
    for j in range(delay.size):
        for k in range(t.size):
            u = abs(t[k] - delay[j]) * scale
            if u > top:
                u = top
            i = int(u)
            out[j, k] = (u - i) * step[i] + value[i]


def _key(cir: DiscreteCIR, link_of_path: np.ndarray, pad: float) -> tuple[np.ndarray, float, float]:
    """Sort key ``link * stride + (delay - base)``, increasing over the (link, delay)-sorted CIR,
    so one ``searchsorted`` finds the paths of any link in any delay interval."""
    if cir.delay_s.size == 0:
        return np.zeros(0), 0.0, 1.0
    base = float(cir.delay_s.min()) - pad
    stride = float(cir.delay_s.max()) - base + pad + 1e-9
    return link_of_path * stride + (cir.delay_s - base), base, stride


def _paths_near(
    key: np.ndarray, base: float, stride: float, link: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Index ranges ``[start, stop)`` of the paths of ``link`` with delay in ``[lo, hi]``."""
    k0 = link * stride - base
    return (
        np.searchsorted(key, k0 + lo, side="left"),
        np.searchsorted(key, k0 + hi, side="right"),
    )


@dataclass(frozen=True)
class LobePlan:
    """Noiseless part of the first-lobe receiver for one set of paths (one snapshot, one band).

    Attributes
    ----------
    n_links : int
    links : (M,) int64, links with at least one non-negligible path (the others are undetected)
    t0_s : (M,) float, seconds, time of window sample 0
    n_samples : (M,) int64, window samples of each row (rows are padded to a common length)
    signal : (M, W) complex, 1/s, ``sum_j A_j h(t - tau_j)`` on the window samples
    peak_signal : (M,) complex, 1/s, ``s`` at the strongest peak of the noiseless response
    peak_time_s : (M,) float, seconds, time of that peak
    dt_s, period_s : float, seconds, sample spacing and pulse period T
    noise_std : float, 1/s, correlator noise std ``sigma_n``
    alpha : float, CFAR power factor (:func:`cfar_factor`)
    rho : float, relative threshold (amplitude ratio)
    band : Band
    budget : LinkBudget
    pulse : PulseShape
    settings : FirstLobeSettings
    cir : DiscreteCIR, the non-negligible paths (for the fallback and the lobe's dominant path)
    key : tuple, sort key of ``cir`` (see ``_key``)
    options : WindowOptions, what differs from the first-lobe receiver's windows and noise
    """

    n_links: int
    links: np.ndarray
    t0_s: np.ndarray
    n_samples: np.ndarray
    signal: np.ndarray
    peak_signal: np.ndarray
    peak_time_s: np.ndarray
    dt_s: float
    period_s: float
    noise_std: float
    alpha: float
    rho: float
    band: Band
    budget: LinkBudget
    pulse: PulseShape
    settings: FirstLobeSettings
    cir: DiscreteCIR
    key: tuple[np.ndarray, float, float]
    options: WindowOptions = WindowOptions()

    @property
    def processing_gain(self) -> float:
        """Correlation gain ``t_s B`` (linear)."""
        return self.budget.processing_gain(self.band)


@dataclass(frozen=True)
class LobeMeasurement:
    """What the first-lobe receiver measures on every link (``(n_links,)`` arrays).

    Attributes
    ----------
    toa_s : float, seconds, top of the first detected lobe; NaN where nothing was detected
    detected : bool
    snr_db : float, dB, SNR of the first lobe before processing gain, from its peak and the noise
        estimate (``|r_peak|^2 / sigma_hat^2 / (t_s B)``); NaN where not detected
    peak_ratio_db : float, dB, first lobe's peak over the strongest peak (<= 0)
    lobe_width : float, half-amplitude width of the first lobe over an isolated pulse's
        (NaN where the lobe's half-amplitude points are not both in the window)
    lobe_path : int64, index into the caller's path arrays of the path that contributes most to
        the response at the measured ToA, -1 where not detected
    refits : int, link-epochs measured again on the whole response
    """

    toa_s: np.ndarray
    detected: np.ndarray
    snr_db: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    lobe_path: np.ndarray
    refits: int


def prepare_first_lobe(
    cir: DiscreteCIR,
    band: Band,
    budget: LinkBudget,
    pulse: PulseShape,
    settings: FirstLobeSettings,
    *,
    full: np.ndarray | None = None,
    only: np.ndarray | None = None,
    min_width: int = 0,
    options: WindowOptions | None = None,
) -> LobePlan:
    """Noiseless windows of the first-lobe receiver for every link of ``cir``.

    Parameters
    ----------
    cir : DiscreteCIR
    band, budget, pulse, settings : the receiver
    full : (n_links,) bool, optional
        Links whose window spans their whole response (the fallback), not just the first lobe.
    only : (n_links,) bool, optional
        Prepare these links alone (each link's window does not depend on the others).
    min_width : int, pad the signal rows to at least this many samples (the width of the plan
        of every link, so that the noise drawn per row is the same as with all links)
    options : WindowOptions, optional (default: the first-lobe receiver's own)
    """
    n_links = cir.n_links
    period = pulse.period_s(band)
    dt = period / pulse.oversampling
    half_width = pulse.span * period
    options = options or WindowOptions()
    noise_std = options.noise_std
    noise_std = budget.correlator_noise_std(band, pulse) if noise_std is None else noise_std
    alpha = cfar_factor(budget.false_alarm_probability, settings.cfar_cells)
    rho = settings.rho
    amp = np.abs(cir.gain) / period  # each path's own peak |A| / T
    link_of_path = np.repeat(np.arange(n_links), np.diff(cir.offsets))
    keep = amp >= noise_std * 10.0 ** (NEGLIGIBLE_DB / 20.0)
    counts = np.bincount(link_of_path[keep], minlength=n_links)
    links = np.flatnonzero((counts > 0) & (True if only is None else np.asarray(only, bool)))
    kept = DiscreteCIR(
        np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        cir.path_index[keep],
        cir.delay_s[keep],
        cir.gain[keep],
    )
    k_link = link_of_path[keep]
    k_amp = amp[keep]
    key_info = _key(kept, k_link, 2 * half_width)
    fixed = (dt, period, noise_std, alpha, rho, band, budget, pulse, settings, kept, key_info)
    m = links.size
    if m == 0:
        return LobePlan(n_links, links, np.zeros(0), links, np.zeros((0, 0), complex),
                        np.zeros(0, complex), np.zeros(0), *fixed, options)  # fmt: skip
    table = pulse_table(float(pulse.roll_off), int(pulse.span))
    reach = rho if options.window_rho is None else options.window_rho  # paths that open a window
    pre = precursor_extent_t(pulse.roll_off, reach, pulse.span) * period
    gamma_noise = noise_std * math.sqrt(alpha)
    whole = np.zeros(m, dtype=bool) if full is None else np.asarray(full, dtype=bool)[links]
    half = pulse.oversampling // 2
    around_top = np.arange(-half, half + 1) * dt  # +-T/2 on the grid
    around_next = np.arange(-1, 2) * dt
    t0 = np.empty(m)
    n_samples = np.empty(m, dtype=np.int64)
    peak_signal = np.empty(m, dtype=complex)
    t_peak = np.empty(m)
    rows: list[np.ndarray] = []
    # One link at a time: each is a few dense matrix products over its own paths (a few hundred
    # by a few dozen samples), faster than gathering every (path, sample) pair of all links.
    for r, lk in enumerate(links):
        lo, hi = kept.offsets[lk], kept.offsets[lk + 1]
        d, g, a = kept.delay_s[lo:hi], kept.gain[lo:hi], k_amp[lo:hi]
        # Strongest peak: on the T/8 grid within +-T/2 of the strongest path, and at the next
        # strongest paths and a sample either side (the grid maximum is within 0.05 dB).
        top = np.argsort(-a, kind="stable")[:TOP_PATHS]
        cand = np.concatenate([d[top[0]] + around_top, (d[top[1:], None] + around_next).ravel()])
        s_c = _response(d, g, cand, half_width, period, table)
        k = int(np.argmax(np.abs(s_c)))
        peak_signal[r], t_peak[r] = s_c[k], cand[k]
        # Window: from the earliest path that could cross the threshold to the first that must
        # (or the strongest peak), with the precursor margin before and POST_T after.
        gamma0 = max(gamma_noise, reach * abs(s_c[k]))
        can = np.flatnonzero(a >= MIN_CROSSING * gamma0)
        start = d[can[0]] if can.size else t_peak[r]  # no path can cross alone: a pile-up
        sure = np.flatnonzero(a >= SURE_CROSSING * gamma0)
        t_end = min(d[sure[0]] if sure.size else np.inf, t_peak[r]) + POST_T * period
        if options.to_peak:
            t_end = t_peak[r] + POST_T * period
        if whole[r]:
            start, t_end = d[0], d[-1] + half_width
        t0[r] = start - pre
        t_end = max(t_end, t0[r] + (POST_T + 2) * period)
        n_samples[r] = max(int(np.floor((t_end - t0[r]) / dt)) + 1, 5)
        t = t0[r] + np.arange(n_samples[r]) * dt
        rows.append(_response(d, g, t, half_width, period, table))
    signal = np.zeros((m, max(int(n_samples.max()), int(min_width))), dtype=complex)
    for r, row in enumerate(rows):
        signal[r, : row.size] = row
    return LobePlan(n_links, links, t0, n_samples, signal, peak_signal, t_peak, *fixed, options)


def _scan(
    amp: np.ndarray, n_samples: np.ndarray, thr: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """First crossing of ``thr (M, W)`` and the top of its lobe in each row of ``amp (M, W)``.

    Returns ``top (M,)`` sample index, ``u (M,)`` sub-sample offset, ``peak (M,)`` amplitude,
    ``ok (M,)``: a crossing exists, is not the window's first sample, and its lobe top has
    two samples on each side inside the window, and ``cross (M,)``, the first crossing's index.
    """
    m, w = amp.shape
    idx = np.arange(w)[None, :]
    inside = idx < n_samples[:, None]
    above = (amp >= thr) & inside
    has = above.any(axis=1)
    cross = np.argmax(above, axis=1)
    falling = np.zeros_like(above)
    falling[:, :-1] = amp[:, 1:] < amp[:, :-1]
    top = np.argmax(falling & (idx >= cross[:, None]) & inside, axis=1)
    ok = has & (cross > 0) & (top >= 2) & (top <= n_samples - 3)
    rows = np.arange(m)
    k5 = np.clip(top[:, None] + np.arange(-2, 3)[None, :], 0, w - 1)
    u, peak = quartic_top(amp[rows[:, None], k5])
    return top, u, peak, ok, cross


def _half_width(amp: np.ndarray, n_samples: np.ndarray, top: np.ndarray, peak: np.ndarray):
    """Half-amplitude full width of the lobe at ``top`` in samples (NaN if it leaves the window)."""
    m, w = amp.shape
    idx = np.arange(w)[None, :]
    half = 0.5 * peak[:, None]
    low = amp < half
    left_cand = low & (idx < top[:, None])
    right_cand = low & (idx > top[:, None]) & (idx < n_samples[:, None])
    has_l, has_r = left_cand.any(axis=1), right_cand.any(axis=1)
    kl = w - 1 - np.argmax(left_cand[:, ::-1], axis=1)  # last low sample before the top
    kr = np.argmax(right_cand, axis=1)  # first low sample after it
    rows = np.arange(m)
    kl1 = np.minimum(kl + 1, w - 1)
    kr0 = np.maximum(kr - 1, 0)
    ok = has_l & has_r
    out = np.full(m, np.nan)
    r = rows[ok]
    # linear interpolation of the half-amplitude crossings on either side of the top
    xl = kl[ok] + (half[ok, 0] - amp[r, kl[ok]]) / (amp[r, kl1[ok]] - amp[r, kl[ok]])
    xr = kr0[ok] + (amp[r, kr0[ok]] - half[ok, 0]) / (amp[r, kr0[ok]] - amp[r, kr[ok]])
    out[ok] = xr - xl
    return out


def lobe_path(plan: LobePlan, link: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Caller's index of the path that contributes most to ``|s|`` of ``link`` at ``t``."""
    out = np.full(link.size, -1, dtype=np.int64)
    if link.size == 0:
        return out
    cir, period = plan.cir, plan.period_s
    key, base, stride = plan.key
    start, stop = _paths_near(key, base, stride, link, t - period, t + period)
    idx = concat_ranges(start, stop - start)
    row = np.repeat(np.arange(link.size), stop - start)
    table = pulse_table(float(plan.pulse.roll_off), int(plan.pulse.span))
    val = np.abs(cir.gain[idx] * pulse_at(t[row] - cir.delay_s[idx], period, table))
    order = np.lexsort((-val, row))
    first = np.ones(order.size, dtype=bool)
    first[1:] = row[order][1:] != row[order][:-1]
    out[row[order][first]] = cir.path_index[idx[order][first]]
    return out


def _measure_rows(
    plan: LobePlan,
    rows: np.ndarray,
    gamma_cfar: np.ndarray,
    pmax: np.ndarray,
    rng: np.random.Generator | None,
):
    """Scan the windows ``rows`` of ``plan`` with the given thresholds (one epoch): the lobe
    tops' times, peaks, widths and validity, the noisy windows and the first crossings' times."""
    sig = plan.signal[rows]
    n_s = plan.n_samples[rows]
    if rng is not None:
        sig = sig + correlator_noise(
            rng, rows.size, sig.shape[1], plan.dt_s, plan.period_s, plan.pulse.roll_off,
            plan.noise_std, guard=NOISE_GUARD_T * plan.pulse.oversampling,
            power=plan.options.noise_power,
        )  # fmt: skip
    amp = np.abs(sig)
    # Thresholds per sample: the noise (CFAR), rho times the strongest peak, and before the
    # strongest peak its own pulse's precursor envelope plus the noise margin, so that neither
    # its sidelobes nor noise on them pass for an earlier path.
    x, env = envelope_table(float(plan.pulse.roll_off), int(plan.pulse.span))
    t_k = plan.t0_s[rows, None] + np.arange(sig.shape[1])[None, :] * plan.dt_s
    lead = (plan.peak_time_s[rows, None] - t_k) / plan.period_s
    side = np.where(lead > 0, np.interp(lead, x, env, right=0.0), 0.0)
    margin = gamma_cfar[:, None] * (lead > 0)
    thr = np.maximum(
        np.maximum(gamma_cfar, plan.rho * pmax)[:, None], side * pmax[:, None] + margin
    )
    top, u, peak, ok, cross = _scan(amp, n_s, thr)
    width = _half_width(amp, n_s, top, peak)
    t = plan.t0_s[rows] + (top + u) * plan.dt_s
    return t, peak, width, ok, sig, plan.t0_s[rows] + cross * plan.dt_s


@dataclass(frozen=True)
class NoisyWindows:
    """One epoch's noisy windows of a plan, as the first-lobe scan saw them (for the receivers
    that search further in them, :mod:`.search_back`).

    Attributes
    ----------
    rows : (R,) int64, rows of the plan (indices into ``plan.links``) measured in their own
        window: the strongest peak above the noise, the first lobe inside the window
    signal : (R, W) complex, 1/s, the delay profile with noise on the plan's samples
    t_cross_s : (R,) float, s, the first-lobe scan's first crossing
    gamma : (R,) float, 1/s, the CFAR threshold ``sqrt(alpha) sigma_hat``
    pmax : (R,) float, 1/s, the strongest peak with noise
    sigma_hat2 : (R,) float, the CFAR noise power estimate
    """

    rows: np.ndarray
    signal: np.ndarray
    t_cross_s: np.ndarray
    gamma: np.ndarray
    pmax: np.ndarray
    sigma_hat2: np.ndarray


def measure_first_lobe(plan: LobePlan, rng: np.random.Generator | None) -> LobeMeasurement:
    """One epoch of the first-lobe receiver on every link of ``plan``.

    Parameters
    ----------
    plan : LobePlan, from :func:`prepare_first_lobe`
    rng : numpy.random.Generator or None
        Noise (CFAR noise estimate, noise at the strongest peak, correlator noise on the window,
        in this order); None: no noise, and the receiver's noise estimate is exact.

    Returns
    -------
    LobeMeasurement
    """
    return measure_windows(plan, rng)[0]


def measure_windows(
    plan: LobePlan, rng: np.random.Generator | None
) -> tuple[LobeMeasurement, NoisyWindows]:
    """:func:`measure_first_lobe`, and the noisy windows it scanned (:class:`NoisyWindows`)."""
    n = plan.n_links
    toa = np.full(n, np.nan)
    snr_db = np.full(n, np.nan)
    ratio_db = np.full(n, np.nan)
    width = np.full(n, np.nan)
    detected = np.zeros(n, dtype=bool)
    m = plan.links.size
    if m == 0:
        none = np.zeros(0)
        return LobeMeasurement(toa, detected, snr_db, ratio_db, width, np.full(n, -1, np.int64),
                               0), NoisyWindows(np.zeros(0, np.int64), np.zeros((0, 0), complex),
                                                none, none, none, none)  # fmt: skip
    cells = plan.settings.cfar_cells
    g_over_m = np.ones(m)
    peak_noise = np.zeros(m, dtype=complex)
    if rng is not None:
        # Noise power estimate of the CFAR (M exponential cells), then the noise on the strongest
        # peak (any single sample of n(t) is CN(0, sigma_n^2)).
        if cells is not None:
            g_over_m = rng.gamma(cells, 1.0, m) / cells
        w = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        peak_noise = plan.noise_std * w / math.sqrt(2.0)
    sigma_hat2 = plan.noise_std**2 * g_over_m
    gamma_cfar = np.sqrt(plan.alpha * sigma_hat2)
    pmax = np.abs(plan.peak_signal + peak_noise)
    live = pmax >= gamma_cfar  # the strongest peak is above the noise threshold
    rows = np.flatnonzero(live)
    t, peak, w, ok, sig, t_cross = _measure_rows(plan, rows, gamma_cfar[rows], pmax[rows], rng)
    windows = NoisyWindows(rows[ok], sig[ok], t_cross[ok], gamma_cfar[rows[ok]], pmax[rows[ok]],
                           sigma_hat2[rows[ok]])  # fmt: skip
    refit = rows[~ok]
    refits = int(refit.size)
    if refits:
        # Lobe outside the window: the whole response of those links, fresh noise, same thresholds.
        whole = np.zeros(n, dtype=bool)
        whole[plan.links[refit]] = True
        # only the refitted links are prepared again; the others' windows keep their widths,
        # which set the noise rows' width as if every link had been prepared again
        others = np.ones(m, dtype=bool)
        others[refit] = False
        wide = int(plan.n_samples[others].max()) if others.any() else 0
        full_plan = prepare_first_lobe(
            plan.cir, plan.band, plan.budget, plan.pulse, plan.settings, full=whole, only=whole,
            min_width=wide, options=plan.options,
        )  # fmt: skip
        sub = np.searchsorted(full_plan.links, plan.links[refit])
        t2, p2, w2, ok2, _, _ = _measure_rows(full_plan, sub, gamma_cfar[refit], pmax[refit], rng)
        pos = np.searchsorted(rows, refit)
        t[pos], peak[pos], w[pos], ok[pos] = t2, p2, w2, ok2
    good = rows[ok]
    lk = plan.links[good]
    toa[lk] = t[ok]
    detected[lk] = True
    with np.errstate(divide="ignore"):
        snr_db[lk] = np.asarray(
            linear_power_to_db(peak[ok] ** 2 / sigma_hat2[good] / plan.processing_gain)
        )
        ratio_db[lk] = 20.0 * np.log10(peak[ok] / np.maximum(pmax[good], peak[ok]))
    width[lk] = w[ok] * plan.dt_s / (isolated_half_width_t(plan.pulse.roll_off) * plan.period_s)
    lobe_path_ = np.full(n, -1, dtype=np.int64)
    lobe_path_[lk] = lobe_path(plan, lk, t[ok])
    return LobeMeasurement(toa, detected, snr_db, ratio_db, width, lobe_path_, refits), windows
