"""Deprecated: ``positioning.fingerprint`` moved to :mod:`positioning.twin.fingerprint`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "ARRAYS": "positioning.twin.fingerprint",
    "FingerprintMap": "positioning.twin.fingerprint",
    "PATH_ARRAYS": "positioning.twin.fingerprint",
    "READ_VERSIONS": "positioning.twin.fingerprint",
    "SCHEMA": "positioning.twin.fingerprint",
    "SCHEMA_VERSION": "positioning.twin.fingerprint",
    "read_map": "positioning.twin.fingerprint",
    "write_map": "positioning.twin.fingerprint",
}

__getattr__, __dir__ = forward(__name__, MOVED)
