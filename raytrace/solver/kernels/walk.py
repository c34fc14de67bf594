"""Compiled segment walk of the penetration analysis (numba, options in :mod:`raytrace.core.jit`).

The walk (:func:`raytrace.solver.penetration.segment_crossings`) asks Embree for the next hit of
every segment still going, round after round. Here: its rays (:func:`walk_rays`), a round of its
hits one hit at a time (:func:`walk_hits`: the face a hit at an edge is booked on,
:func:`_canonical`; touches, :func:`_contact`; the walk past a touched solid,
:func:`_off_the_solid`; boundaries of coincident faces, :func:`_coincident`), the bookkeeping of
a boundary (decided on scalars by :func:`_boundary`, written by the kernels themselves:
:func:`walk_record`, :func:`unseen_entries`), the crossings' entry points
(:func:`entry_points`) and the segments whose end may lie in a closed solid entered unseen
(:func:`end_probes`).

Helpers take scalars where they branch (:func:`raytrace.core.jit.inline`: an array live across
a helper's branch costs numba's reference counts per call). The kernels write the numpy
expressions they replaced in numpy's order, so the penetrations are bitwise those of the numpy
form, the choice of the canonical face included (whose numpy form took its dot products from
BLAS).
"""

from __future__ import annotations

import numpy as np

from ...core.jit import helper, inline, kernel
from ...core.vec import dot3
from .solids import edge_distance1, line_span1, sheet_touch1, touches1

