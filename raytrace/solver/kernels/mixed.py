"""Compiled candidates of the mixed stages RD and DR (numba, options in :mod:`raytrace.core.jit`).

:func:`reflection_edge_points` takes the (end, facet, wedge) triples of
:func:`raytrace.solver.kernels.prune.facet_wedge_pairs` and the other ends, prunes the pairs as
:func:`~raytrace.solver.kernels.prune.expand_over_others` does, and tests them exactly one at a
time with the physics and scene modules' compiled scalar rules
(:func:`raytrace.physics.utd.keller_point`, :func:`raytrace.scene.accel.facet_box_test`,
:func:`raytrace.physics.utd.diffraction_valid1`), in the arithmetic of their vectorised forms
(bitwise the same candidates). :func:`mixed_candidates` lays the survivors out as the back
end's candidate arrays.
"""

from __future__ import annotations

import numpy as np

from ...core.jit import kernel
from ...core.vec import dot3
from ...physics.utd import diffraction_valid1, keller_point
from ...scene.accel import FACET_TEST_SIG, facet_box_test, in_triangles
from .prune import along_and_off, in_span

__all__ = ["reflection_edge_points", "mixed_candidates"]


@kernel(
    "Tuple((i8[::1], i8[::1], f8[:, ::1], i8))("
    # triples start:stop: end, facet, wedge (M,), the end's image (M, 3), span lo, hi (M,)
    "i8, i8, i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], f8[::1], "
    # other ends (O, 3); along, off and open per (wedge, other end) (W, O)
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], b1[:, ::1], "
    # wedges (W, 3): start, unit direction, end; facets: normal (K, 3), offset (K,)
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], "
    # reflecting side of each facet for each end (E, K); the wedges' UTD frames e, t0, n0 (W, 3)
    # and n (W,); the reflection before the edge (RD)
    f"i1[:, ::1], {FACET_TEST_SIG}, f8, f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], b1, b1)"
)
def reflection_edge_points(start, stop, e_idx, f_idx, w_idx, img, t_lo, t_hi, others, td_w,
                           rho_w, open_w, w_start, w_dir, w_end, normal, offset, side, lo, hi,
                           rect, r_lo, r_hi, tri_start, tri_count, corner, v0, v1, d00, d01, d11,
                           den, bary_tol, rect_inside, keller_tol, fr_e, fr_t0, fr_n0, fr_n,
                           before, prune):  # fmt: skip
    """The RD or DR candidates of triples ``start:stop`` (end, facet, wedge, the end's image in
    the facet) and the other ends: the pruning of
    :func:`~raytrace.solver.kernels.prune.expand_over_others`, then the exact tests of
    :func:`raytrace.solver.diffraction._one_reflection` one pair at a time, with the same
    arithmetic as their vectorised forms:

    * Keller's point of the image and the other end on the edge
      (:func:`raytrace.physics.utd.keller_point`);
    * that point on the end's reflecting side of the facet's plane;
    * the segment image -> point crossing the plane between its ends (``0 < u < 1``);
    * the crossing inside the facet (:func:`raytrace.scene.accel.facet_box_test`,
      :func:`~raytrace.scene.accel.in_triangles`);
    * a valid diffraction from the image (``before``, RD) or the other end (DR) to the other
      (:func:`raytrace.physics.utd.diffraction_valid1`).

    The image's edge coordinate and distance from the edge line (which prune only) are computed
    here (:func:`along_and_off`).

    Returns
    -------
    q : (M,) int, triples (absolute indices), in order
    o : (M,) int, other ends
    points : (M, 6) float, metres: the diffraction point, then the reflection point
    n_pairs : int, the pairs that passed the pruning (the exact tests' candidates)
    """
    n_o = td_w.shape[1]
    # room for every pair: no growth, no reassignment in the loop (see expand_over_others; 14 %
    # of this kernel on the 2 m grid)
    cap = max(stop - start, 0) * n_o
    out_q = np.empty(cap, dtype=np.int64)
    out_o = np.empty(cap, dtype=np.int64)
    out_p = np.empty((cap, 6))
    m, n_pairs = 0, 0
    for q in range(start, stop):
        w, f = w_idx[q], f_idx[q]
        ix, iy, iz = img[q, 0], img[q, 1], img[q, 2]
        tq, rq = along_and_off(ix, iy, iz, w_start[w, 0], w_start[w, 1], w_start[w, 2],
                               w_dir[w, 0], w_dir[w, 1], w_dir[w, 2])  # fmt: skip
        lo_q, hi_q = t_lo[q], t_hi[q]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        sd = side[e_idx[q], f]
        sa = dot3(ix, iy, iz, nx, ny, nz) - off  # the image's signed distance from the plane
        for o in range(n_o):
            if prune and not (open_w[w, o] and in_span(tq, rq, lo_q, hi_q, td_w[w, o],
                                                       rho_w[w, o])):  # fmt: skip
                continue
            n_pairs += 1
            px, py, pz, _, on_edge = keller_point(
                ix, iy, iz, others[o, 0], others[o, 1], others[o, 2], w_start[w, 0],
                w_start[w, 1], w_start[w, 2], w_end[w, 0], w_end[w, 1], w_end[w, 2], keller_tol)  # fmt: skip
            if not on_edge:
                continue
            sb = dot3(px, py, pz, nx, ny, nz) - off
            if not ((sb > 0 and sd > 0) or (sb < 0 and sd < 0) or (sb == 0 and sd == 0)):
                continue  # np.sign(sb) != side (NaN: never equal)
            den_u = sa - sb
            if not abs(den_u) > 0:
                continue
            u = sa / den_u
            if not (u > 0 and u < 1):
                continue
            cx, cy, cz = ix + u * (px - ix), iy + u * (py - iy), iz + u * (pz - iz)
            quick = facet_box_test(cx, cy, cz, f, lo, hi, rect, r_lo, r_hi, rect_inside)
            if quick == 0 or (quick < 0 and not in_triangles(
                    cx, cy, cz, f, tri_start, tri_count, corner, v0, v1, d00, d01, d11, den,
                    bary_tol)):  # fmt: skip
                continue
            # the diffraction's source and receiver: the image first for RD, last for DR
            ax, ay, az = (ix, iy, iz) if before else (others[o, 0], others[o, 1], others[o, 2])
            bx, by, bz = (others[o, 0], others[o, 1], others[o, 2]) if before else (ix, iy, iz)
            if not diffraction_valid1(fr_e, fr_t0, fr_n0, fr_n, w, ax, ay, az, bx, by, bz, px,
                                      py, pz):  # fmt: skip
                continue
            out_q[m], out_o[m] = q, o
            out_p[m, 0], out_p[m, 1], out_p[m, 2] = px, py, pz
            out_p[m, 3], out_p[m, 4], out_p[m, 5] = cx, cy, cz
            m += 1
    return out_q[:m].copy(), out_o[:m].copy(), out_p[:m].copy(), n_pairs


