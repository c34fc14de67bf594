"""The reconstruction of a point cloud (:func:`reconstruct`: steps 2-7 of
:mod:`raytrace.halls.scan`): cleaning and normals, planes, objects, materials by rules and
names, the residual distance of the points to the mesh, and its summary.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ...core.errors import HallrayError
from .cloud import import_open3d
from .element import Element
from .objects import near_planes, object_elements
from .options import MAX_EXTENT_M, ORIENTATION_TOL_DEG, MaterialRules, ScanOptions
from .planes import find_planes, plane_elements


def reconstruct(
    points: np.ndarray,
    options: ScanOptions | None = None,
    rules: MaterialRules | None = None,
) -> tuple[list[Element], dict[str, Any]]:
    """Planes and objects of a point cloud (steps 2-7 of the module docstring).

    Parameters
    ----------
    points : (N, 3) float, metres
    options : ScanOptions
    rules : MaterialRules (default :data:`DEFAULT_RULES`)

    Returns
    -------
    elements : list of Element, planes (largest first) then objects (largest first), named
    summary : dict, counts, triangles, residual distances, stage times (see ``docs/scan.md``)

    Raises
    ------
    HallrayError
        An empty cloud, too few points after cleaning, no plane at all.
    """
    o3d = import_open3d()
    opt = (options or ScanOptions()).resolved()
    rules = rules or MaterialRules.load()
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    pts, nrm, counts = _prepare(points, opt, o3d)  # 2. downsample, outliers, normals
    times["prepare_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    pieces = find_planes(pts, nrm, opt, o3d)  # 3. planes
    if not pieces:
        raise HallrayError(
            f"no plane found in the point cloud (none with >= {opt.plane_min_points} points "
            f"within {opt.plane_distance_m} m and >= {opt.plane_min_area_m2} m^2); "
            "is it a scan of a room?"
        )
    assigned = np.zeros(len(pts), dtype=bool)
    for piece in pieces:
        assigned[piece.members] = True
    # the scanner's noise, from the largest plane: RMS distance of its inliers
    dist0 = pts[pieces[0].members] @ pieces[0].n - pieces[0].d
    noise = float(np.sqrt(np.mean(dist0[np.abs(dist0) < opt.plane_distance_m] ** 2)))
    times["planes_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    elements = plane_elements(pieces, pts, opt)  # 4. slabs and sheets
    times["outlines_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()  # 5. residual: absorb edge points, cluster into objects
    residual = np.flatnonzero(~assigned)
    residual = residual[~near_planes(pts[residual], elements, opt)]
    objects, counts["object_points"] = object_elements(pts[residual], opt, o3d, noise)
    elements += objects
    times["objects_s"] = time.perf_counter() - t3

    _assign_materials(elements, pts, opt, rules)  # 6. materials and names

    t4 = time.perf_counter()
    dist = _distance_to_mesh(pts, elements, o3d)  # 7. residual distance
    times["residual_s"] = time.perf_counter() - t4
    times["total_s"] = time.perf_counter() - t0
    return elements, _summary(elements, counts, noise, dist, times)


def _prepare(
    points: np.ndarray, opt: ScanOptions, o3d: Any
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Step 2: finite points, voxel downsampling, statistical outlier removal, normals.
    Returns the points (n, 3) m, their unit normals (n, 3) and the point counts of the steps."""
    pts_in = np.asarray(points, dtype=float).reshape(-1, 3)
    finite = np.isfinite(pts_in).all(axis=1)
    n_in = len(pts_in)
    pts_in = pts_in[finite]
    if len(pts_in) == 0:
        raise HallrayError("the point cloud has no (finite) points")
    extent = float(np.linalg.norm(pts_in.max(axis=0) - pts_in.min(axis=0)))
    if extent > MAX_EXTENT_M:
        raise HallrayError(f"the point cloud spans {extent:.0f} m; are the coordinates in metres?")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts_in))
    down = pcd.voxel_down_sample(opt.voxel_size_m)
    n_down = len(down.points)
    if n_down > opt.outlier_neighbors:
        down, _ = down.remove_statistical_outlier(opt.outlier_neighbors, opt.outlier_std_ratio)
    pts = np.asarray(down.points, dtype=float)
    if len(pts) < max(opt.plane_min_points, 3):
        raise HallrayError(
            f"too few points after downsampling and outlier removal ({len(pts)} < plane min "
            f"points {opt.plane_min_points}); use a smaller voxel size"
        )
    down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(opt.normal_radius_m, 20))
    counts = {"input": n_in, "finite": int(finite.sum()), "downsampled": n_down}
    return pts, np.asarray(down.normals, dtype=float), counts


