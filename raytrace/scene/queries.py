"""A scene's Embree scenes and the queries on them: what segments and rays meet, and which
solid contains a point.

:class:`EmbreeQueries` is the part of :class:`~raytrace.scene.model.Scene` that builds Embree
scenes (through embreex) of the scene's triangles and asks them: :meth:`~EmbreeQueries.occluded`,
:meth:`~EmbreeQueries.segment_objects`, :meth:`~EmbreeQueries.first_hit_among`,
:meth:`~EmbreeQueries.intersect` and :meth:`~EmbreeQueries.inside_solid` (with the convex solids
of :meth:`~EmbreeQueries.convex_objects`). The Embree scenes and the arrays derived for them are
kept in the scene's caches (:class:`~raytrace.scene.caches.SceneCaches`: ``embree``,
``prim_start``, ``prim_face``, ``embree_meshes``, ``subset_embree``, ``convex``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import SceneError
from ..core.jit import carray
from . import accel
from .caches import (
    convex_flags,
    embree_meshes,
    embree_origin_of,
    embree_scene,
    object_boxes,
    subset_scene,
)
from .spatial import build_tree, query_boxes

if TYPE_CHECKING:
    from .caches import SceneCaches
    from .elements import Facets, SceneObject

__all__ = ["EmbreeQueries"]


class EmbreeQueries:
    """The Embree scenes of a scene and the queries on them (a base of
    :class:`~raytrace.scene.model.Scene`, whose arrays, caches and properties they use)."""

    vertices: np.ndarray
    faces: np.ndarray
    objects: list[SceneObject]
    facets: Facets
    caches: SceneCaches
    margin: float
    extent: float
    bounds: np.ndarray
    object_closed: np.ndarray

    def build_embree(self) -> None:
        """(Re)build the scene's Embree intersector (``caches.embree``) and its primitive-to-face
        map (``caches.prim_start``, ``caches.prim_face``): when the scene is built, unpickled, or
        copied for a worker process (a native Embree scene is neither pickled nor shared)."""
        c = self.caches
        c.embree, c.prim_start, c.prim_face = embree_scene(self.embree_meshes(), self.objects)

    def embree_meshes(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Each object's triangles as Embree is given them (:func:`raytrace.scene.caches.
        embree_meshes`): float32 points (P, 3), int32 triangles (T, 3) and the object's face (T,)
        each triangle is part of. Cached."""
        cached = self.caches.embree_meshes
        if cached is None or len(cached) != len(self.objects):
            extent = self.extent if len(self.vertices) else 0.0
            origin = self.embree_origin()
            local = self.vertices - origin if origin.any() else self.vertices
            cached = embree_meshes(local, self.faces, self.objects, extent)
            self.caches.embree_meshes = cached
        return cached

    def embree_origin(self) -> np.ndarray:
        """(3,) float, metres: the origin of the frame Embree is given the scene and the rays
        in (:func:`raytrace.scene.caches.embree_origin_of`: zero unless the scene lies far from
        the origin, as survey coordinates do). Cached."""
        if self.caches.embree_origin is None:
            origin = embree_origin_of(self.bounds) if len(self.vertices) else np.zeros(3)
            origin.setflags(write=False)
            self.caches.embree_origin = origin
        return self.caches.embree_origin

    def _embree_points(self, points: np.ndarray) -> np.ndarray:
        """Points (n, 3), metres, as Embree takes them: float32, in its frame."""
        origin = self.embree_origin()
        if origin.any():
            return (np.asarray(points, dtype=np.float64) - origin).astype(np.float32)
        return np.asarray(points, dtype=np.float32)

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
            res = self.caches.embree.run(
                self._embree_points(o[ok]),
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
        cache = self.caches.subset_embree
        key = objects.tobytes()
        if key not in cache:
            cache[key] = subset_scene(self.embree_meshes(), objects)
        es, members = cache[key]
        if not ok.all():  # (most calls ask about every ray)
            origins, directions, length = origins[ok], directions[ok], np.asarray(length)[ok]
        res = es.run(
            self._embree_points(origins),
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
        res = self.caches.embree.run(
            self._embree_points(origins),
            np.asarray(directions, dtype=np.float32),
            dists=dist,
            query="INTERSECT",
            output=1,
        )
        return accel.hit_records(res["geomID"], res["primID"], res["tfar"],
                                 self.caches.prim_start, self.caches.prim_face)  # fmt: skip

    def convex_objects(self) -> np.ndarray:
        """(O,) bool: closed solids that are convex (every vertex on or behind every facet plane
        of the object: :func:`raytrace.scene.caches.convex_flags`). Cached."""
        if self.caches.convex is None:
            self.caches.convex = convex_flags(self.vertices, self.faces, self.objects, self.facets,
                                              self.object_closed, self.extent)  # fmt: skip
        return self.caches.convex

    def inside_solid(self, points: np.ndarray, exclude: np.ndarray | None = None) -> np.ndarray:
        """Index of the closed solid that contains each point, or -1.

        Convex solids (boxes, prisms: all of a typical hall) are tested exactly: a point is inside
        when it lies strictly behind every facet plane of the object. Other closed solids count
        the crossings of rays from the point (parity, with Embree) along three directions and
        take the majority: one ray can miscount where it grazes an edge or passes from one solid
        into another through a face they share.

        Parameters
        ----------
        points : (n, 3) float, metres
        exclude : (n,) int, optional, an object per point that the crossings' test does not ask
            about (a probe just outside its own object: whether it is in another): a point in
            a convex solid still gets that solid's index, whichever it is

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
                skip = None if exclude is None else np.asarray(exclude, np.int64)[todo]
                found = self._inside_by_parity(pts[todo], others, skip)
                out[todo] = found
        return out

    def object_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Each object's bounding box, ``lo``, ``hi`` (O, 3), metres (cached)."""
        if self.caches.object_boxes is None:
            self.caches.object_boxes = object_boxes(self.vertices, self.faces, self.objects)
        return self.caches.object_boxes

    def _inside_by_parity(self, pts: np.ndarray, candidates: np.ndarray,
                          exclude: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
        """:meth:`inside_solid` for the ``candidates`` (O,) bool objects that are not convex:
        the first object (lowest index) whose bounding box holds the point and that an odd
        number of crossings on at least two of three rays says the point is in.

        Only (point, object) pairs with the point in the object's box are asked, and each ray
        stops where it leaves the last of its point's boxes: the crossings of those objects are
        all counted, none of any other (memory and time in the pairs and crossings, not in
        points x objects)."""
        n = len(pts)
        out = np.full(n, -1, dtype=np.int64)
        lo, hi = self.object_boxes()
        grow = self.margin
        cand = np.flatnonzero(candidates & np.isfinite(lo[:, 0]))
        if n == 0 or cand.size == 0:
            return out
        tree = build_tree(lo[cand] - grow, hi[cand] + grow, 0.5 * (lo[cand] + hi[cand]),
                          0.5 * np.linalg.norm(hi[cand] - lo[cand], axis=1) + 2 * grow)  # fmt: skip
        offsets, hits = query_boxes(tree, pts, pts)
        p_idx = np.repeat(np.arange(n), np.diff(offsets))
        o_idx = cand[hits]
        if exclude is not None:
            keep = o_idx != exclude[p_idx]
            p_idx, o_idx = p_idx[keep], o_idx[keep]
        if p_idx.size == 0:
            return out
        n_obj = len(self.objects)
        pair_key = p_idx * n_obj + o_idx
        votes = np.zeros(len(pair_key), dtype=np.int64)
        # component ratios golden (badly approximable by fractions), so that rays from points on
        # a decimetre grid do not pass exactly through edges of boxes on that grid
        g = 0.5 * (1.0 + np.sqrt(5.0))
        dirs = np.array([[1.0, g, g * g], [-g * g, 1.0, g], [g, -g * g, 1.0]])
        ask = np.unique(p_idx)
        for d in dirs / np.linalg.norm(dirs, axis=1, keepdims=True):
            reach = np.zeros(n)
            np.maximum.at(reach, p_idx, _box_exit(pts[p_idx], d, lo[o_idx] - grow,
                                                  hi[o_idx] + grow))  # fmt: skip
            crossed = _crossings(self, pts[ask], d, reach[ask] + grow, self.margin, n_obj)
            key = ask[crossed[0]] * n_obj + crossed[1]
            k, c = np.unique(key, return_counts=True)
            odd = k[c % 2 == 1]
            votes += np.isin(pair_key, odd)
        inside = votes >= 2
        if not inside.any():  # points in boxes, none in a solid
            return out
        # the lowest object index per point among its pairs inside
        order = np.lexsort((o_idx[inside], p_idx[inside]))
        pi, oi = p_idx[inside][order], o_idx[inside][order]
        first = np.r_[True, pi[1:] != pi[:-1]]
        out[pi[first]] = oi[first]
        return out


def _box_exit(p: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance (m) along the unit direction ``d`` (3,) from points ``p`` (n, 3) inside boxes
    (``lo``, ``hi`` (n, 3)) to where the ray leaves them."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (hi - p) / d, np.where(d < 0, (lo - p) / d, np.inf))
    return np.maximum(t.min(axis=1), 0.0)


def _crossings(scene: Any, pts: np.ndarray, d: np.ndarray, reach: np.ndarray, step: float,
               n_obj: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Every surface crossing of rays from ``pts`` (n, 3) along ``d`` (3,) within ``reach`` (n,)
    metres: ``(ray, object)`` per crossing, (H,) int each. Each round asks Embree for the next
    hit of the rays still going and moves them past it by ``step`` metres."""
    origin = pts.copy()
    left = reach.astype(float).copy()
    active = np.arange(len(pts))
    rays, objs = [], []
    for _ in range(4 * n_obj + 8):
        if active.size == 0:
            break
        t, _, obj = scene.intersect(origin[active], np.broadcast_to(d, (len(active), 3)),
                                    left[active])  # fmt: skip
        hit = obj >= 0
        rays.append(active[hit])
        objs.append(obj[hit])
        moved = active[hit]
        origin[moved] += (t[hit] + step)[:, None] * d
        left[moved] -= t[hit] + step
        active = moved[left[moved] > 0]
    if not rays:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(rays), np.concatenate(objs)


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

