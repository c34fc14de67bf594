"""What a :class:`~raytrace.scene.model.Scene` derives from its arrays and keeps: one
:class:`SceneCaches` per scene, and the functions that build the scene layer's caches.

A scene's geometry and objects do not change once it is built, and the tracer asks for the
same derived arrays thousands of times per trace (the margin, the per-object flags), or pays
milliseconds to build them (Embree's scenes, the convex solids' planes): each is built on first
use and kept in a named field of ``scene.caches``. The caches are never pickled: a pickled scene
(a worker's copy) carries its arrays only and rebuilds its intersector when unpickled, so that
the bytes of a scene, and the digest its kept worker pool is found by
(:mod:`raytrace.solver.parallel`), do not change once it has been traced. A scene made by
``dataclasses.replace`` (a snapshot with moved objects) starts with empty caches.

The scene layer builds its own fields (:func:`embree_meshes`, :func:`embree_scene`,
:func:`subset_scene`, :func:`bounds_of`, :func:`margin_of`, :func:`convex_flags`; the getters
are the scene's properties and methods). The solver's fields are built by the solver, which
knows what its kernels take (:mod:`raytrace.solver.penetration`, :mod:`raytrace.solver.shadow`):
the storage is here, the builders there, and the scene layer never imports the solver.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import accel
from .elements import Facets, SceneObject

__all__ = ["SceneCaches", "embree_meshes", "embree_scene", "subset_scene", "bounds_of",
           "margin_of", "embree_origin_of", "convex_flags", "object_boxes", "EMBREE_LOCAL_M"]

#: A scene whose coordinates all lie within this distance of the origin (m) is given to Embree
#: as it is; one farther out (survey or CAD-origin coordinates: 1e5 to 1e7 m) is given relative
#: to its own centre (:func:`embree_origin_of`). Embree works in float32, whose spacing at 1e5 m
#: is 8 mm (at 1e3 m, 0.06 mm: below the tracer's end margin of 0.1 mm).
EMBREE_LOCAL_M = 1000.0


@dataclass(eq=False, slots=True)
class SceneCaches:
    """The derived arrays of one scene, each built on first use (``None`` or empty until then).
    Only these fields can be set (slots): a new cache is a new, documented field.

    Scene layer (:mod:`raytrace.scene.model`, :mod:`raytrace.scene.queries`)
    -------------------------------------------------------------------------
    embree : embreex EmbreeScene, every object's triangles, geometry id = object index
        (:meth:`~raytrace.scene.model.Scene.build_embree`, when the scene is built or unpickled)
    prim_start : (O,) int, each object's first Embree primitive; prim_face : (T,) int, the
        scene face of each Embree triangle (built with ``embree``)
    embree_meshes : list of O ``(points (P, 3) float32, triangles (T, 3) int32, face (T,) int)``,
        each object's triangles as Embree is given them (:func:`embree_meshes`), relative to
        ``embree_origin``
    embree_origin : (3,) float, metres, the origin of Embree's frame (:func:`embree_origin_of`:
        zero but for a scene far from the origin)
    subset_embree : dict, ``objects.tobytes()`` -> ``(EmbreeScene, members)``, the scenes of
        :meth:`~raytrace.scene.model.Scene.first_hit_among` (:func:`subset_scene`)
    bounds : (2, 3) float, read-only, metres (:func:`bounds_of`)
    margin : float, metres (:func:`margin_of`)
    object_closed : (O,) bool; object_material : (O,) int; object_face_start : (O,) int:
        read-only per-object arrays
    convex : (O,) bool, the convex closed solids (:func:`convex_flags`)
    object_boxes : ``(lo (O, 3), hi (O, 3))`` float, each object's bounding box, metres
        (:func:`object_boxes`; empty objects have ``lo = inf``, ``hi = -inf``)
    extends : Scene or None, the scene this one extends by more objects, of the same extent
        (:func:`raytrace.scene.dynamic.extend_scene`: a forklift snapshot): its objects are this
        scene's first ones, so what is derived per object can be taken from it

    Solver (:mod:`raytrace.solver.penetration`, :mod:`raytrace.solver.shadow`)
    ---------------------------------------------------------------------------
    convex_planes : ``(normal (O, K, 3), offset (O, K), valid (O, K))``, the convex solids'
        facet planes, padded
    convex_plane_arrays : ``(normal, offset, count (O,))``, the same as the kernels take them
    flat_sheet_arrays : ``(plane (O, 4), reach (O,), edge_start, edge_count (O,), edges
        (E, 6))``, the open sheets that lie in one plane and their outlines
    coincident_faces : ``(start, count (F,), face (C,))``, faces of solids and flat sheets in one
        plane that overlap
    closed_solid_grid : the closed solids by cell of a grid over the footprint, and every
        object's bounding box
    sheet_thickness : (O,) float, metres, each object's material thickness
    object_faces : ``(face_start (O,), face_count (O,))``
    face_normals : (F, 3) float, C-ordered
    edge_planes : ``(corners (F, 3, 3), edge_normals (F, 3, 3))``
    shadow_groups : the scene's facet corners and edge ends, grouped per facet and edge
    kept_shadows : dict, (end positions, opaque flags) -> the transmitters' shadows, bounded
        (:data:`raytrace.solver.shadow.SHADOWS_KEPT`)
    """

    embree: Any = None
    prim_start: np.ndarray | None = None
    prim_face: np.ndarray | None = None
    embree_meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    embree_origin: np.ndarray | None = None
    subset_embree: dict[bytes, tuple[Any, np.ndarray]] = field(default_factory=dict)
    bounds: np.ndarray | None = None
    margin: float | None = None
    object_closed: np.ndarray | None = None
    object_material: np.ndarray | None = None
    object_face_start: np.ndarray | None = None
    convex: np.ndarray | None = None
    object_boxes: tuple[np.ndarray, np.ndarray] | None = None
    extends: Any = None
    convex_planes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    convex_plane_arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    flat_sheet_arrays: tuple[np.ndarray, ...] | None = None
    coincident_faces: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    closed_solid_grid: tuple[Any, ...] | None = None
    sheet_thickness: np.ndarray | None = None
    object_faces: tuple[np.ndarray, np.ndarray] | None = None
    face_normals: np.ndarray | None = None
    edge_planes: tuple[np.ndarray, np.ndarray] | None = None
    shadow_groups: tuple[np.ndarray, ...] | None = None
    kept_shadows: dict[Any, Any] = field(default_factory=dict)


def embree_meshes(
    vertices: np.ndarray, faces: np.ndarray, objects: list[SceneObject], extent: float
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each object's triangles as Embree is given them (:func:`raytrace.scene.accel.embree_mesh`:
    the objects as large as the scene, of bounding-box diagonal ``extent`` (m), cut smaller):
    float32 points (P, 3), int32 triangles (T, 3) and the object's face (T,) each triangle is
    part of."""
    out = []
    for obj in objects:
        f = faces[obj.face_start : obj.face_start + obj.face_count]
        n = accel.embree_split(vertices, f, extent)
        out.append(accel.embree_mesh(vertices, f, n))
    return out


