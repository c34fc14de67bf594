"""Small-vector arithmetic on (..., 3) arrays, written one component at a time.

``np.cross`` and ``np.linalg.norm(..., axis=-1)`` go through generic machinery (axis moves,
broadcasting checks, a reduction over an axis of length 3) that costs several times the
arithmetic on the (N, 3) arrays the tracer handles. These give bitwise the same results
(the same operations in the same order), faster. :func:`dot3` and :func:`cross3` are the
scalar forms the compiled kernels (solver, physics) share.
"""

from __future__ import annotations

import numpy as np

from .jit import inline

__all__ = ["cross", "norm", "index", "rows", "broadcast_rows", "dot3", "cross3"]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of (..., 3) arrays (broadcasting), bitwise as ``np.cross(a, b)``."""
    a, b = np.asarray(a), np.asarray(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


def norm(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis of a real (..., 3) array, bitwise as
    ``np.linalg.norm(v, axis=-1)``."""
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)


def index(sel: np.ndarray) -> np.ndarray:
    """Integer row indices of a selection: a boolean mask's true rows, or the indices as they
    are. Convert a mask once when it selects from several arrays."""
    sel = np.asarray(sel)
    return np.flatnonzero(sel) if sel.dtype == bool else sel


def rows(x: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """``x[sel]`` along the first axis (``sel`` a boolean mask or indices), bitwise the same.

    Boolean indexing with a mask that is neither mostly true nor mostly false costs several
    times the gather of its indices (branch mispredictions), and fancy indexing of
    multi-dimensional rows goes through generic machinery: ``take`` copies whole rows, about
    7x faster for an (N, 3) array (25 000 rows: 16 us against 108 us, 236 us with a mask)."""
    return np.take(x, index(sel), axis=0)


def broadcast_rows(*arrays: object) -> tuple[tuple[int, ...], list[np.ndarray]]:
    """The broadcast shape of ``arrays`` and each broadcast to it, flat, C-contiguous and
    writable, as the compiled kernels take them: an array already of that shape as a view, the
    others copied. Not ``np.broadcast_arrays``, whose views raise numpy 2's FutureWarning when
    asked whether they are writable (as the kernels' argument checks do)."""
    arrs = [np.asarray(a) for a in arrays]
    shape = np.broadcast_shapes(*(a.shape for a in arrs))
    out = []
    for a in arrs:
        if a.shape == shape and a.flags.c_contiguous and a.flags.writeable:
            out.append(a.reshape(-1))
        else:
            out.append(np.array(np.broadcast_to(a, shape).reshape(-1)))
    return shape, out


# -- scalar forms, for compiled kernels (raytrace.core.jit) -------------------------------------
@inline
def dot3(x0, x1, x2, y0, y1, y2):
    """A 3-vector dot product of scalars, summed as numpy's ``einsum("ij,ij->i")`` sums it on the
    machines checked, ``(x0 y0 + x2 y2) + x1 y1``, so that kernels written with it give the
    numpy form's bits."""
    return (x0 * y0 + x2 * y2) + x1 * y1


@inline
def cross3(ax, ay, az, bx, by, bz):
    """``a x b`` of scalars, in :func:`cross`'s order."""
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
