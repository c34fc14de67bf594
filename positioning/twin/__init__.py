"""The subpackage ``positioning.twin`` holds the estimator that positions against a ray-traced
fingerprint map and everything it needs: the map file (:mod:`~positioning.twin.fingerprint`), the
noiseless first-lobe receiver (:mod:`~positioning.twin.lobe`), the map as a lattice with its
cache and rasters (:mod:`~positioning.twin.lattice`), the match to cells
(:mod:`~positioning.twin.match`), the re-synthesis of paths (:mod:`~positioning.twin.resynth`) and
the estimator (:mod:`~positioning.twin.estimator`). It imports the models and estimators below it,
nothing above.

Until issue 35 ``positioning.twin`` was one module; its names keep working from here for one
release (a :class:`DeprecationWarning` names each one's new module).
"""

from __future__ import annotations

from ..deprecated import forward

#: Old name -> its new module.
MOVED = {
    "FALLBACK_M": "positioning.twin.estimator",
    "NLOS_BIAS_M": "positioning.twin.estimator",
    "PRIOR_M": "positioning.twin.estimator",
    "RASTER_CHUNK": "positioning.twin.estimator",
    "RESYNTH_CHUNK": "positioning.twin.estimator",
    "RESYNTH_M": "positioning.twin.estimator",
    "RESYNTH_PRIOR_M": "positioning.twin.estimator",
    "RESYNTH_TOP": "positioning.twin.estimator",
    "SEARCH_M": "positioning.twin.estimator",
    "TOP": "positioning.twin.estimator",
    "clamp_to_polygon": "positioning.twin.estimator",
    "twin": "positioning.twin.estimator",
    "BS_TOL_M": "positioning.twin.lattice",
    "COARSE_CELLS": "positioning.twin.lattice",
    "MAX_RASTERS": "positioning.twin.lattice",
    "check_bs": "positioning.twin.lattice",
    "check_dataset": "positioning.twin.lattice",
    "interp_bias": "positioning.twin.lattice",
    "load": "positioning.twin.lattice",
    "nearest_cell": "positioning.twin.lattice",
    "prepare": "positioning.twin.lattice",
    "REFINE_BOX": "positioning.twin.match",
    "REFINE_ITER": "positioning.twin.match",
    "WINDOW_GROUP": "positioning.twin.match",
    "coarse_match": "positioning.twin.match",
    "match_quality": "positioning.twin.match",
    "refine_at_cells": "positioning.twin.match",
    "window_match": "positioning.twin.match",
}

__getattr__, __dir__ = forward(__name__, MOVED)
