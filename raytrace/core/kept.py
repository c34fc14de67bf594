"""Small bounded stores of derived results kept on a scene's caches between traces.

The tracer's stages run on threads, and several may keep results in the same store (the RD and
RDR stages both keep the transmitters' triples): :func:`keep` inserts under a lock and drops the
oldest entries beyond the limit, so that two threads never evict the same entry or iterate a
store another one is changing. Reads are plain ``dict.get`` (atomic in CPython).
"""

from __future__ import annotations

import threading
from typing import Any, TypeVar

__all__ = ["keep"]

_LOCK = threading.Lock()
T = TypeVar("T")


def keep(store: dict[Any, Any], key: Any, value: T, limit: int) -> T:
    """Put ``value`` in ``store`` under ``key``, first dropping the oldest entries so that at most
    ``limit`` remain; returns ``value``."""
    with _LOCK:
        store.pop(key, None)
        while store and len(store) >= limit:
            store.pop(next(iter(store)))
        store[key] = value
    return value
