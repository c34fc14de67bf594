"""Compiled pruning of the tracer's candidates (numba, options in :mod:`raytrace.core.jit`).

The mixed stages (RD, DR, RDR) look for (end point, facet, wedge) triples where a reflection in
the facet can reach the edge (:func:`facet_wedge_pairs`), then expand each triple over the other
ends (:func:`expand_over_others`); double reflections test second images against the receivers
(:func:`second_order_candidates`); :func:`surely_inside` tells points well inside a wedge. In
numpy these steps built dense (object, facet), (edge, facet), (triple, other end) and (image,
receiver) matrices of which a few per cent survive; these loops test the same exact necessary
conditions, cheapest first, and stop at the first that fails. They only prune: which paths are
found is decided by the exact tests after them (Keller's point on the edge, point in facet,
wedge validity, Embree), and :data:`raytrace.solver.kernels.PRUNE` switches them off to show it.

The loops write the numpy expressions they replaced in numpy's order (bitwise the same
candidates: ``tools/trace_identity.py``).
"""

from __future__ import annotations

import numpy as np

from ...core.jit import helper, inline, kernel
from ...core.vec import dot3
from ...scene.accel import FACET_TEST_SIG, facet_box_test, in_triangles
from ...scene.spatial import sphere_in_beam

__all__ = ["surely_inside", "inside1", "beam_reaches1", "facet_wedge_pairs", "grown_pairs",
           "edge_span", "FRAME_SIG", "PAIRS_OUT_SIG", "along_and_off",
           "along_and_off_rows", "in_span", "expand_over_others", "second_order_candidates"]


@inline
def inside1(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2, w, px, py, pz):
    """One point against one wedge: see :func:`surely_inside`. (Every array is read before the
    first branch: see :func:`raytrace.scene.accel.facet_box_test`.)"""
    ok, cn, sn = prunable[w], cos_n[w], sin_n[w]
    x = px * t0[0, w] + py * t0[1, w] + pz * t0[2, w] - t_start[w]
    y = px * n0[0, w] + py * n0[1, w] + pz * n0[2, w] - n_start[w]
    if not ok:
        return False
    r2 = x * x + y * y
    m2 = m2_coef * r2
    side_n = cn * y - sn * x
    return r2 > min_rho2 and y < 0 and y * y > m2 and side_n > 0 and side_n * side_n > m2


#: The numba signature of a wedge frame as the kernels take it (:func:`surely_inside`).
FRAME_SIG = "f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], b1[::1], f8, f8"


@kernel(f"b1[::1]({FRAME_SIG}, i8[::1], f8[::1], f8[::1], f8[::1])")
def surely_inside(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                  wi, px, py, pz):  # fmt: skip
    """(n,) bool: points ``(px, py, pz)`` (n,) m inside wedges ``wi`` (n,) by a margin.

    With ``x, y`` the point's coordinates along the wedge's edge-fixed axes ``t0``, ``n0`` (3, W)
    from the edge (``t_start``, ``n_start`` (W,): the start's coordinates), the interior of a
    wedge with exterior angle ``n pi``, ``1 <= n < 2`` (``prunable``), is where ``y < 0`` and
    ``cos(n pi) y - sin(n pi) x > 0``; both by ``sqrt(m2_coef)`` times ``r`` (``m2_coef =
    sin(margin)^2``), at ``r^2 > min_rho2``.
    """
    out = np.empty(len(wi), dtype=np.bool_)
    for i in range(len(wi)):
        out[i] = inside1(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                         wi[i], px[i], py[i], pz[i])  # fmt: skip
    return out


#: The beam (apex, unit axis, half-angle cos/sin) can meet the sphere (centre, radius):
#: :func:`raytrace.solver.reflection.beam_reaches` times ``|c - a|``, the same test the scene's
#: trees walk with (one function).
beam_reaches1 = sphere_in_beam


#: The numba signature of the (end, facet, wedge, image, span lo, hi) triples' buffers.
PAIRS_OUT_SIG = "i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], f8[::1]"


