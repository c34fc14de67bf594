"""The band-limited (pulse-shaped) response of whole links, sampled, with correlator noise
(:func:`band_limited_response`), and the reference ToA estimators on it (``peak``,
``leading-edge``: :func:`pulse_toa`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ...core.constants import db_to_linear_power
from ...core.errors import HallrayError
from ..bands import Band, get_band
from .budget import LinkBudget
from .cir import DiscreteCIR, discrete_cir
from .pulse import PulseShape, raised_cosine, raised_cosine_spectrum

#: Golden-section iterations of the sub-sample peak refinement: the bracket of 2 samples shrinks
#: by 0.618**32 ~ 2e-7 (~1e-8 T), far below any physical resolution.
_GOLDEN_ITERATIONS = 32
#: Largest number of array elements one chunk of the pulse-shaped response may hold (complex
#: samples and path taps each): bounds memory at ~64 MB however many links are estimated at once.
_CHUNK_ELEMENTS = 1 << 22


def concat_ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for each (s, c), vectorised; ``(sum counts,) int64``."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    shift = np.repeat(starts - np.cumsum(counts) + counts, counts)
    return np.arange(total, dtype=np.int64) + shift


def _noise_spectrum(
    rng: np.random.Generator,
    rows: int,
    length: int,
    dt: float,
    period: float,
    roll_off: float,
    noise_std: float,
    power: int = 1,
) -> tuple[np.ndarray, int, np.ndarray]:
    """Frequency-domain draw of correlator-output noise on ``rows`` grids of ``length`` samples.

    The noise after correlation (matched filtering) is complex Gaussian with power spectrum
    proportional to the pulse's, so its autocorrelation is the pulse itself and samples T apart
    are uncorrelated (``power = 1``). ``power = 2``: the spectrum squared, the noise of a white
    channel-frequency-response estimate weighted by the pulse's spectrum as a window
    (:mod:`raytrace.emulation.channel.cfr`). Returns the FFT bins it occupies (ascending signed
    frequency), the signed number of the first, and the ``(rows, n_bins)`` coefficients ``X``,
    scaled so that ``E|n_k|^2 = noise_std^2`` for ``n = ifft(X)`` (``n = (1/L) sum X e^{...}``).
    """
    freq = np.fft.fftfreq(length, dt)
    spec = raised_cosine_spectrum(freq, period, roll_off)
    bins = np.flatnonzero(spec > 0)
    # Signed bin numbers, ascending: a contiguous run -K..K (the spectrum is an even interval).
    signed = np.rint(freq[bins] * length * dt).astype(np.int64)
    order = np.argsort(signed)
    bins = bins[order]
    shape = (rows, bins.size)
    white = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / math.sqrt(2.0)
    if power != 1:
        spec = spec**power
    scale = noise_std * length / math.sqrt(float(spec[bins].sum()))
    return bins, int(signed[order][0]), scale * np.sqrt(spec[bins]) * white


def correlator_noise(
    rng: np.random.Generator,
    rows: int,
    width: int,
    dt: float,
    period: float,
    roll_off: float,
    noise_std: float,
    *,
    guard: int = 0,
    power: int = 1,
) -> np.ndarray:
    """Correlator-output noise on ``rows`` windows of ``width`` samples ``dt`` apart.

    Drawn on a circular grid of at least ``width + guard`` samples (an FFT) and cut to the window:
    with ``guard`` samples beyond it, the circular wrap leaves the correlation inside the window
    that of the pulse up to its value at ``guard * dt``.

    Parameters
    ----------
    rng : numpy.random.Generator
    rows, width, guard : int
    dt, period : float, seconds, sample spacing and pulse period T
    roll_off : float
    noise_std : float, per-sample standard deviation (units of the response, 1/s)
    power : int, the noise spectrum is the pulse's to this power (2: a windowed CFR's noise)

    Returns
    -------
    (rows, width) complex
    """
    length = scipy.fft.next_fast_len(int(width + guard))
    bins, _, x = _noise_spectrum(rng, rows, length, dt, period, roll_off, noise_std, power)
    full = np.zeros((rows, length), dtype=complex)
    full[:, bins] = x
    return scipy.fft.ifft(full, axis=1)[:, :width]


class _ResponseChunk:
    """Pulse-shaped response (plus optional noise) of a group of links on per-link time grids.

    Row ``r`` is link ``links[r]``; its samples are at ``t0[r] + k dt``, ``k < n_samples[r]``
    (the array is padded to a common length). The response stays evaluable at any time (for the
    sub-sample refinement): the signal from the closed-form pulse, the noise from its spectrum.
    """

    def __init__(
        self,
        cir: DiscreteCIR,
        links: np.ndarray,
        period: float,
        pulse: PulseShape,
        noise_std: float,
        rng: np.random.Generator | None,
    ) -> None:
        self.period, self.roll_off = period, pulse.roll_off
        self.half_width = pulse.span * period
        self.dt = period / pulse.oversampling
        lo, hi = cir.offsets[links], cir.offsets[links + 1]
        sel = concat_ranges(lo, hi - lo)
        self.row = np.repeat(np.arange(links.size), hi - lo)
        self.tau, self.amp = cir.delay_s[sel], cir.gain[sel]
        self.t0 = cir.delay_s[lo] - self.half_width
        t_end = cir.delay_s[hi - 1] + self.half_width
        self.n_samples = np.floor((t_end - self.t0) / self.dt).astype(np.int64) + 2
        self.length = scipy.fft.next_fast_len(int(self.n_samples.max()))
        self.samples = self._grid_signal(links.size, pulse)
        self.noise_x = None
        if rng is not None:
            self._add_noise(rng, noise_std)

    def _grid_signal(self, n_rows: int, pulse: PulseShape) -> np.ndarray:
        n_tap = 2 * pulse.span * pulse.oversampling + 2
        k_lo = np.ceil((self.tau - self.half_width - self.t0[self.row]) / self.dt).astype(np.int64)
        k = k_lo[:, None] + np.arange(n_tap)[None, :]
        lag = self.t0[self.row][:, None] + k * self.dt - self.tau[:, None]
        val = self.amp[:, None] * raised_cosine(lag, self.period, self.roll_off)
        keep = (np.abs(lag) <= self.half_width) & (k >= 0) & (k < self.length)
        flat = (self.row[:, None] * self.length + k)[keep]
        size = n_rows * self.length
        re = np.bincount(flat, weights=val.real[keep], minlength=size)
        im = np.bincount(flat, weights=val.imag[keep], minlength=size)
        return (re + 1j * im).reshape(n_rows, self.length)

    def _add_noise(self, rng: np.random.Generator, noise_std: float) -> None:
        self.noise_bins, self.noise_k0, self.noise_x = _noise_spectrum(
            rng, self.samples.shape[0], self.length, self.dt, self.period, self.roll_off, noise_std
        )
        full = np.zeros(self.samples.shape, dtype=complex)
        full[:, self.noise_bins] = self.noise_x
        self.samples = self.samples + np.fft.ifft(full, axis=1)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Response of each row at one time per row, ``t (n_rows,)`` s -> ``(n_rows,) complex``."""
        lag = t[self.row] - self.tau
        val = np.where(
            np.abs(lag) <= self.half_width,
            self.amp * raised_cosine(lag, self.period, self.roll_off),
            0,
        )
        n = t.size
        out = np.bincount(self.row, weights=val.real, minlength=n) + 1j * np.bincount(
            self.row, weights=val.imag, minlength=n
        )
        if self.noise_x is not None:
            # n(t) = (1/L) sum_k X_k z^k, z = exp(j 2 pi (t - t0) / (L dt)), k = k0, k0 + 1, ...:
            # powers by a running product instead of one complex exponential per bin.
            theta = 2.0 * np.pi * (t - self.t0) / (self.length * self.dt)
            powers = np.empty(self.noise_x.shape, dtype=complex)
            powers[:, 0] = np.exp(1j * theta * self.noise_k0)
            powers[:, 1:] = np.exp(1j * theta)[:, None]
            np.cumprod(powers, axis=1, out=powers)
            out = out + (self.noise_x * powers).sum(axis=1) / self.length
        return out

    def valid(self) -> np.ndarray:
        """``(n_rows, length) bool``: sample inside the row's own window."""
        return np.arange(self.length)[None, :] < self.n_samples[:, None]

    def refine_peak(self, k: np.ndarray) -> np.ndarray:
        """Time of the maximum of ``|r(t)|`` within one sample of grid index ``k`` (per row), s.

        Golden-section search on the continuous (exactly band-limited) response: equivalent to
        ideal sinc interpolation of the samples, without the bias of a parabola fit.
        """
        g = (math.sqrt(5.0) - 1.0) / 2.0
        centre = self.t0 + k * self.dt
        a, b = centre - self.dt, centre + self.dt
        c, d = b - g * (b - a), a + g * (b - a)
        fc, fd = np.abs(self.evaluate(c)), np.abs(self.evaluate(d))
        for _ in range(_GOLDEN_ITERATIONS):
            left = fc >= fd  # maximum in [a, d]
            a, b = np.where(left, a, c), np.where(left, d, b)
            x = np.where(left, b - g * (b - a), a + g * (b - a))
            fx = np.abs(self.evaluate(x))
            c, d, fc, fd = (
                np.where(left, x, d),
                np.where(left, c, x),
                np.where(left, fx, fd),
                np.where(left, fc, fx),
            )
        return 0.5 * (a + b)


