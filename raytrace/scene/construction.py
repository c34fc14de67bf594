"""Building a scene's arrays from meshes: triangles, objects, planar facets and wedges.

:func:`scene_parts` processes every mesh with trimesh (merging, orientation of closed solids,
degenerate triangles dropped) into the arrays of a :class:`~raytrace.scene.model.Scene`: its
facets (:func:`facets_of`: connected coplanar triangles of one object) and wedges
(:func:`wedges_of`: convex edges of closed solids, free edges of open sheets, collinear pieces
merged). Once the scene can answer which solid contains a point, the edges that are not free
are resolved: :func:`buried_wedges` (an edge whose outward bisector enters another solid) and
:func:`resolve_junctions` (an edge on another object's surface: concave, flat or composite).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..core import vec
from ..core.errors import SceneError
from ..core.jit import carray, kernel
from . import accel, spatial
from .elements import Facets, SceneObject, Wedges
from .repair import DEGENERATE_AREA_M2, REPAIRS, WELD_TOL_M, geometry_key, repaired_parts

__all__ = ["DEGENERATE_AREA_M2", "WELD_TOL_M", "DEFAULT_SMOOTH_ANGLE_DEG", "WEDGE_MIN_ANGLE_RAD", "MAX_SMOOTH_ANGLE_DEG", "BURIED_PROBE_M",
           "JUNCTION_MIN_EXCESS_RAD", "scene_parts", "facets_of", "wedges_of", "buried_wedges",
           "resolve_junctions", "check_smooth_angle", "coplanar_overlaps"]

#: Default smooth angle: two adjacent faces whose normals differ by less than this (rad) meet
#: at a smooth edge, not a wedge (``smooth_angle_deg`` of :func:`scene_parts` chooses another;
#: docs/scene.md, "Smooth edges", has the measurement behind the default).
DEFAULT_SMOOTH_ANGLE_DEG = 1.0
WEDGE_MIN_ANGLE_RAD = np.deg2rad(DEFAULT_SMOOTH_ANGLE_DEG)
#: Largest smooth angle accepted, degrees: beyond it a box's own corners would vanish.
MAX_SMOOTH_ANGLE_DEG = 60.0
#: Distance (m) from an edge along its outward bisector at which a wedge is probed for being
#: buried in another solid (then it is not a free, diffracting edge).
BURIED_PROBE_M = 5e-3
#: A triangle's side at an angle (rad) below this to an edge it covers gets the slack of the
#: margin across it (:func:`resolve_junctions`): the sides of a mesh welded from one with gaps
#: run at ~1e-5 rad to the edges they border.
NEAR_PARALLEL = 1e-3
#: Angle (rad) by which the air around a junction edge must exceed pi to stay a (convex) wedge.
JUNCTION_MIN_EXCESS_RAD = WEDGE_MIN_ANGLE_RAD


def scene_parts(
    meshes: list[tuple[str, Any, str]],
    source: str = "",
    smooth_angle_deg: float | None = None,
    surfaces: bool = False,
) -> dict[str, Any]:
    """The arrays of a scene built from ``(name, trimesh.Trimesh, material_name)`` triples, as
    :class:`~raytrace.scene.model.Scene`'s keyword arguments: ``vertices``, ``faces``,
    ``face_object``, ``face_normal``, ``objects``, ``material_names``, ``facets``, ``wedges``
    (before the buried and junction edges are resolved) and ``n_degenerate_dropped``.

    Closed (watertight) meshes are oriented outward; everything else is an open sheet. With
    ``surfaces`` every mesh is an open sheet, closed or not (Sionna RT's model: each face a slab
    of its material's thickness, a closed mesh a hollow shell). Degenerate triangles are dropped
    and counted. An edge whose two faces' normals differ by
    less than ``smooth_angle_deg`` (default :data:`WEDGE_MIN_ANGLE_RAD`, 1 degree) is smooth: a
    tessellated curve, not a diffracting wedge.

    Raises
    ------
    SceneError
        No triangle in any mesh, a NaN or infinite vertex, or a smooth angle outside
        [0, :data:`MAX_SMOOTH_ANGLE_DEG`] degrees.
    """
    import trimesh

    smooth_rad = check_smooth_angle(smooth_angle_deg)

    verts, faces, face_obj, normals = [], [], [], []
    objects: list[SceneObject] = []
    material_names: list[str] = []
    repairs = dict.fromkeys(["degenerate", *REPAIRS], 0)
    seen: set[bytes] = set()
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
        parts, counts = repaired_parts(name, v, f)
        for key, c in counts.items():
            repairs[key] += c
        for part_name, m in parts:
            key = geometry_key(m)
            if key in seen:  # the same triangles again (a CAD export's doubled instance)
                repairs["duplicate_objects"] += 1
                continue
            seen.add(key)
            closed = not surfaces and bool(m.is_watertight) and bool(m.is_winding_consistent)
            if closed:
                trimesh.repair.fix_normals(m)
                if m.volume < 0:
                    m.invert()
            if mat not in material_names:
                material_names.append(mat)
            mat_id = material_names.index(mat)
            obj_id = len(objects)
            objects.append(SceneObject(part_name, mat, closed, f_offset, len(m.faces)))
            verts.append(np.asarray(m.vertices, dtype=np.float64))
            faces.append(np.asarray(m.faces, dtype=np.int64) + v_offset)
            face_obj.append(np.full(len(m.faces), obj_id, dtype=np.int64))
            normals.append(np.asarray(m.face_normals, dtype=np.float64))
            facet_parts.append(facets_of(m, obj_id, mat_id, closed))
            wedge_parts.append(wedges_of(m, obj_id, mat_id, closed, smooth_rad))
            v_offset += len(m.vertices)
            f_offset += len(m.faces)
    if not objects:
        raise SceneError(f"scene {source or '<memory>'} has no triangles")
    facets = Facets(**{k: _cat([p[k] for p in facet_parts]) for k in facet_parts[0]})
    # tri_start is per object part; make it global
    starts, offset = [], 0
    for p in facet_parts:
        starts.append(p["tri_start"] + offset)
        offset += len(p["triangles"])
    facets = Facets(**{**facets.arrays(), "tri_start": _cat(starts)})
    wedges = Wedges(**{k: _cat([p[k] for p in wedge_parts]) for k in wedge_parts[0]})
    return {
        "vertices": np.concatenate(verts),
        "faces": np.concatenate(faces),
        "face_object": np.concatenate(face_obj),
        "face_normal": np.concatenate(normals),
        "objects": objects,
        "material_names": material_names,
        "smooth_angle_deg": DEFAULT_SMOOTH_ANGLE_DEG if smooth_angle_deg is None
        else float(smooth_angle_deg),
        "surfaces": bool(surfaces),
        "facets": facets,
        "wedges": wedges,
        "n_degenerate_dropped": repairs.pop("degenerate"),
        "repairs": repairs,
    }


def buried_wedges(w: Wedges, inside_solid: Callable[..., np.ndarray]) -> np.ndarray:
    """(W,) bool: the edges that are not free: a convex edge whose outward bisector enters another
    solid right away (a box's bottom edges on a floor slab, racks side by side). The wedge
    there is really the concave junction of two objects, and nothing can reach its edge
    from outside. Half-plane edges of sheets are never buried. ``inside_solid`` is the scene's
    :meth:`~raytrace.scene.model.Scene.inside_solid` (points (n, 3) -> solid index or -1), asked
    whether each probe is in a solid other than its edge's own object (``exclude``)."""
    if len(w) == 0:
        return np.zeros(0, dtype=bool)
    bis = w.normal0 + w.normal1
    nb = np.linalg.norm(bis, axis=1)
    probe_ok = nb > 1e-6
    if not probe_ok.any():
        return np.zeros(len(w), dtype=bool)
    mid = 0.5 * (w.start + w.end)
    probe = mid[probe_ok] + (BURIED_PROBE_M * bis[probe_ok] / nb[probe_ok, None])
    inside = inside_solid(probe, exclude=w.object[probe_ok])
    buried = np.zeros(len(w), dtype=bool)
    buried[np.flatnonzero(probe_ok)] = (inside >= 0) & (inside != w.object[probe_ok])
    return buried


def resolve_junctions(
    w: Wedges, fc: Facets, margin: float, inside_solid: Callable[[np.ndarray], np.ndarray]
) -> tuple[Wedges, int, int] | None:
    """The wedges once the edges that lie on another object's surface (junctions) are resolved.

    A wall sheet standing on a floor sheet, a slab whose side is flush with the wall below it,
    a box on a floor sheet: their meshes have free-looking edges there. For every wedge, the
    facets of other objects whose plane contains the edge (within ``margin``, m) cover parts
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

    Uncovered parts of a partly covered edge are kept as they are. ``inside_solid`` is the
    scene's :meth:`~raytrace.scene.model.Scene.inside_solid`.

    Returns
    -------
    None where no edge is covered, else the new wedges, the number of wedges dropped as junctions
    (some of their pieces) and of the composite pieces kept.
    """
    if len(w) == 0 or len(fc) == 0:
        return None
    w_idx, t_lo, t_hi, cover = _junction_pieces(w, fc, margin)
    if len(w_idx) == 0:
        return None
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
    covered = [j for j in range(m) if len(cover[j])]
    sectors = _air_sectors(w, fc, w_idx[covered], 0.5 * (start[covered] + end[covered]),
                           [cover[j] for j in covered], inside_solid)  # fmt: skip
    for j, sector in zip(covered, sectors):
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
    wedges = Wedges(**{key: v[order] for key, v in parts.items()})
    return wedges, int(len(np.unique(w_idx[~keep]))), n_composite


def _air_sectors(w: Wedges, fc: Facets, wi: np.ndarray, mid: np.ndarray, cover: list,
                 inside_solid: Callable[[np.ndarray], np.ndarray]) -> list:  # fmt: skip
    """Air around wedges ``wi`` (P,) at points ``mid`` (P, 3) once the facets ``cover`` (P
    arrays) covering each are in place: per piece, True (the wedge's own sector is untouched: a
    free edge), None (no air sub-sector wider than pi: a junction, not a wedge) or
    ``(face0_dir, normal0, normal1, n)`` of the one convex air sub-sector (a composite wedge).

    Three passes over the pieces, so that the scene's point queries (facets, solids) are asked
    once for all of them: a city model's buildings stand on its ground, and its tens of
    thousands of covered edges took minutes one query at a time.
    """
    eps = JUNCTION_MIN_EXCESS_RAD
    frames, probes, owners = [], [], []
    for i, m_i, facets in zip(wi, mid, cover):
        t0 = w.face0_dir[i]
        nrm0 = w.normal0[i] - (w.normal0[i] @ w.direction[i]) * w.direction[i]
        nrm0 /= np.linalg.norm(nrm0)
        e = vec.cross(t0, nrm0)  # angles grow from t0 towards n0, right-handed about e
        # half-lines of the covering facets, perpendicular to the edge
        u = vec.cross(fc.normal[facets], e)
        u /= vec.norm(u)[:, None]
        rays = np.concatenate([u, -u])
        owner = np.concatenate([facets, facets])
        probe = m_i + BURIED_PROBE_M * rays
        # onto each facet's own plane (the edge of a mesh welded from one with gaps lies off
        # it by up to the gaps, and a probe in the edge's plane would miss a facet it is on)
        on_plane = probe - (np.einsum("ij,ij->i", probe, fc.normal[owner])
                            - fc.offset[owner])[:, None] * fc.normal[owner]  # fmt: skip
        frames.append((t0, nrm0, rays))
        probes.append(on_plane)
        owners.append(owner)
    n_rays = np.cumsum([0] + [len(o) for o in owners])
    present = accel.points_in_facets(np.concatenate(probes), np.concatenate(owners), fc) \
        if len(owners) else np.zeros(0, bool)  # fmt: skip
    sub, dirs_all = [], []
    for k, (i, m_i) in enumerate(zip(wi, mid)):
        t0, nrm0, rays = frames[k]
        own = w.n[i] * np.pi
        ang = np.mod(np.arctan2(rays @ nrm0, rays @ t0), 2 * np.pi)
        cuts = np.sort(ang[present[n_rays[k]:n_rays[k + 1]] & (ang > eps) & (ang < own - eps)])
        # with no cut the air sector may still be filled by a solid that only touches the edge
        # along one of the wedge's own faces (probed below)
        bounds = np.concatenate([[0.0], cuts, [own]])
        lo, hi = bounds[:-1], bounds[1:]
        wide = hi - lo > 1e-9
        lo, hi = lo[wide], hi[wide]
        mid_ang = 0.5 * (lo + hi)
        dirs = np.cos(mid_ang)[:, None] * t0 + np.sin(mid_ang)[:, None] * nrm0
        sub.append((lo, hi))
        dirs_all.append(m_i + BURIED_PROBE_M * dirs)
    n_sub = np.cumsum([0] + [len(d) for d in dirs_all])
    inside = inside_solid(np.concatenate(dirs_all)) if len(dirs_all) else np.zeros(0, np.int64)
    out: list = []
    for k, i in enumerate(wi):
        t0, nrm0, _ = frames[k]
        lo, hi = sub[k]
        ins = inside[n_sub[k]:n_sub[k + 1]]
        air = (ins < 0) | (ins == w.object[i])
        if len(lo) == 1 and air[0]:
            out.append(True)
            continue
        width = np.where(air, hi - lo, 0.0)
        j = int(np.argmax(width))
        if width[j] <= np.pi + eps:
            out.append(None)
            continue
        # faces of the sub-sector [lo, hi]: outward normals point into it (wedge_geometry: the
        # outward normal of face 0 is at +pi/2 from it, that of face n at -pi/2)
        out.append(tuple(np.cos(a) * t0 + np.sin(a) * nrm0
                         for a in (lo[j], lo[j] + 0.5 * np.pi, hi[j] - 0.5 * np.pi))
                   + (width[j] / np.pi,))  # fmt: skip
    return out


def coplanar_overlaps(fc: Facets, tol: float) -> np.ndarray:
    """(P, 2) int: pairs of facets of different objects that lie in one plane (within ``tol``,
    m), face the same way and overlap: two solids' faces where the solids overlap, or two
    sheets on one another (z-fighting, as CAD exports make it). Both reflect there, so every
    path on them is found twice. (A sheet resting on a solid's face, a ceiling board on a wall's
    top, is modelled so on purpose and not listed.) Overlap: a point of one facet (each
    triangle's centroid and its corners pulled a tenth towards it) lies inside the other."""
    if len(fc) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    lo, hi = accel.facet_boxes(fc, tol)
    offsets, hits = spatial.query_boxes(accel.facet_tree(fc), lo, hi)
    a = np.repeat(np.arange(len(fc)), np.diff(offsets))
    b = hits
    keep = (a < b) & (fc.object[a] != fc.object[b]) & (fc.two_sided[a] == fc.two_sided[b])
    a, b = a[keep], b[keep]
    dot = np.einsum("ij,ij->i", fc.normal[a], fc.normal[b])
    side = np.where(fc.two_sided[a], np.sign(dot), 1.0)  # a sheet faces both ways
    one = (side * dot > 1 - 1e-9) & (np.abs(fc.offset[a] - side * fc.offset[b]) <= tol)
    a, b = a[one], b[one]
    if not len(a):
        return np.zeros((0, 2), dtype=np.int64)
    found = np.zeros(len(a), dtype=bool)
    for x, y in ((a, b), (b, a)):
        cnt = fc.tri_count[x]
        pair = np.repeat(np.arange(len(x)), cnt)
        tri = fc.triangles[np.repeat(fc.tri_start[x], cnt) + np.arange(cnt.sum())
                           - np.repeat(np.cumsum(cnt) - cnt, cnt)]  # fmt: skip
        c = tri.mean(axis=1)
        pts = np.concatenate([c[:, None], 0.9 * tri + 0.1 * c[:, None]], axis=1)  # (T, 4, 3)
        pts = pts.reshape(-1, 3)
        owner = np.repeat(pair, 4)
        n, off = fc.normal[y[owner]], fc.offset[y[owner]]
        pts = pts - (np.einsum("ij,ij->i", pts, n) - off)[:, None] * n
        inside = accel.points_in_facets(pts, y[owner], fc)
        found |= np.bincount(owner[inside], minlength=len(x)) > 0
    return np.stack([a[found], b[found]], axis=1)


def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0)


def facets_of(mesh: Any, obj_id: int, mat_id: int, closed: bool) -> dict[str, np.ndarray]:
    """Group a mesh's faces into facets: trimesh's coplanar groups, plus lone faces."""
    n_faces = len(mesh.faces)
    groups = [np.asarray(g, dtype=np.int64) for g in mesh.facets]
    in_group = np.zeros(n_faces, dtype=bool)
    for g in groups:
        in_group[g] = True
    # trimesh's groups (their faces in its order), then the lone faces; in order of each group's
    # lowest face (arrays, not a list of a million one-face arrays: a scanned mesh is mostly lone
    # faces)
    members = np.concatenate([*groups, np.flatnonzero(~in_group)]).astype(np.int64)
    g_count = np.concatenate([[len(g) for g in groups], np.ones(int((~in_group).sum()))])
    g_count = g_count.astype(np.int64)
    g_start = np.concatenate([[0], np.cumsum(g_count)[:-1]]).astype(np.int64)
    rank = np.argsort(np.minimum.reduceat(members, g_start), kind="stable")
    counts = g_count[rank]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    order = members[np.repeat(g_start[rank] - starts, counts) + np.arange(len(members))]
    fn = np.asarray(mesh.face_normals, dtype=float)
    areas = np.asarray(mesh.area_faces, dtype=float)
    # area-weighted normal of each facet (its faces are coplanar within trimesh's tolerance)
    nsum = np.add.reduceat(fn[order] * areas[order, None], starts, axis=0)
    normal = nsum / np.linalg.norm(nsum, axis=1, keepdims=True)
    tris = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces)[order]]
    centroid = np.add.reduceat(tris.mean(axis=1) * areas[order, None], starts, axis=0)
    farea = np.add.reduceat(areas[order], starts)
    centroid /= farea[:, None]
    k = len(counts)
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


