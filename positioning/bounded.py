"""Deprecated: ``positioning.bounded`` moved to :mod:`positioning.estimators.bounded`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "GRID_STEP_M": "positioning.estimators.bounded",
    "OUTLINE_STEP_M": "positioning.estimators.bounded",
    "bounded_refit": "positioning.estimators.bounded",
    "concentrated_cost": "positioning.estimators.bounded",
    "projected_lm": "positioning.estimators.bounded",
}

__getattr__, __dir__ = forward(__name__, MOVED)