def _summary(
    elements: list[Element],
    counts: dict[str, int],
    noise: float,
    dist: np.ndarray,
    times: dict[str, float],
) -> dict[str, Any]:
    """The summary of :func:`reconstruct` (keys in ``docs/scan.md``)."""
    planes = [e for e in elements if e.kind == "plane"]
    n_pts = len(dist)
    mats: dict[str, int] = {}
    for e in elements:
        mats[e.material] = mats.get(e.material, 0) + 1
    return {
        "input_points": int(counts["input"]),
        "nonfinite_points_dropped": int(counts["input"] - counts["finite"]),
        "downsampled_points": int(counts["downsampled"]),
        "points_used": int(n_pts),
        "outliers_removed": int(counts["downsampled"] - n_pts),
        "planes": len(planes),
        "bounding_planes": int(sum(e.bounding for e in planes)),
        "plane_points": int(sum(e.n_points for e in planes)),
        "objects": len(elements) - len(planes),
        "object_points": int(counts["object_points"]),
        "unexplained_points": int(n_pts - sum(e.n_points for e in elements)),
        "triangles": int(sum(len(e.mesh.faces) for e in elements)),
        "noise_estimate_m": noise,
        "residual_mean_m": float(dist.mean()),
        "residual_p95_m": float(np.percentile(dist, 95)),
        "residual_max_m": float(dist.max()),
        "materials": dict(sorted(mats.items())),
        "floor_z_m": elements[0].features.get("floor_z_m") if elements else None,
        "time_s": {k: round(v, 3) for k, v in times.items()},
        "elements": [_element_summary(e) for e in elements],
    }


def _element_summary(e: Element) -> dict[str, Any]:
    """One element of the summary: name, kind, material, points, triangles, sizes (and the
    plane of a plane piece)."""
    out = {
        "name": e.name,
        "kind": e.kind,
        "material": e.material,
        "closed": e.closed,
        "bounding": e.bounding,
        "points": e.n_points,
        "triangles": int(len(e.mesh.faces)),
        "area_m2": round(e.features["area"], 4),
        "size_m": round(e.features["size"], 4),
        "volume_m3": round(e.features["volume"], 4),
    }
    if e.normal is not None:
        out["normal"] = [round(float(x), 6) for x in e.normal]
        out["offset_m"] = round(float(e.offset), 6)
    return out


def _element_features(e: Element, floor_z: float, ceiling_z: float, join_tol: float) -> dict:
    """The quantities the material rules test (see :class:`MaterialRules`)."""
    b = np.asarray(e.mesh.bounds)
    if e.kind == "plane":
        area = float(e.area_m2)
        nz = abs(float(e.normal[2]))
        tol = math.sin(math.radians(ORIENTATION_TOL_DEG))
        orientation = (
            "horizontal"
            if nz > math.cos(math.radians(ORIENTATION_TOL_DEG))
            else ("vertical" if nz < tol else "inclined")
        )
        volume = 0.0
    else:
        import shapely

        area = float(shapely.MultiPoint(e.mesh.vertices[:, :2]).convex_hull.area)
        orientation = None
        volume = float(abs(e.mesh.volume)) if e.closed else 0.0
    bottom, top = float(b[0, 2]) - floor_z, float(b[1, 2]) - floor_z
    return {
        "kind": e.kind,
        "bounding": bool(e.bounding),
        "orientation": orientation,
        "floor_to_ceiling": bool(
            bottom <= join_tol and top >= ceiling_z - floor_z - join_tol and not e.bounding
        ),
        "area": area,
        "size": float((b[1] - b[0]).max()),
        "height": float(b[1, 2] - b[0, 2]),
        "top": top,
        "bottom": bottom,
        "volume": volume,
        "floor_z_m": floor_z,
    }


def _assign_materials(
    elements: list[Element], pts: np.ndarray, opt: ScanOptions, rules: MaterialRules
) -> None:
    """Features, materials and names (planes largest first, then objects largest first)."""
    from ..spec.model import node_name

    horiz = [e for e in elements if e.kind == "plane" and e.bounding and abs(e.normal[2]) > 0.9]
    floors = [e.offset * e.normal[2] for e in horiz if e.normal[2] > 0]
    ceilings = [e.offset * e.normal[2] for e in horiz if e.normal[2] < 0]
    floor_z = float(min(floors)) if floors else float(pts[:, 2].min())
    ceiling_z = float(max(ceilings)) if ceilings else float(pts[:, 2].max())
    join_tol = max(0.2, 3.0 * opt.plane_distance_m, opt.snap_m)
    for e in elements:
        e.features = _element_features(e, floor_z, ceiling_z, join_tol)
        e.material = rules.assign(e.features)
    planes = sorted((e for e in elements if e.kind == "plane"), key=lambda e: -e.features["area"])
    objs = sorted(
        (e for e in elements if e.kind == "object"),
        key=lambda e: -(e.features["volume"] or e.features["area"]),
    )
    elements[:] = planes + objs
    for group, prefix in ((planes, "plane"), (objs, "object")):
        width = max(2, len(str(len(group))))
        for k, e in enumerate(group, start=1):
            e.name = node_name(f"{prefix}_{k:0{width}d}", e.material, rules.materials)


def _distance_to_mesh(pts: np.ndarray, elements: list[Element], o3d: Any) -> np.ndarray:
    """(N,) float, distance of every point to the nearest triangle, metres (open3d
    ``RaycastingScene.compute_distance``)."""
    scene = o3d.t.geometry.RaycastingScene()
    for e in elements:
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(e.mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(e.mesh.faces, dtype=np.uint32)),
        )
    d = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    return d.astype(float)
