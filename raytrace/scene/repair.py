"""Repairing one object's mesh as CAD exports and scans bring it, before the scene is built from
it (:func:`raytrace.scene.construction.scene_parts`): welding gaps and triangle soups
(:func:`weld_vertices`), degenerate and duplicate triangles, inconsistent winding, T-junctions
(:func:`split_t_junctions`), and several solids, or solids and sheets, in one mesh
(:func:`split_bodies`: an STL holds one object, a CAD export may join the objects of a
material). A clean mesh passes through unchanged. docs/scene.md, "Meshes from CAD and scans",
measures each case.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["DEGENERATE_AREA_M2", "WELD_TOL_M", "REPAIRS", "repaired_parts", "weld_vertices",
           "split_t_junctions", "split_bodies", "geometry_key"]

#: Triangles with an area below this (m^2) are degenerate and dropped.
DEGENERATE_AREA_M2 = 1e-10
#: Vertices of one object closer than this (m) are one vertex (:func:`weld_vertices`), and a
#: vertex closer than this to another triangle's edge lies on it (:func:`split_t_junctions`):
#: the welding gaps of CAD exports and triangle soups (1e-7 to 1e-5 m), far below the tracer's
#: smallest end margin (:func:`raytrace.scene.caches.margin_of`, 1e-4 m), which cannot tell
#: such points apart anyway.
WELD_TOL_M = 1e-4
#: What :func:`repaired_parts` counts, and how the scene's warning says it.
REPAIRS = {
    "welded": f"vertices welded to a neighbour closer than {WELD_TOL_M * 1e3:g} mm",
    "duplicate": "duplicate triangles dropped",
    "t_junctions": "T-junctions closed (a vertex on another triangle's edge)",
    "rewound": "closed objects' faces turned to one winding",
    "bodies": "closed solids split out of open meshes",
    "duplicate_objects": "objects dropped that repeat another object's triangles",
}


def repaired_parts(name: str, v: np.ndarray, f: np.ndarray) -> tuple[list[tuple[str, Any]],
                                                                   dict[str, int]]:  # fmt: skip
    """One object's mesh, repaired: its parts as ``(name, trimesh.Trimesh processed)`` (none if
    no triangle is left; several if it held several closed solids) and the counts of what was
    repaired (the keys of :data:`REPAIRS` and ``degenerate``).

    In order: vertices closer than :data:`WELD_TOL_M` welded, degenerate triangles (area below
    :data:`DEGENERATE_AREA_M2`) and duplicate ones (the same three vertices twice, in either
    winding) dropped; a mesh that is not closed then gets its T-junctions split and, if it is
    still not closed, its closed solids split out of it (:func:`split_bodies`; the rest stays
    one open sheet); a closed mesh's faces
    are turned to one consistent winding. Each of these left a closed solid an open two-sided
    sheet. A clean mesh is built as before, unchanged.
    """
    import trimesh

    v, f, welded = weld_vertices(v, f)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = area > DEGENERATE_AREA_M2
    counts = {"welded": welded, "degenerate": int((~keep).sum()), "duplicate": 0,
              "t_junctions": 0, "rewound": 0, "bodies": 0}  # fmt: skip
    if not keep.any():
        return [], counts
    m = trimesh.Trimesh(vertices=v, faces=f[keep], process=True, validate=False)
    unique = m.unique_faces()
    if not unique.all():
        counts["duplicate"] = int((~unique).sum())
        m.update_faces(unique)
    m.remove_unreferenced_vertices()
    parts = [(name, m)]
    if not m.is_watertight:
        faces, n_split = split_t_junctions(np.asarray(m.vertices), np.asarray(m.faces))
        if n_split:
            counts["t_junctions"] = n_split
            m = trimesh.Trimesh(vertices=np.asarray(m.vertices), faces=faces, process=True,
                                validate=False)  # fmt: skip
            parts = [(name, m)]
        if not m.is_watertight:
            parts = split_bodies(name, m)
            counts["bodies"] = sum(1 for n, _ in parts if n != name and not n.endswith("#sheet"))
    for _, p in parts:
        if p.is_watertight and not p.is_winding_consistent:
            trimesh.repair.fix_winding(p)
            counts["rewound"] += int(bool(p.is_winding_consistent))
    return parts, counts


def weld_vertices(
    vertices: np.ndarray, faces: np.ndarray, tol: float = WELD_TOL_M
) -> tuple[np.ndarray, np.ndarray, int]:
    """One object's vertices closer than ``tol`` made one: the faces of a triangle soup or of a
    CAD export with welding gaps then share their edges, so that a closed solid is found closed
    and its edges are wedges between two faces, not free edges of separate triangles.

    Vertices within ``tol`` of each other, directly or through a chain of such neighbours, take
    the position of the lowest-indexed of them. Exact duplicates are left for trimesh's own
    merge, so a mesh with no distinct vertices within ``tol`` comes back unchanged (the same
    arrays).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    tol : float, metres

    Returns
    -------
    vertices : (V, 3) float, metres (``vertices`` itself)
    faces : (F, 3) int, re-indexed to the surviving vertices
    n_welded : int, the distinct vertices moved onto another
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(vertices) < 2:
        return vertices, faces, 0
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray")
    if len(pairs):
        pairs = pairs[(vertices[pairs[:, 0]] != vertices[pairs[:, 1]]).any(axis=1)]
    if not len(pairs):
        return vertices, faces, 0
    n = len(vertices)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    first = np.full(label.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, label, np.arange(n))
    rep = first[label]
    moved = rep != np.arange(n)
    n_welded = len(np.unique(vertices[moved], axis=0)) if moved.any() else 0
    return vertices, rep[faces], int(n_welded)