def _link_chunks(cir: DiscreteCIR, links: np.ndarray, pulse: PulseShape, period: float):
    """Split ``links`` into groups whose response arrays stay within ``_CHUNK_ELEMENTS``."""
    if links.size == 0:
        return
    counts = cir.offsets[links + 1] - cir.offsets[links]
    span = cir.delay_s[cir.offsets[links + 1] - 1] - cir.delay_s[cir.offsets[links]]
    n_samp = (span + 2 * pulse.span * period) / (period / pulse.oversampling) + 2
    taps = counts * (2 * pulse.span * pulse.oversampling + 2)
    start, rows, longest, n_taps = 0, 0, 0.0, 0
    for i in range(links.size):  # cheap: scalar bookkeeping only
        longest_i, taps_i = max(longest, n_samp[i]), n_taps + taps[i]
        if rows and ((rows + 1) * longest_i > _CHUNK_ELEMENTS or taps_i > _CHUNK_ELEMENTS):
            yield links[start:i]
            start, rows, longest_i, taps_i = i, 0, n_samp[i], taps[i]
        rows, longest, n_taps = rows + 1, longest_i, taps_i
    yield links[start:]


@dataclass(frozen=True)
class SampledResponse:
    """Pulse-shaped responses on per-link time grids.

    Attributes
    ----------
    links : (M,) int64
        Link of each row.
    t0_s : (M,) float, seconds
        Time of sample 0 of each row (its earliest path minus ``span T``).
    dt_s : float, seconds
        Sample spacing ``T / oversampling``.
    n_samples : (M,) int64
        Samples of each row inside its window (rows are zero-padded to a common length).
    samples : (M, N) complex, 1/s
        ``sum_j A_j h(t - tau_j)`` (eq. 1 with eq. 2 as the pulse), plus noise if requested.
    period_s : float, seconds
        Pulse symbol period T.
    """

    links: np.ndarray
    t0_s: np.ndarray
    dt_s: float
    n_samples: np.ndarray
    samples: np.ndarray
    period_s: float

    def times(self, row: int) -> np.ndarray:
        """Sample times of one row, s."""
        return self.t0_s[row] + self.dt_s * np.arange(int(self.n_samples[row]))


