"""Penetration: what a straight segment crosses, and the thickness it traverses.

A segment that crosses objects is attenuated, not blocked. Entering and leaving a closed solid is
one penetration through the traversed chord; crossing an open sheet is one penetration through
its material's thickness. The field loss (slab transmission of ITU-R P.2040 section 3 at the
incidence angle) is applied by the tracer; metal transmits nothing, so it blocks in effect.

Entering or leaving a closed solid is read from the outward normal of the hit face, so that
touching solids (a face shared by two boxes) each get their chord although the second's entry is
stepped over with the first's exit; a solid left without a seen entry began at the previous
boundary or at the segment's start. Which of two coincident faces Embree reports first (the
first solid's exit or the second's entry, at the same distance) depends on its BVH, so the
result must not: a solid entered through the previous boundary takes that boundary's plane as
its entry face (the coincident face it was entered through, turned against the ray), exactly as
when its own entry face is the one reported. A solid left without a seen entry at the segment's
start has no entry face; its exit face stands in. Likewise a hit at an edge or a vertex is
booked on a canonical face, a ray that only touches a convex solid (at an edge, a vertex or
along a face) or a flat sheet (along its plane, or past its outline within the contact
tolerance: a receiver in the plane of a fence, looking past the edge of the pane that meets it)
does not cross it, a sheet lying on a solid's face is crossed with it (both boundaries at the
point are booked, :func:`coincident_faces`), and hit distances are taken on the booked face's
plane in float64 (:func:`raytrace.solver.kernels.walk_hits`): the crossings do not depend on
the BVH, which differs between a static scene and a snapshot with forklifts.

The equivalent slab thickness of a chord through a solid is the chord length times the cosine of
the incidence angle on the more head-on of its entry and exit faces (:func:`raytrace.solver.kernels.walk._more_head_on`):
exact for a slab with parallel faces, an approximation for a chord that leaves through another
face, and the same in both directions along the chord (reciprocity).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.jit import carray
from ..core.vec import norm
from ..scene.model import Scene
from . import kernels


@dataclass(frozen=True)
class Crossings:
    """Penetrations of n segments, at most K each (structure of arrays).

    Attributes
    ----------
    count : (n,) int, penetrations on the segment (valid only where ``exceeded`` is False)
    exceeded : (n,) bool, the segment crosses more than K objects (the path is dropped)
    distance : (n, K) float, distance of the entry point from the segment start, metres (inf pad)
    point : (n, K, 3) float, entry points, metres (NaN pad)
    object : (n, K) int, crossed object (-1 pad)
    normal : (n, K, 3) float, unit normal of the slab's face (a sheet's; a solid's more head-on
        of its entry and exit faces)
    thickness : (n, K) float, equivalent slab thickness, metres
    """

    count: np.ndarray
    exceeded: np.ndarray
    distance: np.ndarray
    point: np.ndarray
    object: np.ndarray
    normal: np.ndarray
    thickness: np.ndarray


#: Contact tolerance, in scene margins. A hit closer than this to an edge of its triangle may as
#: well be on the neighbouring face across that edge (Embree's float32 answer for a ray through
#: an edge depends on its BVH): the face is then chosen canonically. A ray whose line never gets
#: deeper than this into a convex solid only touches it (:func:`raytrace.solver.kernels.walk._contact`).
CONTACT_TOL_MARGINS = 1.0

#: Below this cosine between a ray and a face, the float64 plane distance is not used in place of
#: Embree's (:func:`raytrace.solver.kernels.walk_hits`).
GRAZING_COS = 1e-6

#: Rounds of a segment walk beyond its budget of boundaries, for steps that are not boundaries
#: (float32 noise at either end, at most ``END_GUARD_MARGINS`` steps each, and touches).
FREE_STEPS = 32

#: Hits on the object a segment starts or ends on (a reflection or diffraction vertex) closer
#: than this many scene margins to that end are float32 noise of the vertex itself, not crossings.
END_GUARD_MARGINS = 10.0


class _Walk:
    """Per-segment state of the walk along segments: recorded penetrations and the solid the
    segment is inside of. Arrays over the n segments, K slots each; updated in place by the
    compiled loops :func:`raytrace.solver.kernels.walk_hits` and its siblings."""

    def __init__(self, scene: Scene, d: np.ndarray, k: int) -> None:
        n, kk = len(d), max(k, 1)
        self.scene, self.d, self.k = scene, carray(d), k
        self.closed = carray(scene.object_closed, bool)
        self.sheet_thickness = _sheet_thickness(scene)
        self.count = np.zeros(n, dtype=np.int64)
        self.exceeded = np.zeros(n, dtype=bool)
        self.dist = np.full((n, kk), np.inf)
        self.obj = np.full((n, kk), -1, dtype=np.int64)
        self.normal = np.zeros((n, kk, 3))
        self.thick = np.zeros((n, kk))
        self.inside = np.full(n, -1, dtype=np.int64)  # closed solid the segment is inside of
        self.t_in = np.zeros(n)
        self.normal_in = np.zeros((n, 3))  # unit normal of the entry face of ``inside``
        self.t_last = np.zeros(n)  # distance of the last boundary crossed (0: the start)
        self.normal_last = np.zeros((n, 3))  # unit normal of that boundary's face (0: the start)

    @property
    def _state(self) -> tuple:
        return (self.d, self.closed, self.k, self.count, self.exceeded, self.dist, self.obj,
                self.normal, self.thick, self.inside, self.t_in, self.normal_in, self.t_last,
                self.normal_last)  # fmt: skip

    def record(
        self, rows: np.ndarray, t_entry: np.ndarray, o: np.ndarray, fn: np.ndarray, th: np.ndarray
    ) -> None:
        """One penetration of object ``o`` entered at ``t_entry``, chord ``th`` (a sheet: its
        thickness), with the slab's face of unit normal ``fn`` (n, 3): a sheet's, or for a solid
        the more head-on of its entry and exit faces (:func:`raytrace.solver.kernels.walk._more_head_on`); a solid's
        equivalent slab is the chord times cos(incidence) on that face."""
        kernels.walk_record(carray(rows, np.int64), carray(t_entry), carray(o, np.int64),
                            carray(fn), carray(th), *self._state)  # fmt: skip

    def unseen(self, r: np.ndarray, o: np.ndarray, fn_exit: np.ndarray, t_exit: np.ndarray):
        """The segments ``r``, outside any solid, leave solid ``o`` at ``t_exit`` through a face
        of normal ``fn_exit`` without a seen entry: it was entered at the previous boundary
        (through a coincident face: that boundary's plane, turned against the ray, is the entry
        face) or the segment starts in it (no entry face: the exit face stands in)."""
        r = carray(r, np.int64)
        t_entry, fn = kernels.unseen_entries(r, carray(fn_exit), self.d, self.t_last,
                                             self.normal_last)  # fmt: skip
        self.record(r, t_entry, o, fn, t_exit - t_entry)

    def result(self, a: np.ndarray, tmax: np.ndarray) -> Crossings:
        """The crossings, after closing the chord of segments that end inside a solid."""
        m = (self.inside >= 0) & ~self.exceeded
        if m.any():
            r = np.flatnonzero(m)
            self.record(r, self.t_in[r], self.inside[r], self.normal_in[r], tmax[r] - self.t_in[r])
        dist, k = self.dist, self.k
        point = kernels.entry_points(a, self.d, dist)
        arrays = [dist, point, self.obj, self.normal, self.thick]
        if k == 0:
            arrays = [x[:, :0] for x in arrays]
        dist, point, obj, normal, thick = arrays
        return Crossings(self.count, self.exceeded | (self.count > k), dist, point, obj, normal,
                         thick)  # fmt: skip


def _convex_planes(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Facet planes of every convex closed object, padded: normals (O, K, 3), offsets (O, K)
    (plane ``n . x = offset``, m) and valid (O, K) bool (none for other objects). Cached
    (``scene.caches.convex_planes``)."""
    cache = scene.caches.convex_planes
    if cache is not None:
        return cache
    fc = scene.facets
    n_obj = len(scene.objects)
    use = scene.convex_objects()[fc.object]
    obj = fc.object[use]
    order = np.argsort(obj, kind="stable")
    obj = obj[order]
    per = np.bincount(obj, minlength=n_obj)
    slot = np.arange(len(obj)) - np.concatenate([[0], np.cumsum(per)[:-1]])[obj]
    k = max(int(per.max(initial=0)), 1)
    normal = np.zeros((n_obj, k, 3))
    offset = np.zeros((n_obj, k))
    valid = np.zeros((n_obj, k), dtype=bool)
    normal[obj, slot] = fc.normal[use][order]
    offset[obj, slot] = fc.offset[use][order]
    valid[obj, slot] = True
    scene.caches.convex_planes = (normal, offset, valid)
    return normal, offset, valid