_PAIRS_SIG = (
    f"Tuple(({PAIRS_OUT_SIG}, i8))("
    # per facet of the end (F,): indices, side sign, end's distance from the plane, image
    # components (3, F), beam axis components (3, F), cos, sin of its half-angle, apex inside
    "i8[::1], f8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], "
    # facets (K,): normals (K, 3), offsets, chosen; boxes lo, hi (K, 3)
    "f8[:, ::1], f8[::1], b1[::1], f8[:, ::1], f8[:, ::1], "
    # groups (G,): order (W,), start, count, centres (G, 3), radii, chosen
    "i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], b1[::1], "
    # wedges (W,): start, end, middle (W, 3), half-length, length
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], "
    # the end's index, the output buffers (end, facet, wedge, image (n, 3), span lo, hi) and
    # the rows already in them
    f"{FRAME_SIG}, f8, f8, b1, i8, {PAIRS_OUT_SIG}, i8)"
)


@helper
def grown_pairs(out_e, out_f, out_w, out_img, out_lo, out_hi, need):
    """:func:`facet_wedge_pairs`' output buffers, at least twice as long and ``need`` rows, with
    their rows copied."""
    n = len(out_e)
    n2 = max(2 * n, need)
    e2, f2, w2 = np.empty(n2, np.int64), np.empty(n2, np.int64), np.empty(n2, np.int64)
    img2, lo2, hi2 = np.empty((n2, 3)), np.empty(n2), np.empty(n2)
    e2[:n], f2[:n], w2[:n], img2[:n], lo2[:n], hi2[:n] = out_e, out_f, out_w, out_img, out_lo, out_hi
    return e2, f2, w2, img2, lo2, hi2


@inline
def _box_axis(a_c, b_c, i_c, u, cut_a, cut_b, k_a, k_b, lo_c, hi_c, s_in, s_out):
    """One axis of :func:`edge_span`: the edge ``a -> b`` (this axis' components), cut at ``u``
    where ``cut_a`` / ``cut_b``, projected from the image ``i`` (at ``k_a``, ``k_b`` of the way
    from it), clipped to the box's slab ``lo_c <= x <= hi_c``: the projected parameter range
    ``[s_in, s_out]`` narrowed by this slab."""
    p = a_c + u * (b_c - a_c)
    if cut_a:
        a_c = p
    if cut_b:
        b_c = p
    qa = i_c + k_a * (a_c - i_c)
    dq = i_c + k_b * (b_c - i_c) - qa
    # parallel to a slab: +-huge (in or out of it) or 0 (on its boundary: in)
    inv = 1.0 / (dq if dq != 0.0 else 1e-300)
    t1 = (lo_c - qa) * inv
    t2 = (hi_c - qa) * inv
    return max(s_in, min(t1, t2)), min(s_out, max(t1, t2))


@inline
def edge_span(ax, ay, az, bx, by, bz, ix, iy, iz, da, db, eps, h, lx, ly, lz, hx, hy, hz, length,
               pad):  # fmt: skip
    """Condition 4 of :func:`facet_wedge_pairs` for one (facet, wedge) pair, on scalars: the
    edge ``a -> b`` (its ends ``da``, ``db`` m in front of the facet's plane, on the end's side),
    clipped to the end's side (by ``eps``) and projected from the image ``i`` (``h`` m behind the
    plane) onto the plane, meets the facet's box ``l``, ``h``: ``(True, lo, hi)``, the part of
    the edge that does, metres from its start (of ``length``), padded by ``pad``; else
    ``(False, 0, 0)``."""
    # clip the edge to the end's side: the cut point at parameter u from the start
    cut_a, cut_b = da <= eps, db <= eps
    u = 0.0
    if cut_a or cut_b:
        u = (eps - da) / ((db - da) if db != da else 1.0)
    # project from the image (distance h behind the plane): a point at distance s in front
    # projects at h / (h + s) of the way from the image
    d_a = h + max(da, eps)
    d_b = h + max(db, eps)
    k_a, k_b = h / d_a, h / d_b
    s_in, s_out = _box_axis(ax, bx, ix, u, cut_a, cut_b, k_a, k_b, lx, hx, 0.0, 1.0)
    s_in, s_out = _box_axis(ay, by, iy, u, cut_a, cut_b, k_a, k_b, ly, hy, s_in, s_out)
    s_in, s_out = _box_axis(az, bz, iz, u, cut_a, cut_b, k_a, k_b, lz, hz, s_in, s_out)
    if not s_in <= s_out:
        return False, 0.0, 0.0
    # the projection is a perspective map: projected parameter s is edge parameter
    # s D_a / (s D_a + (1 - s) D_b)
    lam_in = s_in * d_a / (s_in * d_a + (1 - s_in) * d_b)
    lam_out = s_out * d_a / (s_out * d_a + (1 - s_out) * d_b)
    t_a = u * length if cut_a else 0.0
    t_b = u * length if cut_b else length
    return True, t_a + lam_in * (t_b - t_a) - pad, t_a + lam_out * (t_b - t_a) + pad


