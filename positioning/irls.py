"""Deprecated: ``positioning.irls`` moved to :mod:`positioning.estimators.irls`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "EPSILON_M": "positioning.estimators.irls",
    "LS_MAX_ITER": "positioning.estimators.irls",
    "LS_TOL_M": "positioning.estimators.irls",
    "MAX_ITER": "positioning.estimators.irls",
    "U_MAX_M": "positioning.estimators.irls",
    "andrews_weight": "positioning.estimators.irls",
    "irls": "positioning.estimators.irls",
    "least_squares": "positioning.estimators.irls",
    "plausible": "positioning.estimators.irls",
    "region_box": "positioning.estimators.irls",
    "uncertainties": "positioning.estimators.irls",
}

__getattr__, __dir__ = forward(__name__, MOVED)
