"""Scenes: triangles with per-face objects and materials, planar facets, wedges, Embree queries.

A :class:`Scene` is what the mechanisms (reflection, penetration, diffraction) work on:

* all triangles of all objects, grouped by object, with outward normals for closed solids;
* planar *facets* (connected coplanar triangles of one object) for the image method;
* *wedges* (convex edges of closed solids, free edges of open sheets) for diffraction, without
  the junctions where an edge lies on another object's surface (concave or flat there);
* an Embree scene (through embreex) with one geometry per object, so that a hit names its object.

Objects are either closed solids (watertight, oriented outward here whatever the file says) or
open sheets (everything else: two-sided, with the material's slab thickness).

The class is the scene's arrays and what it says about them; its parts live in their own
modules: the arrays are built from meshes by :mod:`raytrace.scene.construction`, the Embree
scenes and queries are :class:`raytrace.scene.queries.EmbreeQueries` (a base of
:class:`Scene`), and everything derived and kept is one :class:`~raytrace.scene.caches.
SceneCaches` (``scene.caches``), never pickled.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from ..physics.materials import MaterialLibrary
from .caches import SceneCaches, bounds_of, margin_of
from .construction import (
    DEFAULT_SMOOTH_ANGLE_DEG,
    buried_wedges,
    coplanar_overlaps,
    resolve_junctions,
    scene_parts,
)
from .elements import Facets, SceneObject, Wedges
from .queries import EmbreeQueries
from .repair import REPAIRS


@dataclass
class Scene(EmbreeQueries):
    """Triangle scene with materials, facets, wedges and an Embree intersector.

    Build it with :func:`load_scene` or :meth:`Scene.from_meshes`.

    Attributes
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int, vertex indices, grouped by object
    face_object : (F,) int, object index of each face
    face_normal : (F, 3) float, unit normals (outward for closed solids)
    objects : list of SceneObject
    materials : MaterialLibrary, with every bound material
    material_names : list of str, the materials used, indexed by ``face_material``
    facets : Facets
    wedges : Wedges
    metadata : dict, the ``hallray`` metadata of the file (base stations, points, ...)
    source : str, where the scene came from
    caches : SceneCaches, everything derived from the arrays and kept (not an argument, not
        pickled, empty in a copy made by ``dataclasses.replace``)
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_object: np.ndarray
    face_normal: np.ndarray
    objects: list[SceneObject]
    materials: MaterialLibrary
    material_names: list[str]
    facets: Facets
    wedges: Wedges
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    n_degenerate_dropped: int = 0
    n_buried_wedges: int = 0
    n_junction_wedges: int = 0
    n_composite_wedges: int = 0
    smooth_angle_deg: float = 1.0
    #: Built with every mesh an open surface (:func:`~raytrace.scene.construction.scene_parts`'s
    #: ``surfaces``: Sionna RT's model, the default for a Mitsuba XML that hallray did not write).
    surfaces: bool = False
    #: The file's axis that was up: "y" when the file was turned into the z-up frame
    #: (:func:`~raytrace.scene.io.load_scene`'s ``up``).
    up: str = "z"
    #: The unit of the file's numbers, scaled to metres as it was read (``load_scene``'s ``unit``).
    unit: str = "m"
    caches: SceneCaches = field(default_factory=SceneCaches, init=False, repr=False,
                                compare=False)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_meshes(
        cls,
        meshes: list[tuple[str, Any, str]],
        materials: MaterialLibrary,
        metadata: dict[str, Any] | None = None,
        source: str = "",
        smooth_angle_deg: float | None = None,
        surfaces: bool = False,
    ) -> Scene:
        """Build a scene from ``(name, trimesh.Trimesh, material_name)`` triples.

        Closed (watertight) meshes are oriented outward; everything else is an open sheet (every
        mesh with ``surfaces``: :func:`~raytrace.scene.construction.scene_parts`). Degenerate triangles are dropped and counted. Edges bending by less than
        ``smooth_angle_deg`` (default 1 degree) are smooth, not wedges. The edges that are not free are dropped
        or resolved (:func:`raytrace.scene.construction.buried_wedges`,
        :func:`~raytrace.scene.construction.resolve_junctions`).
        """
        parts = scene_parts(meshes, source, smooth_angle_deg, surfaces)
        n_dropped = parts["n_degenerate_dropped"]
        repairs = parts.pop("repairs")
        done = [f"{repairs[k]} {text}" for k, text in REPAIRS.items() if repairs[k]]
        if done:
            warnings.warn(f"{source or 'scene'} repaired: {', '.join(done)}", stacklevel=2)
        if n_dropped:
            warnings.warn(
                f"{n_dropped} degenerate triangle(s) dropped from {source or 'scene'}",
                stacklevel=2,
            )
        scene = cls(**parts, materials=materials, metadata=dict(metadata or {}), source=source)
        scene.build_embree()
        buried = buried_wedges(scene.wedges, scene.inside_solid)
        if buried.any():
            keep = ~buried
            scene.wedges = Wedges(**{k: v[keep] for k, v in scene.wedges.arrays().items()})
            scene.n_buried_wedges = int(buried.sum())
        resolved = resolve_junctions(scene.wedges, scene.facets, scene.margin, scene.inside_solid)
        if resolved is not None:
            scene.wedges, scene.n_junction_wedges, scene.n_composite_wedges = resolved
        # surfaces (Sionna RT's model): a building's bottom lying on its ground is how such
        # scenes are made (simple_street_canyon's six), not a mistake to name
        overlaps = (coplanar_overlaps(scene.facets, scene.margin) if not surfaces
                    else np.zeros((0, 2), dtype=np.int64))  # fmt: skip
        if len(overlaps):
            names = sorted({tuple(sorted(scene.objects[o].name for o in scene.facets.object[p]))
                            for p in overlaps})  # fmt: skip
            shown = ", ".join(f"{x} and {y}" for x, y in names[:3])
            more = f" (+{len(names) - 3} more)" if len(names) > 3 else ""
            warnings.warn(
                f"{source or 'scene'}: {len(overlaps)} facet pair(s) of different objects lie on "
                f"one another facing the same way (z-fighting: {shown}{more}); both reflect "
                "there: remove one or move it apart",
                stacklevel=2,
            )
        return scene

    def __getstate__(self) -> dict[str, Any]:
        # the Embree scenes are native objects: a pickled scene (for worker processes) carries the
        # arrays only and rebuilds its intersector when unpickled. The caches stay behind
        # (SceneCaches): the bytes of a scene, and the digest its kept worker pool is found by,
        # must not change once it has been traced
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "caches"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        for name, value in state.items():
            setattr(self, name, value)
        self.caches = SceneCaches()
        self.build_embree()

    # -- properties ---------------------------------------------------------------------------
    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float, axis-aligned bounding box, metres (read-only; cached: every trace asks
        several times, and a scan over the vertices took 0.07 ms each)."""
        if self.caches.bounds is None:
            self.caches.bounds = bounds_of(self.vertices)
        return self.caches.bounds

    @property
    def extent(self) -> float:
        """Length of the bounding-box diagonal, metres."""
        b = self.bounds
        return float(np.linalg.norm(b[1] - b[0]))

    @property
    def margin(self) -> float:
        """Offset (m) for rays that leave or end on a surface: Embree works in float32
        (:func:`raytrace.scene.caches.margin_of`). (Cached, like the per-object arrays below: the
        tracer reads them thousands of times per trace, and a scene's geometry and objects do
        not change once it is built.)"""
        if self.caches.margin is None:
            self.caches.margin = margin_of(self.extent)
        return self.caches.margin

    @property
    def object_closed(self) -> np.ndarray:
        """(O,) bool, True for closed solids (read-only)."""
        c = self.caches
        if c.object_closed is None or len(c.object_closed) != len(self.objects):
            c.object_closed = _read_only(np.array([o.closed for o in self.objects], dtype=bool))
        return c.object_closed

    @property
    def object_material(self) -> np.ndarray:
        """(O,) int, material index of each object (read-only)."""
        c = self.caches
        if c.object_material is None or len(c.object_material) != len(self.objects):
            c.object_material = _read_only(np.array(
                [self.material_names.index(o.material) for o in self.objects], dtype=np.int64))  # fmt: skip
        return c.object_material

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    @property
    def object_face_start(self) -> np.ndarray:
        """(O,) int, index of each object's first face in ``faces`` (read-only)."""
        c = self.caches
        if c.object_face_start is None or len(c.object_face_start) != len(self.objects):
            c.object_face_start = _read_only(
                np.array([o.face_start for o in self.objects], dtype=np.int64))  # fmt: skip
        return c.object_face_start


    def material_thickness(self) -> np.ndarray:
        """(n_materials,) float, slab thickness (m) of each used material, for open sheets."""
        return np.array([self.materials[m].thickness_m for m in self.material_names], dtype=float)

    def floor_outline(
        self, min_fraction: float = 0.25, wall_fraction: float = 0.8
    ) -> np.ndarray | None:
        """Outline of the floor area inside the walls: ``(K, 2)`` float, metres, counter-clockwise,
        first vertex not repeated; None if the scene has no floor.

        The floor is the lowest level of upward-facing horizontal facets (either face of an open
        sheet, the top face of a solid slab) covering at least ``min_fraction`` of the scene's
        horizontal bounding box. From it the footprints of walls are removed: closed solids that
        stand on it and rise at least ``wall_fraction`` of the way to the top of the scene (walls
        and pillars). The exterior of the largest remaining piece is the outline, so an L-shaped
        hall gives an L and the pillars inside it leave no holes.
        """
        from shapely import union_all
        from shapely.geometry import Polygon

        fc = self.facets
        if len(fc) == 0:
            return None
        nz = fc.normal[:, 2]
        up = np.where(fc.two_sided, np.abs(nz), nz) > 1.0 - 1e-6
        if not up.any():
            return None
        level = fc.offset / np.where(np.abs(nz) > 0, nz, 1.0)  # z of the plane n.x = offset
        lo, hi = self.bounds
        box = float(np.prod(hi[:2] - lo[:2]))
        tol = 10 * self.margin

        def shadow(tris: np.ndarray) -> Any:
            polys = [Polygon(t[:, :2]) for t in tris]
            return union_all([q for q in polys if q.area > 1e-12]).buffer(0)

        for z in np.unique(np.round(level[up], 6)):
            on = np.flatnonzero(up & (np.abs(level - z) <= tol))
            if fc.area[on].sum() < min_fraction * box:
                continue
            area = shadow(np.concatenate([
                fc.triangles[fc.tri_start[k] : fc.tri_start[k] + fc.tri_count[k]] for k in on
            ]))  # fmt: skip
            walls = []
            for i, obj in enumerate(self.objects):
                if not obj.closed:
                    continue
                v = self.vertices[self.faces[self.face_object == i]]
                zmin, zmax = v[..., 2].min(), v[..., 2].max()
                if zmin <= z + tol and zmax - z >= wall_fraction * (hi[2] - z):
                    walls.append(shadow(v))
            if walls:
                area = area.difference(union_all(walls))
            parts = [g for g in getattr(area, "geoms", [area]) if g.area > 0]
            if not parts:
                return None
            best = max(parts, key=lambda g: g.area).simplify(tol)
            ring = np.asarray(best.exterior.coords)[:-1]
            if not best.exterior.is_ccw:
                ring = ring[::-1]
            return np.ascontiguousarray(ring, dtype=float)
        return None

    def content_hash(self) -> str:
        """SHA-256 of the geometry and material binding (independent of the file format)."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices).tobytes())
        h.update(np.ascontiguousarray(self.faces).tobytes())
        h.update(json.dumps([(o.name, o.material, o.closed) for o in self.objects]).encode())
        if self.smooth_angle_deg != DEFAULT_SMOOTH_ANGLE_DEG:
            # another smooth angle is another set of wedges; the default's hash stays what
            # datasets made before the option recorded
            h.update(f"smooth {self.smooth_angle_deg!r}".encode())
        return h.hexdigest()

    def summary(self) -> dict[str, Any]:
        """Extent, objects, materials, triangles, facets and wedges, as plain data."""
        b = self.bounds
        mats: dict[str, int] = {}
        for o in self.objects:
            mats[o.material] = mats.get(o.material, 0) + 1
        return {
            "source": self.source,
            "bounds_min_m": b[0].round(6).tolist(),
            "bounds_max_m": b[1].round(6).tolist(),
            "size_m": (b[1] - b[0]).round(6).tolist(),
            "objects": len(self.objects),
            "closed_solids": int(self.object_closed.sum()),
            "open_sheets": int((~self.object_closed).sum()),
            "materials": dict(sorted(mats.items())),
            "triangles": int(len(self.faces)),
            "facets": len(self.facets),
            "wedges": len(self.wedges),
            "degenerate_triangles_dropped": self.n_degenerate_dropped,
            "buried_wedges_dropped": self.n_buried_wedges,
            "junction_wedges_dropped": self.n_junction_wedges,
            "composite_wedges": self.n_composite_wedges,
            "smooth_angle_deg": self.smooth_angle_deg,
            "surfaces": self.surfaces,
            "up": self.up,
            "unit": self.unit,
        }



def _read_only(a: np.ndarray) -> np.ndarray:
    """``a``, made read-only (a cached array that callers share)."""
    a.setflags(write=False)
    return a
