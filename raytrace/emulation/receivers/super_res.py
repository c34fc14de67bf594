"""``super-res``: a sparse fit of the PRS CFR's delay profile on a continuous delay axis (Newton
orthogonal matching pursuit), reporting the earliest component above the noise.

On the windows of the ``search-back`` receiver (:mod:`.search_back`; same noise draws):

1. the strongest lobes that lie after the first lobe's region are cancelled with the known pulse
   (CLEAN, :func:`positioning.model.searchback.clean`), so that their sidelobes do not enter
   the fit; the region runs from the window's start to ``post_t`` periods after the first
   lobe's crossing;
2. in the region, components are added one at a time at the strongest residual sample, and after
   each addition all delays are refined by Gauss-Newton steps and all complex amplitudes fitted
   jointly by least squares (NOMP: Mamandipoor, Ramasamy and Madhow, IEEE Trans. Signal Process.
   64(19), 2016, on the pulse of eq. 2 instead of a sinusoid), until the strongest residual
   sample is under the noise threshold (CFAR) or ``depth_db`` under the strongest peak: the
   model order follows the noise, at most ``components``;
3. the earliest component whose amplitude exceeds the noise threshold plus ``kappa`` times the
   stronger components' sidelobe envelope is the first arrival, at its fitted delay.

Two paths closer than a pulse width are separated where the SNR allows (their merged lobe no
longer moves the ToA); what the fit cannot separate it reports as one component.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from positioning.model.pulse import TABLE_PER_T, envelope_table, pulse_at, pulse_table, quartic_top
from positioning.model.searchback import clean

from ...core.constants import linear_power_to_db
from ...core.errors import HallrayError
from .first_lobe import LobeMeasurement, LobePlan, lobe_path, measure_windows

#: Two components closer than this many periods, or one with an amplitude above
#: :data:`_AMP_CAP` times the row's largest sample, make a fit ill-posed: the component that
#: caused it is dropped and the row's model order stops there.
_MIN_SEPARATION_T = 0.15
_AMP_CAP = 4.0
#: The fit starts this many periods before the first sample above its floor.
LEAD_T = 2.0
#: Samples per period T of the fit (the profile's samples, T / oversampling apart, decimated).
FIT_PER_T = 4
#: Ridge added to the normal equations, relative to their diagonal (keeps two components that
#: meet on one delay solvable).
_RIDGE = 1e-9


@dataclass(frozen=True)
class SuperResSettings:
    """Settings of the ``super-res`` receiver (module docstring).

    Parameters
    ----------
    components : int, largest model order in the first lobe's region (default 6)
    depth_db : float, dB, fit down to this far under the strongest peak (default -40 dB; also the
        window's depth, as ``search-back``'s)
    newton : int, Gauss-Newton rounds after each added component (default 2)
    kappa : float, share of a stronger component's sidelobe envelope an earlier one must exceed
        besides the noise (default 0.25)
    post_t : float, the region ends this many periods after the first lobe's crossing (default 3)
    """

    components: int = 6
    depth_db: float = -40.0
    newton: int = 2
    kappa: float = 0.25
    post_t: float = 3.0

    def __post_init__(self) -> None:
        for name, lo, hi in (("components", 1, 32), ("newton", 0, 10)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise HallrayError(f"super-res {name} must be an integer in [{lo}, {hi}], got {v!r}")
        for name, lo, hi in (("depth_db", -80.0, -6.0), ("kappa", 0.0, 10.0), ("post_t", 1.0, 16.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise HallrayError(f"super-res {name} must be a number in [{lo:g}, {hi:g}], got {v!r}")

    @property
    def depth(self) -> float:
        """Fit depth as an amplitude ratio."""
        return float(10.0 ** (self.depth_db / 20.0))


def _pulse_and_slope(
    lag: np.ndarray, period: float, table: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """``T h(lag)`` (as :func:`positioning.model.pulse.pulse_at`) and its derivative in ``lag``
    (1/s, the slope of the table's linear piece), from one look-up."""
    value, step = table
    u = np.abs(lag) * (TABLE_PER_T / period)
    np.minimum(u, value.size - 2, out=u)
    i = u.astype(np.intp)
    d = step[i]
    h = (u - i) * d + value[i]
    return h, np.sign(lag) * d * (TABLE_PER_T / period)


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched ``a x = b`` with a small ridge; ``a (R, K, K)``, ``b (R, K)``."""
    k = a.shape[-1]
    diag = np.abs(np.einsum("rkk->rk", a)).max(axis=1, initial=0.0)
    a = a + (_RIDGE * np.maximum(diag, 1e-300))[:, None, None] * np.eye(k)[None]
    return np.linalg.solve(a, b[..., None])[..., 0]


def _fit(s, t, valid, tau, period, table, rounds):
    """Joint least-squares amplitudes and Gauss-Newton delays of the components ``tau (R, K)``
    of the rows ``s (R, W)`` sampled at ``t (R, W)``; returns ``tau, amp, residual``."""
    for it in range(rounds + 1):
        lag = t[:, :, None] - tau[:, None, :]
        h, slope = _pulse_and_slope(lag, period, table)
        h *= valid[:, :, None]
        hh = np.swapaxes(h, 1, 2)  # real
        amp = _solve(hh @ h, (hh @ s[:, :, None])[..., 0])
        if it == rounds:
            break
        e = s - np.einsum("rwk,rk->rw", h, amp)
        jac = -slope * valid[:, :, None] * amp[:, None, :]
        jh = np.conj(np.swapaxes(jac, 1, 2))
        step = _solve(np.real(jh @ jac), np.real((jh @ e[:, :, None])[..., 0]))
        tau = tau + np.clip(step, -period / 4, period / 4)
    res = s - np.einsum("rwk,rk->rw", h, amp)
    return tau, amp, res


def nomp(s, t, valid, floor, settings: SuperResSettings, period, table):
    """Newton OMP on rows ``s (R, W)`` (module docstring, step 2): ``tau, amp`` (R, K), NaN / 0
    beyond each row's model order."""
    r_all, k_max = s.shape[0], settings.components
    tau = np.full((r_all, k_max), np.nan)
    amp = np.zeros((r_all, k_max), dtype=complex)
    live = np.arange(r_all)
    res = s.copy()
    five = np.arange(-2, 3)
    w = s.shape[1]
    inner = valid.copy()
    inner[:, :2] = False
    inner[:, w - 2 :] = False
    cap = _AMP_CAP * np.max(np.abs(s) * valid, axis=1)
    for k in range(k_max):
        mag = np.where(inner[live], np.abs(res[live]), -1.0)
        i = np.argmax(mag, axis=1)
        go = mag[np.arange(live.size), i] >= floor[live]
        live, i = live[go], i[go]
        if live.size == 0:
            break
        u, _ = quartic_top(np.abs(res[live[:, None], i[:, None] + five[None, :]]))
        dt = t[live, 1] - t[live, 0]
        tau[live, k] = t[live, 0] + (i + u) * dt
        tk, ak, rk = _fit(s[live], t[live], valid[live], tau[live, : k + 1], period, table,
                          settings.newton)  # fmt: skip
        gap = np.abs(tk[:, :, None] - tk[:, None, :]) + np.eye(k + 1)[None] * period
        bad = (gap.min(axis=(1, 2)) < _MIN_SEPARATION_T * period) | (
            np.abs(ak).max(axis=1) > cap[live]
        ) | ~np.isfinite(tk).all(axis=1)
        tau[live[bad], k] = np.nan  # ill-posed: keep the fit of order k, stop the row
        good = live[~bad]
        tau[good, : k + 1], amp[good, : k + 1], res[good] = tk[~bad], ak[~bad], rk[~bad]
        live = good
    return tau, amp


def measure_super_res(
    plan: LobePlan, rng: np.random.Generator | None, settings: SuperResSettings
) -> LobeMeasurement:
    """One epoch of ``super-res`` on a plan of :func:`.search_back.prepare_cfr` (with
    ``settings.depth``); links not measured in their window keep the first lobe's result."""
    fl, win = measure_windows(plan, rng)
    if win.rows.size == 0:
        return fl
    period, dt = plan.period_s, plan.dt_s
    roll, span = float(plan.pulse.roll_off), int(plan.pulse.span)
    table, (x, env) = pulse_table(roll, span), envelope_table(roll, span)
    n_s, t0 = plan.n_samples[win.rows], plan.t0_s[win.rows]
    floor = np.maximum(win.gamma, settings.depth * win.pmax)
    w = win.signal.shape[1]
    t = t0[:, None] + np.arange(w)[None, :] * dt
    end = win.t_cross_s + settings.post_t * period
    # 1. cancel the strong lobes after the region; put back the ones inside it
    tau_c, amp_c, res = clean(win.signal, n_s, t0, dt, period, table, floor, 8)
    inside = np.isfinite(tau_c) & (tau_c <= end[:, None])
    for k in range(tau_c.shape[1]):
        r = np.flatnonzero(inside[:, k])
        res[r] += amp_c[r, k, None] * pulse_at(t[r] - tau_c[r, k, None], period, table)
    # 2. the fit, from LEAD_T before the first sample above the floor to the region's end, on
    # samples T/4 apart (3.2 per 1/B: the band-limited profile is all there)
    os_ = plan.pulse.oversampling
    step = max(1, os_ // FIT_PER_T)
    above = (np.abs(res) >= floor[:, None]) & (np.arange(w)[None, :] < n_s[:, None])
    start = np.maximum(np.argmax(above, axis=1) - int(LEAD_T * os_), 0)
    stop = np.minimum(n_s, np.ceil((end - t0) / dt).astype(np.int64) + 1)
    n_fit = int(max(1, np.ceil((stop - start) / step).max()))
    idx = start[:, None] + step * np.arange(n_fit)[None, :]
    valid = idx < stop[:, None]
    idx = np.minimum(idx, w - 1)
    tau, amp = nomp(np.take_along_axis(res, idx, axis=1), t0[:, None] + idx * dt, valid, floor,
                    settings, period, table)  # fmt: skip
    # 3. the earliest component above the noise and the stronger ones' sidelobes
    mag = np.abs(amp)
    have = np.isfinite(tau)
    t_ = np.where(have, tau, 0.0)
    lag = np.abs(t_[:, :, None] - t_[:, None, :]) / period
    stronger = (mag[:, None, :] > mag[:, :, None]) & have[:, None, :]
    guard = np.sum(np.where(stronger, mag[:, None, :] * np.interp(lag, x, env, right=0.0), 0.0),
                   axis=2)  # fmt: skip
    acc = have & (mag >= win.gamma[:, None] + settings.kappa * guard)
    first = np.where(acc, t_, np.inf)
    k = np.argmin(first, axis=1)
    ok = np.isfinite(first[np.arange(k.size), k])
    out_toa, snr, ratio = fl.toa_s.copy(), fl.snr_db.copy(), fl.peak_ratio_db.copy()
    width, path, detected = fl.lobe_width.copy(), fl.lobe_path.copy(), fl.detected.copy()
    rows = win.rows[ok]
    lk = plan.links[rows]
    a = mag[ok, k[ok]]
    out_toa[lk] = first[ok, k[ok]]
    detected[lk] = True
    with np.errstate(divide="ignore"):
        snr[lk] = np.asarray(linear_power_to_db(a**2 / win.sigma_hat2[ok] / plan.processing_gain))
        ratio[lk] = 20.0 * np.log10(a / np.maximum(win.pmax[ok], a))
    width[lk] = math.nan
    path[lk] = lobe_path(plan, lk, out_toa[lk])
    return replace(fl, toa_s=out_toa, detected=detected, snr_db=snr, peak_ratio_db=ratio,
                   lobe_width=width, lobe_path=path)  # fmt: skip