def band_limited_response(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    band: Band | str,
    *,
    links: np.ndarray | None = None,
    pulse: PulseShape | None = None,
    budget: LinkBudget | None = None,
    rng: np.random.Generator | None = None,
) -> SampledResponse:
    """Channel impulse response convolved with the raised-cosine pulse of eq. 2, sampled.

    For link ``l``: ``r_l(t) = sum_j A_j h(t - tau_j) [+ n(t)]`` on ``t0 + k T/oversampling`` over
    a window from ``span T`` before the first path to ``span T`` after the last (not the whole
    transmission period), vectorised over paths x pulse taps.

    Noise (only when ``rng`` is given) is the correlator-output noise of ``budget``: complex
    Gaussian, band-limited with the pulse's spectrum, per-sample standard deviation
    :meth:`LinkBudget.correlator_noise_std`, so that a path's peak-to-noise ratio is its
    post-correlation SNR ``SNR_path t_s B``.

    Parameters
    ----------
    link, delay_s, gain, n_links
        Path arrays (see module docstring).
    band : Band or str
        Sets T = (1 + beta) / B.
    links : (M,) int, optional
        Links to evaluate (default every link with at least one path). Links without paths are
        rejected.
    pulse : PulseShape, optional
    budget : LinkBudget, optional
        Only used for the noise level.
    rng : numpy.random.Generator, optional
        Noise source; None gives the noiseless response.
    """
    band = get_band(band)
    cir = discrete_cir(link, delay_s, gain, n_links)
    pulse = pulse or PulseShape()
    budget = budget or LinkBudget()
    has_paths = cir.offsets[1:] > cir.offsets[:-1]
    if links is None:
        links = np.flatnonzero(has_paths)
    links = np.asarray(links, dtype=np.int64).reshape(-1)
    if links.size and (links.min() < 0 or links.max() >= n_links or not has_paths[links].all()):
        raise HallrayError("band_limited_response: links must be indices of links that have paths")
    period = pulse.period_s(band)
    if links.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return SampledResponse(empty, np.zeros(0), period / pulse.oversampling, empty,
                               np.zeros((0, 0), dtype=complex), period)  # fmt: skip
    chunk = _ResponseChunk(cir, links, period, pulse, budget.correlator_noise_std(band, pulse), rng)
    return SampledResponse(links, chunk.t0, chunk.dt, chunk.n_samples, chunk.samples, period)