def _line_span(
    scene: Scene, o: np.ndarray, a: np.ndarray, d: np.ndarray, inset: float
) -> tuple[np.ndarray, ...]:
    """Where lines ``a + t d`` are at least ``inset`` metres inside convex solids ``o`` (``inset <
    0``: within ``-inset`` outside, the solid grown): ``convex`` (n,) bool (the other rows are
    not answered), ``t_in``, ``t_out`` (n,) metres, and ``parallel_out`` (n,) bool, a line
    parallel to a plane and beyond it (no span). Objects are taken by their number of planes
    (the first ``count`` slots are theirs): most are boxes, and padding every row to the largest
    solid's planes would triple the work."""
    return kernels.line_span(*convex_plane_arrays(scene), carray(o, np.int64), carray(a),
                             carray(d), float(inset))  # fmt: skip


def convex_plane_arrays(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_convex_planes` as the kernels take them: normals (O, K, 3), offsets (O, K) and
    each object's number of planes (O,) (cached: ``scene.caches.convex_plane_arrays``)."""
    cache = scene.caches.convex_plane_arrays
    if cache is None:
        normal, offset, valid = _convex_planes(scene)
        cache = scene.caches.convex_plane_arrays = (normal, offset,
                                                    valid.sum(axis=1).astype(np.int64))  # fmt: skip
    return cache


def flat_sheet_arrays(
    scene: Scene,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The open sheets that lie in one plane (a pane, a fence, a partition), as the kernels take
    them (:func:`raytrace.solver.kernels.solids.sheet_touch1`); cached
    (``scene.caches.flat_sheet_arrays``).

    Returns
    -------
    plane : (O, 4) float, each flat sheet's unit normal and offset (``n . x = offset``, m)
    reach : (O,) float, its bounding-box diagonal, metres; 0 for every other object
    edge_start, edge_count : (O,) int, its outline's edges in ``edges``
    edges : (E, 6) float, the outline's edges (the faces' edges that no other face of the sheet
        shares, corners welded by position): both ends, metres
    """
    cache = scene.caches.flat_sheet_arrays
    if cache is not None:
        return cache
    base = scene.caches.extends
    if base is None:
        cache = _flat_sheets(scene, 0)
    else:
        # a snapshot (the static scene and more objects, the same extent): the static sheets'
        # rows are the static scene's (kept on it), the added objects' are appended
        n0 = len(base.objects)
        head, tail = flat_sheet_arrays(base), _flat_sheets(scene, n0)
        plane, reach, start, count = (x[n0:] for x in tail[:4])
        edges = tail[4]
        start = np.where(count > 0, start + len(head[4]), 0)
        cache = (np.concatenate([head[0], plane]), np.concatenate([head[1], reach]),
                 np.concatenate([head[2], start]), np.concatenate([head[3], count]),
                 np.ascontiguousarray(np.concatenate([head[4], edges])))  # fmt: skip
    scene.caches.flat_sheet_arrays = cache
    return cache


def _flat_sheets(scene: Scene, first: int) -> tuple[np.ndarray, ...]:
    """:func:`flat_sheet_arrays` of the objects from ``first`` on (the rows of the others are
    zero and their outlines left out)."""
    n_obj = len(scene.objects)
    plane = np.zeros((n_obj, 4))
    reach = np.zeros(n_obj)
    start = np.zeros(n_obj, dtype=np.int64)
    count = np.zeros(n_obj, dtype=np.int64)
    parts = [np.zeros((0, 6))]
    tol = 1e-9 * max(scene.extent, 1.0) if len(scene.vertices) else 1e-9
    total = 0
    for o in range(first, n_obj):
        obj = scene.objects[o]
        if obj.closed or obj.face_count == 0:
            continue
        sl = slice(obj.face_start, obj.face_start + obj.face_count)
        tri = scene.vertices[scene.faces[sl]]  # (m, 3, 3)
        fn = scene.face_normal[sl]
        n0 = fn[0]
        if np.any(np.abs(fn @ n0) < 1.0 - 1e-9):
            continue
        off = tri.reshape(-1, 3) @ n0
        if off.max() - off.min() > tol:
            continue
        # the outline: edges of one face only, the corners welded by their coordinates
        _, ids = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
        ids = ids.reshape(-1, 3)
        e = np.sort(np.stack([ids, np.roll(ids, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        _, inv, k = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        once = k[inv.reshape(-1)] == 1
        ends = np.stack([tri, np.roll(tri, -1, axis=1)], axis=2).reshape(-1, 6)[once]
        lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
        plane[o] = (*n0, off.mean())
        reach[o] = float(np.linalg.norm(hi - lo))
        start[o], count[o] = total, len(ends)
        total += len(ends)
        parts.append(ends)
    return plane, reach, start, count, np.ascontiguousarray(np.concatenate(parts))


def coincident_faces(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces of closed solids and of flat sheets that lie in one plane and overlap (a ceiling
    board resting on a wall's top face, a pane on a frame), as the kernels take them; cached
    (``scene.caches.coincident_faces``).

    A segment crosses both at one point, and the walk steps over a boundary by the margin, so it
    would book whichever of the two Embree reports and miss the other (or, leaving a solid
    through a face a sheet lies on, never leave it). :func:`raytrace.solver.kernels.walk_hits`
    books both. Face pairs are in one plane when their normals are parallel and every corner of
    one is within the contact tolerance of the other's plane, and overlap when their bounding
    boxes do (grown by the tolerance).

    Returns
    -------
    start, count : (F,) int, each face's coincident faces in ``face``
    face : (C,) int, the coincident faces (of another object: a sheet for a solid's face, a
        solid's face for a sheet's)
    """
    cache = scene.caches.coincident_faces
    if cache is not None:
        return cache
    n_f = len(scene.faces)
    plane, reach, _, _, _ = flat_sheet_arrays(scene)
    tol = CONTACT_TOL_MARGINS * scene.margin
    pairs = []
    sheets = np.flatnonzero(reach > 0)
    solid_faces = np.flatnonzero(scene.object_closed[scene.face_object])
    if len(sheets) and len(solid_faces):
        tri = scene.vertices[scene.faces]
        lo, hi = tri.min(axis=1) - tol, tri.max(axis=1) + tol
        for o in sheets:
            n, off = plane[o, :3], plane[o, 3]
            cand = solid_faces[np.abs(scene.face_normal[solid_faces] @ n) >= 1.0 - 1e-9]
            cand = cand[np.all(np.abs(tri[cand] @ n - off) <= tol, axis=1)]
            obj = scene.objects[o]
            mine = np.arange(obj.face_start, obj.face_start + obj.face_count)
            for g in mine:
                near = cand[np.all((lo[cand] <= hi[g]) & (hi[cand] >= lo[g]), axis=1)]
                pairs += [(f, g) for f in near] + [(g, f) for f in near]
    pairs = np.array(sorted(set(pairs)), dtype=np.int64).reshape(-1, 2)
    count = np.bincount(pairs[:, 0], minlength=n_f).astype(np.int64)
    start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    cache = (start, count, np.ascontiguousarray(pairs[:, 1]))
    scene.caches.coincident_faces = cache
    return cache


#: Cells of :func:`_closed_solid_grid` along the longer side of the scene's footprint.
GRID_CELLS = 64


def _closed_solid_grid(scene: Scene) -> tuple:
    """The closed solids by cell of a grid over the scene's footprint (x, y), as
    :func:`raytrace.solver.kernels.end_probes` takes it: origin ``x0, y0``, cell size, the
    number of cells ``nx, ny``, each cell's first item (nx ny + 1,) and the items (the solids
    whose bounding box meets the cell, grown by a margin), and every object's bounding box
    ``lo, hi`` (O, 3), metres. Cached (``scene.caches.closed_solid_grid``)."""
    cache = scene.caches.closed_solid_grid
    if cache is not None:
        return cache
    lo, hi = scene.object_boxes()
    pad = 10 * scene.margin
    b_lo, b_hi = scene.bounds
    cell = max(float((b_hi[:2] - b_lo[:2]).max()) / GRID_CELLS, 1e-3)
    nx, ny = (int(np.ceil((b_hi[i] - b_lo[i]) / cell)) + 1 for i in range(2))
    # every (cell, solid) of the solids' cell ranges, solids in index order within a cell (a
    # snapshot of the hall builds this grid anew: numpy, not a loop over cells)
    solids = np.flatnonzero(scene.object_closed & np.isfinite(lo[:, 0]))
    i0, j0 = np.floor((lo[solids, :2] - pad - b_lo[:2]) / cell).astype(int).T
    i1, j1 = np.floor((hi[solids, :2] + pad - b_lo[:2]) / cell).astype(int).T
    i0, j0 = np.maximum(i0, 0), np.maximum(j0, 0)
    ni = np.maximum(np.minimum(i1, nx - 1) + 1 - i0, 0)
    nj = np.maximum(np.minimum(j1, ny - 1) + 1 - j0, 0)
    per = ni * nj
    owner = np.repeat(np.arange(len(solids)), per)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(per) - per, per)
    ci = i0[owner] + k // np.maximum(nj[owner], 1)
    cj = j0[owner] + k % np.maximum(nj[owner], 1)
    cell_of = ci * ny + cj
    order = np.argsort(cell_of, kind="stable")
    items = solids[owner[order]].astype(np.int64)
    start = np.concatenate([[0], np.cumsum(np.bincount(cell_of, minlength=nx * ny))])
    start = start.astype(np.int64)
    cache = (float(b_lo[0]), float(b_lo[1]), cell, nx, ny, start, items, carray(lo), carray(hi))
    scene.caches.closed_solid_grid = cache
    return cache


def _sheet_thickness(scene: Scene) -> np.ndarray:
    """Each object's material thickness (O,), metres, the slab of an open sheet, as the kernels
    take it (cached: ``scene.caches.sheet_thickness``)."""
    cache = scene.caches.sheet_thickness
    if cache is None:
        cache = carray(scene.material_thickness()[scene.object_material])
        scene.caches.sheet_thickness = cache
    return cache


def _object_faces(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Each object's first face and number of faces, (O,) int each, as the kernels take them
    (cached: ``scene.caches.object_faces``)."""
    cache = scene.caches.object_faces
    if cache is None:
        count = np.array([ob.face_count for ob in scene.objects], dtype=np.int64)
        cache = (carray(scene.object_face_start, np.int64), count)
        scene.caches.object_faces = cache
    return cache


def _face_normals(scene: Scene) -> np.ndarray:
    """The scene's face normals (F, 3) as the kernels take them (cached:
    ``scene.caches.face_normals``)."""
    cache = scene.caches.face_normals
    if cache is None:
        cache = scene.caches.face_normals = carray(scene.face_normal)
    return cache


def touches(
    scene: Scene,
    o: np.ndarray,
    a: np.ndarray,
    d: np.ndarray,
    tol: float,
    t_max: np.ndarray | None = None,
) -> np.ndarray:
    """(n,) bool: the line ``a + t d`` never gets deeper than ``tol`` into object ``o``, a convex
    closed solid (False for other objects); with ``t_max`` (n,) metres, only its segment
    ``0 <= t <= t_max`` is asked about."""
    o = carray(o, np.int64)
    segment = t_max is not None
    t_max = carray(np.broadcast_to(np.inf if t_max is None else t_max, o.shape))
    return kernels.touch_rows(o, carray(a), carray(d), t_max, segment,
                              *convex_plane_arrays(scene), float(tol))  # fmt: skip


def _edge_planes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Every face's corners (F, 3, 3) and the outward in-plane unit normals of its three edges
    (F, 3, 3), edge ``i`` from corner ``i`` to corner ``i + 1``. Cached
    (``scene.caches.edge_planes``)."""
    cache = scene.caches.edge_planes
    if cache is not None:
        return cache
    tri = scene.vertices[scene.faces]
    nrm = scene.face_normal
    m = np.empty_like(tri)
    for i in range(3):
        v, w = tri[:, i, :], tri[:, (i + 1) % 3, :]
        e = np.cross(w - v, nrm)  # in-plane normal of the edge, outward (counter-clockwise)
        m[:, i] = e / np.maximum(np.linalg.norm(e, axis=-1, keepdims=True), 1e-300)
    scene.caches.edge_planes = (tri, m)
    return tri, m


def _edge_distance(scene: Scene, face: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Signed in-plane distance of points from their triangle's boundary, metres: the largest
    of the distances outside its three edge lines, so <= 0 inside the triangle (minus the
    distance to the nearest edge) and > 0 outside. Broadcasts ``face`` (...) against ``point``
    (..., 3)."""
    corners, normals = _edge_planes(scene)
    face, point = np.asarray(face), np.asarray(point)
    if face.ndim == 1 and point.shape == (len(face), 3):  # one point per face: most calls
        return kernels.edge_distance(corners, normals, carray(face, np.int64), carray(point))
    shape = np.broadcast_shapes(face.shape, point.shape[:-1])
    face = np.broadcast_to(face, shape).reshape(-1)
    point = np.broadcast_to(point, (*shape, 3)).reshape(-1, 3)
    return kernels.edge_distance(corners, normals, carray(face, np.int64),
                                 carray(point)).reshape(shape)  # fmt: skip


def segment_crossings(
    scene: Scene,
    a: np.ndarray,
    b: np.ndarray,
    max_crossings: int,
    end_objects: np.ndarray | None = None,
) -> Crossings:
    """Objects crossed by the segments ``a -> b``, in order, with batched Embree queries.

    The segments' ends are shortened by ``scene.margin`` so that a segment that starts or ends on
    a surface (a reflection or diffraction point) does not count that surface. Each round asks
    Embree for the next hit of every segment still walking (one batched query,
    :func:`raytrace.solver.kernels.walk_rays`), steps over it by the margin and updates the
    penetration bookkeeping (:class:`_Walk`) in one compiled pass over the hits
    (:func:`raytrace.solver.kernels.walk_hits`).

    Parameters
    ----------
    scene : Scene
    a, b : (n, 3) float, segment ends, metres
    max_crossings : int, K, the most penetrations kept per segment
    end_objects : (n, 2) int, optional, the object each segment starts and ends on (-1 for none);
        hits on it within ``END_GUARD_MARGINS`` margins of that end are ignored (a segment
        that leaves or reaches a vertex on an edge may graze its object within float32 noise)

    Returns
    -------
    Crossings
    """
    a = np.asarray(a, dtype=float).reshape(-1, 3)
    b = np.asarray(b, dtype=float).reshape(-1, 3)
    n = len(a)
    k = max(int(max_crossings), 0)
    margin = scene.margin
    v = b - a
    length = norm(v)
    d = np.divide(v, length[:, None], out=np.zeros_like(v), where=length[:, None] > 0)
    tmax = length - margin
    walk = _Walk(scene, d, k)
    guard = END_GUARD_MARGINS * margin
    if end_objects is None:
        end_objects = np.full((n, 2), -1, dtype=np.int64)
    t = np.full(n, margin)
    active = (tmax > t) & (length > 0)
    # each penetration of a solid takes two boundaries; one more detects an excess. Steps over
    # float32 noise at a vertex and over touches are not boundaries: they must not use up a
    # segment's budget, or a segment leaving a diffraction point along its wedge's face would
    # exceed it where the same segment reversed does not (reciprocity)
    limit = 2 * k + 2
    crossed = np.zeros(n, dtype=np.int64)
    # after a touch, the walk goes on along a parallel line shifted off the touched solid until
    # past it: on the segment's own line Embree reports the grazed face again at every step, or
    # not at all, depending on the direction (a ray in the plane of a pillar's face)
    shift = np.zeros((n, 3))
    shift_end = np.full(n, -np.inf)
    a, length, tmax = carray(a), carray(length), carray(tmax)
    end_objects = carray(end_objects, np.int64)
    scene_arrays = (*_edge_planes(scene), *convex_plane_arrays(scene), *_object_faces(scene),
                    _face_normals(scene), *flat_sheet_arrays(scene), *coincident_faces(scene),
                    carray(scene.face_object, np.int64), walk.sheet_thickness)  # fmt: skip
    for _ in range(limit + FREE_STEPS):
        # one round: the next hit of every segment still walking (kernels.walk_hits says what
        # is done with it)
        rows, org, dirs, reach = kernels.walk_rays(active, a, walk.d, t, tmax, shift, shift_end)
        if not len(rows):
            break
        th, face, o = scene.intersect(org, dirs, reach)
        kernels.walk_hits(rows, th, face, o, a, length, tmax, t, active, crossed, shift,
                          shift_end, end_objects, margin, guard,
                          CONTACT_TOL_MARGINS * margin, GRAZING_COS, limit, *scene_arrays,
                          *walk._state)  # fmt: skip
    else:
        # still hitting after the last round (a ray along a face, touching it again and again)
        walk.exceeded |= active
    _left_at_the_end(scene, walk, a, tmax)
    return walk.result(a, tmax)


#: Direction of the probe ray that finds the solid a segment ends in (:func:`_left_at_the_end`):
#: horizontal and off the axes, so it leaves a pallet or a box through a side face rather than
#: through the planes it shares with the floor or the load (unit vector).
PROBE_DIRECTION = np.array([0.6, 0.8, 0.0])


def _left_at_the_end(scene: Scene, walk: _Walk, a: np.ndarray, tmax: np.ndarray) -> None:
    """Close the chord of a solid entered through a face coincident with the last boundary
    (stepped over with it) and not left before the segment's end: a segment from boxes into the
    pallet under them, ending on the floor under the pallet. Whether the pallet was counted
    depended on which coincident face Embree reported first. For every segment that left a
    solid last and ends outside any, a probe ray from the middle of its last stretch (in
    ``PROBE_DIRECTION``) finds the solid that point is in: its first hit leaves a closed solid
    (for a convex one, the point is also more than a contact tolerance inside its planes). Only
    a point that may be in a closed solid is probed (:func:`kernels.end_probes`, from the
    solids by grid cell): the others cannot pass that test."""
    tol = CONTACT_TOL_MARGINS * scene.margin
    rows, q = kernels.end_probes(walk.exceeded, walk.inside, walk.t_last, walk.normal_last,
                                 walk.d, carray(tmax), carray(a), *_closed_solid_grid(scene),
                                 *convex_plane_arrays(scene), tol)  # fmt: skip
    if not len(rows):
        return
    probe = np.broadcast_to(PROBE_DIRECTION, q.shape)
    _, face, o = scene.intersect(q, probe, np.inf)
    ok = o >= 0
    ok[ok] = walk.closed[o[ok]]
    fn = scene.face_normal[np.maximum(face, 0)]
    ok &= np.einsum("ij,ij->i", fn, probe) > 0
    if ok.any():
        normal, offset, valid = _convex_planes(scene)
        k = np.flatnonzero(ok)
        depth = np.einsum("mkj,mj->mk", normal[o[k]], q[k]) - offset[o[k]]
        convex = valid[o[k]].any(axis=1)
        ok[k] = ~convex | np.all(~valid[o[k]] | (depth < -tol), axis=1)
    if ok.any():
        r = rows[ok]
        walk.unseen(r, o[ok], fn[ok], tmax[r])
