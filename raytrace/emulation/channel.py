"""Link budget, channel impulse response, raised-cosine pulse and the pulse-shaped response (eqs. 1-3).

Everything here works on plain path arrays (the fields of :class:`raytrace.solver.paths.Paths`, without
importing it): for P paths, ``link (P,) int`` in ``[0, n_links)``, ``delay_s (P,) float`` seconds
and ``gain (P,) complex`` (field amplitude relative to the transmitted one, between isotropic
antennas).

Model, in one paragraph (details and reasons in ``docs/channel.md``):

* The received PRS of one link is eq. 1, ``r(t) = sum_j A_j s(t - tau_j) + n``. After correlation
  with the known PRS over its duration ``t_s`` the receiver sees the channel impulse response
  convolved with a band-limited pulse, taken as the raised cosine of eq. 2 with roll-off
  ``beta = 0.25`` and symbol period ``T = (1 + beta) / B`` so that the pulse spectrum fills exactly
  the channel bandwidth B.
* Noise is thermal, ``N = k T0 B F`` (T0 = 290 K, noise figure F = 9 dB). A path's SNR is
  ``P_tx G_t G_r |gain|^2 / N``. Correlating over ``t_s`` gains ``t_s B`` (= number of subcarriers
  for one OFDM symbol, 35.2 dB); a path is *detectable* when ``SNR t_s B`` reaches the SNR a
  square-law detector needs for ``P_d = 0.9`` at ``P_fa = 1e-6`` (13.2 dB).
* The response of whole links, sampled (:func:`band_limited_response`) and with correlator noise,
  serves the reference estimators ``peak`` and ``leading-edge`` (:func:`pulse_toa`); the ToA
  estimators themselves, the default first-lobe receiver among them, are in
  :mod:`raytrace.emulation.receivers`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft
from scipy.optimize import brentq
from scipy.stats import ncx2

from ..core.constants import K_BOLTZMANN, db_to_linear_power, linear_power_to_db, watt_to_dbm
from ..core.errors import HallrayError
from .bands import Band, get_band

__all__ = [
    "DEFAULT_ROLL_OFF",
    "DiscreteCIR",
    "LinkBudget",
    "PulseShape",
    "SampledResponse",
    "band_limited_response",
    "check_paths",
    "concat_ranges",
    "correlator_noise",
    "detection_snr_db",
    "discrete_cir",
    "first_detectable_path",
    "pulse_toa",
    "raised_cosine",
    "raised_cosine_spectrum",
    "thermal_noise_power_w",
    "toa_std_eq3_s",
]

#: Default raised-cosine roll-off (see :class:`PulseShape`).
DEFAULT_ROLL_OFF = 0.25
#: Golden-section iterations of the sub-sample peak refinement: the bracket of 2 samples shrinks
#: by 0.618**32 ~ 2e-7 (~1e-8 T), far below any physical resolution.
_GOLDEN_ITERATIONS = 32
#: Largest number of array elements one chunk of the pulse-shaped response may hold (complex
#: samples and path taps each): bounds memory at ~64 MB however many links are estimated at once.
_CHUNK_ELEMENTS = 1 << 22


# --------------------------------------------------------------------------------------------
# Noise and link budget
# --------------------------------------------------------------------------------------------


def thermal_noise_power_w(bandwidth_hz: float, temperature_k: float = 290.0) -> float:
    """Thermal noise power ``k T B``, W (``-174 dBm/Hz`` at 290 K; ``-93.98 dBm`` over 100 MHz).

    Parameters
    ----------
    bandwidth_hz : float, Hz
        Noise bandwidth.
    temperature_k : float, K
        Noise temperature; 290 K is the IEEE/ITU reference temperature T0 of noise figures.
    """
    return float(K_BOLTZMANN * temperature_k * bandwidth_hz)


def _check_probability(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and 0.0 < value < 1.0):
        raise HallrayError(f"{name} must be strictly between 0 and 1, got {value!r}")


@lru_cache(maxsize=64)
def detection_snr_db(false_alarm_probability: float, detection_probability: float) -> float:
    """SNR a square-law detector needs on one complex sample, dB (non-fluctuating signal).

    One complex sample ``x = s + w`` with ``w ~ CN(0, 1)`` is compared with a threshold
    ``|x|^2 > gamma``: ``P_fa = exp(-gamma)`` and ``P_d = Q_1(sqrt(2 snr), sqrt(2 gamma))``, the
    Marcum Q function, i.e. the survival function of a noncentral chi-square with 2 degrees of
    freedom and noncentrality ``2 snr`` at ``2 gamma`` (Richards, *Fundamentals of Radar Signal
    Processing*, 2nd ed., sec. 6.2; Albersheim's approximation agrees within 0.2 dB).
    ``P_fa = 1e-6, P_d = 0.9`` gives 13.18 dB.

    Parameters
    ----------
    false_alarm_probability : float
        Probability that noise alone crosses the threshold in one delay bin.
    detection_probability : float
        Required probability that the signal crosses it; must exceed the false-alarm probability.
    """
    _check_probability("false_alarm_probability", false_alarm_probability)
    _check_probability("detection_probability", detection_probability)
    if detection_probability <= false_alarm_probability:
        raise HallrayError("detection_probability must exceed false_alarm_probability")
    gamma = -math.log(false_alarm_probability)

    def excess(snr: float) -> float:
        return float(ncx2.sf(2.0 * gamma, 2, 2.0 * snr)) - detection_probability

    hi = gamma + 1.0
    while excess(hi) < 0.0:  # P_d increases with SNR; reach a bracket
        hi *= 2.0
    return float(linear_power_to_db(brentq(excess, 0.0, hi, xtol=1e-12, rtol=1e-12)))


@dataclass(frozen=True)
class LinkBudget:
    """Transmit power, antennas, receiver noise and the detection rule.

    Parameters
    ----------
    tx_power_dbm : float, dBm
        Transmit power over the whole band; 20 dBm is the paper's Table I.
    tx_antenna_gain_dbi, rx_antenna_gain_dbi : float, dBi
        Antenna gains; 0 dBi = the paper's omnidirectional (isotropic) antennas. Path gains from the
        tracer are between isotropic antennas, so these simply scale every path.
    noise_figure_db : float, dB
        Receiver noise figure; 9 dB is the UE noise figure of 3GPP system-level evaluations
        (TR 38.901 sec. 7.8 calibration parameters, and the NR positioning studies TR 38.855 /
        TR 38.857 that use it; gNB 5 dB). The device is the receiver in DL-TDoA.
    temperature_k : float, K
        Noise reference temperature (290 K, the temperature noise figures are defined at).
    n_symbols : int
        OFDM symbols' worth of PRS energy the receiver correlates coherently, so the signal duration
        of eq. 3 is ``t_s = n_symbols / subcarrier_spacing`` and the processing gain ``t_s B``.
        1 is the smallest NR PRS that covers all subcarriers (comb-K over K symbols) without
        repetition: processing gain B / spacing = 3333 (35.2 dB) for both bands.
    false_alarm_probability, detection_probability : float
        Detector operating point: ``P_fa`` per delay bin and the ``P_d`` a path must reach to count
        as detectable. 1e-6 / 0.9 give a required post-correlation SNR of 13.18 dB
        (:func:`detection_snr_db`); with ~1e3 delay bins searched per PRS, about one false alarm
        per thousand searches.
    detection_threshold_db : float or None, dB
        Overrides the required post-correlation SNR (``SNR t_s B``) derived from the two
        probabilities.
    dynamic_range_db : float or None, dB
        If set, a path more than this below the strongest path of its link is also undetectable
        (receiver dynamic range, masking by the strong path's sidelobes and channel-estimation
        leakage). None (default) follows the paper: any path above the noise threshold counts.
    """

    tx_power_dbm: float = 20.0
    tx_antenna_gain_dbi: float = 0.0
    rx_antenna_gain_dbi: float = 0.0
    noise_figure_db: float = 9.0
    temperature_k: float = 290.0
    n_symbols: int = 1
    false_alarm_probability: float = 1e-6
    detection_probability: float = 0.9
    detection_threshold_db: float | None = None
    dynamic_range_db: float | None = None

    def __post_init__(self) -> None:
        for name in (
            "tx_power_dbm",
            "tx_antenna_gain_dbi",
            "rx_antenna_gain_dbi",
            "noise_figure_db",
        ):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise HallrayError(f"link budget: {name} must be a finite number, got {value!r}")
        if self.noise_figure_db < 0:
            raise HallrayError(
                f"link budget: noise_figure_db must be >= 0, got {self.noise_figure_db}"
            )
        if not (isinstance(self.temperature_k, (int, float)) and self.temperature_k > 0):
            raise HallrayError(
                f"link budget: temperature_k must be > 0, got {self.temperature_k!r}"
            )
        if (
            isinstance(self.n_symbols, bool)
            or not isinstance(self.n_symbols, int)
            or self.n_symbols < 1
        ):
            raise HallrayError(
                f"link budget: n_symbols must be an integer >= 1, got {self.n_symbols!r}"
            )
        _check_probability("link budget: false_alarm_probability", self.false_alarm_probability)
        _check_probability("link budget: detection_probability", self.detection_probability)
        if self.detection_probability <= self.false_alarm_probability:
            raise HallrayError(
                "link budget: detection_probability must exceed false_alarm_probability"
            )
        for name in ("detection_threshold_db", "dynamic_range_db"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise HallrayError(f"link budget: {name} must be a finite number or None")
        if self.dynamic_range_db is not None and self.dynamic_range_db <= 0:
            raise HallrayError("link budget: dynamic_range_db must be > 0")

    # -- noise -----------------------------------------------------------------------------
    def noise_power_w(self, band: Band) -> float:
        """Receiver noise power ``k T B F`` over the band, W."""
        return thermal_noise_power_w(band.bandwidth_hz, self.temperature_k) * float(
            db_to_linear_power(self.noise_figure_db)
        )

    def noise_power_dbm(self, band: Band) -> float:
        """Receiver noise power over the band, dBm (-84.98 dBm for C-band with NF 9 dB)."""
        return float(watt_to_dbm(self.noise_power_w(band)))

    def integration_time_s(self, band: Band) -> float:
        """Signal duration ``t_s`` of eq. 3: ``n_symbols`` useful OFDM symbols, s."""
        return self.n_symbols / band.subcarrier_spacing_hz

    def processing_gain(self, band: Band) -> float:
        """Correlation gain ``t_s B`` (linear; 3333.3 = 35.2 dB for one symbol of either band)."""
        return self.integration_time_s(band) * band.bandwidth_hz

    @property
    def required_snr_db(self) -> float:
        """Post-correlation SNR (``SNR t_s B``) a path needs to be detectable, dB."""
        if self.detection_threshold_db is not None:
            return float(self.detection_threshold_db)
        return detection_snr_db(self.false_alarm_probability, self.detection_probability)

    @property
    def detector_threshold_db(self) -> float:
        """``|r|^2`` threshold over the noise variance giving ``P_fa`` per sample: -ln P_fa, dB."""
        return float(linear_power_to_db(-math.log(self.false_alarm_probability)))

    def correlator_noise_std(self, band: Band, pulse: PulseShape) -> float:
        """Std of the complex noise on the pulse-shaped response, in the units of eq. 2 (1/s).

        A path of gain ``a`` peaks at ``|a| / T``; dividing by this std gives its post-correlation
        SNR ``SNR_path t_s B``. It does not depend on the oversampling: the noise is band-limited
        with the pulse's own spectrum (see :func:`band_limited_response`).
        """
        tx = float(
            db_to_linear_power(
                self.tx_power_dbm + self.tx_antenna_gain_dbi + self.rx_antenna_gain_dbi
            )
        )
        unit_snr = 1e-3 * tx / self.noise_power_w(band)  # SNR of a path with |gain| = 1
        return 1.0 / (pulse.period_s(band) * math.sqrt(unit_snr * self.processing_gain(band)))

    # -- paths -----------------------------------------------------------------------------
    def received_power_w(self, gain: np.ndarray) -> np.ndarray:
        """Received power of each path, ``P_tx G_t G_r |gain|^2``, W; ``(P,) float``."""
        eirp_dbm = self.tx_power_dbm + self.tx_antenna_gain_dbi + self.rx_antenna_gain_dbi
        return 1e-3 * float(db_to_linear_power(eirp_dbm)) * np.abs(np.asarray(gain)) ** 2

    def path_snr(self, gain: np.ndarray, band: Band) -> np.ndarray:
        """Per-path SNR before processing gain, ``P_tx G_t G_r |gain|^2 / N``; ``(P,) float``."""
        return self.received_power_w(gain) / self.noise_power_w(band)

    def path_snr_db(self, gain: np.ndarray, band: Band) -> np.ndarray:
        """Per-path SNR before processing gain, dB (``-inf`` for a zero gain), ``(P,) float``."""
        return np.asarray(linear_power_to_db(self.path_snr(gain, band)), dtype=float)

    def detectable(
        self,
        gain: np.ndarray,
        band: Band,
        link: np.ndarray | None = None,
        n_links: int | None = None,
    ) -> np.ndarray:
        """Which paths a PRS receiver detects, ``(P,) bool``.

        A path is detectable when ``SNR_path t_s B >= required_snr_db`` and, if
        ``dynamic_range_db`` is set, its power is within that of the strongest path of its link
        (which needs ``link`` and ``n_links``).
        """
        snr = self.path_snr(gain, band)
        with np.errstate(divide="ignore"):
            post_db = linear_power_to_db(snr * self.processing_gain(band))
        ok = np.asarray(post_db >= self.required_snr_db - 1e-12)
        if self.dynamic_range_db is not None:
            if link is None or n_links is None:
                raise HallrayError("link budget: dynamic_range_db needs link and n_links")
            link = np.asarray(link, dtype=np.int64)
            strongest = np.zeros(int(n_links))
            np.maximum.at(strongest, link, snr)
            ok &= snr * float(db_to_linear_power(self.dynamic_range_db)) >= strongest[link]
        return ok


def toa_std_eq3_s(
    snr: np.ndarray | float, bandwidth_hz: float, signal_duration_s: float
) -> np.ndarray:
    """ToA standard deviation of the paper's eq. 3, seconds.

    ``sigma^2 = c^2 / ((2 pi B)^2 t_s B SNR)`` is in m^2; divided by ``c^2`` it is
    ``1 / ((2 pi B)^2 t_s B SNR)`` in s^2.

    Parameters
    ----------
    snr : (...) float
        Linear SNR before processing gain (``P / (N0 B)``); ``inf`` gives 0, 0 gives ``inf``.
    bandwidth_hz : float, Hz
        Signal bandwidth B.
    signal_duration_s : float, s
        Signal duration ``t_s`` (see :meth:`LinkBudget.integration_time_s`).
    """
    snr = np.asarray(snr, dtype=float)
    with np.errstate(divide="ignore"):
        var = 1.0 / ((2.0 * np.pi * bandwidth_hz) ** 2 * signal_duration_s * bandwidth_hz * snr)
    return np.sqrt(var)


# --------------------------------------------------------------------------------------------
# Raised-cosine pulse, eq. 2
# --------------------------------------------------------------------------------------------


def raised_cosine(t: np.ndarray | float, period_s: float, roll_off: float) -> np.ndarray:
    """Raised-cosine pulse of eq. 2: ``(1/T) sinc(t/T) cos(pi beta t/T) / (1 - (2 beta t/T)^2)``.

    The factor ``cos(pi u / 2) / (1 - u^2)`` with ``u = 2 beta t / T`` is evaluated as
    ``sin(pi e / 2) / (e (2 - e))`` with ``e = 1 - |u|``, the same function written without the
    cancellation near ``|u| = 1``; at ``t = +-T/(2 beta)`` exactly it takes its limit ``pi/4``, so
    ``h = (pi / (4 T)) sinc(1 / (2 beta))`` there.

    Parameters
    ----------
    t : (...) float, seconds
        Times.
    period_s : float, s
        Symbol period T (zero crossings at ``t = k T``, ``k != 0``).
    roll_off : float
        beta in [0, 1]; 0 is the sinc pulse.

    Returns
    -------
    (...) float, 1/s
        ``h(0) = 1/T``; the pulse integrates to 1 (its spectrum is 1 at f = 0).
    """
    x = np.asarray(t, dtype=float) / period_s
    out = np.sinc(x) / period_s
    if roll_off == 0.0:
        return out
    e = 1.0 - np.abs(2.0 * roll_off * x)
    denom = e * (2.0 - e)
    factor = np.divide(np.sin(0.5 * np.pi * e), denom, out=np.full_like(e, np.pi / 4), where=e != 0)
    return out * factor


def raised_cosine_spectrum(f: np.ndarray | float, period_s: float, roll_off: float) -> np.ndarray:
    """Fourier transform of :func:`raised_cosine` (dimensionless, 1 in the flat band).

    1 for ``|f| <= (1 - beta)/(2T)``, ``(1 + cos(pi T/beta (|f| - (1 - beta)/(2T)))) / 2`` up to
    ``(1 + beta)/(2T)``, 0 beyond.
    """
    f = np.abs(np.asarray(f, dtype=float))
    f1 = (1.0 - roll_off) / (2.0 * period_s)
    f2 = (1.0 + roll_off) / (2.0 * period_s)
    out = np.where(f <= f1, 1.0, 0.0)
    if roll_off > 0.0:
        taper = (f > f1) & (f <= f2)
        out = np.where(taper, 0.5 * (1.0 + np.cos(np.pi * period_s / roll_off * (f - f1))), out)
    return out


@dataclass(frozen=True)
class PulseShape:
    """Raised-cosine pulse settings and its sampling.

    Parameters
    ----------
    roll_off : float
        beta of eq. 2, default 0.25. The symbol period is ``T = (1 + beta) / B``, so that the
        pulse spectrum (two-sided width ``(1 + beta) / T``) fills exactly the channel bandwidth B:
        flat over the central ``(1 - beta)/(1 + beta)`` = 60 %, cosine taper to the band edges.
        0.25 keeps the main lobe narrow (first zeros at +-T = +-1.25/B, 12.5 ns at 100 MHz) with
        sidelobes at -14.3 dB (sinc: -13.3 dB; 0.5 would give -17.5 dB and a 20 % wider main
        lobe).
    oversampling : int
        Samples per T of the evaluated response (default 8: the grid maximum is within
        ``T/16`` of the true peak before the sub-sample refinement).
    span : int
        The pulse is evaluated within ``+-span T`` of each path (default 16: the tail beyond is
        below ``1 / (pi span (4 beta^2 span^2 - 1))`` ~ 3e-4 of the peak, -70 dB).
    """

    roll_off: float = DEFAULT_ROLL_OFF
    oversampling: int = 8
    span: int = 16

    def __post_init__(self) -> None:
        if not (isinstance(self.roll_off, (int, float)) and 0.0 <= self.roll_off <= 1.0):
            raise HallrayError(f"pulse roll_off must be in [0, 1], got {self.roll_off!r}")
        for name, lo in (("oversampling", 2), ("span", 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise HallrayError(f"pulse {name} must be an integer >= {lo}, got {value!r}")

    def period_s(self, band: Band) -> float:
        """Symbol period ``T = (1 + beta) / B`` of eq. 2, s."""
        return (1.0 + self.roll_off) / band.bandwidth_hz

    def sample_period_s(self, band: Band) -> float:
        """Spacing of the evaluated response, ``T / oversampling``, s."""
        return self.period_s(band) / self.oversampling


# --------------------------------------------------------------------------------------------
# Path arrays -> per-link structure
# --------------------------------------------------------------------------------------------


def check_paths(
    link: np.ndarray, delay_s: np.ndarray, gain: np.ndarray, n_links: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    link = np.asarray(link)
    delay_s = np.asarray(delay_s, dtype=float)
    gain = np.asarray(gain, dtype=complex)
    if isinstance(n_links, bool) or not isinstance(n_links, (int, np.integer)) or n_links < 0:
        raise HallrayError(f"n_links must be a non-negative integer, got {n_links!r}")
    if link.ndim != 1 or delay_s.shape != link.shape or gain.shape != link.shape:
        raise HallrayError(
            f"link, delay_s and gain must be 1-D of equal length, got shapes "
            f"{link.shape}, {delay_s.shape}, {gain.shape}"
        )
    if link.size and link.dtype.kind not in "iu":
        raise HallrayError(f"link must be an integer array, got dtype {link.dtype}")
    link = link.astype(np.int64)
    if link.size and (link.min() < 0 or link.max() >= n_links):
        raise HallrayError(
            f"link indices must be in [0, {n_links}), got {link.min()}..{link.max()}"
        )
    if not np.all(np.isfinite(delay_s)):
        raise HallrayError("delay_s contains NaN or infinite values")
    if not np.all(np.isfinite(gain)):
        raise HallrayError("gain contains NaN or infinite values")
    return link, delay_s, gain, int(n_links)


@dataclass(frozen=True)
class DiscreteCIR:
    """Discrete channel impulse responses of all links, paths sorted by (link, delay).

    Attributes
    ----------
    offsets : (n_links + 1,) int64
        Paths of link ``l`` are ``[offsets[l], offsets[l + 1])`` of the arrays below.
    path_index : (P,) int64
        Index of each sorted entry in the caller's path arrays.
    delay_s : (P,) float, seconds
    gain : (P,) complex
        Complex amplitude (field relative to transmitted), as given.
    """

    offsets: np.ndarray
    path_index: np.ndarray
    delay_s: np.ndarray
    gain: np.ndarray

    @property
    def n_links(self) -> int:
        return int(self.offsets.size - 1)

    def link(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Delays (s) and complex amplitudes of one link, in order of arrival."""
        lo, hi = int(self.offsets[index]), int(self.offsets[index + 1])
        return self.delay_s[lo:hi], self.gain[lo:hi]


def discrete_cir(
    link: np.ndarray, delay_s: np.ndarray, gain: np.ndarray, n_links: int
) -> DiscreteCIR:
    """Group paths per link in order of arrival: ``h_l(t) = sum_j A_j delta(t - tau_j)`` (eq. 1).

    Parameters
    ----------
    link : (P,) int
        Link index of each path, in ``[0, n_links)``.
    delay_s : (P,) float, seconds
    gain : (P,) complex
    n_links : int

    Ties in delay keep the callers' order.
    """
    link, delay_s, gain, n_links = check_paths(link, delay_s, gain, n_links)
    order = np.lexsort((np.arange(link.size), delay_s, link))
    offsets = np.searchsorted(link[order], np.arange(n_links + 1), side="left").astype(np.int64)
    return DiscreteCIR(offsets, order.astype(np.int64), delay_s[order], gain[order])


def first_detectable_path(
    link: np.ndarray, delay_s: np.ndarray, detectable: np.ndarray, n_links: int
) -> np.ndarray:
    """Index of the earliest detectable path of each link, ``(n_links,) int64``, -1 if none.

    An undetectable path is never the first arrival, however early it is. Ties in delay go to the
    lower path index.
    """
    link = np.asarray(link, dtype=np.int64)
    detectable = np.asarray(detectable, dtype=bool)
    out = np.full(int(n_links), -1, dtype=np.int64)
    idx = np.flatnonzero(detectable)
    if idx.size == 0:
        return out
    order = idx[np.lexsort((idx, np.asarray(delay_s)[idx], link[idx]))]
    lk = link[order]
    first = np.ones(order.size, dtype=bool)
    first[1:] = lk[1:] != lk[:-1]
    out[lk[first]] = order[first]
    return out


# --------------------------------------------------------------------------------------------
# Band-limited (pulse-shaped) response
# --------------------------------------------------------------------------------------------


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
) -> tuple[np.ndarray, int, np.ndarray]:
    """Frequency-domain draw of correlator-output noise on ``rows`` grids of ``length`` samples.

    The noise after correlation (matched filtering) is complex Gaussian with power spectrum
    proportional to the pulse's, so its autocorrelation is the pulse itself and samples T apart
    are uncorrelated. Returns the FFT bins it occupies (ascending signed frequency), the signed
    number of the first, and the ``(rows, n_bins)`` coefficients ``X``, scaled so that
    ``E|n_k|^2 = noise_std^2`` for ``n = ifft(X)`` (``n = (1/L) sum X e^{...}``).
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

    Returns
    -------
    (rows, width) complex
    """
    length = scipy.fft.next_fast_len(int(width + guard))
    bins, _, x = _noise_spectrum(rng, rows, length, dt, period, roll_off, noise_std)
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