def embree_scene(
    meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]], objects: list[SceneObject]
) -> tuple[Any, np.ndarray, np.ndarray]:
    """An Embree scene of every object's triangles (:func:`embree_meshes`), geometry id = object
    index (the order of adding), so that a hit names its object; and ``prim_start`` (O,),
    ``prim_face`` (T,): Embree's triangle primID of object g is face
    ``prim_face[prim_start[g] + primID]``."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    es = rtcs.EmbreeScene()
    for points, triangles, _ in meshes:
        TriangleMesh(es, points, triangles)
    counts = np.array([len(t) for _, t, _ in meshes], dtype=np.int64)
    prim_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    prim_face = np.concatenate(
        [np.zeros(0, dtype=np.int64)]
        + [o.face_start + face for o, (_, _, face) in zip(objects, meshes, strict=True)]
    )
    return es, prim_start, prim_face


def subset_scene(
    meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray]], objects: np.ndarray
) -> tuple[Any, np.ndarray]:
    """An Embree scene of some objects (``objects`` (O,) bool), the objects' triangles as in the
    full scene (:func:`embree_meshes`), and the members (M,) int: geometry id = position in
    ``members``."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    es = rtcs.EmbreeScene()
    members = np.flatnonzero(objects)
    for i in members:
        points, triangles, _ = meshes[i]
        TriangleMesh(es, points[triangles])
    return es, members


def object_boxes(
    vertices: np.ndarray, faces: np.ndarray, objects: list[SceneObject]
) -> tuple[np.ndarray, np.ndarray]:
    """Each object's axis-aligned bounding box: ``lo``, ``hi`` (O, 3) float, metres, read-only
    (``inf`` / ``-inf`` for an object without faces). Faces are grouped by object."""
    n = len(objects)
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    start = np.array([ob.face_start for ob in objects], dtype=np.int64)
    count = np.array([ob.face_count for ob in objects], dtype=np.int64)
    has = count > 0
    if has.any():
        tri = vertices[faces]
        lo[has] = np.minimum.reduceat(tri.min(axis=1), start[has], axis=0)
        hi[has] = np.maximum.reduceat(tri.max(axis=1), start[has], axis=0)
    for x in (lo, hi):
        x.setflags(write=False)
    return lo, hi