def split_t_junctions(
    vertices: np.ndarray, faces: np.ndarray, tol: float = WELD_TOL_M, rounds: int = 4
) -> tuple[np.ndarray, int]:
    """Faces with their T-junctions split: a vertex within ``tol`` of the inside of an edge that
    only one face uses (a CAD export's face split on one side of an edge and not on the other)
    becomes a corner of that face, which is fanned from its opposite corner. The edge's two
    sides then share their edges again.

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int
    tol : float, metres
    rounds : int, passes (a face with T-junctions on two edges is split one edge per pass)

    Returns
    -------
    faces : (F', 3) int, in the orientation of the faces they split
    n_split : int, the vertices inserted into edges
    """
    from scipy.spatial import cKDTree

    faces = np.asarray(faces, dtype=np.int64)
    used = np.unique(faces)
    if len(used) < 4:
        return faces, 0
    tree = cKDTree(vertices[used])
    n_split = 0
    for _ in range(rounds):
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        _, inv, cnt = np.unique(_edge_keys(e, len(vertices)), return_inverse=True,
                                return_counts=True)  # fmt: skip
        free = np.flatnonzero(cnt[inv] == 1)
        if not len(free):
            break
        a, b = vertices[e[free, 0]], vertices[e[free, 1]]
        length = np.linalg.norm(b - a, axis=1)
        near = tree.query_ball_point(0.5 * (a + b), 0.5 * length + tol)
        # (edge, vertex) pairs: the vertices inside each edge, away from its ends
        cnt_near = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
        k_of = np.repeat(np.arange(len(free)), cnt_near)
        ids = used[np.fromiter((i for x in near for i in x), dtype=np.int64, count=cnt_near.sum())]
        ab = b[k_of] - a[k_of]
        rel = vertices[ids] - a[k_of]
        t = np.einsum("ij,ij->i", rel, ab) / length[k_of] ** 2
        off = np.linalg.norm(rel - t[:, None] * ab, axis=1)
        inside = ((off <= tol) & (t * length[k_of] > tol) & ((1 - t) * length[k_of] > tol)
                  & (length[k_of] > 2 * tol))  # fmt: skip
        new_faces: dict[int, list[list[int]]] = {}
        for k in np.unique(k_of[inside]):  # the few edges with a T-junction
            face = int(free[k] % len(faces))
            if face in new_faces:
                continue
            sel = inside & (k_of == k)
            on = ids[sel][np.argsort(t[sel])]
            i0, i1 = int(e[free[k], 0]), int(e[free[k], 1])
            apex = int(next(x for x in faces[face] if x not in (i0, i1)))
            chain = [i0, *on.tolist(), i1]
            new_faces[face] = [[chain[j], chain[j + 1], apex] for j in range(len(chain) - 1)]
            n_split += len(on)
        if not new_faces:
            break
        keep = np.ones(len(faces), dtype=bool)
        keep[list(new_faces)] = False
        faces = np.concatenate([faces[keep], np.array([t for fs in new_faces.values() for t in fs])])
    return faces, n_split


