"""Noise and link budget: thermal noise, the SNR a square-law detector needs, the
:class:`LinkBudget` of a link (SNR per path, detectability, correlator noise) and the ToA
standard deviation of eq. 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq
from scipy.stats import ncx2

from ...core.constants import K_BOLTZMANN, db_to_linear_power, linear_power_to_db, watt_to_dbm
from ...core.errors import HallrayError
from ..bands import Band
from .pulse import PulseShape


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
