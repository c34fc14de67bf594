"""Deprecated: ``positioning.integrity`` moved to :mod:`positioning.evaluation.integrity`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "ALERT_LIMIT_M": "positioning.evaluation.integrity",
    "K_SIGMA": "positioning.evaluation.integrity",
    "P_CONSISTENT": "positioning.evaluation.integrity",
    "integrity": "positioning.evaluation.integrity",
}

__getattr__, __dir__ = forward(__name__, MOVED)
