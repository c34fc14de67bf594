"""Deprecated: ``positioning.area`` moved to :mod:`positioning.model.area`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "BOUNDARY_TOL_M": "positioning.model.area",
    "ServiceArea": "positioning.model.area",
    "area_from_meta": "positioning.model.area",
}

__getattr__, __dir__ = forward(__name__, MOVED)
