"""Deprecated: ``positioning.resynth`` moved to :mod:`positioning.twin.resynth`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "FD_STEP_M": "positioning.twin.resynth",
    "ITERATIONS": "positioning.twin.resynth",
    "MAX_BIAS_SLOPE": "positioning.twin.resynth",
    "MAX_STEP_M": "positioning.twin.resynth",
    "MISSING_PENALTY_M": "positioning.twin.resynth",
    "PathMap": "positioning.twin.resynth",
    "RASTER_BATCH": "positioning.twin.resynth",
    "RASTER_STEP_M": "positioning.twin.resynth",
    "SNAP": "positioning.twin.resynth",
    "TILE": "positioning.twin.resynth",
    "ToaRaster": "positioning.twin.resynth",
    "normal_step": "positioning.twin.resynth",
    "refine_resynth": "positioning.twin.resynth",
}

__getattr__, __dir__ = forward(__name__, MOVED)
