"""Geometry of a scene's facets and wedges, and the derived arrays the mechanisms reuse.

Point-in-facet tests and the acceleration arrays that every mechanism prunes with: facet
bounding boxes and spheres, the facet pairs that can exchange a reflection, wedges grouped by
object. The derived arrays are computed on first use and kept in the ``cache`` of the
:class:`~raytrace.scene.model.Facets` or :class:`~raytrace.scene.model.Wedges` they describe
(read-only arrays; a new Facets starts with an empty cache).

A facet of a closed solid reflects only on its outward side; a facet of an open sheet on both.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.jit import carray, helper, inline, kernel
from ..core.vec import dot3
from .elements import Facets, Wedges
from .spatial import SphereTree, build_tree, query_beams

#: Barycentric tolerance of the point-in-triangle test (dimensionless): a point on the shared
#: edge of two triangles of one facet must not fall through the crack.
BARY_TOL = 1e-9
#: Points closer than this to a facet's plane (m) are on it: no reflection from there.
PLANE_TOL_M = 1e-9
#: A point farther than this (m) inside an axis-aligned rectangular facet is inside it without
#: the barycentric test (far above its rounding, so the answer is the test's).
RECT_INSIDE_M = 1e-6


def points_in_facets(points: np.ndarray, facet: np.ndarray, facets: Facets) -> np.ndarray:
    """Whether each point (on its facet's plane) lies inside that facet.

    A facet is a union of triangles; the point is inside if it is in any of them (barycentric
    test in 3D, with :data:`BARY_TOL`).

    Parameters
    ----------
    points : (n, 3) float, metres
    facet : (n,) int, facet index of each point
    facets : Facets

    Returns
    -------
    (n,) bool
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=bool)
    return _points_in(carray(points), carray(facet, np.int64), *facet_test_arrays(facets),
                      BARY_TOL, RECT_INSIDE_M)  # fmt: skip


def facet_test_arrays(facets: Facets) -> tuple[np.ndarray, ...]:
    """What :func:`facet_box_test` and :func:`in_triangles` take about the facets, as the
    kernels take it (cached): the boxes of :func:`facet_boxes`, the rectangles of
    :func:`_rectangles`, the facets' runs of triangles and the triangles' terms of
    :func:`_triangle_terms`."""
    cached = facets.cache.get("facet_test_arrays")
    if cached is None:
        lo, hi = facet_boxes(facets)
        # a facet whose corners lie off its plane (welding gaps of a repaired mesh): a point on
        # the plane may lie outside the corners' box along the normal by as much
        off = facet_off_plane(facets)
        if (off > PLANE_TOL_M).any():
            pad = np.where(off > PLANE_TOL_M, off, 0.0)[:, None]
            lo, hi = lo - pad, hi + pad
        rect, r_lo, r_hi = _rectangles(facets)
        cached = (carray(lo), carray(hi), carray(rect, bool), carray(r_lo), carray(r_hi),
                  carray(facets.tri_start, np.int64), carray(facets.tri_count, np.int64),
                  *(carray(x) for x in _triangle_terms(facets)))  # fmt: skip
        facets.cache["facet_test_arrays"] = cached
    return cached


@inline
def facet_box_test(px, py, pz, f, lo, hi, rect, r_lo, r_hi, rect_inside):
    """The quick part of :func:`points_in_facets` for a point on facet ``f``'s plane (a compiled
    scalar helper for kernels, with :func:`facet_test_arrays`' arrays): 0 outside the facet's
    bounding box, 1 well inside an axis-aligned rectangular facet, -1 undecided (the caller
    then calls :func:`in_triangles`).

    Every array is read before the first branch: in an inlined helper, an array read after a
    branch that merges back (an early return, ``a and b``) or passed on from there costs numba
    a reference count per call, about ten times the test itself."""
    l0, l1, l2, h0, h1, h2 = lo[f, 0], lo[f, 1], lo[f, 2], hi[f, 0], hi[f, 1], hi[f, 2]
    is_rect = rect[f]
    a0, a1, a2, b0, b1, b2 = r_lo[f, 0], r_lo[f, 1], r_lo[f, 2], r_hi[f, 0], r_hi[f, 1], r_hi[f, 2]
    if not (l0 <= px <= h0 and l1 <= py <= h1 and l2 <= pz <= h2):
        return 0
    if (is_rect and a0 + rect_inside <= px <= b0 - rect_inside
            and a1 + rect_inside <= py <= b1 - rect_inside
            and a2 + rect_inside <= pz <= b2 - rect_inside):  # fmt: skip
        return 1
    return -1