__all__ = ["walk_record", "unseen_entries", "walk_rays", "walk_hits", "entry_points",
           "end_probes"]


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
    against the solid (:func:`touches1`).

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
    e = edge_distance1(corners, edge_normals, f, px, py, pz)
    dn = dot3(nx, ny, nz, dx, dy, dz)
    cos = abs(dn)
    cos = cos if (cos > 1e-300 or cos != cos) else 1e-300  # numpy's maximum(cos, 1e-300)
    return px, py, pz, e, np.sign(dn), e >= -(tol + 2.0 * tol / cos)


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
            ok = abs(h) <= tol and edge_distance1(corners, edge_normals, c, px, py, pz) <= tol
        if ok and abs(dn) > best_score:
            best, best_score = c, abs(dn)
    return best


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
    """The equivalent slab of a penetration (:meth:`raytrace.solver.penetration._Walk.record`):
    a sheet's thickness, or a solid's chord times the cosine of the ray ``d`` on the slab's face
    ``n``; a negative chord (rounding) counts as 0."""
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
    entry (:meth:`raytrace.solver.penetration._Walk.unseen`): it was entered at the previous
    boundary, of unit normal ``q`` (that plane, turned against the ray ``d``, is the entry face),
    or the segment starts in it (``q`` zero: the exit face stands in); the more head-on of entry
    and exit faces."""
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
    """One penetration per row (:meth:`raytrace.solver.penetration._Walk.record`): object ``o``
    entered at ``t_entry``, chord (a sheet: thickness) ``th``, the slab's face normal ``fn``
    (n, 3)."""
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
    """Where solids left without a seen entry were entered
    (:meth:`raytrace.solver.penetration._Walk.unseen`): the segments' last boundaries ``t_last``
    (n,) metres, and the slabs' face normals (n, 3) (:func:`_unseen_face`)."""
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
    "Tuple((i8[::1], f8[:, ::1], f4[:, ::1], f4[::1]))("
    "b1[::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[:, ::1], f8[::1])"
)
def walk_rays(active, a, d, t, tmax, shift, shift_end):
    """The next query of every segment still walking: ``rows`` (n,) int, and Embree's rays:
    origins ``a + t d`` (n, 3; float64, which the scene's queries take into Embree's frame and
    float32), shifted by ``shift`` while ``t < shift_end`` (a walk past a touched solid),
    directions ``d`` (n, 3; float32), and reaches ``tmax - t`` (at most ``shift_end - t`` while
    shifted; 1e30 for an unbounded one; float32), metres."""
    n = 0
    for r in range(len(active)):
        n += active[r]
    rows = np.empty(n, dtype=np.int64)
    org = np.empty((n, 3))
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
    the point (within ``tol``), are crossed there (not a touch: :func:`touches1`,
    :func:`sheet_touch1`) and are not an end vertex's own (within ``guard``), one per object,
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
        if edge_distance1(corners, edge_normals, g, px, py, pz) > tol:
            continue
        if closed[og]:
            if touches1(og, qx, qy, qz, dx, dy, dz, normal, offset, count_planes, tol):
                continue
        elif sheet_touch1(og, qx, qy, qz, dx, dy, dz, True, sheet_plane, sheet_reach,
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
    cv, lo, hi, par = line_span1(normal, offset, count, ob, ax, ay, az, dx, dy, dz, -tol)
    if cv and np.isfinite(hi) and size > 0:
        return sx, sy, sz, hi
    return 0.0, 0.0, 0.0, -np.inf


@inline
def _on_plane(f, t_hit, qx, qy, qz, dx, dy, dz, face_normal, corners, grazing_cos, tol):
    """The distance of a hit at ``t_hit`` on face ``f`` taken on the face's plane, in float64,
    along the line queried (origin ``q``, unit direction ``d``): where the ray is not grazing
    (``|cos| > grazing_cos``) and the plane is within ``tol`` of Embree's answer; else
    ``t_hit``. Embree's float32 distance to one plane differs by ~1e-7 relative between the
    triangles of a face and between coincident faces of two objects, so chords, and the slab
    delays and losses made of them, would depend on which triangle the BVH reported. (The
    face's arrays are read before the first branch.)"""
    nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
    cx, cy, cz = corners[f, 0, 0], corners[f, 0, 1], corners[f, 0, 2]
    dn = dot3(nx, ny, nz, dx, dy, dz)
    ok = abs(dn) > grazing_cos
    tp = dot3(nx, ny, nz, cx - qx, cy - qy, cz - qz) / (dn if ok else 1.0)
    if ok and abs(tp - t_hit) <= tol:
        return tp
    return t_hit


#: How :func:`walk_hits` steps over a hit that is not a crossing (:func:`_step_off`).
_ON_LINE, _OFF_OWN_SOLID, _OFF_SOLID, _ALONG_SHEET = 0, 1, 2, 3


@inline
def _step_off(how, f, ob, ax, ay, az, dx, dy, dz, t_hit, face_normal, normal, offset, count,
              sheet_plane, sheet_reach, tol):  # fmt: skip
    """Where the walk goes on after a hit on face ``f`` of object ``ob`` at ``t_hit`` that it
    steps over (the line ``a + t d``): ``(moved, sx, sy, sz, shift_end)``, a new shift of the
    query line and where it ends (``moved`` False: the walk stays as it is).

    ``how``: :data:`_ON_LINE` (noise of the end vertex, a touch of a sheet across its outline:
    on the same line); :data:`_OFF_OWN_SOLID` (noise of the start vertex: off its solid when
    the line only touches it, :func:`~raytrace.solver.kernels.solids.line_span1`, leaving the
    vertex along the solid's face); :data:`_OFF_SOLID` (a touch of a convex solid: off it,
    :func:`_off_the_solid`); :data:`_ALONG_SHEET` (along a flat sheet's plane: off the plane,
    :func:`_across`, until past the sheet)."""
    if how == _ALONG_SHEET:
        sx, sy, sz, _ = _across(sheet_plane[ob, 0], sheet_plane[ob, 1], sheet_plane[ob, 2], dx,
                                dy, dz, tol)  # fmt: skip
        return True, sx, sy, sz, t_hit + sheet_reach[ob] + tol
    if how == _OFF_OWN_SOLID:
        cv, lo, hi, par = line_span1(normal, offset, count, ob, ax, ay, az, dx, dy, dz, tol)
        if not (cv and (par or hi <= lo)):
            return False, 0.0, 0.0, 0.0, 0.0
    elif how != _OFF_SOLID:
        return False, 0.0, 0.0, 0.0, 0.0
    sx, sy, sz, end = _off_the_solid(f, ob, ax, ay, az, dx, dy, dz, face_normal, normal, offset,
                                     count, tol)  # fmt: skip
    return True, sx, sy, sz, end


@inline
def _book(r, n_book, book_ob, book_f, t_hit, dx, dy, dz, face_normal, closed, sheet_thickness,
          k, count, exceeded, dist, obj, normal_p, thick, inside, t_in, normal_in, t_last,
          normal_last):  # fmt: skip
    """The bookkeeping of :func:`walk_hits` at one point of segment ``r`` (unit direction ``d``):
    the ``n_book`` boundaries ``book_ob``, ``book_f`` (object, face) met at ``t_hit``, in order,
    each decided by :func:`_boundary` and written into the walk's arrays (``count`` to
    ``normal_last``, :class:`raytrace.solver.penetration._Walk`): a penetration booked in the
    next of the ``k`` slots (or the budget exceeded), the solid the segment is inside of, its
    entry and the last boundary. (An inlined helper that holds the walk's arrays across its
    branches, as :func:`_step_off` does: numba's reference counts cost nothing measurable here.
    On the hall, ``walk_hits`` with this loop and the steps over hits in its body took 16.9-26.5
    ms over the 71 calls of a trace, and 17.0-19.5 ms with them in these helpers: the minimum of
    31 runs, six times each, CPU time.)"""
    for c in range(n_book):
        ob, f = book_ob[c], book_f[c]
        nx, ny, nz = face_normal[f, 0], face_normal[f, 1], face_normal[f, 2]
        # the boundary's bookkeeping (_boundary decides on scalars)
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
    a hit on the object under either end within ``guard`` of it is float32 noise of the vertex
    (on a shifted line, within ``guard + 2 tol / cos`` on a face through the vertex,
    :func:`_own_face_shifted`) and a touch of a convex solid (:func:`_contact`) or of a flat
    sheet (:func:`sheet_touch1`) is not a crossing: both are stepped over (:func:`_step_off`).
    Otherwise the hit is booked on its canonical face (:func:`_canonical`), at its distance on
    that face's plane (:func:`_on_plane`), with the boundaries of coincident faces there
    (:func:`_coincident`), by :func:`_book`. Every step is by ``margin``; a segment that meets
    more than ``limit`` boundaries exceeds its budget.

    ``t``, ``active``, ``crossed``, ``shift``, ``shift_end`` (per segment) and the arrays after
    ``sheet_thickness`` (:class:`raytrace.solver.penetration._Walk`) are updated; ``a`` (N, 3),
    ``length``, ``tmax`` (N,) metres and ``end_objects`` (N, 2) describe the segments; the
    arrays from ``corners`` to ``face_normal`` are the scene's, as the other kernels take them,
    ``sheet_plane`` to ``sheet_edges`` its flat sheets (:func:`raytrace.solver.penetration.
    flat_sheet_arrays`), ``co_start`` to ``co_face`` the faces of other objects in each face's
    plane (:func:`~raytrace.solver.penetration.coincident_faces`), ``face_object`` each face's.
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
        if ob < 0:  # a miss: the walk ends, or a shifted stretch does (back on the own line)
            shifted = t[r] < shift_end[r]
            t[r] = shift_end[r] if shifted else t[r]
            active[r] = shifted and t[r] < tmax[r]
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
        how = -1  # a crossing, unless it is stepped over (_step_off)
        if (ob == end_objects[r, 0] and near_start) or (ob == end_objects[r, 1] and near_end):
            how = _OFF_OWN_SOLID if ob == end_objects[r, 0] else _ON_LINE
        else:
            px, py, pz, e, side, near = _contact(f, ax, ay, az, dx, dy, dz, t_hit, face_normal,
                                                 corners, edge_normals, tol)  # fmt: skip
            touch = near and touches1(ob, ax, ay, az, dx, dy, dz, normal, offset, count_planes,
                                      tol)  # fmt: skip
            along = False
            if not touch and not closed[ob]:
                touch, along = sheet_touch1(ob, ax, ay, az, dx, dy, dz, near, sheet_plane,
                                            sheet_reach, sheet_edge_start, sheet_edge_count,
                                            sheet_edges, tol)  # fmt: skip
            if e >= -tol:
                f = _canonical(f, ob, px, py, pz, dx, dy, dz, side, face_start, face_count,
                               face_normal, corners, edge_normals, tol)  # fmt: skip
            if touch:
                how = _ALONG_SHEET if along else _OFF_SOLID if closed[ob] else _ON_LINE
        if how >= 0:
            t[r] = t_hit + margin
            moved, sx, sy, sz, end = _step_off(how, f, ob, ax, ay, az, dx, dy, dz, t_hit,
                                               face_normal, normal, offset, count_planes,
                                               sheet_plane, sheet_reach, tol)  # fmt: skip
            if moved:
                shift[r, 0], shift[r, 1], shift[r, 2], shift_end[r] = sx, sy, sz, end
            active[r] = t[r] < tmax[r]
            continue
        # the distance on the booked face's plane, in float64, along the line queried
        t_hit = _on_plane(f, t_hit, qx, qy, qz, dx, dy, dz, face_normal, corners, grazing_cos,
                          tol)  # fmt: skip
        book_ob[0], book_f[0] = ob, f
        n_book = 1
        if co_count[f] > 0:  # a boundary of another object in this face's plane, at this point?
            n_book = _coincident(r, ob, f, t_hit, qx, qy, qz, dx, dy, dz, length[r], guard,
                                 end_objects, co_start, co_count, co_face, face_object, closed,
                                 corners, edge_normals, normal, offset, count_planes,
                                 sheet_plane, sheet_reach, sheet_edge_start, sheet_edge_count,
                                 sheet_edges, tol, book_ob, book_f)  # fmt: skip
        _book(r, n_book, book_ob, book_f, t_hit, dx, dy, dz, face_normal, closed, sheet_thickness,
              k, count, exceeded, dist, obj, normal_p, thick, inside, t_in, normal_in, t_last,
              normal_last)  # fmt: skip
        t[r] = t_hit + margin
        crossed[r] += n_book
        active[r] = t[r] < tmax[r] and not exceeded[r]
        if active[r] and crossed[r] >= limit:
            exceeded[r] = True
            active[r] = False


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
    :func:`~raytrace.solver.kernels.solids.line_span`, with a slack of 1e-9 m for the order of
    the sums) or within the bounding box ``lo``, ``hi`` (O, 3) of another closed solid; the probe's answer can only be a solid
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
