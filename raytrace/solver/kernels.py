"""Compiled loops of the tracer (numba, options in :mod:`raytrace.core.jit`).

* **Pruning** (:func:`facet_wedge_pairs`, :func:`expand_over_others`,
  :func:`second_order_candidates`, :func:`surely_inside`). The mixed stages (RD, DR, RDR) look
  for (end point, facet, wedge) triples where a reflection in the facet can reach the edge, then
  expand each triple over the other ends; double reflections test second images against the
  receivers. In numpy these steps built dense (object, facet), (edge, facet), (triple, other
  end) and (image, receiver) matrices of which a few per cent survive; these loops test the
  same exact necessary conditions, cheapest first, and stop at the first that fails. They only
  prune: which paths are found is decided by the exact tests after them (Keller's point on the
  edge, point in facet, wedge validity, Embree), and :data:`PRUNE` switches them off to show it.
* **Mixed candidates** (:func:`reflection_edge_points`): the RD and DR pairs pruned as
  :func:`expand_over_others` does, then tested exactly one at a time with the physics and
  scene modules' compiled scalar rules (:func:`raytrace.physics.utd.keller_point`,
  :func:`raytrace.scene.accel.facet_box_test`, :func:`raytrace.physics.utd.diffraction_valid1`).
* **Penetration** (:func:`line_span`, :func:`touch_rows`, :func:`edge_distance`,
  :func:`walk_rays`, :func:`walk_hits`, :func:`walk_record`, :func:`unseen_entries`,
  :func:`entry_points`, :func:`end_probes`): lines against convex solids, points against
  triangles, and the segment walk (:mod:`raytrace.solver.penetration`): its rays, a round of
  its hits one hit at a time (the face a hit at an edge is booked on, :func:`_canonical`;
  touches, :func:`_contact`; the walk past a touched solid, :func:`_off_the_solid`), the
  crossings' entry points and the segments whose end may lie in a closed solid entered unseen.
* **Opaque test** (:func:`segment_rays`, :func:`opaque_blocks`): the rays of one segment of
  every candidate, and which first opaque hits block (not the segment's own vertex objects, not
  a solid it only touches).
* **Fields** (:func:`path_gains`): the field vector carried along each path, with the ITU-R
  P.2040 coefficients of its penetrations and reflections computed on the way by the physics
  module's scalar helpers and the diffraction operators computed beforehand; the paths'
  interaction sequences (:func:`interaction_sequences`).

Helpers take scalars where they branch (:func:`raytrace.core.jit.inline`: an array live across
a helper's branch costs numba's reference counts per call), so the walk's bookkeeping is decided
by :func:`_boundary` on scalars and written by :func:`walk_hits` itself.

The pruning and walk kernels write the numpy expressions they replaced in numpy's order, so the
traced paths' geometry and penetrations are bitwise those of the numpy form on the machine they
were checked on (``tools/trace_identity.py``), the choice of the canonical face included
(whose numpy form took its dot products from BLAS). :func:`path_gains` differs from the numpy
form in the last bits only (numpy's complex products use fused multiply-adds on CPUs with
AVX-512, its complex square roots and divisions are not numba's; numba rounds each product and
sum as written), about 1e-13 relative on the gains; the delays of paths without penetrations
are bitwise the same.
"""

from __future__ import annotations

import numpy as np

from ..core.constants import C0
from ..core.jit import helper, inline, kernel
from ..core.vec import cross3, dot3
from ..physics.materials import clipped_cos1, group_delay1, reflection1, slab1
from ..physics.utd import diffraction_valid1, keller_point
from ..scene.accel import FACET_TEST_SIG, facet_box_test, in_triangles

__all__ = ["PRUNE", "surely_inside", "facet_wedge_pairs", "expand_over_others",
           "reflection_edge_points", "along_and_off_rows", "second_order_candidates", "line_span",
           "shadowed_groups", "shadowed_triples", "edge_distance",
           "opaque_blocks", "touch_rows", "entry_points", "end_probes",
           "walk_record", "unseen_entries", "walk_rays", "walk_hits", "segment_rays",
           "path_gains", "interaction_sequences", "mixed_candidates"]

#: The callers pass this as the kernels' ``prune``: False switches their pruning tests off (they
#: then return every candidate that satisfies the rules, with unbounded spans), so that a trace
#: with it set shows that the pruning loses no path (the tests do; it is far slower).
PRUNE = True


@inline
def _inside(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2, w, px, py, pz):
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


_FRAME = "f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], b1[::1], f8, f8"


@kernel(f"b1[::1]({_FRAME}, i8[::1], f8[::1], f8[::1], f8[::1])")
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
        out[i] = _inside(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                         wi[i], px[i], py[i], pz[i])  # fmt: skip
    return out


@inline
def _beam_reaches(ax, ay, az, ux, uy, uz, cos_a, sin_a, inside, cx, cy, cz, radius):
    """The beam (apex ``a``, unit axis ``u``, half-angle cos/sin) can meet the sphere (centre
    ``c``, ``radius``): :func:`raytrace.solver.reflection.beam_reaches` times ``|c - a|``
    (no division), a necessary condition."""
    if inside:
        return True
    vx, vy, vz = cx - ax, cy - ay, cz - az
    dt2 = vx * vx + vy * vy + vz * vz
    r2 = radius * radius
    if dt2 <= r2:
        return True
    dot = ux * vx + uy * vy + uz * vz
    dt = np.sqrt(dt2)
    return dot >= cos_a * np.sqrt(dt2 - r2) - sin_a * min(radius, dt) - 1e-7 * dt


_PAIRS_OUT = "i8[::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], f8[::1]"
_PAIRS_SIG = (
    f"Tuple(({_PAIRS_OUT}, i8))("
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
    f"{_FRAME}, f8, f8, b1, i8, {_PAIRS_OUT}, i8)"
)


