"""Step 5 of the reconstruction: the residual points near a plane join it
(:func:`near_planes`), the rest is clustered (DBSCAN) into objects: upright boxes, convex hulls
or alpha-shape meshes (:func:`object_elements`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .element import Element
from .geometry import box_decomposition
from .options import ScanOptions


def near_planes(pts: np.ndarray, elements: list[Element], opt: ScanOptions) -> np.ndarray:
    """(n,) bool, points within the plane distance of a plane polygon (grown by the normal
    radius): edge points whose blurred normals kept them out of the plane."""
    import shapely

    near = np.zeros(len(pts), dtype=bool)
    if len(pts) == 0:
        return near
    grow = float(opt.normal_radius_m)
    for e in elements:
        if e.kind != "plane" or e.polygon is None:
            continue
        origin, u, v = e.frame
        cand = np.flatnonzero(~near & (np.abs(pts @ e.normal - e.offset) < opt.plane_distance_m))
        if cand.size == 0:
            continue
        rel = pts[cand] - origin
        region = e.polygon.buffer(grow, join_style="mitre")
        inside = shapely.contains_xy(region, rel @ u, rel @ v)
        near[cand[inside]] = True
        e.n_points += int(inside.sum())
    return near


def object_elements(
    pts: np.ndarray, opt: ScanOptions, o3d: Any, noise: float
) -> tuple[list[Element], int]:
    """Clusters of the residual points (DBSCAN) as boxes, hulls or meshes."""
    if opt.objects == "none" or len(pts) < opt.object_min_points:
        return [], 0
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    labels = np.asarray(
        pcd.cluster_dbscan(opt.cluster_eps_m, opt.cluster_min_points, print_progress=False)
    )
    out: list[Element] = []
    n_used = 0
    if labels.size == 0 or labels.max() < 0:
        return out, 0
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(labels.max() + 2))
    for k in range(labels.max() + 1):
        idx = order[bounds[k] : bounds[k + 1]]
        if len(idx) < opt.object_min_points:
            continue
        cp = pts[idx]
        mesh = None
        if opt.objects == "hull":
            mesh = _hull_mesh(cp, opt, o3d)
        elif opt.objects == "mesh":
            mesh = _alpha_mesh(cp, opt, o3d)
        parts = [(mesh, len(idx))] if mesh is not None else box_decomposition(cp, opt, noise)
        for part, n_part in parts:
            out.append(Element("object", part, bool(part.is_watertight), n_part))
        n_used += len(idx)
    return out, n_used


def _hull_mesh(pts: np.ndarray, opt: ScanOptions, o3d: Any) -> Any:
    import trimesh

    try:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        hull, _ = pcd.compute_convex_hull()
    except RuntimeError:  # flat clusters: qhull refuses, a box is used instead
        return None
    if len(hull.triangles) > opt.max_object_triangles:
        hull = hull.simplify_quadric_decimation(opt.max_object_triangles)
    mesh = trimesh.Trimesh(np.asarray(hull.vertices), np.asarray(hull.triangles), process=True)
    if len(mesh.faces) < 4 or not mesh.is_watertight or abs(mesh.volume) < 1e-9:
        return None
    trimesh.repair.fix_normals(mesh)
    return mesh


def _alpha_mesh(pts: np.ndarray, opt: ScanOptions, o3d: Any) -> Any:
    import trimesh

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    try:
        m = o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, opt.mesh_alpha_m)
    except RuntimeError:
        return None
    if len(m.triangles) == 0:
        return None
    if len(m.triangles) > opt.max_object_triangles:
        m = m.simplify_quadric_decimation(opt.max_object_triangles)
    # quadric decimation keeps the open boundaries of an alpha shape, so it may stop short of
    # the target: then merge vertices on ever coarser grids until the budget is met
    size = 2.0 * opt.voxel_size_m
    base = m
    while len(m.triangles) > opt.max_object_triangles and size < 100.0:
        m = base.simplify_vertex_clustering(size)
        size *= 1.5
    m.remove_degenerate_triangles()
    m.remove_duplicated_triangles()
    m.remove_unreferenced_vertices()
    mesh = trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.triangles), process=True)
    # vertex clustering can leave a triangle and its reverse, or slivers: drop them
    mesh.update_faces(mesh.unique_faces() & mesh.nondegenerate_faces(height=1e-6))
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        return None
    if mesh.is_watertight:
        trimesh.repair.fix_normals(mesh)
    return mesh