@helper
def in_triangles(px, py, pz, f, tri_start, tri_count, corner, v0, v1, d00, d01, d11, den,
                 bary_tol):  # fmt: skip
    """The barycentric test of :func:`points_in_facets` against each of facet ``f``'s
    triangles (a compiled scalar helper for kernels, after :func:`facet_box_test` left the
    point undecided). Products and sums in the order of the vectorised form it replaced."""
    for t in range(tri_start[f], tri_start[f] + tri_count[f]):
        x, y, z = px - corner[t, 0], py - corner[t, 1], pz - corner[t, 2]
        d20 = dot3(x, y, z, v0[t, 0], v0[t, 1], v0[t, 2])
        d21 = dot3(x, y, z, v1[t, 0], v1[t, 1], v1[t, 2])
        v = (d11[t] * d20 - d01[t] * d21) / den[t]
        w = (d00[t] * d21 - d01[t] * d20) / den[t]
        if v >= -bary_tol and w >= -bary_tol and v + w <= 1 + bary_tol:
            return True
    return False


#: The kernels' signature of :func:`facet_test_arrays` and the two tolerances.
FACET_TEST_SIG = (
    "f8[:, ::1], f8[:, ::1], b1[::1], f8[:, ::1], f8[:, ::1], i8[::1], i8[::1], "
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], f8, f8"
)


@kernel(f"b1[::1](f8[:, ::1], i8[::1], {FACET_TEST_SIG})")
def _points_in(points, facet, lo, hi, rect, r_lo, r_hi, tri_start, tri_count, corner, v0, v1,
               d00, d01, d11, den, bary_tol, rect_inside):  # fmt: skip
    """:func:`points_in_facets` over n points: :func:`facet_box_test`, then
    :func:`in_triangles` where it is undecided."""
    out = np.empty(len(points), dtype=np.bool_)
    for r in range(len(points)):
        px, py, pz, f = points[r, 0], points[r, 1], points[r, 2], facet[r]
        quick = facet_box_test(px, py, pz, f, lo, hi, rect, r_lo, r_hi, rect_inside)
        if quick < 0:
            out[r] = in_triangles(px, py, pz, f, tri_start, tri_count, corner, v0, v1, d00, d01,
                                  d11, den, bary_tol)  # fmt: skip
        else:
            out[r] = quick > 0
    return out


