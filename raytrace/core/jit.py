"""Compiled loops (numba) for the places where numpy's array-at-a-time style costs more than the
arithmetic: pruning that runs over (object, facet, edge) triples with early exits, where the
numpy form builds dense matrices of which a few per cent survive, and per-row bookkeeping (the
segment walk, the geometry of a diffraction, field tracking) that numpy spreads over many masked
passes.

Every kernel is compiled with the same options (:func:`kernel`):

* an explicit signature: compiled (or loaded from the cache) when its module is imported, so
  that the worker pools' fork server, which imports the tracer once, hands loaded kernels to
  every worker it forks;
* ``error_model="numpy"``: a division by zero gives ``inf`` or ``nan`` as in numpy, not an
  exception;
* no ``fastmath``: IEEE operations in the order written (no reassociation, no fused
  multiply-add), so a kernel that writes a real numpy expression in the same order gives numpy's
  bits (not for complex products, which numpy fuses on CPUs with AVX-512, nor for ``arctan2``,
  ``sin`` and ``cos``, which numpy computes with its own vectorised routines: last bits only);
* ``nogil=True``: a kernel releases the GIL, so the tracer's stage threads run them side by side;
* ``cache=True``: compiled once per installation (about a second per kernel) and loaded from the
  cache by later processes (``NUMBA_CACHE_DIR`` moves the cache; numba falls back to a per-user
  directory when the installation is read-only).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np

__all__ = ["kernel", "inline", "helper", "carray"]

_OPTIONS: dict[str, Any] = dict(cache=True, nogil=True, error_model="numpy", fastmath=False)


def _njit(fn: Callable[..., Any], *args: Any, **options: Any) -> Any:
    """``numba.njit(*args, **options)(fn)`` with the project's options; where no cache directory
    is writable (numba finds no cache locator), compiled without the cache instead."""
    try:
        return numba.njit(*args, **_OPTIONS, **options)(fn)
    except RuntimeError as exc:
        if "no locator available" not in str(exc):
            raise
        return numba.njit(*args, **{**_OPTIONS, "cache": False}, **options)(fn)


def kernel(signature: str) -> Callable[[Callable[..., Any]], Any]:
    """Decorator: a numba kernel of the given signature with the project's options (module
    docstring). Where no cache directory is writable, the kernel is compiled in every process
    instead."""
    return lambda fn: _njit(fn, signature)


def inline(fn: Callable[..., Any]) -> Any:
    """Decorator: a scalar helper of kernels, compiled into each kernel that calls it (typed
    by its callers), with the same options.

    A helper that takes arrays reads them before its first branch (``if``, ``a and b``, a
    conditional expression, a loop) and writes them only in straight-line code; its branches
    work on scalars. Where an array argument is live across a branch inside a helper, numba
    keeps a reference count per call (atomic operations) that its pruning cannot remove: on
    the hall, 50-130 ns per call, ten times the arithmetic of a small test
    (:func:`raytrace.scene.accel.facet_box_test` was 16 ms of a 0.3 s trace written the other
    way). A kernel's own body is free of it, and so is a straight-line helper called from a
    branch of the kernel."""
    return _njit(fn, inline="always")


def helper(fn: Callable[..., Any]) -> Any:
    """Decorator: a scalar helper of kernels compiled once as a function of its own, which the
    kernels call (typed by its callers), with the same options. For the larger helpers on rare
    branches: :func:`inline` copies a helper into every call site at numba's level, which is
    faster per call but multiplies the compilation time of a kernel that calls it from several
    places."""
    return _njit(fn)


def carray(x: Any, dtype: Any = np.float64) -> np.ndarray:
    """``x`` as the kernels' signatures take arrays: C-ordered, writable, of ``dtype`` (a copy
    only where it is not already)."""
    x = np.asarray(x, dtype=dtype)
    if x.flags.c_contiguous and x.flags.writeable:
        return x
    return np.array(x, dtype=dtype, order="C", copy=True)
