"""Deprecated: ``positioning.sanity`` moved to :mod:`positioning.evaluation.trust`,
:mod:`positioning.io.scale`, :mod:`positioning.model.tdoa`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "MIN_SPREAD_RATIO": "positioning.evaluation.trust",
    "check_trustworthy": "positioning.evaluation.trust",
    "ill_conditioned": "positioning.evaluation.trust",
    "trust_counts": "positioning.evaluation.trust",
    "RANGE_SPANS": "positioning.io.scale",
    "ScaleError": "positioning.io.scale",
    "check_dataset": "positioning.io.scale",
    "check_height": "positioning.io.scale",
    "check_stations": "positioning.io.scale",
    "check_toa_scale": "positioning.io.scale",
    "C0": "positioning.model.tdoa",
}

__getattr__, __dir__ = forward(__name__, MOVED)