@kernel(_PAIRS_SIG)
def facet_wedge_pairs(f_ok, sgn, h_f, img_c, axis_c, cos_a, sin_a, apex_in,
                      normal, offset, f_chosen, lo, hi,
                      g_order, g_start, g_count, g_centre, g_radius, g_chosen,
                      w_start, w_end, w_mid, w_half, w_length,
                      t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                      eps, pad, prune, e, out_e, out_f, out_w, out_img, out_lo, out_hi, m):  # fmt: skip
    """The (facet, wedge) pairs of one end point where a reflection in the facet can reach
    the edge, and the part of the edge it can reach, written after the ``m`` rows already in
    the output buffers (several ends' triples are gathered in one set of buffers, with no
    concatenation).

    Exact necessary conditions, cheapest first, for every group of wedges (one object's) and
    facet of the end's reflecting side, on a pair with a chosen group or facet:

    1. the group's bounding sphere reaches the end's side of the facet plane (by ``eps``) and
       the beam from the end's image through the facet's bounding sphere;
    2. per wedge of the group: an end of the edge is on the end's side by more than ``eps``, and
       the edge's own sphere (``w_mid``, ``w_half``) meets the beam;
    3. the image is not inside the wedge (:func:`surely_inside`);
    4. the edge, clipped to the end's side and projected from the image onto the facet's plane,
       meets the facet's box ``lo``, ``hi``: the part of the edge that does, metres from its
       start and padded by ``pad``, is returned (a diffraction point of the reflection lies in
       it).

    Returns
    -------
    out_e, out_f, out_w : (N,) int, the buffers (grown when full): rows ``m:`` of the new
        triples hold ``e``, the facet (``f_ok[j]``) and the wedge
    out_img : (N, 3) float, metres, the end's image in the facet (``img_c[:, j]``)
    out_lo, out_hi : (N,) float, metres from the wedge's start
    m : int, the rows now written
    """
    n_f = len(f_ok)
    for g in range(len(g_start)):
        gx, gy, gz, gr = g_centre[g, 0], g_centre[g, 1], g_centre[g, 2], g_radius[g]
        for j in range(n_f):
            f = f_ok[j]
            if not (g_chosen[g] or f_chosen[f]):
                continue
            s_j = sgn[j]
            nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
            ix, iy, iz = img_c[0, j], img_c[1, j], img_c[2, j]
            ux, uy, uz = axis_c[0, j], axis_c[1, j], axis_c[2, j]
            ca, sa, ai = cos_a[j], sin_a[j], apex_in[j]
            if prune and not (
                (gx * nx + gy * ny + gz * nz - off) * s_j + gr > eps
                and beam_reaches1(ix, iy, iz, ux, uy, uz, ca, sa, ai, gx, gy, gz, gr)
            ):
                continue
            h = h_f[j]
            # room for every wedge of the group, made here and not per triple: the check and
            # call in the inner loop cost 11 % of this kernel's time on the 2 m grid
            if m + g_count[g] > len(out_e):
                out_e, out_f, out_w, out_img, out_lo, out_hi = grown_pairs(
                    out_e, out_f, out_w, out_img, out_lo, out_hi, m + g_count[g])  # fmt: skip
            for k in range(g_start[g], g_start[g] + g_count[g]):
                w = g_order[k]
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
    return out_e, out_f, out_w, out_img, out_lo, out_hi, m


