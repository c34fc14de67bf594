"""Deprecated: ``positioning.track`` moved to :mod:`positioning.estimators.track`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "ACCEL_PSD": "positioning.estimators.track",
    "DEFAULT_DT_S": "positioning.estimators.track",
    "GATE": "positioning.estimators.track",
    "PARAMS": "positioning.estimators.track",
    "RESTART_AFTER": "positioning.estimators.track",
    "SIGMA_M": "positioning.estimators.track",
    "SUFFIX": "positioning.estimators.track",
    "V0_MPS": "positioning.estimators.track",
    "check_params": "positioning.estimators.track",
    "kalman_track": "positioning.estimators.track",
    "split_method": "positioning.estimators.track",
    "step_response": "positioning.estimators.track",
    "track_fixes": "positioning.estimators.track",
}

__getattr__, __dir__ = forward(__name__, MOVED)
