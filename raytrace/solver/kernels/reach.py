"""Compiled pruning driven by the scene's trees (:mod:`raytrace.scene.spatial`): what a
reflection in a facet can reach, found by walking a tree of edges with the facet's beam.

:func:`raytrace.solver.kernels.prune.facet_wedge_pairs` tests every (facet, object's edges)
group of one end point: (facets x objects) sphere tests, then every edge of an object that
passes. With objects of tens of thousands of edges (a scanned machine) a beam through a small
facet that grazes such an object tests all of its edges. Here the beam walks a tree of edges
instead: a node is skipped when its sphere is entirely behind the facet's plane or outside the
beam (the group test of the old loop on a node's sphere), and the edges of the leaves it reaches
get the old loop's per-edge tests, in its arithmetic. The triples found are the old loop's
(tests: ``tests/test_candidates_oracle.py``); the candidates it finds, and so the paths, do not
depend on the walk.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...core.jit import helper, inline, kernel
from ...scene.accel import facet_sees
from .prune import FRAME_SIG, PAIRS_OUT_SIG, beam_reaches1, edge_span, inside1, point_in_beam1

__all__ = ["EdgeLeaves", "edge_leaves", "facet_wedge_pairs_near", "facet_wedge_pairs_tree",
           "first_order_candidates",
           "second_facets", "second_pairs_reaching"]

@helper
def _grown(buf, m, cap):
    """A copy of ``buf``'s first ``m`` rows in a buffer of ``cap`` rows."""
    out = np.empty(cap, np.int64)
    out[:m] = buf[:m]
    return out


class EdgeLeaves(NamedTuple):
    """A tree of edges (:class:`raytrace.scene.spatial.SphereTree`) with what the walk of
    :func:`facet_wedge_pairs_tree` reads of each edge copied into the tree's leaf order: a leaf's
    edges are consecutive rows, read in order, where reading them through the tree's ``order``
    and the wedges' own order jumped about memory (half of the walk's time on a scanned hall).

    Attributes
    ----------
    node_centre : (M, 3) float, node_radius : (M,) float, left, right, start, count : (M,) int:
        the tree's nodes (:class:`raytrace.scene.spatial.SphereTree`)
    wedge : (N,) int, the wedge in each leaf slot
    geometry : (N, 11) float: start (3), end (3), middle (3), metres; half-length, length, metres
    t0, n0 : (3, N) float; t_start, n_start, cos_n, sin_n : (N,) float; prunable : (N,) bool:
        the wedge frame of :func:`raytrace.solver.kernels.surely_inside` in leaf order (its
        :func:`~raytrace.solver.kernels.prune.inside1` reads them at the leaf slot)
    """

    node_centre: np.ndarray
    node_radius: np.ndarray
    left: np.ndarray
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray
    wedge: np.ndarray
    geometry: np.ndarray
    t0: np.ndarray
    n0: np.ndarray
    t_start: np.ndarray
    n_start: np.ndarray
    cos_n: np.ndarray
    sin_n: np.ndarray
    prunable: np.ndarray


def edge_leaves(tree, w_of: np.ndarray, wedges: tuple, frame: tuple) -> EdgeLeaves:
    """:class:`EdgeLeaves` of ``tree``, whose element ``i`` is wedge ``w_of[i]``.

    Parameters
    ----------
    tree : :class:`raytrace.scene.spatial.SphereTree`
    w_of : (N,) int
    wedges : (start, end, middle (W, 3), half-length, length (W,)), metres
    frame : the wedge frame's arrays ``(t0, n0 (3, W), t_start, n_start, cos_n, sin_n (W,),
        prunable (W,) bool)`` (the scalars after them are not read)
    """
    c = np.ascontiguousarray
    w = c(np.asarray(w_of, np.int64)[tree.order])
    w_start, w_end, w_mid, w_half, w_length = wedges
    t0, n0, t_start, n_start, cos_n, sin_n, prunable = frame[:7]
    geometry = c(np.column_stack([w_start[w], w_end[w], w_mid[w], w_half[w], w_length[w]]))
    return EdgeLeaves(c(tree.node_centre), c(tree.node_radius), c(tree.left, np.int64),
                      c(tree.right, np.int64), c(tree.start, np.int64), c(tree.count, np.int64),
                      w, geometry.reshape(-1, 11), c(t0[:, w]), c(n0[:, w]), c(t_start[w]),
                      c(n_start[w]), c(cos_n[w]), c(sin_n[w]), c(prunable[w], bool))