@inline
def along_and_off(px, py, pz, sx, sy, sz, dx, dy, dz):
    """Position along an edge line (m from its point ``s``, unit direction ``d``) of the foot of
    point ``p``, and its distance from the line (m). These only prune, within a pad."""
    rx, ry, rz = px - sx, py - sy, pz - sz
    t = rx * dx + ry * dy + rz * dz
    ox, oy, oz = rx - t * dx, ry - t * dy, rz - t * dz
    return t, np.sqrt(ox * ox + oy * oy + oz * oz)


@kernel("Tuple((f8[::1], f8[::1]))(f8[:, ::1], f8[:, ::1], f8[:, ::1])")
def along_and_off_rows(p, start, direction):
    """:func:`along_and_off` over n rows ((n, 3) each): ``t``, ``rho`` (n,) metres."""
    n = len(p)
    t, rho = np.empty(n), np.empty(n)
    for i in range(n):
        t[i], rho[i] = along_and_off(p[i, 0], p[i, 1], p[i, 2], start[i, 0], start[i, 1],
                                     start[i, 2], direction[i, 0], direction[i, 1],
                                     direction[i, 2])  # fmt: skip
    return t, rho


@inline
def in_span(tq, rq, lo_q, hi_q, td, rd):
    """Keller's point of an end at edge coordinate ``tq``, distance ``rq`` from the edge line,
    and another at ``td``, ``rd`` lies in ``[lo_q, hi_q]``: ``t = tq + (td - tq) rq / (rq + rd)``,
    the same expression in the same order as numpy. It lies between ``tq`` and ``td`` (up to
    rounding), so a pair with both beyond the same end of the span, by far more than that
    rounding, fails without the division (most do)."""
    slack = 1e-9 * (abs(tq) + abs(td) + 1.0)
    if max(tq, td) < lo_q - slack or min(tq, td) > hi_q + slack:
        return False
    t = tq + (td - tq) * rq / (rq + rd)
    return t >= lo_q and t <= hi_q


@kernel(
    "Tuple((i8[::1], i8[::1]))("
    "f8[::1], f8[::1], f8[::1], f8[::1], i8[::1], f8[:, ::1], f8[:, ::1], b1[:, ::1], i8, i8, b1)"
)
def expand_over_others(ts, rho_s, t_lo, t_hi, w_idx, td_w, rho_w, open_w, start, stop, prune):
    """The (triple, other end) pairs of triples ``start:stop`` whose Keller point lies in the
    triple's span of the edge.

    Keller's point of the image (edge coordinate ``ts``, distance ``rho_s`` from the edge line)
    and the other end (``td_w``, ``rho_w`` (W, O) per wedge) must lie in ``[t_lo, t_hi]``
    (:func:`in_span`), with the other end not surely inside the wedge (``open_w`` (W, O)).
    With ``prune`` False, every pair is returned.

    Returns
    -------
    q : (M,) int, triples (absolute indices), in order
    o : (M,) int, other ends
    """
    n_o = td_w.shape[1]
    # room for every pair (each at most once): no buffer grows, so none is reassigned in the
    # loop (numba counts references of a reassigned array); only the rows written are touched
    cap = max(stop - start, 0) * n_o
    out_q = np.empty(cap, dtype=np.int64)
    out_o = np.empty(cap, dtype=np.int64)
    m = 0
    for q in range(start, stop):
        w = w_idx[q]
        tq, rq, lo_q, hi_q = ts[q], rho_s[q], t_lo[q], t_hi[q]
        for o in range(n_o):
            if not prune or (open_w[w, o] and in_span(tq, rq, lo_q, hi_q, td_w[w, o],
                                                      rho_w[w, o])):  # fmt: skip
                out_q[m], out_o[m] = q, o
                m += 1
    return out_q[:m].copy(), out_o[:m].copy()


@inline
def point_in_beam1(ax, ay, az, ux, uy, uz, cos_a, inside, px, py, pz):
    """The point is within the beam's half-angle (``cos(angle) >= cos_a - 1e-7``, multiplied by
    the distance: no division): :func:`raytrace.solver.reflection.cone_reaches` with a target of
    radius 0, a necessary condition."""
    vx, vy, vz = px - ax, py - ay, pz - az
    dt = np.sqrt(vx * vx + vy * vy + vz * vz)
    dot = ux * vx + uy * vy + uz * vz
    return dot >= (cos_a - 1e-7) * dt or inside or dt <= 0.0