def pulse_toa(
    cir: DiscreteCIR,
    links: np.ndarray,
    band: Band,
    pulse: PulseShape,
    budget: LinkBudget,
    rng: np.random.Generator | None,
    method: str,
    leading_edge_db: float,
) -> tuple[np.ndarray, np.ndarray]:
    """ToA of ``links`` by ``peak`` or ``leading-edge`` on their whole pulse-shaped response.

    ``peak``: time of the maximum of ``|r(t)|``; ``leading-edge``: first sample at or above
    ``max(peak * 10**(leading_edge_db/20), noise threshold)``, then the top of its lobe; both
    refined between samples (golden section on the continuous response). The noise threshold is
    ``sqrt(-ln P_fa)`` times the correlator noise std (the noise power known).

    Returns
    -------
    toa_s : (M,) float, seconds, NaN where ``|r|`` never reaches the noise threshold
    found : (M,) bool
    """
    period = pulse.period_s(band)
    noise_std = budget.correlator_noise_std(band, pulse)
    # Noise-only threshold: |n|^2 exceeds gamma sigma^2 with probability P_fa per sample.
    floor = noise_std * math.sqrt(float(db_to_linear_power(budget.detector_threshold_db)))
    toa = np.full(links.size, np.nan)
    pos = 0
    for group in _link_chunks(cir, links, pulse, period):
        ch = _ResponseChunk(cir, group, period, pulse, noise_std, rng)
        amp = np.where(ch.valid(), np.abs(ch.samples), -1.0)
        peak_k = np.argmax(amp, axis=1)
        peak = amp[np.arange(group.size), peak_k]
        found = peak >= floor
        if method == "peak":
            k = peak_k
        else:
            thr = np.maximum(peak * float(10.0 ** (leading_edge_db / 20.0)), floor)
            above = amp >= thr[:, None]
            cross = np.argmax(above, axis=1)
            # Climb from the crossing to the top of its lobe: first sample not below the next one.
            idx = np.arange(ch.length)[None, :]
            top = np.empty_like(amp, dtype=bool)
            top[:, :-1] = amp[:, 1:] < amp[:, :-1]
            top[:, -1] = True
            k = np.argmax(top & (idx >= cross[:, None]), axis=1)
        t = ch.refine_peak(k)
        toa[pos : pos + group.size] = np.where(found, t, np.nan)
        pos += group.size
    return toa, np.isfinite(toa)
