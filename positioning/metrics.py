"""Deprecated: ``positioning.metrics`` moved to :mod:`positioning.evaluation.metrics`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "cdf": "positioning.evaluation.metrics",
    "error_2d": "positioning.evaluation.metrics",
    "summarize": "positioning.evaluation.metrics",
}

__getattr__, __dir__ = forward(__name__, MOVED)
