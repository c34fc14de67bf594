"""Compiled pruning driven by the scene's trees (:mod:`raytrace.scene.spatial`): what a
reflection in a facet can reach, found by walking a tree of edges with the facet's beam.

:func:`raytrace.solver.kernels.prune.facet_wedge_pairs` tests every (facet, object's edges)
group of one end point: (facets x objects) sphere tests, then every edge of an object that
passes. With objects of tens of thousands of edges (a scanned machine) a beam through a small
facet that grazes such an object tests all of its edges. Here the beam walks a tree of edges
instead: a node is skipped when its sphere is entirely behind the facet's plane or outside the
beam (the group test of the old loop on a node's sphere), and the edges of the leaves it reaches
get the old loop's per-edge tests, in its arithmetic. The triples found are the old loop's
(tests: ``tests/test_reach.py``); the candidates it finds, and so the paths, do not depend on the
walk.
"""

from __future__ import annotations

import numpy as np

from ...core.jit import helper, kernel
from .prune import FRAME_SIG, PAIRS_OUT_SIG, beam_reaches1, edge_span, grown_pairs, inside1

__all__ = ["facet_wedge_pairs_tree", "first_order_candidates"]

@helper
def _grown(buf, m, cap):
    """A copy of ``buf``'s first ``m`` rows in a buffer of ``cap`` rows."""
    out = np.empty(cap, np.int64)
    out[:m] = buf[:m]
    return out


_TREE_PAIRS_SIG = (
    f"Tuple(({PAIRS_OUT_SIG}, i8, i8))("
    # per facet of the end (F,): indices, side sign, end's distance from the plane, image
    # components (3, F), beam axis components (3, F), cos, sin of its half-angle, apex inside,
    # asked about this tree
    "i8[::1], f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], b1[::1], "
    # facets (K,): normals (K, 3), offsets; boxes lo, hi (K, 3)
    "f8[:, ::1], f8[::1], f8[:, ::1], f8[:, ::1], "
    # the tree: node centres (M, 3), radii, left, right, leaf start, count; element order and
    # the wedge of each element
    "f8[:, ::1], f8[::1], i8[::1], i8[::1], i8[::1], i8[::1], i8[::1], i8[::1], "
    # wedges (W,): start, end, middle (W, 3), half-length, length
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], "
    f"{FRAME_SIG}, f8, f8, b1, i8, {PAIRS_OUT_SIG}, i8, i8, i8)"
)


@kernel(_TREE_PAIRS_SIG)
def facet_wedge_pairs_tree(f_ok, sgn, h_f, img_c, axis_c, cos_a, sin_a, apex_in, f_active,
                           normal, offset, lo, hi,
                           node_centre, node_radius, left, right, start, count, order, w_of,
                           w_start, w_end, w_mid, w_half, w_length,
                           t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           eps, pad, prune, e, out_e, out_f, out_w, out_img, out_lo, out_hi,
                           m, j0, cap):  # fmt: skip
    """The (facet, wedge) triples of one end point (``e``) where a reflection in the facet can
    reach the edge, for the edges of one tree, written after the ``m`` rows already in the
    output buffers: the conditions of :func:`raytrace.solver.kernels.prune.facet_wedge_pairs`,
    condition 1 on the tree's node spheres instead of objects' groups. Only the facets with
    ``f_active`` ask this tree. Same outputs as that function, and the first facet (index into
    ``f_ok``) not asked: the facets are taken from ``j0`` on and no new one once the buffers
    hold ``cap`` rows (one facet's triples are never split), so that a caller can stream an
    end's triples in bounded chunks.

    long kernel: one walk per facet with the per-edge tests at its leaves; split into helpers,
    the output buffers would be live across their branches (numba's reference counts per call,
    :func:`raytrace.core.jit.inline`). The per-edge tests are those of
    :func:`~raytrace.solver.kernels.prune.facet_wedge_pairs`, written out again for that reason
    (an inline helper of them reads the edge arrays after its first branch; numba also refuses
    to inline it).
    """
    stack = np.empty(256, np.int64)
    for j in range(j0, len(f_ok)):
        if m >= cap:
            return out_e, out_f, out_w, out_img, out_lo, out_hi, m, j
        if not f_active[j]:
            continue
        f = f_ok[j]
        s_j = sgn[j]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        ix, iy, iz = img_c[0, j], img_c[1, j], img_c[2, j]
        ux, uy, uz = axis_c[0, j], axis_c[1, j], axis_c[2, j]
        ca, sa, ai = cos_a[j], sin_a[j], apex_in[j]
        h = h_f[j]
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
            if m + count[node] > len(out_e):
                out_e, out_f, out_w, out_img, out_lo, out_hi = grown_pairs(
                    out_e, out_f, out_w, out_img, out_lo, out_hi, m + count[node])  # fmt: skip
            for k in range(start[node], start[node] + count[node]):
                w = w_of[order[k]]
                ax, ay, az = w_start[w, 0], w_start[w, 1], w_start[w, 2]
                bx, by, bz = w_end[w, 0], w_end[w, 1], w_end[w, 2]
                da = (ax * nx + ay * ny + az * nz - off) * s_j
                db = (bx * nx + by * ny + bz * nz - off) * s_j
                # the rule, not a pruning: a reflection reaches only an edge with a part strictly
                # on the reflecting side (an edge in the facet's plane, one of its own, does not)
                if not (da > eps or db > eps):
                    continue
                if not prune:
                    out_e[m], out_f[m], out_w[m] = e, f, w
                    out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
                    out_lo[m], out_hi[m] = -np.inf, np.inf
                    m += 1
                    continue
                if not beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, ai,
                                     w_mid[w, 0], w_mid[w, 1], w_mid[w, 2], w_half[w]):  # fmt: skip
                    continue
                if inside1(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           w, ix, iy, iz):  # fmt: skip
                    continue
                ok, t_lo, t_hi = edge_span(ax, ay, az, bx, by, bz, ix, iy, iz, da, db, eps, h,
                                            lo[f, 0], lo[f, 1], lo[f, 2], hi[f, 0], hi[f, 1],
                                            hi[f, 2], w_length[w], pad)  # fmt: skip
                if not ok:
                    continue
                out_e[m], out_f[m], out_w[m] = e, f, w
                out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
                out_lo[m], out_hi[m] = t_lo, t_hi
                m += 1
    return out_e, out_f, out_w, out_img, out_lo, out_hi, m, len(f_ok)


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
            nx, ny, nz = normal[k, 0], normal[k, 1], normal[k, 2]
            d = px * nx + py * ny + pz * nz - offset[k]
            ix, iy, iz = px - 2.0 * d * nx, py - 2.0 * d * ny, pz - 2.0 * d * nz
            # the beam from the image through the facet's sphere
            vx, vy, vz = centre[k, 0] - ix, centre[k, 1] - iy, centre[k, 2] - iz
            dist = np.sqrt(vx * vx + vy * vy + vz * vz)
            inside = dist <= radius[k]
            ux, uy, uz = vx / dist, vy / dist, vz / dist
            sa = min(radius[k] / dist, 1.0)
            ca = np.sqrt(1.0 - sa * sa)
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
