"""Compiled test of path segments against oriented boxes (numba, options in
:mod:`raytrace.core.jit`): which paths a forklift snapshot affects
(:meth:`raytrace.solver.incremental.PathSegments.affected`).

Per box, a segment's axis-aligned bounding box must meet the box's (the prefilter), then the
slab test of :func:`raytrace.solver.incremental.segments_meet_boxes` decides, with its
arithmetic: one pass over the segments instead of numpy's dozen over all of them per box and
band (a hall snapshot has about 100 000 segments per band and four boxes).
"""

from __future__ import annotations

import numpy as np

from ...core.jit import kernel

__all__ = ["paths_meeting_boxes"]


@kernel("b1[::1](f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], i8[::1], i8, f8[:, ::1], "
        "f8[:, :, ::1], f8[:, ::1], f8[:, ::1])")  # fmt: skip
def paths_meeting_boxes(a, b, lo, hi, path, n_paths, centre, rotation, half, ext):
    """(P,) bool: the paths with a segment ``a -> b`` (S, 3), metres, that meets a box.

    Parameters
    ----------
    a, b : (S, 3) float, segment ends; lo, hi : (S, 3) float, their bounding boxes, metres
    path : (S,) int, the path of each segment, ``< n_paths``
    centre : (B, 3) float, rotation : (B, 3, 3) float (columns: the box axes), half : (B, 3)
        float, the boxes' half extents already grown by the test's margin, metres
    ext : (B, 3) float, half extents of each grown box's axis-aligned bounding box, metres

    A path already found is not tested again; the slab test is that of
    :func:`raytrace.solver.incremental.segments_meet_boxes` (the local coordinates summed in
    the same order; a decision can differ from numpy's only for a segment within a rounding of
    the grown box's surface, which then crosses no box and re-evaluates to the same path).
    """
    out = np.zeros(n_paths, dtype=np.bool_)
    for s in range(len(a)):
        if out[path[s]]:
            continue
        for k in range(len(centre)):
            c0, c1, c2 = centre[k, 0], centre[k, 1], centre[k, 2]
            if (lo[s, 0] > c0 + ext[k, 0] or hi[s, 0] < c0 - ext[k, 0]
                    or lo[s, 1] > c1 + ext[k, 1] or hi[s, 1] < c1 - ext[k, 1]
                    or lo[s, 2] > c2 + ext[k, 2] or hi[s, 2] < c2 - ext[k, 2]):  # fmt: skip
                continue
            ax, ay, az = a[s, 0] - c0, a[s, 1] - c1, a[s, 2] - c2
            bx, by, bz = b[s, 0] - c0, b[s, 1] - c1, b[s, 2] - c2
            enter, leave = 0.0, 1.0
            for j in range(3):
                r0, r1, r2 = rotation[k, 0, j], rotation[k, 1, j], rotation[k, 2, j]
                pa = ax * r0 + ay * r1 + az * r2
                d = (bx * r0 + by * r1 + bz * r2) - pa
                h = half[k, j]
                if d == 0:
                    if abs(pa) > h:
                        enter, leave = 1.0, 0.0  # parallel and outside this slab
                    continue
                t1 = (-h - pa) / d
                t2 = (h - pa) / d
                enter = max(enter, min(t1, t2))
                leave = min(leave, max(t1, t2))
            if enter <= leave:
                out[path[s]] = True
                break
    return out
