"""Per-measurement error model of a band-limited ToA: noise core, overlap spread, NLoS excess.

Used by the ``nlos-map`` estimator (:mod:`positioning.estimators.nlos`) and the integrity figures
(:mod:`positioning.evaluation.integrity`). Every constant is derived from the receiver physics
(``docs/channel.md``) or from the measured spread of line-of-sight range errors; see
``docs/positioning.md`` ("nlos-map").

Range error of measurement n (metres), a mixture of three causes::

    e_n = noise                              share 1 - p_wide - p_late   N(0, sigma_n^2)
        | noise + overlap shift               share p_wide                N(0, sigma_n^2 + s_w^2)
        | noise + NLoS excess x, x >= 0       share p_late                x ~ Exp(mean LATE_MEAN_M)

* ``sigma_n^2 = sigma_crlb^2 + sigma_floor^2``: the Cramér-Rao bound of the raised-cosine pulse
  at the link's SNR, ``c^2 / (8 pi^2 f_rms^2 SNR t_s B)`` with ``f_rms = 0.235 B`` and
  ``t_s B = B / delta_f`` (the processing gain), plus a floor (:data:`FLOOR_FIRST_LOBE` ``c/B``).
* ``s_w = WIDE_PULSES * 1.25 c / B``: paths within a pulse width shift the lobe top either way by
  up to about a pulse width (a doublet in opposite phase leaves a lobe 0.9 pulse widths early).
* the shares from what the receiver reports (SNR against the free-space SNR at the candidate
  position, the lobe's width and its level under the strongest peak).
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

from .problem import LinkInfo
from .tdoa import C0

#: Noise floor of a first-lobe (band-limited) ToA in units of the range resolution c/B: the
#: measured spread of LoS range errors whose lobe is a lone pulse (lobe_width 0.95-1.05) is
#: sigma 0.18 m at 100 MHz (0.060 c/B) and 0.045 m at 400 MHz (0.060 c/B) on the bundled hall
#: (p10-p90 over 2.56 sigma; docs/positioning.md).
FLOOR_FIRST_LOBE = 0.06
#: Noise floor of the ideal first-path receiver (eq. 3 noise only), in units of c/B: a small
#: guard against a vanishing scale at high SNR.
FLOOR_IDEAL = 0.005
#: Floor in metres when the bandwidth is unknown.
FLOOR_UNKNOWN_M = 0.1
#: RMS bandwidth of the paper's raised cosine (roll-off 0.25) in units of B.
F_RMS_PER_B = 0.235
#: Spread of the overlap shift in pulse widths (1.25 c/B).
WIDE_PULSES = 0.6
#: Mean NLoS excess (m): a prior of the hall's scale (a detour around a 2-4 m obstacle or via a
#: wall 5-10 m away adds metres), not fitted.
LATE_MEAN_M = 5.0
#: Prior shares of a late (NLoS or overlap) and of a two-sided (overlap) error with no report.
P_LATE0 = 0.1
P_WIDE0 = 0.05
#: Shares far below free space (deficit >> DEFICIT_DB): the link is almost surely blocked, and
#: the noise core keeps only 1 - 0.75 - 0.2 = 5 %.
P_LATE_BLOCKED = 0.75
P_WIDE_BLOCKED = 0.2
#: SNR deficit (dB) under the free-space SNR at which a link is more likely blocked than not:
#: floor two-ray interference moves a LoS SNR by up to about +-5 dB (measured p10/p90 -4 / +5 dB),
#: diffraction costs 6 dB and more at the shadow boundary.
DEFICIT_DB = 6.0
#: Width (dB) of the logistic transition around DEFICIT_DB.
DEFICIT_SLOPE_DB = 1.5
#: A lobe wider than this (in isolated-pulse widths) holds overlapping paths; narrower than
#: NARROW_LOBE, destructive interference of two paths (either may shift the top).
WIDE_LOBE = 1.05
NARROW_LOBE = 0.95
#: A lobe this far under the strongest peak (dB) is a weak first path: likely not LoS.
WEAK_LOBE_DB = -3.0


def pulse_width_m(links: LinkInfo | None) -> float:
    """1.25 c / B in metres (the raised cosine's main-lobe width), 3.7 m if B is unknown."""
    if links is None or not links.bandwidth_hz:
        return 3.7
    return 1.25 * C0 / links.bandwidth_hz


def link_sigma(links: LinkInfo | None, shape: tuple[int, int]) -> np.ndarray:
    """(E, N) noise core ``sigma_n`` in metres (see the module docstring)."""
    if links is None or not links.bandwidth_hz:
        return np.full(shape, FLOOR_UNKNOWN_M)
    B = links.bandwidth_hz
    frac = FLOOR_IDEAL if links.receiver == "first-path" else FLOOR_FIRST_LOBE
    floor = frac * C0 / B
    gain = B / links.subcarrier_spacing_hz if links.subcarrier_spacing_hz else 1.0
    snr = 10.0 ** (np.where(np.isfinite(links.snr_db), links.snr_db, 40.0) / 10.0)
    crlb2 = C0**2 / (8.0 * np.pi**2 * (F_RMS_PER_B * B) ** 2 * snr * gain)
    return np.sqrt(crlb2 + floor**2)


def free_space_snr_db(links: LinkInfo, dist_m: np.ndarray) -> np.ndarray:
    """SNR (dB) of a LoS link over ``dist_m``: ``snr_offset_db + 20 log10(lambda / (4 pi d))``."""
    lam = C0 / float(links.center_frequency_hz)
    return float(links.snr_offset_db) + 20.0 * np.log10(
        lam / (4.0 * np.pi * np.maximum(dist_m, 0.1))
    )


def shares(
    links: LinkInfo | None, dist_m: np.ndarray | None, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(E, N) shares ``p_wide`` and ``p_late`` of the mixture at candidate ranges ``dist_m``.

    * no report: ``P_WIDE0``, ``P_LATE0``;
    * SNR deficit ``d`` under free space at the candidate range: ``p_late`` rises logistically to
      :data:`P_LATE_BLOCKED` around :data:`DEFICIT_DB`; a blocked link is also more often early
      (a weak first path overlapped by a stronger one), ``p_wide`` rises to
      :data:`P_WIDE_BLOCKED`;
    * lobe wider than :data:`WIDE_LOBE`: ``p_late >= 0.5`` (overlap pulls the top late);
      narrower than :data:`NARROW_LOBE`: ``p_wide >= 0.5`` (destructive interference);
    * lobe under the strongest peak by more than :data:`WEAK_LOBE_DB`: ``p_late >= 0.3``.
    """
    deficit = None
    if links is not None and dist_m is not None and links.snr_offset_db is not None \
            and links.center_frequency_hz:  # fmt: skip
        deficit = free_space_snr_db(links, dist_m) - links.snr_db
    return shares_at_deficit(links, deficit, valid)


def shares_at_deficit(
    links: LinkInfo | None, deficit_db: np.ndarray | None, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shares` from the SNR deficit ``deficit_db`` (dB, the free-space SNR at the
    candidate range less the reported one; None: no deficit known), for a caller that has the
    free-space SNR of many epochs at once (the grid of ``nlos-map``: one per cell)."""
    shape = valid.shape
    p_late = np.full(shape, P_LATE0)
    p_wide = np.full(shape, P_WIDE0)
    if links is None:
        return p_wide, p_late
    if deficit_db is not None:
        s = 1.0 / (1.0 + np.exp(-(np.nan_to_num(deficit_db, nan=0.0) - DEFICIT_DB) / DEFICIT_SLOPE_DB))
        p_late = P_LATE0 + (P_LATE_BLOCKED - P_LATE0) * s
        p_wide = P_WIDE0 + (P_WIDE_BLOCKED - P_WIDE0) * s
    w = links.lobe_width
    p_late = np.where(w > WIDE_LOBE, np.maximum(p_late, 0.5), p_late)
    p_wide = np.where(w < NARROW_LOBE, np.maximum(p_wide, 0.5), p_wide)
    p_late = np.where(links.peak_ratio_db < WEAK_LOBE_DB, np.maximum(p_late, 0.3), p_late)
    # keep a core share: the shares of the three causes sum to 1
    tot = p_late + p_wide
    scale = np.where(tot > 0.95, 0.95 / tot, 1.0)
    return p_wide * scale, p_late * scale


def _log_norm(r: np.ndarray, s: np.ndarray) -> np.ndarray:
    return -0.5 * (r / s) ** 2 - np.log(s) - 0.5 * np.log(2.0 * np.pi)


def component_logpdf(
    r: np.ndarray, sigma: np.ndarray, s_wide: float, lam: float = LATE_MEAN_M
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Log densities of a residual ``r`` (m) under the core, wide and late components.

    The late one is the exponentially modified Gaussian (excess ~ Exp(mean lam), plus noise):
    ``log f = -ln lam + sigma^2 / (2 lam^2) - r / lam + ln Phi(r / sigma - sigma / lam)``.
    """
    core = _log_norm(r, sigma)
    wide = _log_norm(r, np.sqrt(sigma**2 + s_wide**2))
    late = -np.log(lam) + sigma**2 / (2.0 * lam**2) - r / lam + log_ndtr(r / sigma - sigma / lam)
    return core, wide, late


def mixture_nll(
    r: np.ndarray, sigma: np.ndarray, p_wide: np.ndarray, p_late: np.ndarray, s_wide: float
) -> tuple[np.ndarray, np.ndarray]:
    """Negative log-likelihood per measurement and the (3, ...) responsibilities of the causes
    (core, wide, late) for residuals ``r`` (m)."""
    lc, lw, ll = component_logpdf(r, sigma, s_wide)
    stack = np.stack([lc + np.log1p(-(p_wide + p_late)), lw + np.log(p_wide), ll + np.log(p_late)])
    top = stack.max(axis=0)
    lse = top + np.log(np.sum(np.exp(stack - top), axis=0))
    return -lse, np.exp(stack - lse)


def late_mean_excess(r: np.ndarray, sigma: np.ndarray, lam: float = LATE_MEAN_M) -> np.ndarray:
    """``E[x | r, late]``: the excess x >= 0 given the residual ``r = x + noise`` (a normal
    ``N(r - sigma^2 / lam, sigma^2)`` truncated to x >= 0): ``mu + sigma phi(mu/sigma) /
    Phi(mu/sigma)``."""
    mu = r - sigma**2 / lam
    z = mu / sigma
    # phi / Phi through logs (stable for z << 0, where the mean tends to sigma / |z|)
    ratio = np.exp(-0.5 * z * z - 0.5 * np.log(2.0 * np.pi) - log_ndtr(z))
    return np.maximum(mu + sigma * ratio, 0.0)
