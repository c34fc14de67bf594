"""Deprecated: ``positioning.noise`` moved to :mod:`positioning.model.noise`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "DEFICIT_DB": "positioning.model.noise",
    "DEFICIT_SLOPE_DB": "positioning.model.noise",
    "FLOOR_FIRST_LOBE": "positioning.model.noise",
    "FLOOR_IDEAL": "positioning.model.noise",
    "FLOOR_UNKNOWN_M": "positioning.model.noise",
    "F_RMS_PER_B": "positioning.model.noise",
    "LATE_MEAN_M": "positioning.model.noise",
    "NARROW_LOBE": "positioning.model.noise",
    "P_LATE0": "positioning.model.noise",
    "P_LATE_BLOCKED": "positioning.model.noise",
    "P_WIDE0": "positioning.model.noise",
    "P_WIDE_BLOCKED": "positioning.model.noise",
    "WEAK_LOBE_DB": "positioning.model.noise",
    "WIDE_LOBE": "positioning.model.noise",
    "WIDE_PULSES": "positioning.model.noise",
    "component_logpdf": "positioning.model.noise",
    "free_space_snr_db": "positioning.model.noise",
    "late_mean_excess": "positioning.model.noise",
    "link_sigma": "positioning.model.noise",
    "mixture_nll": "positioning.model.noise",
    "pulse_width_m": "positioning.model.noise",
    "shares": "positioning.model.noise",
}

__getattr__, __dir__ = forward(__name__, MOVED)
