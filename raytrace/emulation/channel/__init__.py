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

Modules: :mod:`.budget` (noise and link budget, eq. 3), :mod:`.pulse` (the raised cosine, eq. 2),
:mod:`.cir` (path arrays per link), :mod:`.response` (the sampled response and its ToA),
:mod:`.cfr` (the PRS channel frequency response and its delay profile).
"""

from .budget import LinkBudget, detection_snr_db, thermal_noise_power_w, toa_std_eq3_s
from .cfr import PRS_COMBS, PrsSettings, cfr_delay_profile, prs_cfr
from .cir import DiscreteCIR, check_paths, discrete_cir, first_detectable_path
from .pulse import DEFAULT_ROLL_OFF, PulseShape, raised_cosine, raised_cosine_spectrum
from .response import (
    SampledResponse,
    band_limited_response,
    concat_ranges,
    correlator_noise,
    pulse_toa,
)

__all__ = [
    "DEFAULT_ROLL_OFF",
    "PRS_COMBS",
    "PrsSettings",
    "DiscreteCIR",
    "LinkBudget",
    "PulseShape",
    "SampledResponse",
    "band_limited_response",
    "cfr_delay_profile",
    "check_paths",
    "concat_ranges",
    "correlator_noise",
    "detection_snr_db",
    "discrete_cir",
    "first_detectable_path",
    "prs_cfr",
    "pulse_toa",
    "raised_cosine",
    "raised_cosine_spectrum",
    "thermal_noise_power_w",
    "toa_std_eq3_s",
]
