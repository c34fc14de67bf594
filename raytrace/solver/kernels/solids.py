"""Compiled tests of lines against convex solids and flat sheets, and of points against
triangles (numba, options in :mod:`raytrace.core.jit`).

* :func:`line_span1` / :func:`line_span`: where a line is at least some depth inside a convex
  solid given by its facet planes (float64);
* :func:`shadowed_groups`, :func:`shadowed_triples`: the shadows of opaque convex solids
  (:mod:`raytrace.solver.shadow`): facets, edges and (end, facet, edge) triples an end point
  sees only through one;
* :func:`edge_distance1` / :func:`edge_distance`: a point's signed in-plane distance from its
  triangle's boundary;
* :func:`touches1`, :func:`touches_segment1`, :func:`sheet_touch1` / :func:`touch_rows`: a line
  or segment that only touches a convex solid or a flat sheet (at an edge, a vertex, along a
  face or plane), which the segment walk (:mod:`raytrace.solver.kernels.walk`) and the opaque
  test (:mod:`raytrace.solver.kernels.opaque`) step over.

The scalar helpers (``...1``) are the ones the walk's and the opaque test's kernels call; the
row kernels run them over arrays for :mod:`raytrace.solver.penetration` and the tests.
"""

from __future__ import annotations

import numpy as np

from ...core.jit import helper, inline, kernel
from ...core.vec import dot3

__all__ = ["line_span1", "shadowed_groups", "shadowed_triples", "line_span", "edge_distance1",
           "edge_distance", "touches1", "sheet_touch1", "touches_segment1", "touch_rows"]


@helper
def line_span1(normal, offset, count, ob, ax, ay, az, dx, dy, dz, inset):
    """One line against one convex solid: see :func:`line_span` (``lo > hi``: no span)."""
    lo, hi, par = -np.inf, np.inf, False
    for k in range(count[ob]):
        nx, ny, nz = normal[ob, k, 0], normal[ob, k, 1], normal[ob, k, 2]
        dn = dot3(nx, ny, nz, dx, dy, dz)
        # signed distance of the line's points from the plane, at least inset inside:
        # s + t dn <= 0
        s = dot3(nx, ny, nz, ax, ay, az) - offset[ob, k] + inset
        tp = -s / dn
        if dn < 0 and tp > lo:
            lo = tp
        elif dn > 0 and tp < hi:
            hi = tp
        elif dn == 0 and s > 0:
            par = True
    return count[ob] > 0, lo, hi, par


@inline
def _deep_through(normal, offset, count, c, ex, ey, ez, px, py, pz, depth):
    """The segment from ``e`` to ``p`` passes through convex solid ``c`` shrunk by ``depth``
    (:func:`line_span1`) before reaching ``p``."""
    dx, dy, dz = px - ex, py - ey, pz - ez
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if not length > 0.0:
        return False
    _, lo, hi, par = line_span1(normal, offset, count, c, ex, ey, ez, dx / length, dy / length,
                                dz / length, depth)  # fmt: skip
    return not par and max(lo, 0.0) < min(hi, length)


