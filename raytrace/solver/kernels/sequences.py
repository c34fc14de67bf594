"""Compiled interaction sequences of the paths (numba, options in :mod:`raytrace.core.jit`).

:func:`interaction_sequences`: each path's interactions in the order the field meets them (each
segment's penetrations, then its vertex), as :class:`raytrace.solver.paths.Paths` stores them.
"""

from __future__ import annotations

import numpy as np

from ...core.jit import kernel

__all__ = ["interaction_sequences"]


@kernel(
    "Tuple((i1[:, ::1], f8[:, :, ::1], i8[:, ::1], i8[:, ::1]))("
    "i8[:, ::1], i8[:, :, ::1], f8[:, :, :, ::1], i1[:, ::1], f8[:, :, ::1], i8[:, ::1], "
    "i8[:, ::1], i8, i1, i8[::1])"
)
def interaction_sequences(count, pen_obj, pen_pts, kinds, verts, vobj, elem, depth, penetration,
                          rows):  # fmt: skip
    """The interaction sequences of the paths ``rows`` (N,) of M in the order the field meets
    them: the penetrations of segment ``j`` (``count`` (M, k+1), objects (M, k+1, P), entry
    points (M, k+1, P, 3)), then vertex ``j`` (``kinds``, ``verts``, ``vobj``, ``elem``: (M, k),
    (M, k, 3)), padded to ``depth`` columns.

    Returns
    -------
    interaction : (N, depth) int8, codes (0 pad; ``penetration`` for a penetration)
    points : (N, depth, 3) float, metres (NaN pad)
    objects, elements : (N, depth) int, the object of each interaction and the facet or wedge of
        a vertex (-1 pad; -1 for a penetration's element)
    """
    n, k = len(rows), kinds.shape[1]
    inter = np.zeros((n, depth), dtype=np.int8)
    pts = np.full((n, depth, 3), np.nan)
    objs = np.full((n, depth), -1, dtype=np.int64)
    elems = np.full((n, depth), -1, dtype=np.int64)
    for i in range(n):
        r = rows[i]
        pos = 0
        for j in range(k + 1):
            for s in range(min(count[r, j], pen_obj.shape[2])):
                inter[i, pos] = penetration
                pts[i, pos, 0], pts[i, pos, 1] = pen_pts[r, j, s, 0], pen_pts[r, j, s, 1]
                pts[i, pos, 2] = pen_pts[r, j, s, 2]
                objs[i, pos] = pen_obj[r, j, s]
                pos += 1
            if j < k:
                inter[i, pos] = kinds[r, j]
                pts[i, pos, 0], pts[i, pos, 1], pts[i, pos, 2] = (verts[r, j, 0], verts[r, j, 1],
                                                                  verts[r, j, 2])  # fmt: skip
                objs[i, pos] = vobj[r, j]
                elems[i, pos] = elem[r, j]
                pos += 1
    return inter, pts, objs, elems
