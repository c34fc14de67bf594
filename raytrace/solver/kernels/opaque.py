"""Compiled opaque test of candidate paths (numba, options in :mod:`raytrace.core.jit`).

Before the segment walk, :func:`raytrace.solver.evaluate.blocked_by_opaque` asks Embree for the
first opaque hit on each segment of every candidate: :func:`segment_rays` makes the rays of one
segment of all live candidates, :func:`opaque_blocks` says which first hits block (not a
segment's own vertex objects, not a solid or sheet it only touches:
:func:`raytrace.solver.kernels.solids.touches_segment1`,
:func:`~raytrace.solver.kernels.solids.sheet_touch1`).
"""

from __future__ import annotations

import numpy as np

from ...core.jit import kernel
from .solids import sheet_touch1, touches_segment1

__all__ = ["segment_rays", "opaque_blocks"]


@kernel(
    "Tuple((f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], f4[:, ::1], f4[::1]))("
    "f8[:, :, ::1], i8[::1], i8, f8)"
)
def segment_rays(chain, live, j, margin):
    """The rays of segment ``j`` of the chains ``live`` (chain (M, k + 2, 3), metres), as
    :func:`raytrace.solver.evaluate.blocked_by_opaque` asks Embree about them: the start ``a``
    (n, 3), unit direction ``d`` (n, 3; zero for a segment of zero length), length (n,), and
    the ray shortened by ``margin`` at both ends: origin ``a + margin d`` (n, 3; float64, which
    the scene's queries take into Embree's frame and float32), direction (float32, as Embree
    takes it) and reach ``length - 2 margin`` (n,; float32), metres."""
    n = len(live)
    a = np.empty((n, 3))
    d = np.empty((n, 3))
    length = np.empty(n)
    org = np.empty((n, 3))
    d32 = np.empty((n, 3), dtype=np.float32)
    reach = np.empty(n, dtype=np.float32)
    for i in range(n):
        c = live[i]
        ax, ay, az = chain[c, j, 0], chain[c, j, 1], chain[c, j, 2]
        vx, vy, vz = chain[c, j + 1, 0] - ax, chain[c, j + 1, 1] - ay, chain[c, j + 1, 2] - az
        ln = np.sqrt(vx * vx + vy * vy + vz * vz)
        if ln > 0:
            dx, dy, dz = vx / ln, vy / ln, vz / ln
        else:
            dx, dy, dz = 0.0, 0.0, 0.0
        a[i, 0], a[i, 1], a[i, 2] = ax, ay, az
        d[i, 0], d[i, 1], d[i, 2] = dx, dy, dz
        d32[i, 0], d32[i, 1], d32[i, 2] = dx, dy, dz
        length[i] = ln
        org[i, 0], org[i, 1], org[i, 2] = ax + margin * dx, ay + margin * dy, az + margin * dz
        reach[i] = ln - 2 * margin
    return a, d, length, org, d32, reach


@kernel(
    "b1[::1](i8[::1], i8[::1], i8, i8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[:, :, ::1], "
    "f8[:, ::1], i8[::1], f8[:, ::1], f8[::1], i8[::1], i8[::1], f8[:, ::1], f8)"
)
def opaque_blocks(hit, live, j, vobj, a, d, length, normal, offset, count, sheet_plane,
                  sheet_reach, sheet_edge_start, sheet_edge_count, sheet_edges, tol):  # fmt: skip
    """Which of the rays of :func:`segment_rays` (segment ``j`` of the chains ``live``) are
    blocked by their first opaque hit ``hit`` (n,) (-1: none): not when it is the object under
    either end of the segment (``vobj`` (M, k): the vertex's own, within float32 noise), nor
    when the segment ``a + t d``, ``0 <= t <= length``, only touches that convex solid (no span
    deeper than ``tol``; planes as in :func:`~raytrace.solver.kernels.solids.line_span`) or that
    flat sheet (along its plane or past its outline, :func:`sheet_touch1`; arrays as
    ``flat_sheet_arrays`` gives them), which
    Embree reports in one direction and not in the other: both are left to the segment walk,
    which records exactly what a segment crosses."""
    k = vobj.shape[1]
    out = np.zeros(len(hit), dtype=np.bool_)
    for i in range(len(hit)):
        ob, c = hit[i], live[i]
        if ob < 0 or (j > 0 and ob == vobj[c, j - 1]) or (j < k and ob == vobj[c, j]):
            continue
        ax, ay, az, dx, dy, dz = a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2]
        touch = touches_segment1(ob, ax, ay, az, dx, dy, dz, length[i], normal, offset, count,
                                 tol)  # fmt: skip
        if not touch and sheet_reach[ob] > 0.0:
            touch = sheet_touch1(ob, ax, ay, az, dx, dy, dz, True, sheet_plane, sheet_reach,
                                 sheet_edge_start, sheet_edge_count, sheet_edges, tol)[0]  # fmt: skip
        out[i] = not touch
    return out
