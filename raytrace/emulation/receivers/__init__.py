"""The ToA receivers: the first-lobe receiver (:mod:`.first_lobe`, evaluated in a window), the
receivers on the PRS channel frequency response (``first-lobe-cfr`` and ``search-back``,
:mod:`.search_back`; ``super-res``, :mod:`.super_res`) and every estimator behind one interface
(:mod:`.receiver`, :class:`Receiver`).
"""

from positioning.model.pulse import TABLE_PER_T, precursor_extent_t

from .first_lobe import (
    MIN_CROSSING,
    NEGLIGIBLE_DB,
    NOISE_GUARD_T,
    POST_T,
    SURE_CROSSING,
    TOP_PATHS,
    FirstLobeSettings,
    LobeMeasurement,
    LobePlan,
    cfar_factor,
    isolated_half_width_t,
    measure_first_lobe,
    prepare_first_lobe,
)
from .receiver import (
    CFR_METHODS,
    DEFAULT_TOA_METHOD,
    TOA_METHODS,
    PreparedLinks,
    Receiver,
    ToAEstimate,
    estimate_toa,
)
from .search_back import SearchBackSettings
from .super_res import SuperResSettings

__all__ = [
    "CFR_METHODS",
    "DEFAULT_TOA_METHOD",
    "MIN_CROSSING",
    "NEGLIGIBLE_DB",
    "NOISE_GUARD_T",
    "POST_T",
    "SURE_CROSSING",
    "TABLE_PER_T",
    "TOP_PATHS",
    "FirstLobeSettings",
    "LobeMeasurement",
    "LobePlan",
    "PreparedLinks",
    "Receiver",
    "SearchBackSettings",
    "SuperResSettings",
    "TOA_METHODS",
    "ToAEstimate",
    "cfar_factor",
    "estimate_toa",
    "isolated_half_width_t",
    "measure_first_lobe",
    "precursor_extent_t",
    "prepare_first_lobe",
]
