"""Receivers on the PRS channel frequency response: ``first-lobe-cfr`` (today's first-lobe rule on
the CFR's delay profile) and ``search-back`` (the first lobe, then a sidelobe-aware search for a
weaker, earlier arrival).

Both see the delay profile of the link's CFR (:mod:`raytrace.emulation.channel.cfr`): the
pulse-shaped response of the paths with their delays shifted by the base station's timing offset
and folded into the comb's unambiguous period, plus white per-subcarrier noise weighted by the
pulse's spectrum (noise spectrum ``W^2``, 0.69 dB above the correlator model's). They are
evaluated in windows, as the first-lobe receiver is (:mod:`.first_lobe`).

``search-back`` (details and the measured choice of its settings in ``docs/channel.md``):

1. the first lobe exactly as ``first-lobe-cfr`` finds it (CFAR, -12 dB of the strongest peak,
   the strongest peak's sidelobe guard); its window, though, runs from the earliest path within
   ``depth_db`` of the strongest peak to 2 T after that peak;
2. the ``components`` strongest lobes are cancelled with the known pulse (CLEAN,
   :func:`positioning.model.searchback.clean`);
3. before the first lobe's crossing less ``guard_t`` periods, the earliest residual lobe or
   cancelled component above ``kappa`` times the cancelled lobes' sidelobe envelope plus the
   larger of the noise threshold over the residual's own sidelobe bound and ``margin`` times that
   bound is the first arrival (:func:`positioning.model.searchback.search_back`); its ToA is the
   top of its lobe with the stronger lobes removed. Without one, the first lobe's ToA stands,
   unless the cancelled lobes explain the first lobe (no component of its own, what is left of it
   under that threshold: their summed sidelobe, :func:`positioning.model.searchback.explained`);
   then the earliest component within the first-lobe rule's ``rho`` of the strongest stands for it;
4. (``two_pulse``) the reported lobe is fitted with one pulse and, where that leaves more than
   noise, with two (:func:`positioning.model.lobefit.refine_lobe`): where the fit determines
   them, the earlier of the two is the ToA (two paths merged in anti-phase top before the
   first; in phase, between the two); where it does not, a lobe top that the best fit of up to
   three pulses places well before all its components (more than three standard errors and a
   quarter period) gives way to that fit's first component (a lobe step 3 found stands out of
   the later lobes' sidelobes: it moves by less than :data:`MOVE_T` periods, not onto them).

A weak first path 20-30 dB under the strongest, a few periods before it, is found; the strongest
path's sidelobes (predicted by the pulse, not by a fixed -12 dB) and noise (CFAR) are not taken
for one; a path within about one period of the first lobe is separated by the two-pulse fit
where the band and the other paths let it (docs/channel.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from positioning.model.lobefit import noise_gain, refine_lobe
from positioning.model.pulse import envelope_table, pulse_table
from positioning.model.searchback import clean, explained, search_back

from ...core.constants import linear_power_to_db
from ...core.errors import HallrayError
from ..bands import Band
from ..channel.budget import LinkBudget
from ..channel.cfr import PrsSettings, delay_profile_noise_std, fold_cir
from ..channel.cir import DiscreteCIR
from ..channel.pulse import PulseShape
from .first_lobe import (
    FirstLobeSettings,
    LobeMeasurement,
    LobePlan,
    WindowOptions,
    lobe_path,
    measure_windows,
    prepare_first_lobe,
)

#: A lobe the search found is moved by the two-pulse step's consistency rule (a merged cluster
#: tops before its paths) by less than this many periods: the pulse's first zero, beyond which a
#: fitted component is another lobe (the far pass fits the found lobe with the strongest peak).
MOVE_T = 1.0


def _number(name: str, value: object, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise HallrayError(f"search-back {name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    return float(value)


@dataclass(frozen=True)
class SearchBackSettings:
    """Settings of the ``search-back`` receiver (module docstring; defaults measured on the
    bundled hall, docs/channel.md).

    Parameters
    ----------
    components : int, strongest lobes cancelled with the known pulse (default 4)
    depth_db : float, dB, how far under the strongest peak the search reaches: the window starts
        at the earliest path within it, and the cancellation stops there (default -40 dB)
    kappa : float, share of a cancelled lobe's sidelobe envelope the one-pulse model may miss
        (paths merged in one lobe are not one pulse; default 0.5)
    margin : float, a sample must reach this many times the residual's own sidelobe bound, as well
        as the noise threshold above it (default 2: merged lobes' sidelobes exceed the one-pulse
        bound; :func:`positioning.model.searchback.search_back`, docs/channel.md)
    guard_t : float, periods T before the first lobe's crossing where the search ends (default 1:
        closer paths are part of that lobe)
    two_pulse : bool, refine the reported lobe with two pulses where it is not one
        (:mod:`positioning.model.lobefit`; default True)
    """

    components: int = 4
    depth_db: float = -40.0
    kappa: float = 0.5
    margin: float = 2.0
    guard_t: float = 1.0
    two_pulse: bool = True

    def __post_init__(self) -> None:
        c = self.components
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not 1 <= c <= 32:
            raise HallrayError(f"search-back components must be an integer in [1, 32], got {c!r}")
        _number("depth_db", self.depth_db, -80.0, -6.0)
        _number("kappa", self.kappa, 0.0, 10.0)
        _number("margin", self.margin, 0.0, 10.0)
        _number("guard_t", self.guard_t, 0.0, 8.0)
        if not isinstance(self.two_pulse, (bool, np.bool_)):
            raise HallrayError(f"search-back two_pulse must be True or False, got {self.two_pulse!r}")

    @property
    def depth(self) -> float:
        """Search depth as an amplitude ratio."""
        return float(10.0 ** (self.depth_db / 20.0))


def cfr_options(
    band: Band, budget: LinkBudget, pulse: PulseShape, prs: PrsSettings, depth: float | None
) -> WindowOptions:
    """Windows and noise of a receiver on the CFR's delay profile (``depth``: the search-back's
    window from the earliest path within that amplitude ratio of the strongest peak to after
    the peak; None: the first-lobe receiver's windows)."""
    return WindowOptions(
        noise_std=delay_profile_noise_std(band, budget, pulse, prs),
        noise_power=2,
        window_rho=depth,
        to_peak=depth is not None,
    )


