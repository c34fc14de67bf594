"""Deprecated: ``positioning.robust`` moved to :mod:`positioning.estimators.robust`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "HUBER_C": "positioning.estimators.robust",
    "MAD_TO_SIGMA": "positioning.estimators.robust",
    "NLOS_K": "positioning.estimators.robust",
    "REGION_MARGIN": "positioning.estimators.robust",
    "REJECT_WEIGHT": "positioning.estimators.robust",
    "SCALE_FLOOR_M": "positioning.estimators.robust",
    "SIGMA_M": "positioning.estimators.robust",
    "TUKEY_C": "positioning.estimators.robust",
    "m_estimator": "positioning.estimators.robust",
    "nlos_aware": "positioning.estimators.robust",
    "nlos_loss": "positioning.estimators.robust",
    "nlos_weights": "positioning.estimators.robust",
    "robust_weights": "positioning.estimators.robust",
    "subset": "positioning.estimators.robust",
}

__getattr__, __dir__ = forward(__name__, MOVED)