_TREE_PAIRS_SIG = (
    "UniTuple(i8, 2)("
    # per facet of the end (F,): indices, side sign, end's distance from the plane, image
    # components (3, F), beam axis components (3, F), cos, sin of its half-angle, apex inside,
    # asked about this tree
    "i8[::1], f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], b1[::1], "
    # facets (K,): normals (K, 3), offsets; boxes lo, hi (K, 3)
    "f8[:, ::1], f8[::1], f8[:, ::1], f8[:, ::1], "
    # the tree of edges in leaf order (EdgeLeaves), its wedge frame with the frame's scalars
    f"f8[:, ::1], f8[::1], i8[::1], i8[::1], i8[::1], i8[::1], i8[::1], f8[:, ::1], {FRAME_SIG}, "
    # tolerances, pruning, the end, the output buffers, the first facet
    f"f8, f8, b1, i8, {PAIRS_OUT_SIG}, i8)"
)


@kernel(_TREE_PAIRS_SIG)
def facet_wedge_pairs_tree(f_ok, sgn, h_f, img_c, axis_c, cos_a, sin_a, apex_in, f_active,
                           normal, offset, lo, hi,
                           node_centre, node_radius, left, right, start, count, leaf_w, geo,
                           t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           eps, pad, prune, e, out_e, out_f, out_w, out_img, out_lo, out_hi,
                           j0):  # fmt: skip
    """The (facet, wedge) triples of one end point (``e``) where a reflection in the facet can
    reach the edge, for the edges of one tree (:class:`EdgeLeaves`): the conditions of
    :func:`raytrace.solver.kernels.prune.facet_wedge_pairs`, condition 1 on the tree's node
    spheres instead of objects' groups. Only the facets with ``f_active`` ask this tree.

    Written into the output buffers from their first row, facets from ``j0`` on (index into
    ``f_ok``), whole facets only: returns ``(m, j)``, the rows written and the first facet not
    done, ``len(f_ok)`` when all are. A facet whose triples do not fit in the rows left is left
    for the next call (``m`` rows of the facets before it; ``m == 0``: the buffers are too small
    for that one facet), so a caller streams an end's triples in chunks of the buffers' size.

    long kernel: one walk per facet with the per-edge tests at its leaves; split into helpers,
    the output buffers would be live across their branches (numba's reference counts per call,
    :func:`raytrace.core.jit.inline`). The per-edge tests are those of
    :func:`~raytrace.solver.kernels.prune.facet_wedge_pairs`, written out again for that reason.
    """
    stack = np.empty(256, np.int64)
    cap = len(out_e)
    m = 0
    for j in range(j0, len(f_ok)):
        if not f_active[j]:
            continue
        m_j = m
        f = f_ok[j]
        s_j = sgn[j]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        ix, iy, iz = img_c[0, j], img_c[1, j], img_c[2, j]
        ux, uy, uz = axis_c[0, j], axis_c[1, j], axis_c[2, j]
        ca, sa, ai = cos_a[j], sin_a[j], apex_in[j]
        h = h_f[j]
        flx, fly, flz, fhx, fhy, fhz = lo[f, 0], lo[f, 1], lo[f, 2], hi[f, 0], hi[f, 1], hi[f, 2]
        top = 0
        stack[0] = 0
        while top >= 0:
            node = stack[top]
            top -= 1
            gx, gy, gz, gr = node_centre[node, 0], node_centre[node, 1], node_centre[node, 2], \
                node_radius[node]  # fmt: skip
            if prune and not (
                (gx * nx + gy * ny + gz * nz - off) * s_j + gr > eps
                and beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, ai, gx, gy, gz, gr)
            ):
                continue
            if left[node] >= 0:
                top += 1
                stack[top] = right[node]
                top += 1
                stack[top] = left[node]
                continue
            if m + count[node] > cap:
                return m_j, j  # this facet does not fit: the next call starts with it
            for k in range(start[node], start[node] + count[node]):
                ax, ay, az = geo[k, 0], geo[k, 1], geo[k, 2]
                bx, by, bz = geo[k, 3], geo[k, 4], geo[k, 5]
                da = (ax * nx + ay * ny + az * nz - off) * s_j
                db = (bx * nx + by * ny + bz * nz - off) * s_j
                # the rule, not a pruning: a reflection reaches only an edge with a part strictly
                # on the reflecting side (an edge in the facet's plane, one of its own, does not)
                if not (da > eps or db > eps):
                    continue
                if not prune:
                    out_e[m], out_f[m], out_w[m] = e, f, leaf_w[k]
                    out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
                    out_lo[m], out_hi[m] = -np.inf, np.inf
                    m += 1
                    continue
                if not beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, ai, geo[k, 6], geo[k, 7],
                                     geo[k, 8], geo[k, 9]):  # fmt: skip
                    continue
                if inside1(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2, k,
                           ix, iy, iz):  # fmt: skip
                    continue
                ok, t_lo, t_hi = edge_span(ax, ay, az, bx, by, bz, ix, iy, iz, da, db, eps, h,
                                            flx, fly, flz, fhx, fhy, fhz, geo[k, 10], pad)  # fmt: skip
                if not ok:
                    continue
                out_e[m], out_f[m], out_w[m] = e, f, leaf_w[k]
                out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
                out_lo[m], out_hi[m] = t_lo, t_hi
                m += 1
    return m, len(f_ok)