@kernel(
    "b1[:, ::1](f8[:, ::1], f8[:, ::1], i8[:, ::1], i8[::1], i8[::1], i8[::1], i8[::1], "
    "f8[:, :, ::1], f8[:, ::1], i8[::1], f8)"
)
def shadowed_groups(ends, points, hit, g_start, g_count, g_point, own, normal, offset, count,
                    depth):  # fmt: skip
    """Which groups of points (a facet's corners, an edge's ends) each end point sees only
    through one convex solid, at least ``depth`` metres inside it on every segment.

    For end ``e`` and group ``g`` (points ``g_point[g_start[g]:][:g_count[g]]`` of ``points``
    (P, 3)), each first hit ``hit[e, p]`` (E, P) (-1: none) other than the group's own object
    ``own[g]`` is a candidate solid; the group is in its shadow when the segment from the end
    to every point of the group passes through the solid shrunk by ``depth`` (its planes
    ``normal . x = offset`` moved inwards, :func:`line_span1`) before reaching the point. Planes
    as in :func:`line_span` (``count[o] = 0``: not a convex solid, never a candidate). Each point's
    segment is tested against its own first hit once per end, shared by the groups it is in.

    Returns
    -------
    (E, G) bool
    """
    n_e, n_g, n_p = len(ends), len(g_start), len(points)
    out = np.zeros((n_e, n_g), dtype=np.bool_)
    deep = np.zeros(n_p, dtype=np.bool_)  # through its own first hit, for the current end
    for e in range(n_e):
        ex, ey, ez = ends[e, 0], ends[e, 1], ends[e, 2]
        for p in range(n_p):
            c = hit[e, p]
            deep[p] = c >= 0 and count[c] > 0 and _deep_through(
                normal, offset, count, c, ex, ey, ez, points[p, 0], points[p, 1], points[p, 2],
                depth)  # fmt: skip
        for g in range(n_g):
            s0, n_in = g_start[g], g_count[g]
            for i in range(n_in):
                c = hit[e, g_point[s0 + i]]
                if not deep[g_point[s0 + i]] or c == own[g]:
                    continue
                seen = False  # the same candidate from an earlier point of the group
                for i2 in range(i):
                    q = g_point[s0 + i2]
                    if hit[e, q] == c and deep[q]:
                        seen = True
                if seen:
                    continue
                through = True
                for i2 in range(n_in):
                    q = g_point[s0 + i2]
                    if hit[e, q] == c:
                        ok = deep[q]
                    else:
                        ok = _deep_through(normal, offset, count, c, ex, ey, ez, points[q, 0],
                                           points[q, 1], points[q, 2], depth)  # fmt: skip
                    if not ok:
                        through = False
                        break
                if through:
                    out[e, g] = True
                    break
    return out


@kernel(
    "b1[::1](f8[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], i8[::1], i8[::1], "
    "i8[:, ::1], f8[:, :, ::1], f8[:, ::1], i8[::1], f8)"
)
def shadowed_triples(end, d_lo, d_hi, r_lo, r_hi, own_f, own_w, hit, normal, offset, count,
                     depth):  # fmt: skip
    """Which (end, facet, edge) triples of one end point have every candidate blocked.

    A triple's diffraction point lies on the part ``d_lo -> d_hi`` (M, 3) of its edge, and its
    reflection point on ``r_lo -> r_hi``, that part's projection from the end's image onto the
    facet's plane. The triple is blocked when, for a convex solid ``c`` among its first hits
    ``hit`` (M, 4) other than the facet's and the edge's objects (``own_f``, ``own_w``), the
    segments from the end to ``r_lo`` and to ``r_hi`` pass ``depth`` into it (then so does every
    segment from the end to a reflection point: :func:`shadowed_groups`' convexity), or the legs
    ``r_lo -> d_lo`` and ``r_hi -> d_hi`` do. For the second: a diffraction point ``D`` between the
    two is ``I + s (c - I)``, ``s >= 1``, with ``I`` the image and ``c`` a weighted mean of the two
    legs' points in the shrunk solid, which lie in front of the facet's plane; so ``c`` is in the
    shrunk solid, in front of the plane and between ``I`` and ``D``: on the leg from the reflection
    point to ``D``. Planes as in :func:`line_span`.

    Returns
    -------
    (M,) bool
    """
    m = len(own_f)
    out = np.zeros(m, dtype=np.bool_)
    ex, ey, ez = end[0], end[1], end[2]
    for i in range(m):
        of, ow = own_f[i], own_w[i]
        for k in range(4):
            c = hit[i, k]
            if c < 0 or c == of or c == ow or count[c] == 0:
                continue
            if k < 2:  # the end's segment to the reflection point
                ok = _deep_through(normal, offset, count, c, ex, ey, ez, r_lo[i, 0], r_lo[i, 1],
                                   r_lo[i, 2], depth) and _deep_through(
                    normal, offset, count, c, ex, ey, ez, r_hi[i, 0], r_hi[i, 1], r_hi[i, 2],
                    depth)  # fmt: skip
            else:  # the leg from the reflection point to the edge
                ok = _deep_through(normal, offset, count, c, r_lo[i, 0], r_lo[i, 1], r_lo[i, 2],
                                   d_lo[i, 0], d_lo[i, 1], d_lo[i, 2], depth) and _deep_through(
                    normal, offset, count, c, r_hi[i, 0], r_hi[i, 1], r_hi[i, 2], d_hi[i, 0],
                    d_hi[i, 1], d_hi[i, 2], depth)  # fmt: skip
            if ok:
                out[i] = True
                break
    return out