def check_smooth_angle(smooth_angle_deg: float | None) -> float:
    """The smooth angle in radians (the default for None); SceneError outside [0, 60] degrees."""
    if smooth_angle_deg is None:
        return float(WEDGE_MIN_ANGLE_RAD)
    a = float(smooth_angle_deg)
    if not 0.0 <= a <= MAX_SMOOTH_ANGLE_DEG:  # also NaN
        raise SceneError(
            f"smooth angle must be between 0 and {MAX_SMOOTH_ANGLE_DEG:g} degrees, got {a:g}"
        )
    return float(np.deg2rad(a))


def wedges_of(
    mesh: Any, obj_id: int, mat_id: int, closed: bool, smooth_rad: float = WEDGE_MIN_ANGLE_RAD
) -> dict[str, np.ndarray]:
    """Convex edges of a closed solid, or free (boundary) edges of an open sheet; edges whose
    faces bend by no more than ``smooth_rad`` (radians) are smooth, not wedges.

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
        sel = angles > smooth_rad
        if closed:
            sel &= convex
        if sel.any():
            seg, n0, n1 = verts[edges[sel]], fn[adj[sel, 0]], fn[adj[sel, 1]]
            if not closed:
                n0, n1 = _fold_outward(seg, n0, n1, centroids[adj[sel, 0]],
                                       centroids[adj[sel, 1]])  # fmt: skip
            segs.append(seg)
            n0s.append(n0)
            n1s.append(n1)
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
    into0 = _across(seg, u, c0)
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


def _fold_outward(seg: np.ndarray, n0: np.ndarray, n1: np.ndarray, c0: np.ndarray,
                  c1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A sheet's fold edges with both face normals turned to the fold's larger side: a sheet has
    no outside, and a wedge's normals say where its exterior is, so a fold is diffracting on its
    convex side (exterior angle above pi) whichever way the file wound the faces (a closed mesh
    read as surfaces and wound inward lost every edge's diffraction).

    Parameters
    ----------
    seg : (E, 2, 3) float, m, the edges; n0, n1 : (E, 3) float, unit normals of their two faces;
    c0, c1 : (E, 3) float, m, the faces' centroids

    Returns
    -------
    n0, n1 : (E, 3) float, each normal pointing away from the other face (unchanged where it did)
    """
    u = seg[:, 1] - seg[:, 0]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    flip0 = np.einsum("ij,ij->i", n0, _across(seg, u, c1)) > 0
    flip1 = np.einsum("ij,ij->i", n1, _across(seg, u, c0)) > 0
    return np.where(flip0[:, None], -n0, n0), np.where(flip1[:, None], -n1, n1)