_NEAR_PAIRS_SIG = (
    "UniTuple(i8, 2)("
    # per facet of the end (F,), as _TREE_PAIRS_SIG
    "i8[::1], f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], b1[::1], "
    # facets (K,): normals, offsets, boxes; each facet's run of near edges' leaf slots
    "f8[:, ::1], f8[::1], f8[:, ::1], f8[:, ::1], i8[::1], i4[::1], "
    # the tree's edges in leaf order (EdgeLeaves) with its wedge frame
    f"i8[::1], f8[:, ::1], {FRAME_SIG}, "
    f"f8, f8, b1, i8, {PAIRS_OUT_SIG}, i8)"
)


@kernel(_NEAR_PAIRS_SIG)
def facet_wedge_pairs_near(f_ok, sgn, h_f, img_c, axis_c, cos_a, sin_a, apex_in, f_active,
                           normal, offset, lo, hi, near_start, near_slot, leaf_w, geo,
                           t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           eps, pad, prune, e, out_e, out_f, out_w, out_img, out_lo, out_hi,
                           j0):  # fmt: skip
    """:func:`facet_wedge_pairs_tree` for the small facets of the approximate discovery
    (:mod:`raytrace.solver.near`): the facets with ``f_active`` take the edges of their own
    lists (``near_slot[near_start[f]:near_start[f + 1]]``, leaf slots of the tree) instead of
    walking the tree with their beams, with the same per-edge tests in the same arithmetic.
    Buffers, ``j0`` and the return as :func:`facet_wedge_pairs_tree`.

    long kernel: the per-edge tests are written out for the reason that kernel gives.
    """
    cap = len(out_e)
    m = 0
    for j in range(j0, len(f_ok)):
        if not f_active[j]:
            continue
        f = f_ok[j]
        k0, k1 = near_start[f], near_start[f + 1]
        if m + (k1 - k0) > cap:
            return m, j  # this facet does not fit: the next call starts with it
        s_j = sgn[j]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        ix, iy, iz = img_c[0, j], img_c[1, j], img_c[2, j]
        ux, uy, uz = axis_c[0, j], axis_c[1, j], axis_c[2, j]
        ca, sa, ai = cos_a[j], sin_a[j], apex_in[j]
        h = h_f[j]
        flx, fly, flz, fhx, fhy, fhz = lo[f, 0], lo[f, 1], lo[f, 2], hi[f, 0], hi[f, 1], hi[f, 2]
        for i in range(k0, k1):
            k = np.int64(near_slot[i])
            ax, ay, az = geo[k, 0], geo[k, 1], geo[k, 2]
            bx, by, bz = geo[k, 3], geo[k, 4], geo[k, 5]
            da = (ax * nx + ay * ny + az * nz - off) * s_j
            db = (bx * nx + by * ny + bz * nz - off) * s_j
            if not (da > eps or db > eps):
                continue
            t_lo, t_hi = -np.inf, np.inf
            if prune:
                if not beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, ai, geo[k, 6], geo[k, 7],
                                     geo[k, 8], geo[k, 9]):  # fmt: skip
                    continue
                if inside1(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           k, ix, iy, iz):  # fmt: skip
                    continue
                ok, t_lo, t_hi = edge_span(ax, ay, az, bx, by, bz, ix, iy, iz, da, db, eps, h,
                                            flx, fly, flz, fhx, fhy, fhz, geo[k, 10], pad)  # fmt: skip
                if not ok:
                    continue
            out_e[m], out_f[m], out_w[m] = e, f, leaf_w[k]
            out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
            out_lo[m], out_hi[m] = t_lo, t_hi
            m += 1
    return m, len(f_ok)