def prepare_cfr(
    cir: DiscreteCIR,
    band: Band,
    budget: LinkBudget,
    pulse: PulseShape,
    first_lobe: FirstLobeSettings,
    prs: PrsSettings,
    depth: float | None = None,
) -> LobePlan:
    """Noiseless windows of the delay profile of every link's PRS CFR (timing offsets applied,
    delays folded into the comb's period from the pulse's span before the earliest path,
    :func:`raytrace.emulation.channel.cfr.fold_cir`)."""
    folded = fold_cir(cir, prs.period_s(band), prs.link_offsets_s(cir.n_links),
                      pulse.span * pulse.period_s(band))  # fmt: skip
    options = cfr_options(band, budget, pulse, prs, depth)
    return prepare_first_lobe(folded, band, budget, pulse, first_lobe, options=options)


def _past_sidelobes(plan, win, fl, tau, amp, res, settings, env):
    """The first lobe's ToA per window row, past the cancelled lobes' sidelobes: where the first
    lobe is their sidelobe (:func:`positioning.model.searchback.explained`), the earliest
    cancelled component reaching the first-lobe rule's ``rho`` of the strongest peak stands for
    it. Returns ``(toa, peak)``, ``(R,)`` s and 1/s; ``peak`` NaN where the first lobe stands."""
    first = fl.toa_s[plan.links[win.rows]]
    peak = np.full(first.shape, np.nan)
    side = explained(win.signal, res, plan.n_samples[win.rows], plan.t0_s[win.rows], plan.dt_s, plan.period_s,
                     tau, amp, win.gamma, first, settings.kappa, settings.margin, env)  # fmt: skip
    strong = np.isfinite(tau) & (np.abs(amp) >= plan.rho * win.pmax[:, None])
    t_comp = np.where(strong & (tau > first[:, None]), tau, np.inf)
    k = np.argmin(t_comp, axis=1)
    r = np.flatnonzero(side & np.isfinite(t_comp[np.arange(k.size), k]))
    first = first.copy()
    first[r] = tau[r, k[r]]
    peak[r] = np.abs(amp[r, k[r]])
    return first, peak