@kernel(
    "Tuple((b1[::1], f8[::1], f8[::1], b1[::1]))("
    "f8[:, :, ::1], f8[:, ::1], i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], f8)"
)
def line_span(normal, offset, count, o, a, d, inset):
    """Where lines ``a + t d`` (n, 3) are at least ``inset`` metres inside convex solids ``o``
    (n,) given by their planes ``normal . x = offset`` (``normal`` (O, K, 3), ``offset`` (O, K),
    the first ``count[o]`` slots of each object's).

    Returns
    -------
    convex : (n,) bool, the object has planes (the other rows are not answered)
    t_in, t_out : (n,) float, metres along the line (``t_in > t_out``: no span)
    parallel_out : (n,) bool, a line parallel to a plane and beyond it (no span)
    """
    n = len(o)
    convex = np.zeros(n, dtype=np.bool_)
    t_in = np.full(n, np.inf)
    t_out = np.full(n, -np.inf)
    parallel_out = np.zeros(n, dtype=np.bool_)
    for r in range(n):
        cv, lo, hi, par = line_span1(normal, offset, count, o[r], a[r, 0], a[r, 1], a[r, 2],
                                     d[r, 0], d[r, 1], d[r, 2], inset)  # fmt: skip
        if cv:
            convex[r], t_in[r], t_out[r], parallel_out[r] = True, lo, hi, par
    return convex, t_in, t_out, parallel_out


@inline
def edge_distance1(corners, edge_normals, f, px, py, pz):
    """One point against one triangle: see :func:`edge_distance`. The three edges are measured
    before the first comparison (arrays before branches: :func:`raytrace.core.jit.inline`)."""
    v0 = _edge_side(corners, edge_normals, f, 0, px, py, pz)
    v1 = _edge_side(corners, edge_normals, f, 1, px, py, pz)
    v2 = _edge_side(corners, edge_normals, f, 2, px, py, pz)
    worst = -np.inf
    if v0 > worst or v0 != v0:
        worst = v0
    if v1 > worst or v1 != v1:
        worst = v1
    if v2 > worst or v2 != v2:
        worst = v2
    return worst


@inline
def _edge_side(corners, edge_normals, f, i, px, py, pz):
    """Signed distance of a point outside edge ``i`` of triangle ``f`` (in its plane)."""
    return ((px - corners[f, i, 0]) * edge_normals[f, i, 0]
            + (py - corners[f, i, 1]) * edge_normals[f, i, 1]) \
        + (pz - corners[f, i, 2]) * edge_normals[f, i, 2]  # fmt: skip


@kernel("f8[::1](f8[:, :, ::1], f8[:, :, ::1], i8[::1], f8[:, ::1])")
def edge_distance(corners, edge_normals, face, point):
    """Signed in-plane distance (n,) of points (n, 3) from the boundary of their triangles
    ``face`` (n,): the largest distance outside the three edge lines (``corners``, outward
    in-plane unit ``edge_normals`` (F, 3, 3), edge ``i`` from corner ``i``); <= 0 inside."""
    out = np.empty(len(face))
    for r in range(len(face)):
        out[r] = edge_distance1(corners, edge_normals, face[r], point[r, 0], point[r, 1],
                                point[r, 2])  # fmt: skip
    return out