@kernel("i1[::1](i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], i8[::1], "
        "f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], b1[::1], f8[:, ::1], i8[::1], i8[::1], f8)")
def second_facets(a_idx, f2, apex, axis, cos_a, sin_a, inside, f1, centre, radius, normal, offset,
                  two_sided, corners, c_start, c_count, tol):  # fmt: skip
    """The exact necessary conditions of a double reflection on (first facet, second facet)
    pairs, in one pass, with the arithmetic of the numpy passes they replaced (a million pairs
    per transmitter of a scanned hall went through five passes and their temporaries): the
    first image on a reflecting side of the second facet
    (:func:`raytrace.solver.reflection.side_of`), the two facets facing each other
    (:func:`raytrace.scene.accel.facing`) and the beam from the first image through the first
    facet reaching the second facet's sphere (:func:`raytrace.solver.reflection.cone_reaches`).

    Pairs: row ``a_idx`` (P,) of the first facets' arrays (``apex`` = the first images, the
    beam's ``axis`` (F, 3), ``cos_a``, ``sin_a``, ``inside`` (F,), the facet ``f1`` (F,)) and the
    second facet ``f2`` (P,). Facets (K,): bounding spheres ``centre`` (K, 3), ``radius``;
    planes; ``two_sided``; corners (V, 3) and each facet's run of them.

    Returns (P,) int8: the side of the second facet the first image is on, 0 where a condition
    fails.
    """
    out = np.zeros(len(a_idx), np.int8)
    for p in range(len(a_idx)):
        a, fb = a_idx[p], f2[p]
        fa = f1[a]
        ix, iy, iz = apex[a, 0], apex[a, 1], apex[a, 2]
        # side_of: the first image against the second facet's plane
        s = ix * normal[fb, 0] + iy * normal[fb, 1] + iz * normal[fb, 2] - offset[fb]
        si = 0
        if s > tol:
            si = 1
        elif s < -tol and two_sided[fb]:
            si = -1
        if si == 0:
            continue
        # facing: each has a corner strictly on a reflecting side of the other
        if fa == fb or not facet_sees(corners, c_start[fa], c_count[fa], normal[fb, 0],
                                      normal[fb, 1], normal[fb, 2], offset[fb], two_sided[fb],
                                      tol):  # fmt: skip
            continue
        if not facet_sees(corners, c_start[fb], c_count[fb], normal[fa, 0], normal[fa, 1],
                          normal[fa, 2], offset[fa], two_sided[fa], tol):  # fmt: skip
            continue
        # cone_reaches (reflection.beam_reaches' arithmetic)
        ex, ey, ez, er = centre[fb, 0], centre[fb, 1], centre[fb, 2], radius[fb]
        vx, vy, vz = ex - ix, ey - iy, ez - iz
        dt = np.sqrt(vx * vx + vy * vy + vz * vz)
        cos_ang = (axis[a, 0] * vx + axis[a, 1] * vy + axis[a, 2] * vz) / dt
        sb = min(er / dt, 1.0)
        if cos_ang >= cos_a[a] * np.sqrt(1.0 - sb * sb) - sin_a[a] * sb - 1e-7 or inside[a] \
                or dt <= er:  # fmt: skip
            out[p] = si
    return out


