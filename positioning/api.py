"""Deprecated: ``positioning.api`` moved to :mod:`positioning.methods.registry`,
:mod:`positioning.methods.run`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "METHODS": "positioning.methods.registry",
    "Method": "positioning.methods.registry",
    "method_names": "positioning.methods.registry",
    "resolve_params": "positioning.methods.registry",
    "OUTSIDE_CHOICES": "positioning.methods.run",
    "apply_area": "positioning.methods.run",
    "locate": "positioning.methods.run",
    "run_method": "positioning.methods.run",
}

__getattr__, __dir__ = forward(__name__, MOVED)