@helper
def touches1(ob, ax, ay, az, dx, dy, dz, normal, offset, count, tol):
    """The line ``a + t d`` only touches convex solid ``ob`` (no span deeper than ``tol``;
    see :func:`raytrace.solver.kernels.walk._contact`)."""
    cv, lo, hi, par = line_span1(normal, offset, count, ob, ax, ay, az, dx, dy, dz, tol)
    return cv and (par or hi <= lo)


@helper
def sheet_touch1(ob, ax, ay, az, dx, dy, dz, near, plane, reach, edge_start, edge_count, edges,
                 tol):  # fmt: skip
    """Whether the line ``a + t d`` only touches flat sheet ``ob``, and whether along its plane.

    The sheets' analogue of :func:`touches1`: a line that stays within ``tol`` of the sheet's
    plane across the whole sheet (``|d . n| reach <= tol``) runs along it, and one that crosses
    the plane within ``tol`` of the sheet's outline passes its edge. Either only touches it:
    whether Embree reports such a hit depends on its BVH (a receiver in the plane of a fence,
    looking past the edge of the pane that meets it). The outline is tested only where the hit
    is ``near`` its triangle's boundary (:func:`raytrace.solver.kernels.walk._contact`). Arrays as
    :func:`raytrace.solver.penetration.flat_sheet_arrays` gives them (``reach`` 0: not a flat
    sheet). Returns (touch, along), bools."""
    r = reach[ob]
    if r <= 0.0:
        return False, False
    nx, ny, nz = plane[ob, 0], plane[ob, 1], plane[ob, 2]
    dn = dot3(nx, ny, nz, dx, dy, dz)
    if abs(dn) * r <= tol:
        return True, True
    if not near:
        return False, False
    tp = (plane[ob, 3] - dot3(nx, ny, nz, ax, ay, az)) / dn
    px, py, pz = ax + tp * dx, ay + tp * dy, az + tp * dz
    for k in range(edge_start[ob], edge_start[ob] + edge_count[ob]):
        ex, ey, ez = edges[k, 3] - edges[k, 0], edges[k, 4] - edges[k, 1], edges[k, 5] - edges[k, 2]
        wx, wy, wz = px - edges[k, 0], py - edges[k, 1], pz - edges[k, 2]
        ee = dot3(ex, ey, ez, ex, ey, ez)
        u = dot3(wx, wy, wz, ex, ey, ez) / ee if ee > 0 else 0.0
        u = min(max(u, 0.0), 1.0)
        qx, qy, qz = wx - u * ex, wy - u * ey, wz - u * ez
        if dot3(qx, qy, qz, qx, qy, qz) <= tol * tol:
            return True, False
    return False, False


@helper
def touches_segment1(ob, ax, ay, az, dx, dy, dz, t_max, normal, offset, count, tol):
    """:func:`touches1` for the segment ``0 <= t <= t_max`` of the line only."""
    cv, lo, hi, par = line_span1(normal, offset, count, ob, ax, ay, az, dx, dy, dz, tol)
    return cv and (par or min(hi, t_max) <= max(lo, 0.0))


@kernel("b1[::1](i8[::1], f8[:, ::1], f8[:, ::1], f8[::1], b1, f8[:, :, ::1], f8[:, ::1], "
        "i8[::1], f8)")  # fmt: skip
def touch_rows(o, a, d, t_max, segment, normal, offset, count, tol):
    """(n,) bool, :func:`touches1` of the lines ``a + t d`` (n, 3) and solids ``o`` (n,), or with
    ``segment`` :func:`touches_segment1` of their segments up to ``t_max`` (n,) metres (planes
    as in :func:`line_span`; False for objects without planes)."""
    out = np.empty(len(o), dtype=np.bool_)
    for i in range(len(o)):
        if segment:
            out[i] = touches_segment1(o[i], a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                      t_max[i], normal, offset, count, tol)  # fmt: skip
        else:
            out[i] = touches1(o[i], a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2], normal,
                              offset, count, tol)  # fmt: skip
    return out