@inline
def image_beam1(px, py, pz, nx, ny, nz, off, cx, cy, cz, r):
    """The mirror image of a point in a plane (``n . x = off``), as
    :func:`raytrace.solver.reflection.mirror` makes it, and the beam from it through a sphere
    (centre ``c``, radius ``r``), as :func:`~raytrace.solver.reflection.beam` makes it, in
    scalars: ``(ix, iy, iz, ux, uy, uz, cos_a, sin_a, dist)``, the image, the axis, the
    half-angle's cosine and sine and the image's distance from the centre (the apex is inside
    the sphere where ``dist <= r``)."""
    d = px * nx + py * ny + pz * nz - off
    ix, iy, iz = px - 2.0 * d * nx, py - 2.0 * d * ny, pz - 2.0 * d * nz
    vx, vy, vz = cx - ix, cy - iy, cz - iz
    dist = np.sqrt(vx * vx + vy * vy + vz * vz)
    sa = min(r / dist, 1.0)
    return ix, iy, iz, vx / dist, vy / dist, vz / dist, np.sqrt(1.0 - sa * sa), sa, dist


@kernel("Tuple((i8[::1], i8[::1], i8[::1]))(i1[:, ::1], i1[:, ::1], b1[::1], f8[:, ::1], "
        "f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], f8, f8, f8, f8, b1)")
def first_order_candidates(side_t, side_r, chosen, tx, rx, normal, offset, centre, radius, cx, cy,
                           cz, rx_radius, prune):  # fmt: skip
    """The (transmitter, facet, receiver) triples of single reflections, in that order: both
    ends strictly on the same reflecting side of the facet (``side_t`` (T, K), ``side_r`` (R,
    K), 0 where it cannot reflect for that end), the facet ``chosen`` (K,); and, a necessary
    condition (``prune``), the receiver in the beam from the transmitter's image through the
    facet's bounding sphere (``centre`` (K, 3), ``radius`` (K,)), tested on the receivers'
    bounding sphere (``cx, cy, cz``, ``rx_radius``) first. In place of a dense (T, K, R) table:
    a trace of a million facets emits the few triples whose beam holds a receiver."""
    n_t, n_k, n_r = side_t.shape[0], side_t.shape[1], side_r.shape[0]
    cap = 1024
    out_t = np.empty(cap, np.int64)
    out_k = np.empty(cap, np.int64)
    out_r = np.empty(cap, np.int64)
    m = 0
    for t in range(n_t):
        px, py, pz = tx[t, 0], tx[t, 1], tx[t, 2]
        for k in range(n_k):
            s = side_t[t, k]
            if s == 0 or not chosen[k]:
                continue
            ix, iy, iz, ux, uy, uz, ca, sa, dist = image_beam1(
                px, py, pz, normal[k, 0], normal[k, 1], normal[k, 2], offset[k], centre[k, 0],
                centre[k, 1], centre[k, 2], radius[k])  # fmt: skip
            inside = dist <= radius[k]
            if prune and not beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, inside, cx, cy, cz,
                                           rx_radius):  # fmt: skip
                continue
            if m + n_r > cap:
                cap = max(2 * cap, m + n_r)
                out_t = _grown(out_t, m, cap)
                out_k = _grown(out_k, m, cap)
                out_r = _grown(out_r, m, cap)
            for r in range(n_r):
                if side_r[r, k] != s:
                    continue
                if prune and not beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, inside, rx[r, 0],
                                               rx[r, 1], rx[r, 2], 0.0):  # fmt: skip
                    continue
                out_t[m], out_k[m], out_r[m] = t, k, r
                m += 1
    return out_t[:m].copy(), out_k[:m].copy(), out_r[:m].copy()


