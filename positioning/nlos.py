"""Deprecated: ``positioning.nlos`` moved to :mod:`positioning.estimators.nlos`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "SAME_OPTIMUM_M": "positioning.estimators.nlos",
    "SEPARATION_PITCHES": "positioning.estimators.nlos",
    "em_fit": "positioning.estimators.nlos",
    "grid_starts": "positioning.estimators.nlos",
    "nlos_map": "positioning.estimators.nlos",
    "posterior_mean": "positioning.estimators.nlos",
}

__getattr__, __dir__ = forward(__name__, MOVED)