def _across(seg: np.ndarray, u: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(E, 3) float, m: from each edge (``seg`` (E, 2, 3), unit direction ``u``) to the point
    ``c`` (E, 3) of a face, square to the edge: the direction into the face, not normalised."""
    v = c - seg[:, 0]
    return v - np.einsum("ij,ij->i", v, u)[:, None] * u


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
    t0 = np.einsum("ij,ij->i", seg[:, 0], d)
    t1 = np.einsum("ij,ij->i", seg[:, 1], d)
    lo, hi = np.minimum(t0, t1), np.maximum(t0, t1)
    order = np.lexsort((lo, group))
    # within a group, touching intervals are joined (in order along the line)
    first, run_lo, run_hi = _joined_runs(carray(order, np.int64), carray(group[order], np.int64),
                                         carray(lo), carray(hi), 1e-6)  # fmt: skip
    pf, df = p[first], d[first]
    out_seg = np.stack([pf + run_lo[:, None] * df, pf + run_hi[:, None] * df], axis=1)
    return out_seg, n0[first], n1[first], c0[first]


@kernel("Tuple((i8[::1], f8[::1], f8[::1]))(i8[::1], i8[::1], f8[::1], f8[::1], f8)")
def _joined_runs(order, g_sorted, lo, hi, gap):
    """Runs of touching intervals: rows ``order`` sorted by group ``g_sorted`` then ``lo``; an
    interval starting within ``gap`` of the run's end joins it. Returns each run's first row,
    its start and its end (the largest ``hi`` of its rows)."""
    n = len(order)
    first = np.empty(n, np.int64)
    run_lo = np.empty(n)
    run_hi = np.empty(n)
    m = 0
    i = 0
    while i < n:
        k0 = order[i]
        cur_lo, cur_hi, cur_first = lo[k0], hi[k0], k0
        j = i + 1
        while j < n and g_sorted[j] == g_sorted[i]:
            k = order[j]
            if lo[k] <= cur_hi + gap:
                cur_hi = max(cur_hi, hi[k])
            else:
                first[m], run_lo[m], run_hi[m] = cur_first, cur_lo, cur_hi
                m += 1
                cur_lo, cur_hi, cur_first = lo[k], hi[k], k
            j += 1
        first[m], run_lo[m], run_hi[m] = cur_first, cur_lo, cur_hi
        m += 1
        i = j
    return first[:m].copy(), run_lo[:m].copy(), run_hi[:m].copy()


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
    empty = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), [])
    wi, fk = _facets_near_edges(w, fc, tol)
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
        # a side at a small angle to the edge (a side of a mesh with welding gaps runs at
        # ~1e-5 rad to the edge it borders) would cut it where the two lines cross, anywhere
        # along it: such a side gets the slack of tol across it too
        slack = np.where(np.abs(c1) <= NEAR_PARALLEL, tol, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -(c0 + slack) / c1
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


def _facets_near_edges(w: Wedges, fc: Facets, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """(wedge, facet) pairs, in (wedge, facet) order, where the edge lies in the plane of a
    facet of another object (the ends of its part within the facet's box within ``tol``, m).

    The facets are found through the facets' tree (:func:`raytrace.scene.accel.facet_tree`):
    only those whose box meets the edge's box grown by twice ``tol``. A facet farther than that
    covers no part of the edge (the covered parts are clipped to its triangles within ``tol``),
    so the pieces of :func:`_junction_pieces` are those of a scan of every pair, with memory and
    time in the candidates found, not in wedges x facets.
    """
    if len(w) == 0 or len(fc) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    grow = 2.0 * tol
    lo = np.minimum(w.start, w.end) - grow
    hi = np.maximum(w.start, w.end) + grow
    offsets, hits = spatial.query_boxes(accel.facet_tree(fc), lo, hi)
    wi = np.repeat(np.arange(len(w)), np.diff(offsets))
    fk = hits
    # the part of the edge within the facet's box (grown): a small facet of a mesh with
    # welding gaps is tilted by ~1e-4 rad, and its plane leaves a long edge it covers a part of
    box_lo, box_hi = accel.facet_boxes(fc, grow)
    t0, t1 = _clip_to_boxes(w.start[wi], w.direction[wi], w.length[wi], box_lo[fk], box_hi[fk])
    pa = w.start[wi] + t0[:, None] * w.direction[wi]
    pb = w.start[wi] + t1[:, None] * w.direction[wi]
    da = np.einsum("ij,ij->i", pa, fc.normal[fk]) - fc.offset[fk]
    db = np.einsum("ij,ij->i", pb, fc.normal[fk]) - fc.offset[fk]
    # another object's facet, or one of the edge's own open sheet across it (a shelf and its
    # wall in one mesh: the shelf's edge lies on the wall's faces, sharing no edge with them)
    across = np.maximum(np.abs(np.einsum("ij,ij->i", fc.normal[fk], w.normal0[wi])),
                        np.abs(np.einsum("ij,ij->i", fc.normal[fk], w.normal1[wi]))) < 1 - 1e-6
    other = (w.object[wi] != fc.object[fk]) | (fc.two_sided[fk] & across)
    near = (np.abs(da) <= tol) & (np.abs(db) <= tol) & other
    wi, fk = wi[near], fk[near]
    order = np.lexsort((fk, wi))
    return wi[order], fk[order]


def _clip_to_boxes(a: np.ndarray, d: np.ndarray, length: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The part ``[t0, t1]`` (n,) of segments ``a + t d``, ``0 <= t <= length`` (metres), within
    boxes ``lo``, ``hi`` (n, 3) (slab clipping; the whole segment where it misses the box, so
    that the caller's test then judges the segment as a whole)."""
    t0, t1 = np.zeros(len(a)), length.astype(float).copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for k in range(3):
            flat = d[:, k] == 0.0
            u = (lo[:, k] - a[:, k]) / d[:, k]
            v = (hi[:, k] - a[:, k]) / d[:, k]
            t0 = np.where(flat, t0, np.maximum(t0, np.minimum(u, v)))
            t1 = np.where(flat, t1, np.minimum(t1, np.maximum(u, v)))
    miss = t0 > t1
    return np.where(miss, 0.0, t0), np.where(miss, length, t1)


def _line_key(a: np.ndarray, b: np.ndarray) -> tuple:
    """Orientation-free key of a segment, to micrometres."""
    pa, pb = (tuple(np.round(x * 1e6).astype(np.int64).tolist()) for x in (a, b))
    return (pa, pb) if pa <= pb else (pb, pa)
