"""The paper's ToA model, as written (section II, eqs. 1-3): the ``paper`` receiver.

For every link:

1. **First-arriving MPC.** The earliest path of the traced list whose power gain is at or
   above the tracer's own floor (:data:`POWER_FLOOR_DB`, the ``min_power_db`` default of
   :class:`raytrace.solver.config.TraceConfig`): "the first-arriving MPC to the UE from each of
   the base stations is used". No detection threshold: the paper has none.
2. **Its ToA: the top of its lobe.** "The ToA of the MPC is estimated from the maximum absolute
   value of the convolution between the channel impulse response and the raised cosine pulse"
   (eq. 2), and "a bias caused by the paths is added": ``r(t) = sum_j A_j h(t - tau_j)`` over
   *every* traced path of the link (``A_j`` the complex path gain, carrier phase included: the
   baseband response; ``h`` the band's raised cosine of :class:`~raytrace.emulation.channel.
   PulseShape`, not truncated), and the ToA is the top of the lobe of ``|r(t)|`` that holds the
   first path's delay, i.e. the local maximum reached by climbing ``|r|`` from that delay (the
   lobe runs from the minimum of ``|r|`` before it to the one after it). Noiseless: it depends
   on the paths alone.
3. **Eq. 3 noise.** Plus zero-mean Gaussian noise of standard deviation
   ``sigma = 1 / (2 pi B sqrt(t_s B SNR))`` seconds, with B the band's bandwidth, ``t_s`` one
   useful OFDM symbol (:meth:`~raytrace.emulation.channel.LinkBudget.integration_time_s`) and
   SNR the first path's own ``P_rx / N`` from the link budget (20 dBm, isotropic antennas,
   ``k T B F``), before processing gain (eq. 3 has ``t_s B`` itself).

How the top is found: ``|r|^2`` is climbed from the first path's delay in steps of
:data:`CLIMB_STEP_T` T (towards the larger neighbour if the delay sits in a minimum; a lobe
narrower than a step can be stepped over) until it falls, then maximised between the two
neighbours of the last step by Brent's bounded method on the exact continuous ``|r|^2`` (to
:data:`TOP_TOL_T` T). A climb longer than :data:`MAX_CLIMB_T` T is not a lobe of this response
and gives no ToA. Every interpretation and the sentence of the paper it reads is listed in
``docs/channel.md`` ("``paper``: the paper's model as written").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...core.jit import carray, helper, kernel
from ...solver.config import MIN_POWER_DB
from ..bands import Band
from ..channel.budget import LinkBudget, toa_std_eq3_s
from ..channel.cir import DiscreteCIR, discrete_cir, first_detectable_path
from ..channel.pulse import PulseShape, raised_cosine1

#: A path whose power gain ``|gain|^2`` is below this (dB) is no MPC: the tracer's own floor
#: (paths through metal carry no power), the only power condition of the paper's model.
POWER_FLOOR_DB = MIN_POWER_DB
#: Step of the climb along ``|r|``, in pulse periods T (0.39 ns at C-band, 0.10 ns at mmWave).
CLIMB_STEP_T = 1.0 / 32.0
#: Longest climb from the first path's delay to its lobe's top, in T.
MAX_CLIMB_T = 64.0
#: Tolerance of the lobe top (Brent's method on the continuous response), in T.
TOP_TOL_T = 1e-9


def first_traced_path(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    floor_db: float = POWER_FLOOR_DB,
) -> np.ndarray:
    """Index of the earliest path of each link with ``20 log10 |gain| >= floor_db``, ``(n_links,)
    int64``, -1 if none (ties in delay: the lower index)."""
    with np.errstate(divide="ignore"):
        power_db = 20.0 * np.log10(np.abs(np.asarray(gain)))
    return first_detectable_path(link, delay_s, power_db >= floor_db, n_links)


@helper
def _power(t, lo, hi, delay, gain, period, roll_off):
    """``|T r(t)|^2`` of the paths ``lo:hi`` (dimensionless)."""
    re = 0.0
    im = 0.0
    for j in range(lo, hi):
        h = raised_cosine1((t - delay[j]) / period, roll_off)
        re += gain[j].real * h
        im += gain[j].imag * h
    return re * re + im * im


@helper
def _brent_top(tc, half, lo, hi, delay, gain, period, roll_off, xatol):
    """Time of the maximum of ``|r|^2`` in ``[tc - half, tc + half]`` (bounded Brent, as scipy's
    ``fminbound``, on ``u = (t - tc) / period``)."""
    sqrt_eps = math.sqrt(2.2e-16)
    golden_mean = 0.5 * (3.0 - math.sqrt(5.0))
    a = -half / period
    b = half / period
    fulc = a + golden_mean * (b - a)
    nfc = fulc
    xf = fulc
    rat = 0.0
    e = 0.0
    fx = -_power(tc + xf * period, lo, hi, delay, gain, period, roll_off)
    ffulc = fx
    fnfc = fx
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * abs(xf) + xatol / 3.0
    tol2 = 2.0 * tol1
    for _ in range(200):
        if abs(xf - xm) <= tol2 - 0.5 * (b - a):
            break
        golden = True
        if abs(e) > tol1:  # a parabola through the three best points
            golden = False
            r = (xf - nfc) * (fx - ffulc)
            q = (xf - fulc) * (fx - fnfc)
            p = (xf - fulc) * q - (xf - nfc) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            r = e
            e = rat
            if abs(p) < abs(0.5 * q * r) and p > q * (a - xf) and p < q * (b - xf):
                rat = p / q
                x = xf + rat
                if (x - a) < tol2 or (b - x) < tol2:
                    rat = tol1 if xm >= xf else -tol1
            else:
                golden = True
        if golden:
            e = (a - xf) if xf >= xm else (b - xf)
            rat = golden_mean * e
        step = max(abs(rat), tol1)
        x = xf + (step if rat >= 0.0 else -step)
        fu = -_power(tc + x * period, lo, hi, delay, gain, period, roll_off)
        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc = nfc, fnfc
            nfc, fnfc = xf, fx
            xf, fx = x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if fu <= fnfc or nfc == xf:
                fulc, ffulc = nfc, fnfc
                nfc, fnfc = x, fu
            elif fu <= ffulc or fulc == xf or fulc == nfc:
                fulc, ffulc = x, fu
        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * abs(xf) + xatol / 3.0
        tol2 = 2.0 * tol1
    return tc + xf * period


@kernel("void(i8[::1], f8[::1], c16[::1], f8[::1], f8, f8, f8, i8, f8, f8[::1], i8[::1])")
def lobe_tops_kernel(offsets, delay, gain, start, period, roll_off, step_t, max_steps, tol_t,
                     top, dominant):  # fmt: skip
    """Top of the lobe of ``|r|`` that holds ``start[l]`` for every link ``l`` (module
    docstring): ``top (L,)`` seconds (NaN where ``start`` is NaN, the link has no path or the
    climb exceeds ``max_steps``) and ``dominant (L,)``, the index into ``delay``/``gain`` of the
    path with the largest ``|A_j h(top - tau_j)|`` (-1 where no top)."""
    dt = step_t * period
    for lk in range(start.size):
        top[lk] = np.nan
        dominant[lk] = -1
        lo = offsets[lk]
        hi = offsets[lk + 1]
        t0 = start[lk]
        if hi <= lo or not (t0 == t0):
            continue
        f0 = _power(t0, lo, hi, delay, gain, period, roll_off)
        fr = _power(t0 + dt, lo, hi, delay, gain, period, roll_off)
        fl = _power(t0 - dt, lo, hi, delay, gain, period, roll_off)
        d = 0.0
        f = f0
        if fr > f0 and fr >= fl:
            d = 1.0
            f = fr
        elif fl > f0:
            d = -1.0
            f = fl
        k = 1 if d != 0.0 else 0
        while k > 0 and k <= max_steps:
            fn = _power(t0 + d * (k + 1) * dt, lo, hi, delay, gain, period, roll_off)
            if fn <= f:
                break
            f = fn
            k += 1
        if k > max_steps:
            continue
        t = _brent_top(t0 + d * k * dt, dt, lo, hi, delay, gain, period, roll_off, tol_t)
        top[lk] = t
        best = -1.0
        for j in range(lo, hi):
            a = abs(gain[j] * raised_cosine1((t - delay[j]) / period, roll_off))
            if a > best:
                best = a
                dominant[lk] = j


@dataclass(frozen=True)
class PaperPlan:
    """The noiseless part of the ``paper`` receiver for one set of paths (reused by every epoch
    of a snapshot that does not change).

    Attributes
    ----------
    first_path : (L,) int64, index of the first-arriving traced path (caller's arrays), -1 none
    lobe_top_s : (L,) float, seconds, top of the lobe of ``|r|`` holding it (NaN where none)
    lobe_path : (L,) int64, caller's index of the path contributing most to ``|r|`` at the top
        (-1 where none)
    snr : (L,) float, linear SNR ``P_rx / N`` of the first path (NaN where none)
    sigma_s : (L,) float, seconds, eq. 3 standard deviation at that SNR (NaN where none)
    """

    first_path: np.ndarray
    lobe_top_s: np.ndarray
    lobe_path: np.ndarray
    snr: np.ndarray
    sigma_s: np.ndarray


def lobe_tops(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    start_s: np.ndarray,
    band: Band,
    pulse: PulseShape,
    cir: DiscreteCIR | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Top of the lobe of ``|sum_j A_j h(t - tau_j)|`` holding ``start_s[l]``, per link.

    Parameters
    ----------
    link : (P,) int; delay_s : (P,) float, seconds; gain : (P,) complex, the paths
    n_links : int
    start_s : (n_links,) float, seconds, a time inside the wanted lobe (NaN: none)
    band : Band, its bandwidth sets the pulse period ``T = (1 + beta) / B``
    pulse : PulseShape, the raised cosine (its ``roll_off``; the pulse is not truncated)
    cir : DiscreteCIR, optional, :func:`discrete_cir` of these paths, made before

    Returns
    -------
    top_s : (n_links,) float, seconds (NaN where none); path : (n_links,) int64, caller's index
    of the path contributing most at the top (-1 where none)
    """
    if cir is None:
        cir = discrete_cir(link, delay_s, gain, n_links)
    top = np.empty(n_links)
    dominant = np.empty(n_links, dtype=np.int64)
    max_steps = int(round(MAX_CLIMB_T / CLIMB_STEP_T))
    lobe_tops_kernel(
        carray(cir.offsets, np.int64), carray(cir.delay_s), carray(cir.gain, np.complex128),
        carray(start_s), float(pulse.period_s(band)), float(pulse.roll_off), CLIMB_STEP_T,
        max_steps, TOP_TOL_T, top, dominant,
    )  # fmt: skip
    path = np.full(n_links, -1, dtype=np.int64)
    path[dominant >= 0] = cir.path_index[dominant[dominant >= 0]]
    return top, path


def prepare_paper(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    band: Band,
    budget: LinkBudget,
    pulse: PulseShape,
    *,
    first: np.ndarray | None = None,
    cir: DiscreteCIR | None = None,
) -> PaperPlan:
    """The noiseless part of the ``paper`` receiver (module docstring) for checked path arrays;
    ``first`` (:func:`first_traced_path`) and ``cir`` (:func:`discrete_cir`) of these paths when
    the caller has them."""
    if first is None:
        first = first_traced_path(link, delay_s, gain, n_links)
    has = first >= 0
    start = np.full(n_links, np.nan)
    start[has] = delay_s[first[has]]
    top, dominant = lobe_tops(link, delay_s, gain, n_links, start, band, pulse, cir)
    snr = np.full(n_links, np.nan)
    snr[has] = budget.path_snr(gain[first[has]], band)
    sigma = np.asarray(
        toa_std_eq3_s(snr, band.bandwidth_hz, budget.integration_time_s(band)), dtype=float
    )
    return PaperPlan(first, top, dominant, snr, sigma)


def measure_paper(
    plan: PaperPlan, rng: np.random.Generator | None
) -> tuple[np.ndarray, np.ndarray]:
    """One epoch: the lobe tops plus eq. 3 noise (``rng`` None: none).

    One standard normal is drawn per link with a first path, in link order (the draws of
    ``first-path`` on the same links), and scaled by that link's ``sigma_s``.

    Returns
    -------
    toa_s : (L,) float, seconds, NaN where not detected; detected : (L,) bool
    """
    toa = plan.lobe_top_s.copy()
    has = plan.first_path >= 0
    if rng is not None:
        toa[has] += plan.sigma_s[has] * rng.standard_normal(int(has.sum()))
    detected = has & np.isfinite(toa)
    toa[~detected] = np.nan
    return toa, detected
