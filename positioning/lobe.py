"""Deprecated: ``positioning.lobe`` moved to :mod:`positioning.model.tdoa`,
:mod:`positioning.twin.lobe`,
:mod:`positioning.model.pulse`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "C0": "positioning.model.tdoa",
    "LobeReceiver": "positioning.twin.lobe",
    "TABLE_PER_T": "positioning.model.pulse",
    "move_paths": "positioning.twin.lobe",
    "raised_cosine": "positioning.model.pulse",
}

__getattr__, __dir__ = forward(__name__, MOVED)