def _rectangles(facets: Facets) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Facets that are axis-aligned rectangles, exactly: two triangles whose vertices are corners
    of the facet's (flat) bounding box and which split it along a diagonal (cached).

    Returns
    -------
    rect : (K,) bool
    lo, hi : (K, 3) float, metres: for a rectangle, the in-plane bounds, and -inf / +inf along
        its normal axis (the plane itself is checked by the caller's box test); 0 elsewhere
    """
    cached = facets.cache.get("rectangles")
    if cached is not None:
        return cached
    box_lo, box_hi = facet_boxes(facets, 0.0)
    k = len(facets)
    flat = box_lo == box_hi
    rect = (facets.tri_count == 2) & (flat.sum(axis=1) == 1)
    cand = np.flatnonzero(rect)
    lo, hi = np.zeros((k, 3)), np.zeros((k, 3))
    if len(cand):
        t0 = facets.tri_start[cand]
        tri = facets.triangles[np.stack([t0, t0 + 1], axis=1)]  # (C, 2 triangles, 3 corners, 3)
        axis = np.argmax(flat[cand], axis=1)
        bits = np.zeros(tri.shape[:3], dtype=np.int64)
        on_box = np.ones(tri.shape[:3], dtype=bool)
        for i, a in enumerate(((axis + 1) % 3, (axis + 2) % 3)):  # the two in-plane axes
            x = np.take_along_axis(tri, a[:, None, None, None], axis=3)[..., 0]
            at_lo = x == box_lo[cand, a][:, None, None]
            at_hi = x == box_hi[cand, a][:, None, None]
            on_box &= at_lo | at_hi
            bits += at_hi.astype(np.int64) << i  # corner index 0..3 (bit i: high on axis i)
        # each triangle on three distinct corners; the corners they miss opposite (a diagonal)
        mask = np.bitwise_or.reduce(1 << bits, axis=2)  # (C, 2)
        three = np.isin(mask, (7, 11, 13, 14))
        missing = np.log2(np.where(three, 15 ^ mask, 1)).astype(np.int64)
        ok = on_box.all(axis=(1, 2)) & three.all(axis=1) & (missing[:, 0] ^ missing[:, 1] == 3)
        rect[cand[~ok]] = False
        good = cand[ok]
        lo[good], hi[good] = box_lo[good], box_hi[good]
        lo[good, axis[ok]], hi[good, axis[ok]] = -np.inf, np.inf
    out = (rect, lo, hi)
    for x in out:
        x.setflags(write=False)
    facets.cache["rectangles"] = out
    return out


def _triangle_terms(facets: Facets) -> tuple[np.ndarray, ...]:
    """The point-independent terms of the barycentric test, per triangle (cached): first corner
    (T, 3), edge vectors ``v0``, ``v1`` (T, 3) and ``d00, d01, d11, den`` (T,). Row-wise
    arithmetic, so taking them per test is bitwise computing them per test."""
    cached = facets.cache.get("triangle_terms")
    if cached is not None:
        return cached
    tri = facets.triangles
    v0 = tri[:, 1] - tri[:, 0]
    v1 = tri[:, 2] - tri[:, 0]
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    den = d00 * d11 - d01 * d01
    out = (np.ascontiguousarray(tri[:, 0]), v0, v1, d00, d01, d11, den)
    for x in out:
        x.setflags(write=False)
    facets.cache["triangle_terms"] = out
    return out


def facet_boxes(facets: Facets, grow: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) lower and upper corners of each facet's axis-aligned bounding box, grown by
    ``grow`` metres (cached per ``grow``)."""
    key = ("boxes", float(grow))
    cached = facets.cache.get(key)
    if cached is not None:
        return cached
    # a facet's triangles are contiguous, starting at tri_start
    lo = np.minimum.reduceat(facets.triangles.min(axis=1), facets.tri_start, axis=0) - grow
    hi = np.maximum.reduceat(facets.triangles.max(axis=1), facets.tri_start, axis=0) + grow
    lo.setflags(write=False)
    hi.setflags(write=False)
    facets.cache[key] = (lo, hi)
    return lo, hi


def facet_off_plane(facets: Facets) -> np.ndarray:
    """(K,) float, metres: the largest distance of a facet's corners from its plane (cached):
    rounding (1e-15 m) for a clean mesh, up to the welding gaps for a repaired one, whose
    coplanar triangles are only nearly so."""
    cached = facets.cache.get("off_plane")
    if cached is not None:
        return cached
    owner = np.repeat(np.arange(len(facets)), facets.tri_count)
    d = np.einsum("tij,tj->ti", facets.triangles, facets.normal[owner]) - facets.offset[owner, None]
    out = np.maximum.reduceat(np.abs(d).max(axis=1), facets.tri_start) if len(facets) else np.zeros(0)
    out.setflags(write=False)
    facets.cache["off_plane"] = out
    return out


def facet_spheres(facets: Facets) -> tuple[np.ndarray, np.ndarray]:
    """Bounding sphere of each facet: centre (K, 3) and radius (K,), metres (cached)."""
    cached = facets.cache.get("spheres")
    if cached is not None:
        return cached
    lo, hi = facet_boxes(facets, 0.0)
    centre = 0.5 * (lo + hi)
    owner = np.repeat(np.arange(len(facets)), facets.tri_count * 3)
    d = np.linalg.norm(facets.triangles.reshape(-1, 3) - centre[owner], axis=1)
    radius = np.maximum.reduceat(d, 3 * facets.tri_start) * (1 + 1e-9) + 1e-9
    centre.setflags(write=False)
    radius.setflags(write=False)
    facets.cache["spheres"] = (centre, radius)
    return centre, radius


def facet_tree(facets: Facets) -> SphereTree:
    """A bounding-volume hierarchy over the facets' boxes (:func:`facet_boxes`, not grown) and
    bounding spheres (:func:`facet_spheres`), for the spatial queries that replace scans of
    every facet (:mod:`raytrace.scene.spatial`); cached."""
    cached = facets.cache.get("tree")
    if cached is None:
        lo, hi = facet_boxes(facets, 0.0)
        centre, radius = facet_spheres(facets)
        cached = facets.cache["tree"] = build_tree(lo, hi, centre, radius)
    return cached


def wedge_tree(wedges: Wedges) -> SphereTree:
    """A bounding-volume hierarchy over the edges: each edge's box and the sphere on its middle
    through its ends (radius grown by a relative 1e-9, as :func:`wedge_groups`); cached."""
    cached = wedges.cache.get("tree")
    if cached is None:
        a, b = wedges.start, wedges.end
        centre = 0.5 * (a + b)
        radius = 0.5 * np.linalg.norm(b - a, axis=1) * (1 + 1e-9) + 1e-9
        cached = wedges.cache["tree"] = build_tree(np.minimum(a, b), np.maximum(a, b), centre,
                                                   radius)  # fmt: skip
    return cached


def facet_forest(facets: Facets) -> tuple[tuple[SphereTree, int], ...]:
    """The facets' trees, each with the index of its first facet: one tree over all of them
    (:func:`facet_tree`), or, for a scene with moving objects joined to a static one
    (:func:`raytrace.scene.dynamic.extend_scene`), the static scene's tree and one over the
    added facets, so that a snapshot builds a tree of its few moving facets only (cached)."""
    cached = facets.cache.get("forest")
    if cached is None:
        cached = facets.cache["forest"] = ((facet_tree(facets), 0),)
    return cached


def wedge_forest(wedges: Wedges) -> tuple[tuple[SphereTree, int], ...]:
    """The edges' trees, each with the index of its first edge: one tree over all of them
    (:func:`wedge_tree`), or for a scene with moving objects the static scene's and the added
    edges' (as :func:`facet_forest`; cached)."""
    cached = wedges.cache.get("forest")
    if cached is None:
        cached = wedges.cache["forest"] = ((wedge_tree(wedges), 0),)
    return cached


def beam_facets(
    facets: Facets,
    beam: Any,
    normal: np.ndarray,
    offset: np.ndarray,
    side: np.ndarray,
    mask: np.ndarray | None = None,
    masked: np.ndarray | None = None,
    forest: tuple[tuple[SphereTree, int], ...] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(query, facet) pairs, in query order: the facets whose bounding sphere each beam can
    reach with some part strictly on its plane's ``side`` (:func:`raytrace.scene.spatial.
    query_beams` on every tree of :func:`facet_forest`).

    Parameters
    ----------
    beam : :class:`raytrace.solver.reflection.Beam` of Q beams (apex, axis, cos_a, sin_a,
        apex_inside)
    normal : (Q, 3) float, offset : (Q,) float, side : (Q,) int, each beam's plane and side
    mask : (K,) bool, optional, facets that may take part (a trace of some objects only)
    masked : (Q,) bool, with ``mask``: the beams from a facet that may take part; the others
        are asked about the facets that may take part only (a tree over those, built here)
    forest : trees to ask instead of :func:`facet_forest` (each with the index its elements
        are offset by), without ``mask``; the hits are then those trees' elements

    Returns
    -------
    q_idx, f_idx : (H,) int
    """
    args = (beam.apex, beam.axis, beam.cos_a, beam.sin_a, beam.apex_inside, normal, offset, side)
    q_parts, f_parts = [], []

    def ask(forest, rows: np.ndarray | None) -> None:
        sub = args if rows is None else tuple(np.asarray(x)[rows] for x in args)
        for tree, first in forest:
            off, hits = query_beams(tree, *sub)
            q = np.repeat(np.arange(len(off) - 1), np.diff(off))
            q_parts.append(q if rows is None else rows[q])
            f_parts.append(hits + first)

    if mask is None:
        ask(facet_forest(facets) if forest is None else forest, None)
    else:
        ask(facet_forest(facets), np.flatnonzero(masked))
        chosen = np.flatnonzero(mask)
        others = np.flatnonzero(~masked)
        if len(chosen) and len(others):
            lo, hi = facet_boxes(facets, 0.0)
            centre, radius = facet_spheres(facets)
            tree = build_tree(lo[chosen], hi[chosen], centre[chosen], radius[chosen])
            n0 = len(f_parts)
            ask(((tree, 0),), others)
            f_parts[n0:] = [chosen[f] for f in f_parts[n0:]]
    if not q_parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    q_idx, f_idx = np.concatenate(q_parts), np.concatenate(f_parts)
    order = np.argsort(q_idx, kind="stable")
    return q_idx[order], f_idx[order]


def facing(facets: Facets, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(n,) bool, per pair of facets ``i``, ``j`` (n,) int: each has some corner strictly on a
    reflecting side of the other (closed solids reflect outward only), and they differ: the
    necessary condition for exchanging a reflection, :func:`facing_pairs` for the given pairs
    only (no (facets x facets) table)."""
    if len(i) == 0:
        return np.zeros(0, dtype=bool)
    starts = carray(3 * (np.cumsum(facets.tri_count) - facets.tri_count), np.int64)
    counts = carray(3 * facets.tri_count, np.int64)
    return _facing(carray(i, np.int64), carray(j, np.int64), carray(facets.triangles.reshape(-1, 3)),
                   starts, counts, carray(facets.normal), carray(facets.offset),
                   carray(facets.two_sided, bool), PLANE_TOL_M)  # fmt: skip


@helper
def facet_sees(verts, start, count, nx, ny, nz, off, two_sided, tol):
    """Some vertex ``verts[start:start + count]`` strictly in front of the plane (or behind it,
    for a two-sided facet)."""
    for k in range(start, start + count):
        s = verts[k, 0] * nx + verts[k, 1] * ny + verts[k, 2] * nz - off
        if s > tol or (two_sided and s < -tol):
            return True
    return False


@kernel("b1[::1](i8[::1], i8[::1], f8[:, ::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], b1[::1], f8)")
def _facing(i, j, verts, starts, counts, normal, offset, two_sided, tol):
    """:func:`facing` in one pass over the pairs."""
    out = np.zeros(len(i), dtype=np.bool_)
    for p in range(len(i)):
        a, b = i[p], j[p]
        if a == b:
            continue
        out[p] = facet_sees(verts, starts[a], counts[a], normal[b, 0], normal[b, 1], normal[b, 2],
                             offset[b], two_sided[b], tol) and facet_sees(
            verts, starts[b], counts[b], normal[a, 0], normal[a, 1], normal[a, 2], offset[a],
            two_sided[a], tol)  # fmt: skip
    return out


def facing_pairs(facets: Facets, known: np.ndarray | None = None) -> np.ndarray:
    """(K, K) bool: facet j can receive a reflection from facet i (necessary condition).

    Some part of facet i must lie strictly on a reflecting side of facet j and vice versa
    (closed solids reflect outward only). Excludes i == j and facets in the same plane. The result
    is cached on the facets and read-only.

    Parameters
    ----------
    facets : Facets
    known : (k0, k0) bool, optional, the result for the first k0 facets (the same facets in the
        same order, e.g. a static scene that moving objects are appended to): only the rows and
        columns of the others are computed. By default, the table of the facets that
        ``facets.cache["extends"]`` names, if any (set by
        :func:`raytrace.scene.dynamic.extend_scene`).
    """
    cached = facets.cache.get("facing")
    if cached is not None:
        return cached
    base = facets.cache.get("extends")
    if known is None and base is not None:
        # a snapshot's facets (:func:`raytrace.scene.dynamic.extend_scene`): the static block is
        # the static scene's table, computed once and kept on its facets
        known = facing_pairs(base)
    k = len(facets)
    k0 = 0 if known is None else int(known.shape[0])
    # sees[i, j]: any vertex of facet i on a reflecting side of facet j; a facet's vertices are
    # contiguous, so one reduceat per block
    starts = 3 * (np.cumsum(facets.tri_count) - facets.tri_count)
    verts = facets.triangles.reshape(-1, 3)

    def sees(rows: slice, cols: slice) -> np.ndarray:
        v0 = starts[rows.start] if rows.start < k else len(verts)
        s = verts[v0 : starts[rows.stop] if rows.stop < k else len(verts)]
        s = s @ facets.normal[cols].T - facets.offset[None, cols]
        first = starts[rows] - v0
        front = np.logical_or.reduceat(s > PLANE_TOL_M, first, axis=0)
        back = np.logical_or.reduceat(s < -PLANE_TOL_M, first, axis=0)
        return front | (back & facets.two_sided[None, cols])

    every = slice(0, k)
    if k0 == 0:
        both = sees(every, every)
        ok = both & both.T
    else:
        ok = np.zeros((k, k), dtype=bool)
        ok[:k0, :k0] = known
    if 0 < k0 < k:
        new = slice(k0, k)
        s_new_all = sees(new, every)  # (k - k0, k)
        s_all_new = sees(every, new)  # (k, k - k0)
        ok[k0:, :] = s_new_all & s_all_new.T
        ok[:, k0:] = s_all_new & s_new_all.T
    np.fill_diagonal(ok, False)
    ok.setflags(write=False)
    facets.cache["facing"] = ok
    return ok


def wedge_groups(w: Wedges) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Wedges grouped by object, with each group's bounding sphere (cached).

    Returns
    -------
    order : (W,) int, wedge indices sorted by object
    start, count : (G,) int, each group's slice of ``order``
    centre : (G, 3) float, metres
    radius : (G,) float, metres (grown by a relative 1e-9)
    """
    cached = w.cache.get("groups")
    if cached is not None:
        return cached
    order = np.argsort(w.object, kind="stable")
    _, start, count = np.unique(w.object[order], return_index=True, return_counts=True)
    a, b = w.start[order], w.end[order]
    lo = np.minimum.reduceat(np.minimum(a, b), start, axis=0)
    hi = np.maximum.reduceat(np.maximum(a, b), start, axis=0)
    centre = 0.5 * (lo + hi)
    owner = np.repeat(np.arange(len(start)), count)
    d = np.maximum(
        np.linalg.norm(a - centre[owner], axis=1), np.linalg.norm(b - centre[owner], axis=1)
    )
    radius = np.maximum.reduceat(d, start) * (1 + 1e-9) + 1e-9
    out = (order, start, count, centre, radius)
    for x in out:
        x.setflags(write=False)
    w.cache["groups"] = out
    return out


# -- the triangles Embree is given, and its answers read in one pass (raytrace.scene.model) -------
#: Embree builds its hierarchy from the triangles' bounding boxes, and a triangle as large as the
#: hall (its floor, roof and walls: 40-60 m across) overlaps every box of it: each ray through the
#: hall tests the shell's triangles. An object with an edge longer than this share of the scene's
#: extent is cut, for Embree only, into n x n smaller copies of each of its triangles
#: (:func:`embree_mesh`). Measured on the hall's walk rays: 119 ns a ray whole, 75-77 ns cut
#: at a half to a quarter of the extent, 64 ns without the shell at all.
EMBREE_SPLIT_FRACTION = 0.25
#: At most this many triangles per object after the cut (n is lowered to stay under it).
EMBREE_SPLIT_MAX_TRIANGLES = 4096


def embree_split(vertices: np.ndarray, faces: np.ndarray, extent: float) -> int:
    """n, the cut of one object's triangles for Embree (1: kept whole): the object's longest edge
    over ``EMBREE_SPLIT_FRACTION`` of the scene's ``extent`` (m), rounded up, at most
    ``EMBREE_SPLIT_MAX_TRIANGLES`` triangles in all. ``vertices`` (V, 3) float, metres;
    ``faces`` (m, 3) int, the object's triangles."""
    if len(faces) == 0 or not extent > 0:
        return 1
    tri = vertices[faces]
    edge = np.sqrt(((tri - np.roll(tri, 1, axis=1)) ** 2).sum(axis=2)).max()
    n = int(np.ceil(edge / (EMBREE_SPLIT_FRACTION * extent)))
    n = min(n, int(np.sqrt(EMBREE_SPLIT_MAX_TRIANGLES / len(faces))))
    return max(n, 1)


def embree_mesh(
    vertices: np.ndarray, faces: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One object's triangles as Embree is given them: each cut into n x n (n >= 1).

    The points of the cut are the barycentric grid ``a + (b - a) i/n + (c - a) j/n``; the points
    on an edge are computed from the edge's lexicographically smaller end, so that the two
    triangles that share an edge cut it at the same float32 points and the mesh stays watertight
    (Embree's hit test is watertight across edges whose ends are identical).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (m, 3) int, the object's triangles (indices into ``vertices``)
    n : int, the cut

    Returns
    -------
    points : (P, 3) float32, metres
    triangles : (m n^2, 3) int32, indices into ``points``, each with its face's orientation
    face : (m n^2,) int, the face (row of ``faces``) each triangle is part of
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if n <= 1:
        used, inv = np.unique(faces, return_inverse=True)
        return (vertices[used].astype(np.float32), inv.reshape(-1, 3).astype(np.int32),
                np.arange(len(faces), dtype=np.int64))  # fmt: skip
    m = len(faces)
    i, j = (g.ravel() for g in np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij"))
    keep = i + j <= n
    i, j = i[keep], j[keep]  # the grid's K points; K = (n + 1)(n + 2) / 2
    a, b, c = (vertices[faces[:, k]] for k in range(3))  # (m, 3) each
    pts = (
        a[:, None]
        + (b - a)[:, None] * (i / n)[None, :, None]
        + (c - a)[:, None] * (j / n)[None, :, None]
    )

    def along(p: np.ndarray, q: np.ndarray, s: np.ndarray, sel: np.ndarray) -> None:
        # the points of edge p -> q at steps s (of n) from p, from the edge's smaller end
        swap = (p[:, 0] > q[:, 0]) | (
            (p[:, 0] == q[:, 0])
            & ((p[:, 1] > q[:, 1]) | ((p[:, 1] == q[:, 1]) & (p[:, 2] > q[:, 2])))
        )
        lo = np.where(swap[:, None], q, p)
        hi = np.where(swap[:, None], p, q)
        k = np.where(swap[:, None], n - s[None, :], s[None, :])
        pts[:, sel] = lo[:, None] + (hi - lo)[:, None] * (k / n)[..., None]

    along(a, b, i[j == 0], j == 0)
    along(a, c, j[i == 0], i == 0)
    along(b, c, j[i + j == n], i + j == n)
    for (ci, cj), v in (((0, 0), a), ((n, 0), b), ((0, n), c)):  # the corners exactly
        pts[:, (i == ci) & (j == cj)] = v[:, None]
    index = np.full((n + 1, n + 1), -1, dtype=np.int64)
    index[i, j] = np.arange(len(i))
    up_i, up_j = np.nonzero(np.add.outer(np.arange(n), np.arange(n)) <= n - 1)
    dn_i, dn_j = np.nonzero(np.add.outer(np.arange(n), np.arange(n)) <= n - 2)
    local = np.concatenate(
        [
            np.stack([index[up_i, up_j], index[up_i + 1, up_j], index[up_i, up_j + 1]], axis=1),
            np.stack(
                [index[dn_i + 1, dn_j], index[dn_i + 1, dn_j + 1], index[dn_i, dn_j + 1]], axis=1
            ),
        ]
    )  # (n^2, 3): the cut of one triangle, in its orientation
    tri = (np.arange(m)[:, None, None] * len(i) + local[None]).reshape(-1, 3)
    points, inv = np.unique(pts.reshape(-1, 3).astype(np.float32), axis=0, return_inverse=True)
    return (points, inv.reshape(-1)[tri].astype(np.int32),
            np.repeat(np.arange(m, dtype=np.int64), n * n))  # fmt: skip


@kernel("Tuple((f8[::1], i8[::1], i8[::1]))(i4[::1], i4[::1], f4[::1], i8[::1], i8[::1])")
def hit_records(geom, prim, tfar, prim_start, prim_face):
    """The first hits of n rays from Embree's ``geomID``, ``primID`` (-1: none) and ``tfar``
    (n,): distance (inf for none), global face (``prim_face[prim_start[geomID] + primID]``: the
    face each of Embree's triangles is part of, :func:`embree_mesh`) and object (-1 for none)
    (:meth:`raytrace.scene.model.Scene.intersect`)."""
    n = len(geom)
    t = np.empty(n)
    face = np.empty(n, dtype=np.int64)
    obj = np.empty(n, dtype=np.int64)
    for i in range(n):
        g = geom[i]
        if g >= 0:
            t[i], face[i], obj[i] = tfar[i], prim_face[prim_start[g] + prim[i]], g
        else:
            t[i], face[i], obj[i] = np.inf, -1, -1
    return t, face, obj


@kernel("i8[::1](i4[::1], i8[::1])")
def subset_hits(geom, members):
    """The objects ``members[geomID]`` of n rays' first hits in a subset's Embree scene, -1 for
    none (:meth:`raytrace.scene.model.Scene.first_hit_among`)."""
    out = np.empty(len(geom), dtype=np.int64)
    for i in range(len(geom)):
        out[i] = members[geom[i]] if geom[i] >= 0 else -1
    return out


@kernel("i8[::1](f8[:, ::1], f8[:, ::1], f8[::1], i8[::1], i8[::1], f8)")
def convex_owner(points, normal, offset, g_start, g_object, tol):
    """The first convex solid that contains each of n points (n, 3), -1 for none
    (:meth:`raytrace.scene.model.Scene.inside_solid`): solid ``g_object[g]``'s facet planes are
    rows ``g_start[g]`` up to the next group's start of ``normal`` (F, 3) and ``offset`` (F,), and
    a point is inside when ``normal . p - offset < -tol`` for every one of them. A loop with an
    exit at the first plane a point is not behind, rather than the (n, F) product of the points
    and the normals: that product went to BLAS, whose threaded matrix product on a grid of
    receivers woke helper threads that then spin for about 0.1 s on the cores the tracing lanes
    run on (docs/tracing.md, "A twelfth round")."""
    n, n_g, n_f = len(points), len(g_start), len(offset)
    out = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for g in range(n_g):
            stop = g_start[g + 1] if g + 1 < n_g else n_f
            inside = True
            for j in range(g_start[g], stop):
                s = dot3(px, py, pz, normal[j, 0], normal[j, 1], normal[j, 2]) - offset[j]
                if not s < -tol:
                    inside = False
                    break
            if inside:
                out[i] = g_object[g]
                break
    return out