_BEAM = "f8[:, ::1], f8[:, ::1], f8[::1], b1[::1]"


@inline
def _in_both_beams(apex2, axis2, cos2, in2, apex1, axis1, cos1, in1, nx, ny, nz, off, rx, q, r,
                   i):  # fmt: skip
    """The beam tests of :func:`second_order_candidates` for second image ``q`` (its first
    image ``i``), receiver ``r``."""
    px, py, pz = rx[r, 0], rx[r, 1], rx[r, 2]
    if not point_in_beam1(apex2[q, 0], apex2[q, 1], apex2[q, 2], axis2[q, 0], axis2[q, 1],
                          axis2[q, 2], cos2[q], in2[q], px, py, pz):  # fmt: skip
        return False
    dist = px * nx + py * ny + pz * nz
    dist -= off
    mx, my, mz = px - 2.0 * dist * nx, py - 2.0 * dist * ny, pz - 2.0 * dist * nz
    return point_in_beam1(apex1[i, 0], apex1[i, 1], apex1[i, 2], axis1[i, 0], axis1[i, 1],
                          axis1[i, 2], cos1[i], in1[i], mx, my, mz)  # fmt: skip


@inline
def _plane_crossing(ax, ay, az, bx, by, bz, nx, ny, nz, off):
    """:func:`raytrace.solver.reflection.segment_plane_point` of one segment ``a -> b`` and
    plane (the same arithmetic): ``u`` (NaN where the segment is parallel) and the point."""
    sa = dot3(ax, ay, az, nx, ny, nz) - off
    sb = dot3(bx, by, bz, nx, ny, nz) - off
    den = sa - sb
    u = sa / den if abs(den) > 0 else np.nan
    return u, ax + u * (bx - ax), ay + u * (by - ay), az + u * (bz - az)