def measure_search_back(
    plan: LobePlan, rng: np.random.Generator | None, settings: SearchBackSettings
) -> LobeMeasurement:
    """One epoch of ``search-back`` on a plan of :func:`prepare_cfr` (with ``settings.depth``).

    The noise is drawn as by the first-lobe receiver (:func:`.first_lobe.measure_windows`); a
    link whose search finds an earlier arrival reports its ToA, its SNR (``|r_peak|^2 /
    sigma_hat^2 / (t_s B)`` at that lobe's top), its peak over the strongest peak and the path
    that dominates there; ``lobe_width`` is NaN for it (the lobe was measured on the residual).
    """
    fl, win = measure_windows(plan, rng)
    if win.rows.size == 0:
        return fl
    period, dt = plan.period_s, plan.dt_s
    roll, span = float(plan.pulse.roll_off), int(plan.pulse.span)
    table, env = pulse_table(roll, span), envelope_table(roll, span)
    n_s, t0 = plan.n_samples[win.rows], plan.t0_s[win.rows]
    floor = np.maximum(win.gamma, settings.depth * win.pmax)
    tau, amp, res = clean(win.signal, n_s, t0, dt, period, table, floor, settings.components)
    limit = win.t_cross_s - settings.guard_t * period
    toa, peak = search_back(res, n_s, t0, dt, period, tau, amp, win.gamma, limit, settings.kappa,
                            settings.margin, env, table)  # fmt: skip
    found = np.isfinite(toa)
    first, first_peak = _past_sidelobes(plan, win, fl, tau, amp, res, settings, env)
    shifted = ~found & np.isfinite(first_peak)
    if settings.two_pulse:
        # the reported lobe, the first lobe's or the earlier one's, refined where not one pulse
        lobe = np.where(found, toa, first)
        lobe, p2, fit = refine_lobe(win.signal, n_s, t0, dt, period, plan.pulse.oversampling, table,
                                    lobe, plan.peak_time_s[win.rows], tau, amp, win.gamma,
                                    win.sigma_hat2, plan.alpha, plan.rho, noise_gain(roll, span))  # fmt: skip
        # a lobe the search found stands out of the later lobes' sidelobes: it may move within
        # itself (a merged cluster tops before its paths) but not onto a lobe a period later
        took = fit.applied & ~(found & fit.moved & (lobe - toa > MOVE_T * period))
        toa = np.where(found & ~took, toa, np.where(took, lobe, np.nan))
        peak = np.where(took, p2, peak)
    # a first lobe that is the cancelled lobes' sidelobe gives way to their earliest strong one
    keep = np.isnan(toa) & shifted
    toa, peak = np.where(keep, first, toa), np.where(keep, first_peak, peak)
    found = np.isfinite(toa)
    if not found.any():
        return fl
    rows = win.rows[found]
    lk = plan.links[rows]
    out_toa, snr, ratio = fl.toa_s.copy(), fl.snr_db.copy(), fl.peak_ratio_db.copy()
    width, path, detected = fl.lobe_width.copy(), fl.lobe_path.copy(), fl.detected.copy()
    p = peak[found]
    out_toa[lk] = toa[found]
    detected[lk] = True
    with np.errstate(divide="ignore"):
        snr[lk] = np.asarray(
            linear_power_to_db(p**2 / win.sigma_hat2[found] / plan.processing_gain)
        )
        ratio[lk] = 20.0 * np.log10(p / np.maximum(win.pmax[found], p))
    width[lk] = math.nan
    path[lk] = lobe_path(plan, lk, toa[found])
    return replace(fl, toa_s=out_toa, detected=detected, snr_db=snr, peak_ratio_db=ratio,
                   lobe_width=width, lobe_path=path)  # fmt: skip