def bounds_of(vertices: np.ndarray) -> np.ndarray:
    """(2, 3) float, the axis-aligned bounding box of ``vertices`` (V, 3), metres, read-only."""
    out = np.stack([vertices.min(axis=0), vertices.max(axis=0)])
    out.setflags(write=False)
    return out


def embree_origin_of(bounds: np.ndarray) -> np.ndarray:
    """(3,) float, metres: the origin of the frame the scene is given to Embree in. Zero for a
    scene within :data:`EMBREE_LOCAL_M` of the origin (every hall built or exported in its own
    coordinates: their queries are unchanged); else the centre of its bounding box ``bounds``
    (2, 3), rounded to the metre (a coordinate minus it is then exact in float64), so that
    float32 resolves the scene as finely as if it were at the origin."""
    b = np.asarray(bounds, dtype=float)
    if not np.isfinite(b).all() or np.abs(b).max() <= EMBREE_LOCAL_M:
        return np.zeros(3)
    return np.round(0.5 * (b[0] + b[1]))


def margin_of(extent: float) -> float:
    """Offset (m) for rays that leave or end on a surface of a scene of bounding-box diagonal
    ``extent`` (m): Embree works in float32."""
    return max(1e-4, 2e-6 * extent)


def convex_flags(
    vertices: np.ndarray,
    faces: np.ndarray,
    objects: list[SceneObject],
    facets: Facets,
    closed: np.ndarray,
    extent: float,
) -> np.ndarray:
    """(O,) bool: the closed solids (``closed`` (O,) bool) that are convex, every vertex on or
    behind every facet plane of the object (within a tolerance ``tol``: the rounding of the
    scene's ``extent``, m, or twice the largest distance of a facet's own corners from its plane,
    whichever is larger).

    The definition costs (vertices x facets) per object: 10^8 operations for one scanned
    machine of 20 000 triangles. A solid that is far from convex is recognised first by its
    volume: if every vertex were within ``tol`` behind every facet plane, its convex hull would
    lie within the facets' half-spaces moved out by ``tol``, whose intersection is inside the
    solid grown by ``tol``; so the hull's volume would exceed the solid's by at most about
    ``tol`` times the hull's area. A solid whose hull exceeds it by more than
    :data:`HULL_EXCESS_FACTOR` times that is not convex; the others (boxes, prisms: a hall's
    solids) get the definition's test.
    """
    from scipy.spatial import ConvexHull, QhullError

    rounding = 1e-9 * max(extent, 1.0) + 1e-9
    convex = closed.copy()
    for o in np.flatnonzero(convex):
        obj = objects[o]
        f = faces[obj.face_start : obj.face_start + obj.face_count]
        ids = np.unique(f)
        v = vertices[ids]
        k = facets.object == o
        # a facet's own corners may lie off its plane by more than rounding (a box welded from
        # a mesh with 1e-6 m gaps): behind within twice that still counts as behind
        tol = max(rounding, 2.0 * float(accel.facet_off_plane(facets)[k].max(initial=0.0)))
        if len(ids) > 64:  # a box or prism: the definition's test is cheaper than a hull
            tri = vertices[f]
            volume = abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6
            try:
                hull = ConvexHull(v)
            except (QhullError, ValueError):
                hull = None
            if hull is not None and hull.volume - volume > HULL_EXCESS_FACTOR * tol * hull.area:
                convex[o] = False
                continue
        convex[o] = _all_behind(v, facets.normal[k], facets.offset[k], tol)
    return convex


#: See :func:`convex_flags`: the hull may exceed a convex solid's volume by about ``tol`` times
#: its area (and by rounding); 100 times that is far above both.
HULL_EXCESS_FACTOR = 100.0


def _all_behind(v: np.ndarray, normal: np.ndarray, offset: np.ndarray, tol: float) -> bool:
    """Whether every point ``v`` (n, 3) is on or behind every plane (``normal`` (k, 3),
    ``offset`` (k,)), within ``tol``; in blocks of bounded size, stopping at the first point in
    front."""
    rows = max(1, 4_000_000 // max(len(normal), 1))
    for i in range(0, len(v), rows):
        if not np.all(v[i : i + rows] @ normal.T - offset <= tol):
            return False
    return True