@kernel(
    "Tuple((i8[::1], i8[::1], f8[:, ::1], i8))("
    f"i8, i8, i8[::1], i1[::1], i1[:, ::1], {_BEAM}, f8[::1], {_BEAM}, "
    "f8[:, ::1], f8, f8, f8, f8, b1, f8[:, ::1], i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], "
    f"f8[::1], i1[::1], {FACET_TEST_SIG}, b1)"
)
def second_order_candidates(q0, q1, f2, s_img, side_rx, apex2, axis2, cos2, in2, sin2, apex1,
                            axis1, cos1, in1, rx, cx, cy, cz, radius, prune, img1, i1,
                            f1, img2, normal, offset, side_t, lo, hi, rect, r_lo, r_hi,
                            tri_start, tri_count, corner, v0, v1, d00, d01, d11, den, bary_tol,
                            rect_inside, exact):  # fmt: skip
    """The (second image, receiver) pairs of double reflections: the receiver tests, then the
    exact tests of the reflection points.

    For second images ``q0 <= q < q1`` (their second facets ``f2`` (Q,), the first image's side
    ``s_img`` of it) and receivers ``rx`` (R, 3): the receiver is on that side of the second
    facet (``side_rx`` (R, K)), within the beam from the second image through the second facet's
    bounding sphere (``apex2``, ``axis2`` (Q, 3), ``cos2``, ``in2``, ``sin2`` (Q,)), and its mirror
    image in the second facet's plane is within the beam from the first image through the first
    facet (``apex1``, ``axis1`` (F, 3), ``cos1``, ``in1`` (F,): row ``i1[q]``, one per first
    image; a copy per pair was most of what a trace of a scanned hall kept): unfolded at the
    second reflection, the path is straight from the first image to that mirror image. A second
    image whose beam cannot reach the receivers' bounding sphere (centre ``cx, cy, cz``,
    ``radius``, m) is skipped whole. The side is the rule; the beams are necessary conditions, not tested with ``prune``
    False.

    With ``exact``, the pairs must also pass the tests of
    :func:`raytrace.solver.specular.second_order` in its arithmetic
    (:func:`_plane_crossing`, :func:`raytrace.scene.accel.points_in_facets`' helpers): the
    segment receiver -> second image (``img2`` (Q, 3)) crosses the second facet's plane between
    its ends, inside the facet; the segment from there to the first image (``img1[i1[q]]``)
    crosses the first facet (``f1`` (Q,); planes ``normal``, ``offset`` (K,)) likewise; and the
    second reflection point is on the transmitter's reflecting side of the first facet
    (``side_t`` (K,)).

    Returns
    -------
    q, r : (M,) int, in (q, r) order
    points : (M, 6) float, metres: the first reflection point, then the second (with
        ``exact``; not written otherwise)
    n_pairs : int, the pairs that passed the receiver tests (the exact tests' candidates)
    """
    # room for every (image, receiver) pair: no growth, no reassignment in the loop (see
    # expand_over_others)
    cap = max(q1 - q0, 0) * rx.shape[0]
    out_q = np.empty(cap, dtype=np.int64)
    out_r = np.empty(cap, dtype=np.int64)
    out_p = np.empty((cap, 6))
    m, n_pairs = 0, 0
    for q in range(q0, q1):
        if prune and not beam_reaches1(apex2[q, 0], apex2[q, 1], apex2[q, 2], axis2[q, 0],
                                       axis2[q, 1], axis2[q, 2], cos2[q], sin2[q], in2[q], cx,
                                       cy, cz, radius):  # fmt: skip
            continue
        f, s, g, i = f2[q], s_img[q], f1[q], i1[q]
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        jx, jy, jz = img1[i1[q], 0], img1[i1[q], 1], img1[i1[q], 2]
        kx, ky, kz = img2[q, 0], img2[q, 1], img2[q, 2]
        gx, gy, gz, g_off, g_side = normal[g, 0], normal[g, 1], normal[g, 2], offset[g], side_t[g]
        for r in range(rx.shape[0]):
            # the rule, not a pruning: the receiver strictly on the reflecting side
            if side_rx[r, f] != s:
                continue
            if prune and not _in_both_beams(apex2, axis2, cos2, in2, apex1, axis1, cos1, in1,
                                            nx, ny, nz, off, rx, q, r, i):  # fmt: skip
                continue
            n_pairs += 1
            if exact:
                # each crossing inside its facet written out (as in reflection_edge_points): a
                # helper holding the facet arrays across its branches would cost numba's
                # reference counts per call (core.jit.inline)
                u2, px, py, pz = _plane_crossing(rx[r, 0], rx[r, 1], rx[r, 2], kx, ky, kz,
                                                 normal[f, 0], normal[f, 1], normal[f, 2],
                                                 offset[f])  # fmt: skip
                if not (u2 > 0 and u2 < 1):
                    continue
                quick = facet_box_test(px, py, pz, f, lo, hi, rect, r_lo, r_hi, rect_inside)
                if quick == 0 or (quick < 0 and not in_triangles(
                        px, py, pz, f, tri_start, tri_count, corner, v0, v1, d00, d01, d11, den,
                        bary_tol)):  # fmt: skip
                    continue
                u1, ox, oy, oz = _plane_crossing(px, py, pz, jx, jy, jz, gx, gy, gz, g_off)
                if not (u1 > 0 and u1 < 1):
                    continue
                quick = facet_box_test(ox, oy, oz, g, lo, hi, rect, r_lo, r_hi, rect_inside)
                if quick == 0 or (quick < 0 and not in_triangles(
                        ox, oy, oz, g, tri_start, tri_count, corner, v0, v1, d00, d01, d11, den,
                        bary_tol)):  # fmt: skip
                    continue
                # the second reflection point on the transmitter's side of the first facet
                s2 = dot3(px, py, pz, gx, gy, gz) - g_off
                if not ((s2 > 0 and g_side > 0) or (s2 < 0 and g_side < 0)
                        or (s2 == 0 and g_side == 0)):  # fmt: skip
                    continue  # np.sign(s2) != side (NaN: never equal)
                out_p[m, 0], out_p[m, 1], out_p[m, 2] = ox, oy, oz
                out_p[m, 3], out_p[m, 4], out_p[m, 5] = px, py, pz
            out_q[m], out_r[m] = q, r
            m += 1
    return out_q[:m].copy(), out_r[:m].copy(), out_p[:m].copy(), n_pairs