@kernel(
    "Tuple((i8[::1], i8[::1], f8[:, :, ::1], i8[:, ::1], i1[:, ::1], f8[:, :, ::1], i8[:, ::1]))("
    "i8[::1], i8[::1], f8[:, ::1], i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], i8[::1], "
    "i8[::1], b1, i1, i1)"
)
def mixed_candidates(q, o_idx, points, e_idx, f_idx, w_idx, tx, rx, facet_object, wedge_object,
                     before, reflection, diffraction):  # fmt: skip
    """The arrays of :class:`raytrace.solver.evaluate.Candidates` of RD (``before``) or DR
    candidates from :func:`reflection_edge_points`' output (triples ``q``, other ends ``o_idx``,
    diffraction and reflection points (M, 6)) and the triples (end, facet, wedge), in one pass:
    ``t_idx, r_idx`` (M,), ``verts`` (M, 2, 3) in path order, ``elem`` (M, 2) (facet of the
    reflection, wedge of the diffraction), ``kinds`` (M, 2), ``chain`` (M, 4, 3) (transmitter,
    vertices, receiver) and ``vobj`` (M, 2) (the object under each vertex)."""
    m = len(q)
    t_out, r_out = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    verts, chain = np.empty((m, 2, 3)), np.empty((m, 4, 3))
    elem, vobj = np.empty((m, 2), dtype=np.int64), np.empty((m, 2), dtype=np.int64)
    kinds = np.empty((m, 2), dtype=np.int8)
    r_v, d_v = (0, 1) if before else (1, 0)  # the reflection's and the diffraction's vertex
    for i in range(m):
        t = q[i]
        e, o, f, w = e_idx[t], o_idx[i], f_idx[t], w_idx[t]
        ti, ri = (e, o) if before else (o, e)
        t_out[i], r_out[i] = ti, ri
        for c in range(3):
            verts[i, d_v, c] = points[i, c]
            verts[i, r_v, c] = points[i, 3 + c]
            chain[i, 0, c] = tx[ti, c]
            chain[i, 1 + d_v, c] = points[i, c]
            chain[i, 1 + r_v, c] = points[i, 3 + c]
            chain[i, 3, c] = rx[ri, c]
        elem[i, r_v], elem[i, d_v] = f, w
        kinds[i, r_v], kinds[i, d_v] = reflection, diffraction
        vobj[i, r_v], vobj[i, d_v] = facet_object[f], wedge_object[w]
    return t_out, r_out, verts, elem, kinds, chain, vobj