@helper
def _grown_pairs(out_e, out_f, out_w, out_img, out_lo, out_hi, need):
    """:func:`facet_wedge_pairs`' output buffers, at least twice as long and ``need`` rows, with
    their rows copied."""
    n = len(out_e)
    n2 = max(2 * n, need)
    e2, f2, w2 = np.empty(n2, np.int64), np.empty(n2, np.int64), np.empty(n2, np.int64)
    img2, lo2, hi2 = np.empty((n2, 3)), np.empty(n2), np.empty(n2)
    e2[:n], f2[:n], w2[:n], img2[:n], lo2[:n], hi2[:n] = out_e, out_f, out_w, out_img, out_lo, out_hi
    return e2, f2, w2, img2, lo2, hi2


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
                and _beam_reaches(ix, iy, iz, ux, uy, uz, ca, sa, ai, gx, gy, gz, gr)
            ):
                continue
            h = h_f[j]
            # room for every wedge of the group, made here and not per triple: the check and
            # call in the inner loop cost 11 % of this kernel's time on the 2 m grid
            if m + g_count[g] > len(out_e):
                out_e, out_f, out_w, out_img, out_lo, out_hi = _grown_pairs(
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
                if not _beam_reaches(ix, iy, iz, ux, uy, uz, ca, sa, ai,
                                     w_mid[w, 0], w_mid[w, 1], w_mid[w, 2], w_half[w]):  # fmt: skip
                    continue
                if _inside(t0, n0, t_start, n_start, cos_n, sin_n, prunable, m2_coef, min_rho2,
                           w, ix, iy, iz):  # fmt: skip
                    continue
                # clip the edge to the end's side: the cut point at parameter u from the start
                cut_a, cut_b = da <= eps, db <= eps
                u = 0.0
                if cut_a or cut_b:
                    u = (eps - da) / ((db - da) if db != da else 1.0)
                # project from the image (distance h behind the plane): a point at distance s
                # in front projects at h / (h + s) of the way from the image
                d_a = h + max(da, eps)
                d_b = h + max(db, eps)
                k_a, k_b = h / d_a, h / d_b
                s_in, s_out = 0.0, 1.0
                for c in range(3):
                    a_c, b_c, i_c = w_start[w, c], w_end[w, c], img_c[c, j]
                    p = a_c + u * (b_c - a_c)
                    if cut_a:
                        a_c = p
                    if cut_b:
                        b_c = p
                    qa = i_c + k_a * (a_c - i_c)
                    dq = i_c + k_b * (b_c - i_c) - qa
                    # parallel to a slab: +-huge (in or out of it) or 0 (on its boundary: in)
                    inv = 1.0 / (dq if dq != 0.0 else 1e-300)
                    t1 = (lo[f, c] - qa) * inv
                    t2 = (hi[f, c] - qa) * inv
                    s_in = max(s_in, min(t1, t2))
                    s_out = min(s_out, max(t1, t2))
                if not s_in <= s_out:
                    continue
                # the projection is a perspective map: projected parameter s is edge
                # parameter s D_a / (s D_a + (1 - s) D_b)
                lam_in = s_in * d_a / (s_in * d_a + (1 - s_in) * d_b)
                lam_out = s_out * d_a / (s_out * d_a + (1 - s_out) * d_b)
                length = w_length[w]
                t_a = u * length if cut_a else 0.0
                t_b = u * length if cut_b else length
                out_e[m], out_f[m], out_w[m] = e, f, w
                out_img[m, 0], out_img[m, 1], out_img[m, 2] = ix, iy, iz
                out_lo[m] = t_a + lam_in * (t_b - t_a) - pad
                out_hi[m] = t_a + lam_out * (t_b - t_a) + pad
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
def _in_span(tq, rq, lo_q, hi_q, td, rd):
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
    (:func:`_in_span`), with the other end not surely inside the wedge (``open_w`` (W, O)).
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
            if not prune or (open_w[w, o] and _in_span(tq, rq, lo_q, hi_q, td_w[w, o],
                                                       rho_w[w, o])):  # fmt: skip
                out_q[m], out_o[m] = q, o
                m += 1
    return out_q[:m].copy(), out_o[:m].copy()


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
    the facet) and the other ends: :func:`expand_over_others`' pruning, then the exact tests
    of :func:`raytrace.solver.diffraction._one_reflection` one pair at a time, with the same
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
            if prune and not (open_w[w, o] and _in_span(tq, rq, lo_q, hi_q, td_w[w, o],
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


@inline
def _point_in_beam(ax, ay, az, ux, uy, uz, cos_a, inside, px, py, pz):
    """The point is within the beam's half-angle (``cos(angle) >= cos_a - 1e-7``, multiplied by
    the distance: no division): :func:`raytrace.solver.reflection.cone_reaches` with a target of
    radius 0, a necessary condition."""
    vx, vy, vz = px - ax, py - ay, pz - az
    dt = np.sqrt(vx * vx + vy * vy + vz * vz)
    dot = ux * vx + uy * vy + uz * vz
    return dot >= (cos_a - 1e-7) * dt or inside or dt <= 0.0


_BEAM = "f8[:, ::1], f8[:, ::1], f8[::1], b1[::1]"


@inline
def _in_both_beams(apex2, axis2, cos2, in2, apex1, axis1, cos1, in1, nx, ny, nz, off, rx, q, r):
    """The beam tests of :func:`second_order_candidates` for second image ``q``, receiver ``r``."""
    px, py, pz = rx[r, 0], rx[r, 1], rx[r, 2]
    if not _point_in_beam(apex2[q, 0], apex2[q, 1], apex2[q, 2], axis2[q, 0], axis2[q, 1],
                          axis2[q, 2], cos2[q], in2[q], px, py, pz):  # fmt: skip
        return False
    dist = px * nx + py * ny + pz * nz
    dist -= off
    mx, my, mz = px - 2.0 * dist * nx, py - 2.0 * dist * ny, pz - 2.0 * dist * nz
    return _point_in_beam(apex1[q, 0], apex1[q, 1], apex1[q, 2], axis1[q, 0], axis1[q, 1],
                          axis1[q, 2], cos1[q], in1[q], mx, my, mz)  # fmt: skip


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
    f"i8, i8, i8[::1], i1[::1], i1[:, ::1], {_BEAM}, f8[::1], {_BEAM}, f8[:, ::1], f8[::1], "
    "f8[:, ::1], f8, f8, f8, f8, b1, f8[:, ::1], i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], "
    f"f8[::1], i1[::1], {FACET_TEST_SIG}, b1)"
)
def second_order_candidates(q0, q1, f2, s_img, side_rx, apex2, axis2, cos2, in2, sin2, apex1,
                            axis1, cos1, in1, n2, off2, rx, cx, cy, cz, radius, prune, img1, i1,
                            f1, img2, normal, offset, side_t, lo, hi, rect, r_lo, r_hi,
                            tri_start, tri_count, corner, v0, v1, d00, d01, d11, den, bary_tol,
                            rect_inside, exact):  # fmt: skip
    """The (second image, receiver) pairs of double reflections: the receiver tests, then the
    exact tests of the reflection points.

    For second images ``q0 <= q < q1`` (their second facets ``f2`` (Q,), the first image's side
    ``s_img`` of it) and receivers ``rx`` (R, 3): the receiver is on that side of the second
    facet (``side_rx`` (R, K)), within the beam from the second image through the second facet's
    bounding sphere (``apex2``, ``axis2`` (Q, 3), ``cos2``, ``in2``, ``sin2`` (Q,)), and its mirror
    image in the second facet's plane (``n2`` (Q, 3), ``off2`` (Q,)) is within the beam from the
    first image through the first facet (``apex1``...): unfolded at the second reflection, the
    path is straight from the first image to that mirror image. A second image whose beam cannot
    reach the receivers' bounding sphere (centre ``cx, cy, cz``, ``radius``, m) is skipped
    whole. The side is the rule; the beams are necessary conditions, not tested with ``prune``
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
        if prune and not _beam_reaches(apex2[q, 0], apex2[q, 1], apex2[q, 2], axis2[q, 0],
                                       axis2[q, 1], axis2[q, 2], cos2[q], sin2[q], in2[q], cx,
                                       cy, cz, radius):  # fmt: skip
            continue
        f, s, g = f2[q], s_img[q], f1[q]
        nx, ny, nz, off = n2[q, 0], n2[q, 1], n2[q, 2], off2[q]
        jx, jy, jz = img1[i1[q], 0], img1[i1[q], 1], img1[i1[q], 2]
        kx, ky, kz = img2[q, 0], img2[q, 1], img2[q, 2]
        gx, gy, gz, g_off, g_side = normal[g, 0], normal[g, 1], normal[g, 2], offset[g], side_t[g]
        for r in range(rx.shape[0]):
            # the rule, not a pruning: the receiver strictly on the reflecting side
            if side_rx[r, f] != s:
                continue
            if prune and not _in_both_beams(apex2, axis2, cos2, in2, apex1, axis1, cos1, in1,
                                            nx, ny, nz, off, rx, q, r):  # fmt: skip
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


# -- penetration: lines against convex solids, points against triangles -------------------------
@helper
def _span(normal, offset, count, ob, ax, ay, az, dx, dy, dz, inset):
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
    (:func:`_span`) before reaching ``p``."""
    dx, dy, dz = px - ex, py - ey, pz - ez
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if not length > 0.0:
        return False
    _, lo, hi, par = _span(normal, offset, count, c, ex, ey, ez, dx / length, dy / length,
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
    ``normal . x = offset`` moved inwards, :func:`_span`) before reaching the point. Planes as in
    :func:`line_span` (``count[o] = 0``: not a convex solid, never a candidate). Each point's
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
        cv, lo, hi, par = _span(normal, offset, count, o[r], a[r, 0], a[r, 1], a[r, 2],
                                d[r, 0], d[r, 1], d[r, 2], inset)  # fmt: skip
        if cv:
            convex[r], t_in[r], t_out[r], parallel_out[r] = True, lo, hi, par
    return convex, t_in, t_out, parallel_out


@inline
def _edge_distance(corners, edge_normals, f, px, py, pz):
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
        out[r] = _edge_distance(corners, edge_normals, face[r], point[r, 0], point[r, 1],
                                point[r, 2])  # fmt: skip
    return out


@inline
def _contact(f, ax, ay, az, dx, dy, dz, t, face_normal, corners, edge_normals, tol):
    """Where a hit on face ``f`` (the ray ``a + t d``) lies, and whether it may only touch its
    solid.

    A ray whose line never gets deeper than ``tol`` into a convex closed solid (the chord of its
    line through the solid shrunk by ``tol``, from the facet planes in float64, is empty) only
    touches it: at an edge or a vertex, or grazing along a face. Such a hit is a *touch*, stepped
    over without a crossing; whether Embree reports it at all depends on its BVH, and a reported
    entry (exit) would be paired with an exit (entry) that is never seen, so that the chord would
    run to the segment's end (start). It is possible only where the hit is close enough to the
    triangle's boundary (closer than ``tol + 2 tol / |cos|``): there the caller tests the line
    against the solid (:func:`_touches`).

    Returns
    -------
    px, py, pz : float, the hit point, metres
    edge : float, its signed distance from the triangle's boundary (<= 0 inside), metres
    side : float, the sign of ``d . n`` (entering -1, leaving +1)
    near : bool, close enough to the boundary for a touch
    """
    nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
    px = ax + t * dx
    py = ay + t * dy
    pz = az + t * dz
    e = _edge_distance(corners, edge_normals, f, px, py, pz)
    dn = dot3(nx, ny, nz, dx, dy, dz)
    cos = abs(dn)
    cos = cos if (cos > 1e-300 or cos != cos) else 1e-300  # numpy's maximum(cos, 1e-300)
    return px, py, pz, e, np.sign(dn), e >= -(tol + 2.0 * tol / cos)


@helper
def _touches(ob, ax, ay, az, dx, dy, dz, normal, offset, count, tol):
    """The line ``a + t d`` only touches convex solid ``ob`` (no span deeper than ``tol``;
    see :func:`_contact`)."""
    cv, lo, hi, par = _span(normal, offset, count, ob, ax, ay, az, dx, dy, dz, tol)
    return cv and (par or hi <= lo)


@helper
def _sheet_touch(ob, ax, ay, az, dx, dy, dz, near, plane, reach, edge_start, edge_count, edges,
                 tol):  # fmt: skip
    """Whether the line ``a + t d`` only touches flat sheet ``ob``, and whether along its plane.

    The sheets' analogue of :func:`_touches`: a line that stays within ``tol`` of the sheet's
    plane across the whole sheet (``|d . n| reach <= tol``) runs along it, and one that crosses
    the plane within ``tol`` of the sheet's outline passes its edge. Either only touches it:
    whether Embree reports such a hit depends on its BVH (a receiver in the plane of a fence,
    looking past the edge of the pane that meets it). The outline is tested only where the hit
    is ``near`` its triangle's boundary (:func:`_contact`). Arrays as
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
def _touches_segment(ob, ax, ay, az, dx, dy, dz, t_max, normal, offset, count, tol):
    """:func:`_touches` for the segment ``0 <= t <= t_max`` of the line only."""
    cv, lo, hi, par = _span(normal, offset, count, ob, ax, ay, az, dx, dy, dz, tol)
    return cv and (par or min(hi, t_max) <= max(lo, 0.0))


@kernel("b1[::1](i8[::1], f8[:, ::1], f8[:, ::1], f8[::1], b1, f8[:, :, ::1], f8[:, ::1], "
        "i8[::1], f8)")  # fmt: skip
def touch_rows(o, a, d, t_max, segment, normal, offset, count, tol):
    """(n,) bool, :func:`_touches` of the lines ``a + t d`` (n, 3) and solids ``o`` (n,), or with
    ``segment`` :func:`_touches_segment` of their segments up to ``t_max`` (n,) metres (planes
    as in :func:`line_span`; False for objects without planes)."""
    out = np.empty(len(o), dtype=np.bool_)
    for i in range(len(o)):
        if segment:
            out[i] = _touches_segment(o[i], a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                      t_max[i], normal, offset, count, tol)  # fmt: skip
        else:
            out[i] = _touches(o[i], a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2], normal,
                              offset, count, tol)  # fmt: skip
    return out


@helper
def _canonical(f, ob, px, py, pz, dx, dy, dz, side, face_start, face_count, face_normal, corners,
               edge_normals, tol):  # fmt: skip
    """The face a hit at ``p`` on face ``f`` of object ``ob`` (ray direction ``d``, ``side`` the
    sign of ``d . n`` on ``f``) is booked on, whichever face Embree reported.

    A ray through an edge (or a vertex) of a solid meets two (or more) of its faces at the same
    point; which one Embree reports depends on its BVH, and the face's normal sets the incidence
    plane (TE/TM basis) and angle of the penetration, so the equivalent slab (chord times the
    cosine on the entry face) of a ray through a box's corner could be anything between the chord
    times one face's cosine and the other's. Of the faces of the object whose plane passes within
    ``tol`` of the point, whose triangle contains it within ``tol`` and that the ray meets the
    same way (entering or leaving), and the reported one, the one met most head-on is taken
    (largest ``|d . n|``; the lowest face index among equals): a choice made from the geometry
    alone, the same in a scene with more objects appended (a snapshot with forklifts keeps the
    static faces' indices). Called by :func:`walk_hits` for hits within ``tol`` of an edge.
    """
    best, best_score = f, -np.inf
    start = face_start[ob]
    for c in range(start, start + face_count[ob]):
        nx, ny, nz = face_normal[c, 0], face_normal[c, 1], face_normal[c, 2]
        dn = (dx * nx + dy * ny) + dz * nz
        ok = c == f
        if not ok and np.sign(dn) == side:
            h = ((px - corners[c, 0, 0]) * nx + (py - corners[c, 0, 1]) * ny) \
                + (pz - corners[c, 0, 2]) * nz  # fmt: skip
            ok = abs(h) <= tol and _edge_distance(corners, edge_normals, c, px, py, pz) <= tol
        if ok and abs(dn) > best_score:
            best, best_score = c, abs(dn)
    return best


# -- penetration: the segment walk's bookkeeping (raytrace.solver.penetration._Walk) ------------
@inline
def _more_head_on(ax, ay, az, bx, by, bz, dx, dy, dz):
    """Of two unit face normals ``a``, ``b``, the one the ray ``d`` meets more head-on (larger
    ``|cos|``; ``a`` among equals).

    A chord through a solid is taken as a slab (ITU-R P.2040 sec. 3) of thickness chord x cos on
    one face, at that face's incidence angle. On the entry face alone, a ray that enters a box
    through a side at grazing incidence and leaves through its end head-on would cross a thin
    slab one way and the whole chord the other way round (the hall: up to 1.7 m of delay and a
    factor 30 in gain between the two directions of one path). Entry and exit swap when the ray
    is reversed, so the more head-on of the two gives the same slab both ways (reciprocity);
    with parallel faces (a wall) both give the exact slab. The straight ray's length inside is
    the chord either way; at the more head-on face the slab's own refraction shortens it least.
    """
    ca = abs(dot3(ax, ay, az, dx, dy, dz))
    cb = abs(dot3(bx, by, bz, dx, dy, dz))
    if cb > ca:
        return bx, by, bz
    return ax, ay, az


@inline
def _slab_thickness(th, closed_ob, nx, ny, nz, dx, dy, dz):
    """The equivalent slab of a penetration (:meth:`_Walk.record`): a sheet's thickness, or a
    solid's chord times the cosine of the ray ``d`` on the slab's face ``n``; a negative chord
    (rounding) counts as 0."""
    chord = th if (th > 0.0 or th != th) else 0.0  # numpy's maximum(th, 0.0)
    if closed_ob:
        return chord * abs(dot3(nx, ny, nz, dx, dy, dz))
    return chord * 1.0


@inline
def _store(r, slot, t_entry, ob, nx, ny, nz, slab, dist, obj, normal, thick):
    """Penetration ``slot`` of segment ``r``, written (straight-line: see :func:`raytrace.core.jit.
    inline`); the caller checks the slot against the budget and counts it."""
    dist[r, slot] = t_entry
    obj[r, slot] = ob
    normal[r, slot, 0], normal[r, slot, 1], normal[r, slot, 2] = nx, ny, nz
    thick[r, slot] = slab


@inline
def _unseen_face(qx, qy, qz, fx, fy, fz, dx, dy, dz):
    """The slab's face normal of a solid left through a face of normal ``f`` without a seen
    entry (:meth:`_Walk.unseen`): it was entered at the previous boundary, of unit normal ``q``
    (that plane, turned against the ray ``d``, is the entry face), or the segment starts in it
    (``q`` zero: the exit face stands in); the more head-on of entry and exit faces."""
    if qx == 0.0 and qy == 0.0 and qz == 0.0:  # from the segment's start: no entry face
        ex, ey, ez = fx, fy, fz
    else:  # the previous boundary's plane, turned against the ray
        side = -1.0 if dot3(qx, qy, qz, dx, dy, dz) > 0 else 1.0
        ex, ey, ez = side * qx, side * qy, side * qz
    return _more_head_on(ex, ey, ez, fx, fy, fz, dx, dy, dz)


_WALK = (
    "f8[:, ::1], b1[::1], i8, i8[::1], b1[::1], f8[:, ::1], i8[:, ::1], f8[:, :, ::1], "
    "f8[:, ::1], i8[::1], f8[::1], f8[:, ::1], f8[::1], f8[:, ::1]"
)


@inline
def _boundary(cur, ob, closed_ob, sheet, th, fx, fy, fz, dx, dy, dz, nix, niy, niz, t_in, qx,
              qy, qz, t_last):  # fmt: skip
    """What a segment does at face ``f`` (unit normal ``fx, fy, fz``) of object ``ob``, met at
    ``th``, being inside solid ``cur`` (-1: none) entered at ``t_in`` through a face of normal
    ``ni``, the last boundary at ``t_last`` of normal ``q`` (scalars only: see
    :func:`raytrace.core.jit.inline`; :func:`walk_hits` applies the answer to the walk).

    Closed solids face outward, so the hit face's orientation says whether the segment enters or
    leaves (the bookkeeping alone would miss an entry through a face coincident with the
    previous exit, two solids stacked, since each hit is stepped over by the margin); an open
    sheet is one penetration through its thickness; leaving the solid the segment is inside of
    closes its chord (the more head-on of its entry and exit faces is the slab's); a solid left
    without a seen entry, outside any other, began at the previous boundary or at the segment's
    start (:func:`_unseen_face`); entering a solid closes an overlapping one first.

    Returns
    -------
    record : bool, a penetration is booked: of object ``rec_ob`` entered at ``rec_t``, chord (a
        sheet: thickness) ``rec_th``, slab face normal ``rx, ry, rz``
    rec_t, rec_ob, rx, ry, rz, rec_th
    inside : int, the solid the segment is inside of afterwards
    entered : bool, it entered ``ob`` here (the entry's distance and face are ``th`` and ``f``)
    """
    dn = dot3(fx, fy, fz, dx, dy, dz)
    record, rec_t, rec_ob, rec_th = False, 0.0, -1, 0.0
    rx, ry, rz = 0.0, 0.0, 0.0
    inside, entered = cur, False
    if not closed_ob:
        record, rec_t, rec_ob, rec_th = True, th, ob, sheet
        rx, ry, rz = fx, fy, fz
    elif dn > 0 or (dn == 0.0 and cur == ob):  # leaving
        if cur == ob:
            rx, ry, rz = _more_head_on(nix, niy, niz, fx, fy, fz, dx, dy, dz)
            record, rec_t, rec_ob, rec_th = True, t_in, ob, th - t_in
            inside = -1
        elif cur < 0:
            rx, ry, rz = _unseen_face(qx, qy, qz, fx, fy, fz, dx, dy, dz)
            record, rec_t, rec_ob, rec_th = True, t_last, ob, th - t_last
    else:  # entering, closing an overlapping solid first
        if cur >= 0:
            rx, ry, rz = _more_head_on(nix, niy, niz, fx, fy, fz, dx, dy, dz)
            record, rec_t, rec_ob, rec_th = True, t_in, cur, th - t_in
        inside, entered = ob, True
    return record, rec_t, rec_ob, rx, ry, rz, rec_th, inside, entered


@kernel(f"void(i8[::1], f8[::1], i8[::1], f8[:, ::1], f8[::1], {_WALK})")
def walk_record(rows, t_entry, o, fn, th, d, closed, k, count, exceeded, dist, obj, normal, thick,
                inside, t_in, normal_in, t_last, normal_last):  # fmt: skip
    """One penetration per row (:meth:`_Walk.record`): object ``o`` entered at ``t_entry``,
    chord (a sheet: thickness) ``th``, the slab's face normal ``fn`` (n, 3)."""
    for i in range(len(rows)):
        r, ob = rows[i], o[i]
        slot = count[r]
        if slot < k:
            _store(r, slot, t_entry[i], ob, fn[i, 0], fn[i, 1], fn[i, 2],
                   _slab_thickness(th[i], closed[ob], fn[i, 0], fn[i, 1], fn[i, 2], d[r, 0],
                                   d[r, 1], d[r, 2]), dist, obj, normal, thick)  # fmt: skip
        else:
            exceeded[r] = True
        count[r] = slot + 1


@kernel("Tuple((f8[::1], f8[:, ::1]))(i8[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1])")
def unseen_entries(rows, fn_exit, d, t_last, normal_last):
    """Where solids left without a seen entry were entered (:meth:`_Walk.unseen`): the
    segments' last boundaries ``t_last`` (n,) metres, and the slabs' face normals (n, 3)
    (:func:`_unseen_face`)."""
    n = len(rows)
    t_entry, fn = np.empty(n), np.empty((n, 3))
    for i in range(n):
        r = rows[i]
        t_entry[i] = t_last[r]
        fn[i, 0], fn[i, 1], fn[i, 2] = _unseen_face(
            normal_last[r, 0], normal_last[r, 1], normal_last[r, 2], fn_exit[i, 0],
            fn_exit[i, 1], fn_exit[i, 2], d[r, 0], d[r, 1], d[r, 2])  # fmt: skip
    return t_entry, fn


@kernel(
    "Tuple((i8[::1], f4[:, ::1], f4[:, ::1], f4[::1]))("
    "b1[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[:, ::1], f8[::1])"
)
def walk_rays(active, a, d, t, tmax, shift, shift_end):
    """The next query of every segment still walking: ``rows`` (n,) int, and Embree's rays
    (float32): origins ``a + t d`` (n, 3), shifted by ``shift`` while ``t < shift_end`` (a walk
    past a touched solid), directions ``d`` (n, 3), and reaches ``tmax - t`` (at most ``shift_end
    - t`` while shifted; 1e30 for an unbounded one), metres."""
    n = 0
    for r in range(len(active)):
        n += active[r]
    rows = np.empty(n, dtype=np.int64)
    org = np.empty((n, 3), dtype=np.float32)
    dirs = np.empty((n, 3), dtype=np.float32)
    reach = np.empty(n, dtype=np.float32)
    i = 0
    for r in range(len(active)):
        if not active[r]:
            continue
        ox, oy, oz = a[r, 0] + t[r] * d[r, 0], a[r, 1] + t[r] * d[r, 1], a[r, 2] + t[r] * d[r, 2]
        far = tmax[r] - t[r]
        if t[r] < shift_end[r]:
            ox, oy, oz = ox + shift[r, 0], oy + shift[r, 1], oz + shift[r, 2]
            far = min(far, shift_end[r] - t[r])
        rows[i] = r
        org[i, 0], org[i, 1], org[i, 2] = ox, oy, oz
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = d[r, 0], d[r, 1], d[r, 2]
        reach[i] = far if np.isfinite(far) else 1e30
        i += 1
    return rows, org, dirs, reach


@helper
def _own_face_shifted(f, at_start, t_hit, length, ax, ay, az, dx, dy, dz, face_normal, corners,
                      guard, tol, near_start, near_end):  # fmt: skip
    """The guard of :func:`walk_hits` for a query on a line shifted by 2 ``tol`` (past a touched
    solid or sheet): a hit on face ``f`` of the object under the segment's start (``at_start``)
    or end whose plane passes within ``tol`` of that end is the vertex's own when it is within
    ``guard + 2 tol / cos`` of it (cos: between the segment and the face's normal, at least
    0.02; the segment's own line meets that plane only at the vertex). Returns the updated
    (near_start, near_end)."""
    nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
    cos = abs(dot3(nx, ny, nz, dx, dy, dz))
    if cos < 0.02:
        return near_start, near_end
    reach = guard + 2.0 * tol / cos
    s = 0.0 if at_start else length
    px, py, pz = ax + s * dx - corners[f, 0, 0], ay + s * dy - corners[f, 0, 1], az + s * dz - corners[f, 0, 2]
    if abs(dot3(nx, ny, nz, px, py, pz)) > tol:
        return near_start, near_end
    if at_start:
        return near_start or t_hit < reach, near_end
    return near_start, near_end or t_hit > length - reach


#: Boundaries of coincident faces booked at one point, at most (:func:`walk_hits`).
_MAX_COINCIDENT = 8


@helper
def _coincident(r, ob, f, t_hit, qx, qy, qz, dx, dy, dz, length, guard, end_objects, co_start,
                co_count, co_face, face_object, closed, corners, edge_normals, normal, offset,
                count_planes, sheet_plane, sheet_reach, sheet_edge_start, sheet_edge_count,
                sheet_edges, tol, book_ob, book_f):  # fmt: skip
    """The boundaries at the point where segment ``r``'s queried line (origin ``q``) meets face
    ``f`` of object ``ob`` at ``t_hit``: ``book_ob[0], book_f[0]`` (``ob, f``) and those of the
    faces in ``f``'s plane (:func:`raytrace.solver.penetration.coincident_faces`) that contain
    the point (within ``tol``), are crossed there (not a touch: :func:`_touches`,
    :func:`_sheet_touch`) and are not an end vertex's own (within ``guard``), one per object,
    sorted by object (so that the order of the booking does not depend on which face Embree
    reported). Returns how many."""
    px, py, pz = qx + t_hit * dx, qy + t_hit * dy, qz + t_hit * dz
    n = 1
    for c in range(co_start[f], co_start[f] + co_count[f]):
        g = co_face[c]
        og = face_object[g]
        seen = False
        for j in range(n):
            seen = seen or book_ob[j] == og
        if seen or n == len(book_ob):
            continue
        if (og == end_objects[r, 0] and t_hit < guard) or (
            og == end_objects[r, 1] and t_hit > length - guard
        ):
            continue
        if _edge_distance(corners, edge_normals, g, px, py, pz) > tol:
            continue
        if closed[og]:
            if _touches(og, qx, qy, qz, dx, dy, dz, normal, offset, count_planes, tol):
                continue
        elif _sheet_touch(og, qx, qy, qz, dx, dy, dz, True, sheet_plane, sheet_reach,
                          sheet_edge_start, sheet_edge_count, sheet_edges, tol)[0]:  # fmt: skip
            continue
        book_ob[n], book_f[n] = og, g
        n += 1
    # insertion sort by object (n is 1 or 2)
    for j in range(1, n):
        bo, bf = book_ob[j], book_f[j]
        m = j
        while m > 0 and book_ob[m - 1] > bo:
            book_ob[m], book_f[m] = book_ob[m - 1], book_f[m - 1]
            m -= 1
        book_ob[m], book_f[m] = bo, bf
    return n


@inline
def _across(nx, ny, nz, dx, dy, dz, tol):
    """A shift of two contact tolerances along the unit normal ``n``, across the ray ``d`` (its
    part along the ray removed), and the length of that part (0: ``n`` along the ray)."""
    dn = dot3(nx, ny, nz, dx, dy, dz)
    cx, cy, cz = nx - dn * dx, ny - dn * dy, nz - dn * dz
    size = np.sqrt(cx * cx + cy * cy + cz * cz)
    grow = 2.0 * tol
    den = size if (size > 1e-300 or size != size) else 1e-300
    return grow * cx / den, grow * cy / den, grow * cz / den, size


@helper
def _off_the_solid(f, ob, ax, ay, az, dx, dy, dz, face_normal, normal, offset, count, tol):
    """Where a walk that touched face ``f`` of convex solid ``ob`` goes on: a shift of two
    contact tolerances along the face's outward normal, across the ray (:func:`_across`), and
    the distance at which the line leaves the solid grown by ``tol`` (past it, the walk is back
    on its own line; a zero shift and -inf for other objects)."""
    sx, sy, sz, size = _across(face_normal[f, 0], face_normal[f, 1], face_normal[f, 2], dx, dy,
                               dz, tol)  # fmt: skip
    cv, lo, hi, par = _span(normal, offset, count, ob, ax, ay, az, dx, dy, dz, -tol)
    if cv and np.isfinite(hi) and size > 0:
        return sx, sy, sz, hi
    return 0.0, 0.0, 0.0, -np.inf


@kernel(
    "void(i8[::1], f8[::1], i8[::1], i8[::1], "
    "f8[:, ::1], f8[::1], f8[::1], f8[::1], b1[::1], i8[::1], f8[:, ::1], f8[::1], i8[:, ::1], "
    "f8, f8, f8, f8, i8, "
    "f8[:, :, ::1], f8[:, :, ::1], f8[:, :, ::1], f8[:, ::1], i8[::1], i8[::1], i8[::1], "
    "f8[:, ::1], f8[:, ::1], f8[::1], i8[::1], i8[::1], f8[:, ::1], "
    "i8[::1], i8[::1], i8[::1], i8[::1], "
    f"f8[::1], {_WALK})"
)
def walk_hits(rows, th, face, o, a, length, tmax, t, active, crossed, shift, shift_end,
              end_objects, margin, guard, tol, grazing_cos, limit, corners, edge_normals, normal,
              offset, count_planes, face_start, face_count, face_normal, sheet_plane,
              sheet_reach, sheet_edge_start, sheet_edge_count, sheet_edges, co_start, co_count,
              co_face, face_object, sheet_thickness,
              d, closed, k, count, exceeded, dist, obj, normal_p, thick, inside, t_in, normal_in,
              t_last, normal_last):  # fmt: skip
    """One round of the segment walk (:func:`raytrace.solver.penetration.segment_crossings`):
    Embree's answers ``th`` (distance from the query's origin, inf: none), ``face``, ``o`` (-1:
    none) for the segments ``rows`` (:func:`walk_rays`) update the walk in place.

    Per segment: a miss ends the walk (a shifted one goes back on its own line past the solid);
    a hit on the object under either end within ``guard`` of it is float32 noise of the vertex,
    stepped over (leaving along the solid's face: go on off the solid; on a shifted line, within
    ``guard + 2 tol / cos`` on a face through the vertex, :func:`_own_face_shifted`); a hit is
    booked on its canonical face (:func:`_canonical`) and a touch of a convex solid
    (:func:`_contact`) or of a flat sheet (:func:`_sheet_touch`) is stepped over, off the solid
    or, along a sheet, off its plane; otherwise its distance is taken on the booked face's plane
    in float64, along the line queried (where
    the ray is not grazing, ``|cos| > grazing_cos``, and the plane is within ``tol`` of
    Embree's answer: Embree's float32 distance to one plane differs by ~1e-7 relative between
    the triangles of a face and between coincident faces of two objects, so chords, and the slab
    delays and losses made of them, would depend on which triangle the BVH reported) and the
    boundary is booked (:func:`_boundary`). Every step is by
    ``margin``; a segment that meets more than ``limit`` boundaries exceeds its budget.

    ``t``, ``active``, ``crossed``, ``shift``, ``shift_end`` (per segment) and the arrays after
    ``sheet_thickness`` (:class:`raytrace.solver.penetration._Walk`) are updated; ``a`` (N, 3),
    ``length``, ``tmax`` (N,) metres and ``end_objects`` (N, 2) describe the segments; the
    arrays from ``corners`` to ``face_normal`` are the scene's, as the other kernels take them,
    and ``sheet_plane`` to ``sheet_edges`` its flat sheets
    (:func:`raytrace.solver.penetration.flat_sheet_arrays`), ``co_start`` to ``co_face`` the
    faces of other objects in each face's plane (:func:`raytrace.solver.penetration.
    coincident_faces`: a boundary on one of them at the hit point is booked at the same
    distance, every boundary there in the order of its object) and ``face_object`` each face's
    object.
    """
    # the boundaries booked at one point: object and face (a sheet on a solid's face: two)
    book_ob = np.empty(_MAX_COINCIDENT, dtype=np.int64)
    book_f = np.empty(_MAX_COINCIDENT, dtype=np.int64)
    for i in range(len(rows)):
        r, f, ob = rows[i], face[i], o[i]
        ax, ay, az, dx, dy, dz = a[r, 0], a[r, 1], a[r, 2], d[r, 0], d[r, 1], d[r, 2]
        # the line this query was on (shifted off a touched solid or sheet, :func:`walk_rays`)
        qx, qy, qz = ax, ay, az
        if t[r] < shift_end[r]:
            qx, qy, qz = ax + shift[r, 0], ay + shift[r, 1], az + shift[r, 2]
        if ob < 0:
            if t[r] < shift_end[r]:  # nothing on the shifted stretch: back on the own line
                t[r] = shift_end[r]
                active[r] = t[r] < tmax[r]
            else:
                active[r] = False
            continue
        t_hit = t[r] + th[i]
        near_start, near_end = t_hit < guard, t_hit > length[r] - guard
        if t[r] < shift_end[r] and (ob == end_objects[r, 0] or ob == end_objects[r, 1]):
            # a line shifted off a touched solid by 2 tol meets the plane of a vertex's own
            # face up to 2 tol / cos from the vertex, beyond the guard at a glancing angle
            near_start, near_end = _own_face_shifted(f, ob == end_objects[r, 0], t_hit,
                                                     length[r], ax, ay, az, dx, dy, dz,
                                                     face_normal, corners, guard, tol,
                                                     near_start, near_end)  # fmt: skip
        if (ob == end_objects[r, 0] and near_start) or (ob == end_objects[r, 1] and near_end):
            t[r] = t_hit + margin
            if ob == end_objects[r, 0]:
                # leaving a vertex along its own solid's face: on, off the solid
                cv, lo, hi, par = _span(normal, offset, count_planes, ob, ax, ay, az, dx, dy, dz,
                                        tol)  # fmt: skip
                if cv and (par or hi <= lo):
                    sx, sy, sz, shift_end[r] = _off_the_solid(f, ob, ax, ay, az, dx, dy, dz,
                                                              face_normal, normal, offset,
                                                              count_planes, tol)  # fmt: skip
                    shift[r, 0], shift[r, 1], shift[r, 2] = sx, sy, sz
            active[r] = t[r] < tmax[r]
            continue
        px, py, pz, e, side, near = _contact(f, ax, ay, az, dx, dy, dz, t_hit, face_normal,
                                             corners, edge_normals, tol)  # fmt: skip
        touch = near and _touches(ob, ax, ay, az, dx, dy, dz, normal, offset, count_planes, tol)
        along = False
        if not touch and not closed[ob]:
            touch, along = _sheet_touch(ob, ax, ay, az, dx, dy, dz, near, sheet_plane,
                                        sheet_reach, sheet_edge_start, sheet_edge_count,
                                        sheet_edges, tol)  # fmt: skip
        if e >= -tol:
            f = _canonical(f, ob, px, py, pz, dx, dy, dz, side, face_start, face_count,
                           face_normal, corners, edge_normals, tol)  # fmt: skip
        if touch:
            t[r] = t_hit + margin
            if along:  # on, off the sheet's plane (:func:`_across`), until past the sheet
                shift[r, 0], shift[r, 1], shift[r, 2], _ = _across(
                    sheet_plane[ob, 0], sheet_plane[ob, 1], sheet_plane[ob, 2], dx, dy, dz, tol)  # fmt: skip
                shift_end[r] = t_hit + sheet_reach[ob] + tol
            elif closed[ob]:
                sx, sy, sz, shift_end[r] = _off_the_solid(f, ob, ax, ay, az, dx, dy, dz,
                                                          face_normal, normal, offset,
                                                          count_planes, tol)  # fmt: skip
                shift[r, 0], shift[r, 1], shift[r, 2] = sx, sy, sz
            active[r] = t[r] < tmax[r]
            continue
        # the distance on the booked face's plane, in float64, along the line queried
        nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
        dn = dot3(nx, ny, nz, dx, dy, dz)
        ok = abs(dn) > grazing_cos
        tp = dot3(nx, ny, nz, corners[f, 0, 0] - qx, corners[f, 0, 1] - qy,
                   corners[f, 0, 2] - qz) / (dn if ok else 1.0)  # fmt: skip
        if ok and abs(tp - t_hit) <= tol:
            t_hit = tp
        book_ob[0], book_f[0] = ob, f
        n_book = 1
        if co_count[f] > 0:  # a boundary of another object in this face's plane, at this point?
            n_book = _coincident(r, ob, f, t_hit, qx, qy, qz, dx, dy, dz, length[r], guard,
                                 end_objects, co_start, co_count, co_face, face_object, closed,
                                 corners, edge_normals, normal, offset, count_planes,
                                 sheet_plane, sheet_reach, sheet_edge_start, sheet_edge_count,
                                 sheet_edges, tol, book_ob, book_f)  # fmt: skip
        for c in range(n_book):
            ob, f = book_ob[c], book_f[c]
            nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
            # the boundary's bookkeeping (_boundary decides on scalars; the walk's arrays are
            # read and written here, in the kernel's body)
            record, rec_t, rec_ob, rnx, rny, rnz, rec_th, now_inside, entered = _boundary(
                inside[r], ob, closed[ob], sheet_thickness[ob], t_hit, nx, ny, nz, dx, dy, dz,
                normal_in[r, 0], normal_in[r, 1], normal_in[r, 2], t_in[r], normal_last[r, 0],
                normal_last[r, 1], normal_last[r, 2], t_last[r])  # fmt: skip
            if record:
                slot = count[r]
                if slot < k:
                    _store(r, slot, rec_t, rec_ob, rnx, rny, rnz,
                           _slab_thickness(rec_th, closed[rec_ob], rnx, rny, rnz, dx, dy, dz),
                           dist, obj, normal_p, thick)  # fmt: skip
                else:
                    exceeded[r] = True
                count[r] = slot + 1
            inside[r] = now_inside
            if entered:
                t_in[r] = t_hit
                normal_in[r, 0], normal_in[r, 1], normal_in[r, 2] = nx, ny, nz
            t_last[r] = t_hit
            normal_last[r, 0], normal_last[r, 1], normal_last[r, 2] = nx, ny, nz
        t[r] = t_hit + margin
        crossed[r] += n_book
        active[r] = t[r] < tmax[r] and not exceeded[r]
        if active[r] and crossed[r] >= limit:
            exceeded[r] = True
            active[r] = False


@kernel(
    "Tuple((f8[:, ::1], f8[:, ::1], f8[::1], f4[:, ::1], f4[:, ::1], f4[::1]))("
    "f8[:, :, ::1], i8[::1], i8, f8)"
)
def segment_rays(chain, live, j, margin):
    """The rays of segment ``j`` of the chains ``live`` (chain (M, k + 2, 3), metres), as
    :func:`raytrace.solver.evaluate.blocked_by_opaque` asks Embree about them: the start ``a``
    (n, 3), unit direction ``d`` (n, 3; zero for a segment of zero length), length (n,), and,
    in float32 as Embree takes them, the ray shortened by ``margin`` at both ends: origin
    ``a + margin d`` (n, 3), direction and reach ``length - 2 margin`` (n,), metres."""
    n = len(live)
    a = np.empty((n, 3))
    d = np.empty((n, 3))
    length = np.empty(n)
    org = np.empty((n, 3), dtype=np.float32)
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
    deeper than ``tol``; planes as in :func:`line_span`) or that flat sheet (along its plane or
    past its outline, :func:`_sheet_touch`; arrays as ``flat_sheet_arrays`` gives them), which
    Embree reports in one direction and not in the other: both are left to the segment walk,
    which records exactly what a segment crosses."""
    k = vobj.shape[1]
    out = np.zeros(len(hit), dtype=np.bool_)
    for i in range(len(hit)):
        ob, c = hit[i], live[i]
        if ob < 0 or (j > 0 and ob == vobj[c, j - 1]) or (j < k and ob == vobj[c, j]):
            continue
        ax, ay, az, dx, dy, dz = a[i, 0], a[i, 1], a[i, 2], d[i, 0], d[i, 1], d[i, 2]
        touch = _touches_segment(ob, ax, ay, az, dx, dy, dz, length[i], normal, offset, count,
                                 tol)  # fmt: skip
        if not touch and sheet_reach[ob] > 0.0:
            touch = _sheet_touch(ob, ax, ay, az, dx, dy, dz, True, sheet_plane, sheet_reach,
                                 sheet_edge_start, sheet_edge_count, sheet_edges, tol)[0]  # fmt: skip
        out[i] = not touch
    return out


@kernel("f8[:, :, ::1](f8[:, ::1], f8[:, ::1], f8[:, ::1])")
def entry_points(a, d, dist):
    """The points ``a + t d`` (n, K, 3) at the distances ``dist`` (n, K) along the segments from
    ``a`` (n, 3) in the unit directions ``d`` (n, 3), metres; NaN where ``dist`` is not finite
    (a slot without a penetration)."""
    n, kk = dist.shape
    out = np.empty((n, kk, 3))
    for r in range(n):
        for s in range(kk):
            t = dist[r, s]
            if np.isfinite(t):
                out[r, s, 0] = a[r, 0] + t * d[r, 0]
                out[r, s, 1] = a[r, 1] + t * d[r, 1]
                out[r, s, 2] = a[r, 2] + t * d[r, 2]
            else:
                out[r, s, 0], out[r, s, 1], out[r, s, 2] = np.nan, np.nan, np.nan
    return out


@kernel(
    "Tuple((i8[::1], f8[:, ::1]))(b1[::1], i8[::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[::1], "
    "f8[:, ::1], f8, f8, f8, i8, i8, i8[::1], i8[::1], f8[:, ::1], f8[:, ::1], f8[:, :, ::1], "
    "f8[:, ::1], i8[::1], f8)"
)
def end_probes(exceeded, inside, t_last, normal_last, d, tmax, a, x0, y0, cell, nx, ny, start,
               items, lo, hi, normal, offset, count, tol):  # fmt: skip
    """The segments of a walk (:class:`raytrace.solver.penetration._Walk` arrays) that left a
    solid last (``normal_last . d > 0``), end outside any and may end in a closed solid entered
    unseen, and the middle ``q`` of their last stretch (``a + (t_last + tmax) / 2 d``), metres:
    :func:`raytrace.solver.penetration._left_at_the_end` probes these.

    "May": ``q`` is more than ``tol`` behind every plane of a convex closed solid (planes as in
    :func:`line_span`, with a slack of 1e-9 m for the order of the sums) or within the bounding
    box ``lo``, ``hi`` (O, 3) of another closed solid; the probe's answer can only be a solid
    ``q`` is in, so the others need none. The closed solids come by cell of a grid over the
    footprint (origin ``x0, y0``, ``cell`` m, ``nx`` by ``ny`` cells, each cell's ``items``
    from ``start``: :func:`raytrace.solver.penetration._closed_solid_grid`).

    Returns
    -------
    rows : (N,) int, increasing; q : (N, 3) float, metres
    """
    n = len(exceeded)
    rows = np.empty(n, dtype=np.int64)
    q = np.empty((n, 3))
    m = 0
    for r in range(n):
        if exceeded[r] or inside[r] >= 0 or not (t_last[r] > 0 and t_last[r] < tmax[r]):
            continue
        if not dot3(normal_last[r, 0], normal_last[r, 1], normal_last[r, 2], d[r, 0], d[r, 1],
                    d[r, 2]) > 0:  # fmt: skip
            continue
        h = 0.5 * (t_last[r] + tmax[r])
        px, py, pz = a[r, 0] + h * d[r, 0], a[r, 1] + h * d[r, 1], a[r, 2] + h * d[r, 2]
        ix = min(max(int(np.floor((px - x0) / cell)), 0), nx - 1)
        iy = min(max(int(np.floor((py - y0) / cell)), 0), ny - 1)
        c = ix * ny + iy
        found = False
        for s in range(start[c], start[c + 1]):
            ob = items[s]
            if (px < lo[ob, 0] - tol or px > hi[ob, 0] + tol or py < lo[ob, 1] - tol
                    or py > hi[ob, 1] + tol or pz < lo[ob, 2] - tol or pz > hi[ob, 2] + tol):  # fmt: skip
                continue
            found = True  # (a closed solid without planes: inside its box)
            for k in range(count[ob]):
                depth = (normal[ob, k, 0] * px + normal[ob, k, 1] * py + normal[ob, k, 2] * pz
                         - offset[ob, k])  # fmt: skip
                if depth >= -tol + 1e-9:
                    found = False
                    break
            if found:
                break
        if found:
            rows[m] = r
            q[m, 0], q[m, 1], q[m, 2] = px, py, pz
            m += 1
    return rows[:m].copy(), q[:m].copy()


# -- fields: the field vector along each path (raytrace.solver.evaluate.path_fields) -------------
@inline
def _te_tm(e0, e1, e2, kx, ky, kz, ox, oy, oz, nx, ny, nz, c_te, c_tm):
    """The field ``e`` after an interaction (penetration or reflection) with TE/TM coefficients.

    Basis: ``s = k_in x n`` normalised (TE, perpendicular to the plane of incidence; at normal
    incidence any ``s`` perpendicular to ``k_in``: ``k_in x x``, or ``k_in x y`` for a ray near
    the x axis) and ``p = s x k`` on either side (TM), so that ``e' = c_te (e . s) s + c_tm (e .
    p_in) p_out``. With this basis the ITU-R P.2040 coefficients (``R_TM -> +1`` for a perfect
    conductor) map the field directly."""
    sx, sy, sz = cross3(kx, ky, kz, nx, ny, nz)
    ns = np.sqrt(sx * sx + sy * sy + sz * sz)
    if ns < 1e-9:
        hx, hy = (1.0, 0.0) if abs(kx) < 0.9 else (0.0, 1.0)
        sx, sy, sz = cross3(kx, ky, kz, hx, hy, 0.0)
        ns = np.sqrt(sx * sx + sy * sy + sz * sz)
    sx, sy, sz = sx / ns, sy / ns, sz / ns
    px, py, pz = cross3(sx, sy, sz, kx, ky, kz)
    qx, qy, qz = cross3(sx, sy, sz, ox, oy, oz)
    a = c_te * ((e0 * sx + e1 * sy) + e2 * sz)
    b = c_tm * ((e0 * px + e1 * py) + e2 * pz)
    return a * sx + b * qx, a * sy + b * qy, a * sz + b * qz


@inline
def _vertical_pol(dx, dy, dz):
    """The field of a vertically polarised antenna for a ray along ``d`` (unit): z made
    perpendicular to the ray (x for a vertical ray), unit."""
    vx, vy, vz = 0.0 - dz * dx, 0.0 - dz * dy, 1.0 - dz * dz
    n = np.sqrt(vx * vx + vy * vy + vz * vz)
    if n < 1e-9:
        vx, vy, vz = 1.0 - dx * dx, 0.0 - dx * dy, 0.0 - dx * dz
        n = np.sqrt(vx * vx + vy * vy + vz * vz)
    return vx / n, vy / n, vz / n


@kernel(
    "Tuple((c16[::1], f8[::1]))(f8[:, :, ::1], i1[:, ::1], i8[:, ::1], i8[:, ::1], "
    "f8[:, :, :, ::1], i8[:, :, ::1], f8[:, :, ::1], i8[::1], c16[::1], c16[::1], f8[::1], "
    "f8[:, ::1], i8[::1], b1[::1], i8[:, ::1], c16[:, :, ::1], f8[:, :, ::1], f8[::1], b1[::1], "
    "c16[::1], f8, f8, f8, b1, i8, i8)"
)
def path_gains(chain, kinds, elem, count, pen_normal, pen_obj, pen_thickness, obj_material, eta,
               eta_slope, thickness, f_normal, f_material, f_two_sided, d_slot, d_matrix, d_basis,
               d_amp, d_valid, amp_scale, f, k0, wavelength, slab_delay, reflection,
               diffraction):  # fmt: skip
    """Complex gain and delay of M paths with ``k`` vertices: the field vector carried from the
    transmitter to the receiver and projected on the receiving antenna's polarisation.

    The field starts vertically polarised (:func:`_vertical_pol`). Along segment ``j``: its
    penetrations (the slab's TE/TM transmission on the slab face's plane of incidence, ITU-R
    P.2040 sec. 2.2.2.2, :func:`raytrace.physics.materials.slab1`; its group delay added to the
    delay when ``slab_delay``, :func:`~raytrace.physics.materials.group_delay1`); then vertex
    ``j``: a reflection (:func:`~raytrace.physics.materials.reflection1` on the facet's plane:
    Fresnel for a solid's face, a slab for an open sheet's) or a diffraction (``[E_beta0, E_phi]
    = -D [E . beta0'_hat, E . phi'_hat] A``, zero where not valid, in
    :func:`raytrace.physics.utd.diffracted_field`'s order of operations). The TE/TM basis is
    :func:`_te_tm`'s. A path without a diffraction spreads as ``lambda / (4 pi d)`` over its
    unfolded length ``d``; a diffracted one carries its spreading in ``d_amp`` and
    ``amp_scale``.

    Parameters
    ----------
    chain : (M, k + 2, 3) float, m, the transmitter, the vertices and the receiver
    kinds : (M, k) int8, vertex codes (``reflection``, ``diffraction``); elem : (M, k) int, a
        reflection's facet
    count : (M, k + 1) int, penetrations per segment; pen_normal : (M, k + 1, K, 3) float,
        their slab faces' unit normals; pen_obj : (M, k + 1, K) int, their objects;
        pen_thickness : (M, k + 1, K) float, m, their slab thickness
    obj_material : (O,) int; eta, eta_slope : (n_materials,) complex, the relative
        permittivity and ``f d eta / d f``; thickness : (n_materials,) float, m, an open
        sheet's thickness
    f_normal : (F, 3) float, f_material : (F,) int, f_two_sided : (F,) bool, of the facets
    d_slot : (M, k) int, a diffraction vertex's row in the next four (-1 elsewhere)
    d_matrix : (D, 2, 2) complex, sqrt(m), a diffraction's dyadic coefficient; d_basis :
        (D, 4, 3) float, its ``beta0'_hat, phi'_hat, beta0_hat, phi_hat``; d_amp : (D,)
        float, its spreading factor; d_valid : (D,) bool
    amp_scale : (M,) complex, an extra factor of the whole path (diffraction's incident leg)
    f, k0, wavelength : Hz, rad/m, m
    slab_delay : bool; reflection, diffraction : int, the codes in ``kinds``

    Returns
    -------
    gain : (M,) complex, ``e . e_rx`` times the path's spreading and phase ``exp(-j k0 d)``
    delay : (M,) float, s, ``d / c`` plus the slabs' group delays
    """
    m, k = kinds.shape[0], kinds.shape[1]
    gain = np.empty(m, dtype=np.complex128)
    delay = np.empty(m)
    dirs = np.empty((k + 1, 3))
    for r in range(m):
        total = 0.0
        for j in range(k + 1):
            vx = chain[r, j + 1, 0] - chain[r, j, 0]
            vy = chain[r, j + 1, 1] - chain[r, j, 1]
            vz = chain[r, j + 1, 2] - chain[r, j, 2]
            ln = np.sqrt(vx * vx + vy * vy + vz * vz)
            total = ln if j == 0 else total + ln
            dn = ln if ln > 1e-300 else 1e-300
            dirs[j, 0], dirs[j, 1], dirs[j, 2] = vx / dn, vy / dn, vz / dn
        px, py, pz = _vertical_pol(dirs[0, 0], dirs[0, 1], dirs[0, 2])
        e0, e1, e2 = px + 0j, py + 0j, pz + 0j
        extra = 0.0
        has_d = False
        for j in range(k + 1):
            dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
            for s in range(count[r, j]):
                nx, ny, nz = pen_normal[r, j, s, 0], pen_normal[r, j, s, 1], pen_normal[r, j, s, 2]
                mat = obj_material[pen_obj[r, j, s]]
                th = pen_thickness[r, j, s]
                c = clipped_cos1(dot3(nx, ny, nz, dx, dy, dz))
                _, _, t_te, t_tm = slab1(eta[mat], c, th, f, False)
                if slab_delay:
                    extra += group_delay1(eta[mat], c, th, eta_slope[mat])
                e0, e1, e2 = _te_tm(e0, e1, e2, dx, dy, dz, dx, dy, dz, nx, ny, nz, t_te, t_tm)
            if j == k:
                break
            if kinds[r, j] == reflection:
                fi = elem[r, j]
                nx, ny, nz = f_normal[fi, 0], f_normal[fi, 1], f_normal[fi, 2]
                mat = f_material[fi]
                c = clipped_cos1(dot3(nx, ny, nz, dx, dy, dz))
                r_te, r_tm = reflection1(eta[mat], c, f_two_sided[fi], thickness[mat], f)
                e0, e1, e2 = _te_tm(e0, e1, e2, dx, dy, dz, dirs[j + 1, 0], dirs[j + 1, 1],
                                    dirs[j + 1, 2], nx, ny, nz, r_te, r_tm)  # fmt: skip
            elif kinds[r, j] == diffraction:
                has_d = True
                q = d_slot[r, j]
                if not d_valid[q]:
                    e0, e1, e2 = 0j, 0j, 0j
                    continue
                b = d_basis[q]
                c0 = (e0 * b[0, 0] + e1 * b[0, 1]) + e2 * b[0, 2]
                c1 = (e0 * b[1, 0] + e1 * b[1, 1]) + e2 * b[1, 2]
                d = d_matrix[q]
                o0 = -(d[0, 0] * c0 + d[0, 1] * c1)
                o1 = -(d[1, 0] * c0 + d[1, 1] * c1)
                amp = d_amp[q]
                e0 = (o0 * b[2, 0] + o1 * b[3, 0]) * amp
                e1 = (o0 * b[2, 1] + o1 * b[3, 1]) * amp
                e2 = (o0 * b[2, 2] + o1 * b[3, 2]) * amp
        qx, qy, qz = _vertical_pol(dirs[k, 0], dirs[k, 1], dirs[k, 2])
        proj = (e0 * qx + e1 * qy) + e2 * qz
        # free-space spreading over the unfolded length (diffracted paths carry their own)
        spread = 1.0 if has_d else wavelength / (4 * np.pi * total)
        gain[r] = spread * amp_scale[r] * np.exp(-1j * k0 * total) * proj
        delay[r] = total / C0 + extra
    return gain, delay


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