@kernel("b1[::1](i8[::1], i8[::1], i1[::1], f8[:, ::1], f8[:, ::1], f8[::1], b1[::1], "
        "f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], i1[:, ::1], f8[:, ::1], f8)")
def second_pairs_reaching(a_idx, f2, s_img, img1, axis1, cos1, in1, normal, offset, centre, radius,
                          side_rx, rx, slack):  # fmt: skip
    """Whether each (first image, second facet) pair of a double reflection can reach one of
    the receivers: a looser form of the receiver tests of
    :func:`raytrace.solver.kernels.prune.second_order_candidates`, for the pairs of a trace
    that are not kept (a pair it rejects, that kernel rejects for every receiver).

    Pairs: row ``a_idx`` (P,) of the first images ``img1`` (F, 3) and of their beams through
    the first facets (``axis1`` (F, 3), ``cos1``, ``in1`` (F,)), second facet ``f2`` (P,), the
    first image's side of it ``s_img`` (P,). The second image (the first mirrored in the second
    facet's plane) and its beam through the second facet's bounding sphere (``centre`` (K, 3),
    ``radius`` (K,)) are made here, as :func:`raytrace.solver.reflection.mirror` and
    :func:`~raytrace.solver.reflection.beam` make them. A receiver (``rx`` (R, 3)) qualifies
    when it is on the first image's side of the second facet (``side_rx`` (R, K), the rule),
    within that beam, and its mirror image in the second facet within the first facet's beam;
    the beams' cosines are lowered by ``slack`` (beyond the other kernel's own 1e-7) so that
    rounding here never rejects what the exact arithmetic there accepts.

    Returns (P,) bool.
    """
    out = np.zeros(len(a_idx), np.bool_)
    for p in range(len(a_idx)):
        a, f, s = a_idx[p], f2[p], s_img[p]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        jx, jy, jz = img1[a, 0], img1[a, 1], img1[a, 2]
        ux1, uy1, uz1, c1, in1_a = axis1[a, 0], axis1[a, 1], axis1[a, 2], cos1[a] - slack, in1[a]
        kx, ky, kz, ux, uy, uz, c2, _, dist = image_beam1(jx, jy, jz, nx, ny, nz, off,
                                                           centre[f, 0], centre[f, 1],
                                                           centre[f, 2], radius[f])  # fmt: skip
        in2 = dist <= radius[f] * (1.0 + 1e-9)
        c2 -= slack
        for r in range(rx.shape[0]):
            if side_rx[r, f] != s:
                continue
            px, py, pz = rx[r, 0], rx[r, 1], rx[r, 2]
            if not point_in_beam1(kx, ky, kz, ux, uy, uz, c2, in2, px, py, pz):
                continue
            # the receiver's mirror image in the second facet, in the first facet's beam
            e = px * nx + py * ny + pz * nz - off
            if point_in_beam1(jx, jy, jz, ux1, uy1, uz1, c1, in1_a, px - 2.0 * e * nx,
                              py - 2.0 * e * ny, pz - 2.0 * e * nz):  # fmt: skip
                out[p] = True
                break
    return out

