"""Small bounded stores of derived results kept on a scene's caches between traces.

The tracer's stages run on threads, and several may keep results in the same store (the RD and
RDR stages both keep the transmitters' triples): :func:`keep` inserts under a lock and drops the
oldest entries beyond the limit, so that two threads never evict the same entry or iterate a
store another one is changing. Reads are plain ``dict.get`` (atomic in CPython). A store may
also be bounded in bytes: a scene of a million triangles makes each transmitter's second images
gigabytes, which are worth keeping only while they are small beside the memory.
"""

from __future__ import annotations

import threading
from typing import Any, TypeVar

import numpy as np

__all__ = ["keep", "nbytes"]

_LOCK = threading.Lock()
T = TypeVar("T")


def nbytes(value: Any) -> int:
    """Bytes of the numpy arrays in ``value`` (nested tuples, lists and dicts; an array and its
    views count once, as their base)."""
    seen: set[int] = set()
    total = 0
    todo = [value]
    while todo:
        x = todo.pop()
        if isinstance(x, np.ndarray):
            while isinstance(x.base, np.ndarray):
                x = x.base
            if id(x) not in seen:
                seen.add(id(x))
                total += x.nbytes
        elif isinstance(x, (tuple, list)):
            todo.extend(x)
        elif isinstance(x, dict):
            todo.extend(x.values())
    return total


def keep(store: dict[Any, Any], key: Any, value: T, limit: int,
         max_bytes: int | None = None) -> T:  # fmt: skip
    """Put ``value`` in ``store`` under ``key``, first dropping the oldest entries so that at most
    ``limit`` remain and, with ``max_bytes``, their arrays (:func:`nbytes`) with ``value``'s
    take at most that many bytes (a ``value`` larger than that alone is not kept); returns
    ``value``."""
    size = 0 if max_bytes is None else nbytes(value)
    with _LOCK:
        store.pop(key, None)
        if max_bytes is not None and size > max_bytes:
            return value
        while store and len(store) >= limit:
            store.pop(next(iter(store)))
        if max_bytes is not None:
            while store and nbytes(list(store.values())) + size > max_bytes:
                store.pop(next(iter(store)))
        store[key] = value
    return value