def split_bodies(name: str, mesh: Any) -> list[tuple[str, Any]]:
    """A mesh that is not closed, as its closed solids (``name#1``, ``name#2``, ...) and, if
    anything else is left, one open sheet of the rest (``name#sheet``).

    Several boxes in one STL that touch along edges or share parts of faces (a hall's walls on
    its floor) make edges of four faces, and the whole mesh an open sheet; a CAD export that
    joins every object of one material (the concrete walls' boxes and an open floor plane) is
    a mesh of solids and a sheet. Faces are grouped by the edges that exactly two of them
    share; a group that is closed on its own (each of its edges used by exactly two of its
    faces) and shares no vertex with an open group is a solid; the rest together is one sheet
    (a closed group glued to the sheet along edges of three faces, as a scan's reconstruction
    makes them, is a fold of that sheet). A mesh that is one group, or has no such solid, comes
    back as it is."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(mesh.faces, dtype=np.int64)
    n = len(faces)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, inv, cnt = np.unique(_edge_keys(e, len(mesh.vertices)), return_inverse=True,
                            return_counts=True)  # fmt: skip
    two = np.flatnonzero(cnt == 2)
    rows = np.flatnonzero(np.isin(inv, two))
    order = rows[np.argsort(inv[rows], kind="stable")]
    f_of = order % n
    pa, pb = f_of[0::2], f_of[1::2]  # the two faces of each manifold edge
    graph = coo_matrix((np.ones(len(pa)), (pa, pb)), shape=(n, n))
    n_comp, label = connected_components(graph, directed=False)
    if n_comp < 2:
        return [(name, mesh)]
    # a group is closed when each of its edges is used by exactly two of its faces
    owner = label[np.arange(3 * n) % n]
    pair, pair_cnt = np.unique(inv * n_comp + owner, return_counts=True)
    open_group = np.zeros(n_comp, dtype=bool)
    open_group[pair[pair_cnt != 2] % n_comp] = True
    # a closed group that shares a vertex with the open rest is a fold of that surface (a scan's
    # reconstruction glues tetrahedra to its sheet along edges of three faces), not a solid of
    # its own: it stays in the sheet
    sheet_faces = open_group[label]
    touching = np.zeros(len(mesh.vertices), dtype=bool)
    touching[faces[sheet_faces].ravel()] = True
    attached = np.zeros(n_comp, dtype=bool)
    attached[label[touching[faces].any(axis=1)]] = True
    solid = ~open_group & ~attached
    if not solid.any():
        return [(name, mesh)]
    vertices = np.asarray(mesh.vertices)
    parts = [(f"{name}#{k + 1}", _part(vertices, faces[label == g]))
             for k, g in enumerate(np.flatnonzero(solid))]  # fmt: skip
    if not solid.all():
        parts.append((f"{name}#sheet", _part(vertices, faces[~solid[label]])))
    return parts


def geometry_key(mesh: Any) -> bytes:
    """A digest of a mesh's triangles, independent of their order, their corners' order and
    the vertex numbering, to the micrometre: two objects with the same key are the same surface
    twice (a CAD export's doubled instance), whose faces would reflect every ray twice."""
    import hashlib

    tri = np.round(np.asarray(mesh.triangles, dtype=float) * 1e6).astype(np.int64)  # (F, 3, 3)
    order = np.lexsort(tri.transpose(2, 0, 1)[::-1], axis=-1)  # corners sorted per triangle
    tri = np.take_along_axis(tri, order[..., None], axis=1).reshape(len(tri), 9)
    tri = tri[np.lexsort(tri.T[::-1])]
    return hashlib.sha256(tri.tobytes()).digest()


def _edge_keys(edges: np.ndarray, n_vertices: int) -> np.ndarray:
    """(E,) int64: one key per undirected edge ``edges`` (E, 2) of vertex indices."""
    lo, hi = np.minimum(edges[:, 0], edges[:, 1]), np.maximum(edges[:, 0], edges[:, 1])
    return lo.astype(np.int64) * int(n_vertices) + hi


def _part(vertices: np.ndarray, faces: np.ndarray) -> Any:
    import trimesh

    m = trimesh.Trimesh(vertices=vertices, faces=faces, process=True, validate=False)
    m.remove_unreferenced_vertices()
    return m
