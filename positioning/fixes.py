"""Deprecated: ``positioning.fixes`` moved to :mod:`positioning.estimators.fixes`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "Fixes": "positioning.estimators.fixes",
    "Status": "positioning.estimators.fixes",
    "UNTRUSTED": "positioning.estimators.fixes",
    "status_label": "positioning.estimators.fixes",
}

__getattr__, __dir__ = forward(__name__, MOVED)
