"""The channel frequency response (CFR) a 5G positioning receiver estimates from the PRS, and
its delay profile.

A device that receives the positioning reference signal (PRS) of one base station knows the
transmitted symbols on the PRS resource elements, so it estimates the channel on those
subcarriers: ``Y_k = H(f_k) + N_k`` with

    H(f) = sum_j A_j exp(-j 2 pi f tau_j)            (eq. 1 in the frequency domain)

at the baseband frequencies ``f_k = k K_comb df``, ``|f_k| <= B/2`` (``df`` the band's subcarrier
spacing, ``K_comb`` the PRS comb: one subcarrier in ``K_comb`` per symbol; comb 1 is every
subcarrier, the de-staggered comb-N over N symbols of NR), and ``N_k`` white complex Gaussian
noise. Its level follows the link budget: over the ``K`` observed subcarriers the PRS carries the
energy of ``n_symbols`` OFDM symbols, so a coherent sum over them reaches the post-correlation SNR
``SNR t_s B`` of :class:`raytrace.emulation.channel.LinkBudget` (35.2 dB of processing gain for
one symbol), i.e. per subcarrier

    sigma_sc^2 = K / (snr_1 t_s B),       snr_1 = P_tx G_t G_r / N   (a path of |A| = 1).

A timing offset ``d_b`` of base station ``b`` (synchronisation error) multiplies its links' CFR
by ``exp(-j 2 pi f d_b)``.

**Delay profile.** The receiver weights the CFR with the raised-cosine spectrum ``W(f)`` of eq. 2
(a window on the flat OFDM spectrum; :class:`raytrace.emulation.channel.PulseShape`) and takes the
inverse DFT::

    r(t) = dF sum_k W(f_k) Y_k exp(j 2 pi f_k t),     dF = K_comb df

By Poisson's sum formula its signal part is exactly ``sum_j A_j sum_m h(t - tau_j - m / dF)``:
the pulse-shaped response of eq. 2, periodic in the unambiguous delay ``1 / dF`` (33.3 us over
``K_comb`` at 30 kHz; 694 ns = 208 m for comb 12 at 120 kHz). Its noise is complex Gaussian
with the spectrum ``W^2`` (the window applied to white noise), per-sample standard deviation
``dF sigma_sc sqrt(sum_k W_k^2)``: 0.69 dB above the correlator model's, the loss of a window
that is not the matched filter of the flat spectrum.

The receivers (:mod:`raytrace.emulation.receivers`) need the delay profile only around the first
arrival and the strongest peak: they evaluate it there, exactly, as the pulse-shaped response of
the paths with their delays folded into one unambiguous period (:func:`fold_cir`) plus noise of
the spectrum ``W^2`` (:func:`raytrace.emulation.channel.response.correlator_noise` with
``power=2``) -- the same signal as the inverse DFT of :func:`prs_cfr` (tested), without synthesising
the 3333 subcarriers of every link in every epoch. :func:`prs_cfr` and :func:`cfr_delay_profile`
are the full frequency-domain model, for studies that want the CFR itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...core.errors import HallrayError
from ..bands import Band, get_band
from .budget import LinkBudget
from .cir import DiscreteCIR, check_paths, discrete_cir
from .pulse import PulseShape, raised_cosine_spectrum

#: PRS comb sizes of NR (TS 38.211 sec. 7.4.1.7) and 1, every subcarrier (a comb-N PRS over N
#: symbols, its combs put together).
PRS_COMBS = (1, 2, 4, 6, 12)
#: Largest number of (path, subcarrier) products one chunk of :func:`prs_cfr` holds.
_CHUNK_ELEMENTS = 1 << 22
#: Subcarriers per inner block of the synthesis (``f = (a * _BLOCK + b) dF``: one matrix product).
_BLOCK = 64


@dataclass(frozen=True)
class PrsSettings:
    """What the receiver's CFR is observed on.

    Parameters
    ----------
    comb : int, one of :data:`PRS_COMBS`
        One subcarrier in ``comb`` carries the PRS (1: every subcarrier). The unambiguous delay
        is ``1 / (comb df)``; a path later than that folds back into the period.
    timing_offsets_s : tuple of float, seconds
        Per base station, a timing (synchronisation) offset added to all its links' delays;
        empty: none. Links are taken tx-major (``link = bs * n_points + point``), so the number
        of links must be a multiple of the number of offsets.
    """

    comb: int = 1
    timing_offsets_s: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        c = self.comb
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or int(c) not in PRS_COMBS:
            known = ", ".join(map(str, PRS_COMBS))
            raise HallrayError(f"unknown PRS comb {c!r}; use one of {known}")
        object.__setattr__(self, "comb", int(c))
        offsets = tuple(self.timing_offsets_s)
        for v in offsets:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise HallrayError(f"PRS timing offsets must be finite numbers of seconds, got {v!r}")
        object.__setattr__(self, "timing_offsets_s", tuple(float(v) for v in offsets))

    def spacing_hz(self, band: Band) -> float:
        """Spacing of the observed subcarriers, ``comb df``, Hz."""
        return self.comb * band.subcarrier_spacing_hz

    def period_s(self, band: Band) -> float:
        """Unambiguous delay of the CFR, ``1 / (comb df)``, s."""
        return 1.0 / self.spacing_hz(band)

    def subcarrier_hz(self, band: Band) -> np.ndarray:
        """(K,) float, Hz: baseband frequencies ``k comb df`` of the observed subcarriers,
        ``|f| <= B/2``, ascending (3333 for both bands with comb 1)."""
        half = int(math.floor(0.5 * band.bandwidth_hz / self.spacing_hz(band) + 1e-9))
        return np.arange(-half, half + 1) * self.spacing_hz(band)

    def link_offsets_s(self, n_links: int) -> np.ndarray:
        """(n_links,) float, s: each link's timing offset (its base station's; tx-major links)."""
        if not self.timing_offsets_s:
            return np.zeros(int(n_links))
        n_bs = len(self.timing_offsets_s)
        if n_links % n_bs:
            raise HallrayError(
                f"{n_links} links cannot be split over {n_bs} base stations' timing offsets"
            )
        return np.repeat(np.asarray(self.timing_offsets_s), n_links // n_bs)


def subcarrier_noise_std(band: Band, budget: LinkBudget, prs: PrsSettings) -> float:
    """Std of the complex noise ``N_k`` on one subcarrier of the CFR (field-gain units).

    ``sigma_sc^2 = K / (snr_1 t_s B)`` (module docstring): a coherent sum over the ``K`` observed
    subcarriers gives a path of gain ``A`` the post-correlation SNR ``|A|^2 snr_1 t_s B``.
    """
    snr_1 = float(budget.path_snr(np.ones(1), band)[0])
    k = prs.subcarrier_hz(band).size
    return math.sqrt(k / (snr_1 * budget.processing_gain(band)))


def window_weights(band: Band, pulse: PulseShape, prs: PrsSettings) -> np.ndarray:
    """(K,) float: the raised-cosine spectrum of eq. 2 at the observed subcarriers."""
    return raised_cosine_spectrum(prs.subcarrier_hz(band), pulse.period_s(band), pulse.roll_off)


def delay_profile_noise_std(
    band: Band, budget: LinkBudget, pulse: PulseShape, prs: PrsSettings
) -> float:
    """Per-sample std of the noise of the delay profile ``r(t)`` (1/s, the unit in which a path
    of gain ``A`` peaks at ``|A| / T``): ``dF sigma_sc sqrt(sum_k W_k^2)``."""
    w = window_weights(band, pulse, prs)
    return prs.spacing_hz(band) * subcarrier_noise_std(band, budget, prs) * float(
        np.sqrt(np.sum(w**2))
    )


def fold_cir(
    cir: DiscreteCIR, period_s: float, offsets_s: np.ndarray, lead_s: float = 0.0
) -> DiscreteCIR:
    """Paths as the delay profile shows them: each link's delays plus its timing offset, folded
    into one unambiguous period that starts ``lead_s`` before the link's earliest (shifted) path.

    The profile is periodic (module docstring): a path later than the earliest by more than
    ``period - lead`` shows an image up to ``lead`` before it, where a receiver searches.

    Parameters
    ----------
    cir : DiscreteCIR
    period_s : float, s, the CFR's unambiguous delay ``1 / (comb df)``
    offsets_s : (n_links,) float, s, timing offset of each link
    lead_s : float, s, how far before the earliest path the period starts (the receivers: the
        pulse's span, the farthest any window reaches before it); below ``period_s``

    Returns
    -------
    DiscreteCIR with delays in ``[first - lead, first - lead + period)`` per link, sorted again;
    its ``path_index`` still points into the caller's path arrays.
    """
    n = cir.n_links
    link = np.repeat(np.arange(n), np.diff(cir.offsets))
    delay = cir.delay_s + np.asarray(offsets_s, dtype=float)[link]
    if delay.size == 0:
        return DiscreteCIR(cir.offsets, cir.path_index, delay, cir.gain)
    first = np.full(n, np.inf)
    np.minimum.at(first, link, delay)
    start = first[link] - min(float(lead_s), 0.5 * period_s)
    excess = delay - start
    folded = excess >= period_s
    if folded.any():
        delay = np.where(folded, start + np.mod(excess, period_s), delay)
    out = discrete_cir(link, delay, cir.gain, n)
    return DiscreteCIR(out.offsets, cir.path_index[out.path_index], out.delay_s, out.gain)


def prs_cfr(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    band: Band | str,
    *,
    budget: LinkBudget | None = None,
    prs: PrsSettings | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The PRS channel frequency response of every link (module docstring), exactly.

    Parameters
    ----------
    link, delay_s, gain, n_links : the path arrays (:mod:`raytrace.emulation.channel`)
    band : Band or band name
    budget : LinkBudget, sets the noise (default ``LinkBudget()``)
    prs : PrsSettings, comb and timing offsets (default comb 1, no offsets)
    rng : numpy.random.Generator, optional: adds the noise ``N_k`` (drawn link by link)

    Returns
    -------
    f_hz : (K,) float, Hz, baseband frequencies of the observed subcarriers
    cfr : (n_links, K) complex, ``H(f_k) [+ N_k]`` (field gain relative to transmitted)
    """
    band = get_band(band)
    budget = budget or LinkBudget()
    prs = prs or PrsSettings()
    link, delay_s, gain, n_links = check_paths(link, delay_s, gain, n_links)
    f = prs.subcarrier_hz(band)
    k = f.size
    cir = discrete_cir(link, delay_s, gain, n_links)
    tau = cir.delay_s + prs.link_offsets_s(n_links)[np.repeat(np.arange(n_links),
                                                                np.diff(cir.offsets))]  # fmt: skip
    counts = np.diff(cir.offsets)
    out = np.zeros((n_links, k), dtype=complex)
    n_a = -(-k // _BLOCK)
    per = max(1, _CHUNK_ELEMENTS // max(1, int(counts.max(initial=1)) * (n_a + _BLOCK)))
    step = prs.spacing_hz(band)
    for lo in range(0, n_links, per):
        hi = min(n_links, lo + per)
        width = int(counts[lo:hi].max(initial=0))
        if width == 0:
            continue
        # paths of the chunk's links padded to one width (padding: gain 0)
        slot = np.arange(width)[None, :]
        idx = cir.offsets[lo:hi, None] + slot
        live = slot < counts[lo:hi, None]
        idx = np.where(live, idx, 0)
        t = np.where(live, tau[idx], 0.0)
        g = np.where(live, cir.gain[idx], 0.0) * np.exp(-2j * np.pi * f[0] * t)
        # f = f0 + (a B + b) dF: exp(-j 2 pi f t) = e0 U_a V_b, one batched product per chunk
        u = np.exp(-2j * np.pi * step * _BLOCK * t[:, :, None] * np.arange(n_a)[None, None, :])
        v = np.exp(-2j * np.pi * step * t[:, :, None] * np.arange(_BLOCK)[None, None, :])
        h = np.matmul(np.swapaxes(u * g[:, :, None], 1, 2), v)  # (links, n_a, _BLOCK)
        out[lo:hi] = h.reshape(hi - lo, -1)[:, :k]
    if rng is not None:
        sigma = subcarrier_noise_std(band, budget, prs)
        w = rng.standard_normal((n_links, k, 2))
        out += sigma * (w[..., 0] + 1j * w[..., 1]) / math.sqrt(2.0)
    return f, out


def cfr_delay_profile(
    cfr: np.ndarray,
    band: Band | str,
    *,
    pulse: PulseShape | None = None,
    prs: PrsSettings | None = None,
    oversampling: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The receiver's delay profile ``r(t) = dF sum_k W_k Y_k exp(j 2 pi f_k t)`` over one
    unambiguous period (module docstring), by one inverse FFT per link.

    Parameters
    ----------
    cfr : (L, K) complex, from :func:`prs_cfr` (same band and PRS settings)
    band : Band or band name
    pulse : PulseShape, the window's roll-off and the default sampling (default ``PulseShape()``)
    prs : PrsSettings
    oversampling : int, samples per pulse period T (default ``pulse.oversampling``)

    Returns
    -------
    t_s : (N,) float, s, sample times ``n / (N dF)`` (spacing at most ``T / oversampling``)
    r : (L, N) complex, 1/s (a path of gain ``A`` peaks at ``|A| / T``)
    """
    band = get_band(band)
    pulse = pulse or PulseShape()
    prs = prs or PrsSettings()
    cfr = np.atleast_2d(np.asarray(cfr, dtype=complex))
    f = prs.subcarrier_hz(band)
    if cfr.shape[-1] != f.size:
        raise HallrayError(f"cfr has {cfr.shape[-1]} subcarriers, the band and comb give {f.size}")
    over = pulse.oversampling if oversampling is None else int(oversampling)
    if over < 1:
        raise HallrayError(f"oversampling must be >= 1, got {over}")
    period = prs.period_s(band)
    n = scipy.fft.next_fast_len(max(int(math.ceil(period * over / pulse.period_s(band))), f.size))
    k = np.rint(f / prs.spacing_hz(band)).astype(np.int64) % n
    spec = np.zeros((cfr.shape[0], n), dtype=complex)
    spec[:, k] = cfr * window_weights(band, pulse, prs)[None, :]
    r = scipy.fft.ifft(spec, axis=1) * (n * prs.spacing_hz(band))
    return np.arange(n) * (period / n), r
