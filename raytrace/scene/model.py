"""Scenes: triangles with per-face objects and materials, planar facets, wedges, Embree queries.

A :class:`Scene` is what the mechanisms (reflection, penetration, diffraction) work on:

* all triangles of all objects, grouped by object, with outward normals for closed solids;
* planar *facets* (connected coplanar triangles of one object) for the image method;
* *wedges* (convex edges of closed solids, free edges of open sheets) for diffraction, without
  the junctions where an edge lies on another object's surface (concave or flat there);
* an Embree scene (through embreex) with one geometry per object, so that a hit names its object.

Objects are either closed solids (watertight, oriented outward here whatever the file says) or
open sheets (everything else: two-sided, with the material's slab thickness).
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from ..core.errors import SceneError
from ..core.jit import carray
from ..physics.materials import MaterialLibrary
from . import accel
from .elements import Facets, SceneObject, Wedges

#: Triangles with an area below this (m^2) are degenerate and dropped.
DEGENERATE_AREA_M2 = 1e-10
#: Two adjacent faces whose normals differ by less than this (rad) are coplanar (no wedge).
WEDGE_MIN_ANGLE_RAD = np.deg2rad(1.0)
#: Distance (m) from an edge along its outward bisector at which a wedge is probed for being
#: buried in another solid (then it is not a free, diffracting edge).
BURIED_PROBE_M = 5e-3
#: Angle (rad) by which the air around a junction edge must exceed pi to stay a (convex) wedge.
JUNCTION_MIN_EXCESS_RAD = WEDGE_MIN_ANGLE_RAD


@dataclass
class Scene:
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
    _embree: Any = field(default=None, repr=False)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_meshes(
        cls,
        meshes: list[tuple[str, Any, str]],
        materials: MaterialLibrary,
        metadata: dict[str, Any] | None = None,
        source: str = "",
    ) -> Scene:
        """Build a scene from ``(name, trimesh.Trimesh, material_name)`` triples.

        Closed (watertight) meshes are oriented outward; everything else is an open sheet.
        Degenerate triangles are dropped and counted.
        """
        import trimesh

        verts, faces, face_obj, normals = [], [], [], []
        objects: list[SceneObject] = []
        material_names: list[str] = []
        n_dropped = 0
        facet_parts: list[dict[str, np.ndarray]] = []
        wedge_parts: list[dict[str, np.ndarray]] = []
        v_offset = 0
        f_offset = 0
        for name, mesh, mat in meshes:
            v = np.asarray(mesh.vertices, dtype=np.float64)
            f = np.asarray(mesh.faces, dtype=np.int64)
            if v.size and not np.all(np.isfinite(v)):
                raise SceneError(f"object {name!r} has NaN or infinite vertex coordinates")
            if f.size == 0:
                continue
            tri = v[f]
            area = 0.5 * np.linalg.norm(
                np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1
            )
            keep = area > DEGENERATE_AREA_M2
            n_dropped += int((~keep).sum())
            if not keep.any():
                continue
            m = trimesh.Trimesh(vertices=v, faces=f[keep], process=True, validate=False)
            m.remove_unreferenced_vertices()
            closed = bool(m.is_watertight) and bool(m.is_winding_consistent)
            if closed:
                trimesh.repair.fix_normals(m)
                if m.volume < 0:
                    m.invert()
            if mat not in material_names:
                material_names.append(mat)
            mat_id = material_names.index(mat)
            obj_id = len(objects)
            objects.append(SceneObject(name, mat, closed, f_offset, len(m.faces)))
            verts.append(np.asarray(m.vertices, dtype=np.float64))
            faces.append(np.asarray(m.faces, dtype=np.int64) + v_offset)
            face_obj.append(np.full(len(m.faces), obj_id, dtype=np.int64))
            normals.append(np.asarray(m.face_normals, dtype=np.float64))
            facet_parts.append(_facets_of(m, obj_id, mat_id, closed))
            wedge_parts.append(_wedges_of(m, obj_id, mat_id, closed))
            v_offset += len(m.vertices)
            f_offset += len(m.faces)
        if not objects:
            raise SceneError(f"scene {source or '<memory>'} has no triangles")
        if n_dropped:
            warnings.warn(
                f"{n_dropped} degenerate triangle(s) dropped from {source or 'scene'}",
                stacklevel=2,
            )
        facets = Facets(**{k: _cat([p[k] for p in facet_parts]) for k in facet_parts[0]})
        # tri_start is per object part; make it global
        starts, offset = [], 0
        for p in facet_parts:
            starts.append(p["tri_start"] + offset)
            offset += len(p["triangles"])
        facets = Facets(**{**facets.arrays(), "tri_start": _cat(starts)})
        wedges = Wedges(**{k: _cat([p[k] for p in wedge_parts]) for k in wedge_parts[0]})
        scene = cls(
            vertices=np.concatenate(verts),
            faces=np.concatenate(faces),
            face_object=np.concatenate(face_obj),
            face_normal=np.concatenate(normals),
            objects=objects,
            materials=materials,
            material_names=material_names,
            facets=facets,
            wedges=wedges,
            metadata=dict(metadata or {}),
            source=source,
            n_degenerate_dropped=n_dropped,
        )
        scene._build_embree()
        scene._drop_buried_wedges()
        scene._resolve_junctions()
        return scene

    def _drop_buried_wedges(self) -> None:
        """Remove edges that are not free: a convex edge whose outward bisector enters another
        solid right away (a box's bottom edges on a floor slab, racks side by side). The wedge
        there is really the concave junction of two objects, and nothing can reach its edge
        from outside. Half-plane edges of sheets are kept."""
        w = self.wedges
        if len(w) == 0:
            return
        bis = w.normal0 + w.normal1
        nb = np.linalg.norm(bis, axis=1)
        probe_ok = nb > 1e-6
        if not probe_ok.any():
            return
        mid = 0.5 * (w.start + w.end)
        probe = mid[probe_ok] + (BURIED_PROBE_M * bis[probe_ok] / nb[probe_ok, None])
        inside = self.inside_solid(probe)
        buried = np.zeros(len(w), dtype=bool)
        buried[np.flatnonzero(probe_ok)] = (inside >= 0) & (inside != w.object[probe_ok])
        if buried.any():
            keep = ~buried
            self.wedges = Wedges(**{k: v[keep] for k, v in w.arrays().items()})
            self.n_buried_wedges = int(buried.sum())

    def _resolve_junctions(self) -> None:
        """Edges that lie on another object's surface are junctions, not free edges.

        A wall sheet standing on a floor sheet, a slab whose side is flush with the wall below it,
        a box on a floor sheet: their meshes have free-looking edges there. For every wedge, the
        facets of other objects whose plane contains the edge (within :attr:`margin`) cover parts
        of it (triangle by triangle); on each covered piece the cross-section around the edge is
        rebuilt: the wedge's own air sector is cut by the covering facets' half-lines (a facet
        passing through the edge gives two, one ending on it gives one) into sub-sectors, each
        probed at :data:`BURIED_PROBE_M` for lying inside another solid. Then

        * no air sub-sector wider than pi (+ :data:`JUNCTION_MIN_EXCESS_RAD`): the edge is concave
          or flat on every air side (a room corner, a box on a floor) and is dropped: the UTD
          coefficient of a right-angle concave perfectly conducting corner is exactly zero (the
          field is the image series, which the traced reflections carry), and a flat junction has
          no edge;
        * an air sub-sector wider than pi but narrower than the wedge's own: a composite convex
          edge (the outside of two sheets meeting in an L): the piece is kept with that sector's
          faces (and the material of the wedge's own object), once per edge line;
        * otherwise the piece is a free edge, unchanged.

        Uncovered parts of a partly covered edge are kept as they are.
        """
        w, fc = self.wedges, self.facets
        if len(w) == 0 or len(fc) == 0:
            return
        w_idx, t_lo, t_hi, cover = _junction_pieces(w, fc, self.margin)
        if len(w_idx) == 0:
            return
        m = len(w_idx)
        keep = np.ones(m, dtype=bool)
        n0 = w.normal0[w_idx].copy()
        n1 = w.normal1[w_idx].copy()
        f0 = w.face0_dir[w_idx].copy()
        n_new = w.n[w_idx].copy()
        start = w.start[w_idx] + t_lo[:, None] * w.direction[w_idx]
        end = w.start[w_idx] + t_hi[:, None] * w.direction[w_idx]
        seen: set[tuple] = set()
        n_composite = 0
        for j in range(m):
            if len(cover[j]) == 0:
                continue
            sector = self._air_sector(w_idx[j], 0.5 * (start[j] + end[j]), cover[j])
            if sector is None:
                keep[j] = False
            elif sector is not True:
                key = _line_key(start[j], end[j])
                if key in seen:  # the same composite edge seen from the other object
                    keep[j] = False
                    continue
                seen.add(key)
                n_composite += 1
                f0[j], n0[j], n1[j], n_new[j] = sector
        touched = np.zeros(len(w), dtype=bool)
        touched[w_idx] = True
        free = np.flatnonzero(~touched)
        k = np.flatnonzero(keep)
        src = np.concatenate([free, w_idx[k]])
        along = np.concatenate([np.zeros(len(free)), t_lo[k]])
        order = np.lexsort((along, src))
        parts = {
            "start": np.concatenate([w.start[free], start[k]]),
            "end": np.concatenate([w.end[free], end[k]]),
            "direction": w.direction[src],
            "length": np.concatenate([w.length[free], (t_hi - t_lo)[k]]),
            "normal0": np.concatenate([w.normal0[free], n0[k]]),
            "normal1": np.concatenate([w.normal1[free], n1[k]]),
            "face0_dir": np.concatenate([w.face0_dir[free], f0[k]]),
            "n": np.concatenate([w.n[free], n_new[k]]),
            "object": w.object[src],
            "material": w.material[src],
        }
        self.wedges = Wedges(**{key: v[order] for key, v in parts.items()})
        self.n_junction_wedges = int(len(np.unique(w_idx[~keep])))
        self.n_composite_wedges = n_composite

    def _air_sector(self, i: int, mid: np.ndarray, facets: np.ndarray):
        """Air around wedge ``i`` at point ``mid`` once the covering ``facets`` are in place.

        Returns True (the wedge's own sector is untouched: a free edge), None (no air
        sub-sector wider than pi: a junction, not a wedge) or ``(face0_dir, normal0, normal1,
        n)`` of the one convex air sub-sector (a composite wedge).
        """
        w, fc = self.wedges, self.facets
        t0 = w.face0_dir[i]
        nrm0 = w.normal0[i] - (w.normal0[i] @ w.direction[i]) * w.direction[i]
        nrm0 /= np.linalg.norm(nrm0)
        e = np.cross(t0, nrm0)  # angles grow from t0 towards n0, right-handed about e
        own = w.n[i] * np.pi
        eps = JUNCTION_MIN_EXCESS_RAD
        # half-lines of the covering facets, perpendicular to the edge
        u = np.cross(fc.normal[facets], e)
        u /= np.linalg.norm(u, axis=1)[:, None]
        rays = np.concatenate([u, -u])
        owner = np.concatenate([facets, facets])
        probe = mid + BURIED_PROBE_M * rays
        on_plane = (
            probe - np.einsum("ij,ij->i", probe - mid, fc.normal[owner])[:, None] * fc.normal[owner]
        )
        present = accel.points_in_facets(on_plane, owner, fc)
        ang = np.mod(np.arctan2(rays @ nrm0, rays @ t0), 2 * np.pi)
        cuts = np.sort(ang[present & (ang > eps) & (ang < own - eps)])
        if len(cuts) == 0:
            # nothing crosses the air sector; it may still be filled by a solid that only
            # touches the edge along one of the wedge's own faces (probed below)
            cuts = np.zeros(0)
        bounds = np.concatenate([[0.0], cuts, [own]])
        lo, hi = bounds[:-1], bounds[1:]
        wide = hi - lo > 1e-9
        lo, hi = lo[wide], hi[wide]
        mid_ang = 0.5 * (lo + hi)
        dirs = np.cos(mid_ang)[:, None] * t0 + np.sin(mid_ang)[:, None] * nrm0
        inside = self.inside_solid(mid + BURIED_PROBE_M * dirs)
        air = (inside < 0) | (inside == w.object[i])
        if len(lo) == 1 and air[0]:
            return True
        width = np.where(air, hi - lo, 0.0)
        j = int(np.argmax(width))
        if width[j] <= np.pi + eps:
            return None

        def d(a: float) -> np.ndarray:
            return np.cos(a) * t0 + np.sin(a) * nrm0

        # faces of the sub-sector [lo, hi]: outward normals point into it (wedge_geometry: the
        # outward normal of face 0 is at +pi/2 from it, that of face n at -pi/2)
        return d(lo[j]), d(lo[j] + 0.5 * np.pi), d(hi[j] - 0.5 * np.pi), width[j] / np.pi

    def __getstate__(self) -> dict[str, Any]:
        # the Embree scenes are native objects: a pickled scene (for worker processes) carries the
        # arrays only and rebuilds its intersector when unpickled. Derived caches (convexity,
        # planes, the scalars below) stay behind too: the bytes of a scene, and the digest its
        # kept worker pool is found by, must not change once it has been traced
        state = {f.name: self.__dict__[f.name] for f in fields(self)}
        state["_embree"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self.__dict__.get("_embree") is None:
            self._build_embree()

    def _build_embree(self) -> None:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self._embree = rtcs.EmbreeScene()
        # geometry id == object index (the order of adding), so a hit names its object; Embree's
        # triangle primID of object g is face prim_face[prim_start[g] + primID]
        meshes = self._embree_meshes()
        for points, triangles, _ in meshes:
            TriangleMesh(self._embree, points, triangles)
        counts = np.array([len(t) for _, t, _ in meshes], dtype=np.int64)
        self.__dict__["_prim_start"] = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(
            np.int64
        )
        self.__dict__["_prim_face"] = np.concatenate(
            [np.zeros(0, dtype=np.int64)]
            + [o.face_start + face for o, (_, _, face) in zip(self.objects, meshes, strict=True)]
        )

    def _embree_meshes(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Each object's triangles as Embree is given them (:func:`accel.embree_mesh`: the
        objects as large as the scene cut smaller): float32 points (P, 3), int32 triangles
        (T, 3) and the object's face (T,) each triangle is part of. Cached."""
        cached = self.__dict__.get("_embree_mesh_list")
        if cached is None or len(cached) != len(self.objects):
            extent = self.extent if len(self.vertices) else 0.0
            cached = []
            for obj in self.objects:
                f = self.faces[obj.face_start : obj.face_start + obj.face_count]
                n = accel.embree_split(self.vertices, f, extent)
                cached.append(accel.embree_mesh(self.vertices, f, n))
            self.__dict__["_embree_mesh_list"] = cached
        return cached

    # -- properties ---------------------------------------------------------------------------
    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float, axis-aligned bounding box, metres (read-only; cached: every trace asks
        several times, and a scan over the vertices took 0.07 ms each)."""
        cached = self.__dict__.get("_bounds")
        if cached is None:
            cached = np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])
            cached.setflags(write=False)
            self.__dict__["_bounds"] = cached
        return cached

    @property
    def extent(self) -> float:
        """Length of the bounding-box diagonal, metres."""
        b = self.bounds
        return float(np.linalg.norm(b[1] - b[0]))

    @property
    def margin(self) -> float:
        """Offset (m) for rays that leave or end on a surface: Embree works in float32.
        (Cached, like the per-object arrays below: the tracer reads them thousands of times per
        trace, and a scene's geometry and objects do not change once it is built.)"""
        m = self.__dict__.get("_margin")
        if m is None:
            m = self.__dict__["_margin"] = max(1e-4, 2e-6 * self.extent)
        return m

    def _per_object(self, key: str, make: Any) -> np.ndarray:
        """A cached, read-only (O,) array derived from ``objects``."""
        cached = self.__dict__.get(key)
        if cached is None or len(cached) != len(self.objects):
            cached = np.asarray(make())
            cached.setflags(write=False)
            self.__dict__[key] = cached
        return cached

    @property
    def object_closed(self) -> np.ndarray:
        """(O,) bool, True for closed solids (read-only)."""
        return self._per_object(
            "_object_closed", lambda: np.array([o.closed for o in self.objects], dtype=bool)
        )

    @property
    def object_material(self) -> np.ndarray:
        """(O,) int, material index of each object (read-only)."""
        return self._per_object(
            "_object_material",
            lambda: np.array(
                [self.material_names.index(o.material) for o in self.objects], dtype=np.int64
            ),
        )

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    @property
    def object_face_start(self) -> np.ndarray:
        """(O,) int, index of each object's first face in ``faces`` (read-only)."""
        return self._per_object(
            "_object_face_start",
            lambda: np.array([o.face_start for o in self.objects], dtype=np.int64),
        )

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
        return h.hexdigest()

    # -- Embree queries -----------------------------------------------------------------------
    def occluded(
        self, origins: np.ndarray, ends: np.ndarray, margin: float | None = None
    ) -> np.ndarray:
        """Whether anything lies on the segments ``origins -> ends``.

        Parameters
        ----------
        origins, ends : (n, 3) float, metres
        margin : float, metres, shaved off both ends (defaults to :attr:`margin`), so that a
            segment that starts or ends on a surface does not hit it.

        Returns
        -------
        (n,) bool
        """
        o, d, length = _rays(origins, ends, self.margin if margin is None else margin)
        hit = np.zeros(len(o), dtype=bool)
        ok = length > 0
        if ok.any():
            res = self._embree.run(
                o[ok].astype(np.float32),
                d[ok].astype(np.float32),
                dists=length[ok].astype(np.float32),
                query="OCCLUDED",
            )
            hit[ok] = np.asarray(res) != -1
        return hit

    def segment_objects(
        self,
        origins: np.ndarray,
        ends: np.ndarray,
        max_objects: int | None = None,
        margin: float | None = None,
    ) -> np.ndarray:
        """The objects on the segments ``origins -> ends``, in the order the segments meet them.

        Each segment is walked with :meth:`intersect` (one Embree query per step for all
        segments still going): after a hit it goes on ``margin`` beyond it. A surface less than
        ``margin`` behind another along the segment (two faces in contact) is therefore not met
        separately; a solid behind such a contact still counts where the segment leaves it. The
        first step is the ray of :meth:`occluded` with the same margin, so a segment is occluded
        exactly when its row names an object.

        Parameters
        ----------
        origins, ends : (n, 3) float, metres
        max_objects : int, stop a segment once it has met this many objects (None: all)
        margin : float, metres, shaved off both ends (defaults to :attr:`margin`)

        Returns
        -------
        (n, K) int, object indices ordered by the distance of their first hit from the origin,
        each object once, padded with -1; K is the most objects on one segment (0 if none)
        """
        m = self.margin if margin is None else margin
        o, d, length = _rays(origins, ends, m)
        n, n_obj = len(o), len(self.objects)
        walked = np.zeros(n)
        distinct = np.zeros(n, dtype=np.int64)
        known = np.zeros(0, dtype=np.int64)  # ray * n_obj + object, of the objects met so far
        keys: list[np.ndarray] = []  # in walk order
        active = np.flatnonzero(length > 0)
        while active.size:  # every step moves a segment on by >= m or ends it: terminates
            rest = length[active] - walked[active]
            start = o[active] + walked[active, None] * d[active]
            t, _, obj = self.intersect(start, d[active], rest)
            hit = obj >= 0
            ray = active[hit]
            key = ray * n_obj + obj[hit]
            new = ~np.isin(key, known)
            distinct[ray[new]] += 1
            known = np.union1d(known, key[new])
            keys.append(key)
            walked[ray] += t[hit] + m
            go = walked[ray] < length[ray]
            if max_objects is not None:
                go &= distinct[ray] < max_objects
            active = ray[go]
        if not keys:
            return np.full((n, 0), -1, dtype=np.int64)
        walk = np.concatenate(keys)
        first = np.sort(np.unique(walk, return_index=True)[1])  # first meeting of each object
        ray, obj = np.divmod(walk[first], max(n_obj, 1))
        order = np.argsort(ray, kind="stable")  # by segment, walk order kept within one
        ray, obj = ray[order], obj[order]
        col = np.arange(len(ray)) - np.searchsorted(ray, ray)  # rank within the segment
        width = int(col.max()) + 1 if len(col) else 0
        if max_objects is not None:
            width = min(width, max_objects)
        out = np.full((n, width), -1, dtype=np.int64)
        keep = col < width
        out[ray[keep], col[keep]] = obj[keep]
        return out

    def first_hit_among(
        self,
        objects: np.ndarray,
        origins: np.ndarray,
        directions: np.ndarray,
        length: np.ndarray,
    ) -> np.ndarray:
        """The first of some objects that rays hit within a distance (one Embree query).

        The subset gets its own Embree scene, built on first use and cached per subset.

        Parameters
        ----------
        objects : (O,) bool, the objects that count
        origins : (n, 3) float, metres
        directions : (n, 3) float, unit vectors
        length : (n,) float, metres; rays with ``length <= 0`` hit nothing

        Returns
        -------
        (n,) int, object index of the first hit among ``objects``, -1 for none
        """
        objects = np.asarray(objects, dtype=bool)
        if objects.shape != (len(self.objects),):
            raise SceneError(
                f"one flag per object is needed ({len(self.objects)}), got shape {objects.shape}"
            )
        out = np.full(len(origins), -1, dtype=np.int64)
        ok = np.asarray(length) > 0
        if not objects.any() or not ok.any():
            return out
        cache = self.__dict__.setdefault("_subset_embree", {})
        key = objects.tobytes()
        if key not in cache:
            from embreex import rtcore_scene as rtcs
            from embreex.mesh_construction import TriangleMesh

            es = rtcs.EmbreeScene()
            members = np.flatnonzero(objects)
            meshes = self._embree_meshes()
            # geometry id == position in ``members``; the objects' triangles as in the full scene
            for i in members:
                points, triangles, _ = meshes[i]
                TriangleMesh(es, points[triangles])
            cache[key] = (es, members)
        es, members = cache[key]
        if not ok.all():  # (most calls ask about every ray)
            origins, directions, length = origins[ok], directions[ok], np.asarray(length)[ok]
        res = es.run(
            np.asarray(origins, dtype=np.float32),
            np.asarray(directions, dtype=np.float32),
            dists=np.asarray(length, dtype=np.float32),
            query="INTERSECT",
            output=1,
        )
        hit = accel.subset_hits(res["geomID"], members)
        if ok.all():
            return hit
        out[ok] = hit
        return out

    def intersect(
        self, origins: np.ndarray, directions: np.ndarray, max_dist: np.ndarray | float = np.inf
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of rays.

        Parameters
        ----------
        origins : (n, 3) float, metres
        directions : (n, 3) float, unit vectors
        max_dist : (n,) float or float, metres

        Returns
        -------
        t : (n,) float, distance to the hit, metres (inf where nothing is hit)
        face : (n,) int, global face index (-1 where nothing is hit)
        obj : (n,) int, object index (-1 where nothing is hit)
        """
        n = len(origins)
        dist = np.asarray(max_dist)
        if dist.dtype != np.float32 or dist.shape != (n,):  # (the walk's reach is float32)
            dist = np.broadcast_to(np.asarray(max_dist, dtype=float), (n,))
        dist = np.where(np.isfinite(dist), dist, 1e30).astype(np.float32, copy=False)
        res = self._embree.run(
            np.asarray(origins, dtype=np.float32),
            np.asarray(directions, dtype=np.float32),
            dists=dist,
            query="INTERSECT",
            output=1,
        )
        return accel.hit_records(res["geomID"], res["primID"], res["tfar"],
                                 self.__dict__["_prim_start"], self.__dict__["_prim_face"])  # fmt: skip

    def convex_objects(self) -> np.ndarray:
        """(O,) bool: closed solids that are convex (every vertex on or behind every facet plane
        of the object). Cached."""
        cache = self.__dict__.get("_convex")
        if cache is not None:
            return cache
        fc = self.facets
        tol = 1e-9 * max(self.extent, 1.0) + 1e-9
        convex = self.object_closed.copy()
        for o in np.flatnonzero(convex):
            obj = self.objects[o]
            v = self.vertices[
                np.unique(self.faces[obj.face_start : obj.face_start + obj.face_count])
            ]
            k = fc.object == o
            convex[o] = bool(np.all(v @ fc.normal[k].T - fc.offset[k] <= tol))
        self.__dict__["_convex"] = convex
        return convex

    def inside_solid(self, points: np.ndarray) -> np.ndarray:
        """Index of the closed solid that contains each point, or -1.

        Convex solids (boxes, prisms: all of a typical hall) are tested exactly: a point is inside
        when it lies strictly behind every facet plane of the object. Other closed solids count
        the crossings of rays from the point (parity, with Embree) along three directions and
        take the majority: one ray can miscount where it grazes an edge or passes from one solid
        into another through a face they share.

        Parameters
        ----------
        points : (n, 3) float, metres

        Returns
        -------
        (n,) int
        """
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        n = len(pts)
        out = np.full(n, -1, dtype=np.int64)
        convex = self.convex_objects()
        fc = self.facets
        tol = 1e-9 * max(self.extent, 1.0)
        if convex.any():
            sel = np.flatnonzero(convex[fc.object])  # facets of convex objects, grouped by object
            owner = fc.object[sel]
            starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
            out = accel.convex_owner(carray(pts), carray(fc.normal[sel]), carray(fc.offset[sel]),
                                     carray(starts, np.int64), carray(owner[starts], np.int64),
                                     float(tol))  # fmt: skip
        others = self.object_closed & ~convex
        if others.any():
            todo = np.flatnonzero(out < 0)
            if todo.size:
                found = self._inside_by_parity(pts[todo], others)
                out[todo] = found
        return out

    def _inside_by_parity(self, pts: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        n = len(pts)
        # component ratios golden (badly approximable by fractions), so that rays from points on
        # a decimetre grid do not pass exactly through edges of boxes on that grid
        g = 0.5 * (1.0 + np.sqrt(5.0))
        dirs = np.array([[1.0, g, g * g], [-g * g, 1.0, g], [g, -g * g, 1.0]])
        votes = np.zeros((n, len(self.objects)), dtype=np.int64)
        step = self.margin
        for d in dirs / np.linalg.norm(dirs, axis=1, keepdims=True):
            counts = np.zeros((n, len(self.objects)), dtype=np.int64)
            origin = pts.copy()
            active = np.ones(n, dtype=bool)
            for _ in range(4 * len(self.objects) + 8):
                if not active.any():
                    break
                idx = np.flatnonzero(active)
                t, _, obj = self.intersect(origin[idx], np.broadcast_to(d, (len(idx), 3)))
                hit = obj >= 0
                counts[idx[hit], obj[hit]] += 1
                origin[idx[hit]] += (t[hit] + step)[:, None] * d
                active[idx[~hit]] = False
            votes += counts % 2
        odd = (votes >= 2) & candidates[None, :]
        return np.where(odd.any(axis=1), np.argmax(odd, axis=1), -1)

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
        }


# -- facets and wedges -----------------------------------------------------------------------
def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def _facets_of(mesh: Any, obj_id: int, mat_id: int, closed: bool) -> dict[str, np.ndarray]:
    """Group a mesh's faces into facets: trimesh's coplanar groups, plus lone faces."""
    n_faces = len(mesh.faces)
    groups = [np.asarray(g, dtype=np.int64) for g in mesh.facets]
    in_group = np.zeros(n_faces, dtype=bool)
    for g in groups:
        in_group[g] = True
    groups += [np.array([i]) for i in np.flatnonzero(~in_group)]
    groups.sort(key=lambda g: int(g.min()))
    order = np.concatenate(groups)
    counts = np.array([len(g) for g in groups], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    fn = np.asarray(mesh.face_normals, dtype=float)
    areas = np.asarray(mesh.area_faces, dtype=float)
    # area-weighted normal of each facet (its faces are coplanar within trimesh's tolerance)
    nsum = np.add.reduceat(fn[order] * areas[order, None], starts, axis=0)
    normal = nsum / np.linalg.norm(nsum, axis=1, keepdims=True)
    tris = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces)[order]]
    centroid = np.add.reduceat(tris.mean(axis=1) * areas[order, None], starts, axis=0)
    farea = np.add.reduceat(areas[order], starts)
    centroid /= farea[:, None]
    k = len(groups)
    return {
        "normal": normal,
        "offset": np.einsum("ij,ij->i", normal, centroid),
        "object": np.full(k, obj_id, dtype=np.int64),
        "material": np.full(k, mat_id, dtype=np.int64),
        "two_sided": np.full(k, not closed, dtype=bool),
        "area": farea,
        "tri_start": starts.astype(np.int64),
        "tri_count": counts,
        "triangles": tris,
    }


def _wedges_of(mesh: Any, obj_id: int, mat_id: int, closed: bool) -> dict[str, np.ndarray]:
    """Convex edges of a closed solid, or free (boundary) edges of an open sheet.

    Collinear pieces of one edge between the same two planes are merged into one wedge.
    """
    verts = np.asarray(mesh.vertices, dtype=float)
    fn = np.asarray(mesh.face_normals, dtype=float)
    centroids = np.asarray(mesh.triangles_center, dtype=float)
    segs: list[np.ndarray] = []
    n0s: list[np.ndarray] = []
    n1s: list[np.ndarray] = []
    c0s: list[np.ndarray] = []
    if len(mesh.face_adjacency):
        adj = np.asarray(mesh.face_adjacency)
        edges = np.asarray(mesh.face_adjacency_edges)
        angles = np.asarray(mesh.face_adjacency_angles)
        convex = np.asarray(mesh.face_adjacency_convex)
        # closed solids diffract at convex edges; a folded sheet wherever it bends
        sel = angles > WEDGE_MIN_ANGLE_RAD
        if closed:
            sel &= convex
        if sel.any():
            segs.append(verts[edges[sel]])
            n0s.append(fn[adj[sel, 0]])
            n1s.append(fn[adj[sel, 1]])
            c0s.append(centroids[adj[sel, 0]])
    if not closed:
        # free edges: used by one face only; the wedge is a half-plane (n = 2)
        edges_sorted = np.sort(np.asarray(mesh.edges), axis=1)
        _, inverse, counts = np.unique(
            edges_sorted, axis=0, return_inverse=True, return_counts=True
        )
        inverse = inverse.reshape(-1)
        boundary = counts[inverse] == 1
        if boundary.any():
            e = np.asarray(mesh.edges)[boundary]
            face_of_edge = np.asarray(mesh.edges_face)[boundary]
            segs.append(verts[e])
            n0s.append(fn[face_of_edge])
            n1s.append(-fn[face_of_edge])
            c0s.append(centroids[face_of_edge])
    empty = {
        "start": np.zeros((0, 3)),
        "end": np.zeros((0, 3)),
        "direction": np.zeros((0, 3)),
        "length": np.zeros(0),
        "normal0": np.zeros((0, 3)),
        "normal1": np.zeros((0, 3)),
        "face0_dir": np.zeros((0, 3)),
        "n": np.zeros(0),
        "object": np.zeros(0, dtype=np.int64),
        "material": np.zeros(0, dtype=np.int64),
    }
    if not segs:
        return empty
    seg = np.concatenate(segs)
    n0 = np.concatenate(n0s)
    n1 = np.concatenate(n1s)
    c0 = np.concatenate(c0s)
    seg, n0, n1, c0 = _merge_collinear(seg, n0, n1, c0)
    d = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(d, axis=1)
    ok = length > 1e-9
    seg, n0, n1, c0, d, length = seg[ok], n0[ok], n1[ok], c0[ok], d[ok], length[ok]
    u = d / length[:, None]
    into0 = c0 - seg[:, 0]
    into0 -= np.einsum("ij,ij->i", into0, u)[:, None] * u
    into0 /= np.linalg.norm(into0, axis=1, keepdims=True)
    cos_between = np.clip(np.einsum("ij,ij->i", n0, n1), -1.0, 1.0)
    # exterior angle = pi + angle between outward normals (half-plane: normals opposite -> 2 pi)
    n = (np.pi + np.arccos(cos_between)) / np.pi
    w = len(seg)
    return {
        "start": seg[:, 0],
        "end": seg[:, 1],
        "direction": d / length[:, None],
        "length": length,
        "normal0": n0,
        "normal1": n1,
        "face0_dir": into0,
        "n": n,
        "object": np.full(w, obj_id, dtype=np.int64),
        "material": np.full(w, mat_id, dtype=np.int64),
    }


def _merge_collinear(
    seg: np.ndarray, n0: np.ndarray, n1: np.ndarray, c0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merge edge pieces that lie on one line between the same pair of face planes."""
    if len(seg) < 2:
        return seg, n0, n1, c0
    d = seg[:, 1] - seg[:, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # canonical direction sign
    flip = (d[:, 0] < -1e-12) | ((np.abs(d[:, 0]) <= 1e-12) & (d[:, 1] < -1e-12))
    flip |= (np.abs(d[:, 0]) <= 1e-12) & (np.abs(d[:, 1]) <= 1e-12) & (d[:, 2] < 0)
    d[flip] *= -1
    # line key: direction, the point of the line closest to the origin, and the normal pair
    p = seg[:, 0] - np.einsum("ij,ij->i", seg[:, 0], d)[:, None] * d
    # the normal pair in a canonical order (adjacent pieces may list the two faces either way)
    ra, rb = np.round(n0 / 1e-6).astype(np.int64), np.round(n1 / 1e-6).astype(np.int64)
    a_first = _lex_less_equal(ra, rb)
    key_pair = np.where(a_first[:, None], np.concatenate([ra, rb], 1), np.concatenate([rb, ra], 1))
    key = np.concatenate(
        [np.round(np.concatenate([d, p], axis=1) / 1e-6).astype(np.int64), key_pair], 1
    )
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.reshape(-1)
    out_seg, out_n0, out_n1, out_c0 = [], [], [], []
    t0 = np.einsum("ij,ij->i", seg[:, 0], d)
    t1 = np.einsum("ij,ij->i", seg[:, 1], d)
    lo, hi = np.minimum(t0, t1), np.maximum(t0, t1)
    order = np.lexsort((lo, group))
    g_sorted = group[order]
    # walk groups; within a group join touching intervals (a small Python loop over edges of
    # the scene at load time, not on the tracing path)
    i = 0
    n_total = len(order)
    while i < n_total:
        j = i
        while j < n_total and g_sorted[j] == g_sorted[i]:
            j += 1
        idx = order[i:j]
        cur_lo, cur_hi = lo[idx[0]], hi[idx[0]]
        first = idx[0]
        for k in idx[1:]:
            if lo[k] <= cur_hi + 1e-6:
                cur_hi = max(cur_hi, hi[k])
            else:
                out_seg.append([p[first] + cur_lo * d[first], p[first] + cur_hi * d[first]])
                out_n0.append(n0[first])
                out_n1.append(n1[first])
                out_c0.append(c0[first])
                cur_lo, cur_hi, first = lo[k], hi[k], k
        out_seg.append([p[first] + cur_lo * d[first], p[first] + cur_hi * d[first]])
        out_n0.append(n0[first])
        out_n1.append(n1[first])
        out_c0.append(c0[first])
        i = j
    return (
        np.asarray(out_seg, dtype=float),
        np.asarray(out_n0),
        np.asarray(out_n1),
        np.asarray(out_c0),
    )


def _lex_less_equal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise lexicographic ``a <= b`` for integer arrays of shape (n, k)."""
    diff = a != b
    first = np.argmax(diff, axis=1)
    rows = np.arange(len(a))
    return ~diff.any(axis=1) | (a[rows, first] < b[rows, first])


def _junction_pieces(
    w: Wedges, fc: Facets, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Split wedges where facets of other objects cover them.

    A facet covers a part of an edge when the edge lies in the facet's plane (both end points
    within ``tol``) and, along that part, inside one of its triangles (within ``tol``).

    Returns
    -------
    w_idx : (M,) int; wedge of each piece (only wedges with a covered part; each such wedge is
        cut into consecutive pieces over its whole length)
    t_lo, t_hi : (M,) float, metres from the wedge's start
    cover : list of M int arrays; the facets covering each piece (empty: not covered)
    """
    da = w.start @ fc.normal.T - fc.offset
    db = w.end @ fc.normal.T - fc.offset
    near = (np.abs(da) <= tol) & (np.abs(db) <= tol) & (w.object[:, None] != fc.object[None, :])
    wi, fk = np.nonzero(near)
    empty = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), [])
    if len(wi) == 0:
        return empty
    # (pair, triangle) rows: clip the edge segment to each triangle in the facet's plane
    cnt = fc.tri_count[fk]
    rep = np.repeat(np.arange(len(wi)), cnt)
    within = np.arange(len(rep)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    tri = fc.triangles[fc.tri_start[fk][rep] + within]  # (R, 3, 3)
    a = w.start[wi][rep]
    d = w.direction[wi][rep]
    length = w.length[wi][rep]
    nrm = fc.normal[fk][rep]
    lo = np.zeros(len(rep))
    hi = length.copy()
    for i in range(3):
        v, v_next, v_other = tri[:, i], tri[:, (i + 1) % 3], tri[:, (i + 2) % 3]
        m = np.cross(nrm, v_next - v)
        m /= np.maximum(np.linalg.norm(m, axis=1), 1e-300)[:, None]
        m *= np.where(np.einsum("ij,ij->i", m, v_other - v) < 0, -1.0, 1.0)[:, None]
        # inside the triangle's side: m . (a + t d - v) >= 0, with a slack of tol across a side
        # that runs along the edge (the edge on the facet's border) and none along the edge (a
        # slack across a side crossed at a grazing angle would stretch along the edge)
        c0 = np.einsum("ij,ij->i", m, a - v)
        c1 = np.einsum("ij,ij->i", m, d)
        along = np.abs(c1) <= 1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -c0 / c1
        lo = np.where(~along & (c1 > 0), np.maximum(lo, bound), lo)
        hi = np.where(~along & (c1 < 0), np.minimum(hi, bound), hi)
        hi = np.where(along & (c0 < -tol), -np.inf, hi)
    lo, hi = np.maximum(lo, 0.0), np.minimum(hi, length)
    ok = hi - lo > 2 * tol
    if not ok.any():
        return empty
    r_w, r_f, r_lo, r_hi = wi[rep[ok]], fk[rep[ok]], lo[ok], hi[ok]
    out_w, out_lo, out_hi, out_cover = [], [], [], []
    for i in np.unique(r_w):  # a short loop over the covered wedges, at load time
        sel = r_w == i
        cuts = np.unique(np.concatenate([[0.0, w.length[i]], r_lo[sel], r_hi[sel]]))
        cuts = cuts[(cuts >= 0) & (cuts <= w.length[i])]
        pieces: list[list] = []  # [lo, hi, key], consecutive, same keys merged
        for p_lo, p_hi in zip(cuts[:-1], cuts[1:]):
            t_mid = 0.5 * (p_lo + p_hi)
            inside = sel & (r_lo <= t_mid) & (r_hi >= t_mid)
            key = tuple(np.unique(r_f[inside]).tolist())
            if pieces and (p_hi - p_lo <= 2 * tol or key == pieces[-1][2]):
                pieces[-1][1] = p_hi  # a sliver between two cuts joins its neighbour
            else:
                pieces.append([p_lo, p_hi, key])
        if len(pieces) > 1 and pieces[0][1] - pieces[0][0] <= 2 * tol:
            pieces[1][0] = pieces[0][0]
            pieces.pop(0)
        for p_lo, p_hi, key in pieces:
            out_w.append(i)
            out_lo.append(p_lo)
            out_hi.append(p_hi)
            out_cover.append(np.array(key, dtype=np.int64))
    return np.array(out_w, dtype=np.int64), np.array(out_lo), np.array(out_hi), out_cover


def _line_key(a: np.ndarray, b: np.ndarray) -> tuple:
    """Orientation-free key of a segment, to micrometres."""
    pa, pb = (tuple(np.round(x * 1e6).astype(np.int64).tolist()) for x in (a, b))
    return (pa, pb) if pa <= pb else (pb, pa)


def _rays(
    origins: np.ndarray, ends: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit directions and lengths of segments, shortened by ``margin`` at both ends."""
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    e = np.asarray(ends, dtype=float).reshape(-1, 3)
    v = e - o
    length = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(length[:, None] > 0, v / length[:, None], 0.0)
    return o + margin * d, d, length - 2 * margin


# -- loading ----------------------------------------------------------------------------------
