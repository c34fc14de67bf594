"""From a laser scan to a traceable scene: point cloud -> planar polygons and objects -> GLB.

Pipeline (details, options and limits in ``docs/scan.md``):

1. read the cloud (.ply, .pcd, .xyz, .pts; .las/.laz with laspy), drop non-finite points;
2. voxel downsampling, statistical outlier removal, normals (open3d);
3. planes, largest first: RANSAC (open3d ``segment_plane``) on a random subsample of the points
   not yet explained that share the dominant normal orientation, inliers by distance *and*
   normal agreement, a least-squares refit, then
   the inliers rasterised in the plane, gaps closed, split into connected pieces, each piece's
   outline traced (marching squares), small holes filled, simplified (Douglas-Peucker) -> planar
   polygons with their true outlines. Pieces smaller than ``plane_min_area_m2`` go back to the
   residual;
4. *bounding* planes (every point on one side: floor, ceiling, outer walls) are closed (holes
   filled: a scan cannot see under the machines), extended to meet each other and extruded
   outward into closed slabs of ``wall_thickness_m``; other planes become open sheets;
5. residual points near a plane polygon join it (edge points whose normals were blurred);
   the rest is clustered (DBSCAN) into objects: upright oriented boxes (a cluster a box fits
   poorly is cut in two, recursively), convex hulls or simplified alpha-shape meshes
   (decimated);
6. materials by rules (YAML, first match wins: bounding -> concrete, floor-to-ceiling ->
   concrete, by size or height, then a default), names carrying them
   (``plane_03_itu_concrete``, ``object_12_itu_metal``), written as a GLB that
   :func:`raytrace.scene.io.load_scene` binds without further input;
7. the residual distance of the points to the mesh (open3d ``RaycastingScene``).

open3d is an optional dependency (``pip install 'hallray[scan]'``); it is imported only inside
the functions that need it.

Modules: :mod:`.options` (settings, material rules), :mod:`.cloud` (reading clouds),
:mod:`.simulate` (simulated scans), :mod:`.geometry` (planes, polygons, meshes), :mod:`.element`,
:mod:`.planes` (steps 3-4), :mod:`.objects` (step 5), :mod:`.reconstruct` (steps 2-7),
:mod:`.write` (the scene and :func:`scan_to_scene`). The floor level of a scene is
:func:`raytrace.scene.facts.floor_level`.
"""

from ...scene.facts import floor_level
from .cloud import import_open3d, read_cloud
from .element import Element
from .options import (
    BOUNDING_OUTSIDE_FRACTION,
    CLOUD_SUFFIXES,
    DEFAULT_RULES,
    EDGE_MIN_COS,
    MAX_EXTENT_M,
    MAX_GRID_CELLS,
    MAX_PLANE_MISSES,
    MIN_OBJECT_THICKNESS_M,
    OBJECT_MODES,
    ORIENTATION_TOL_DEG,
    RECT_FILL,
    TIDY_GRID_M,
    MaterialRules,
    ScanOptions,
)
from .reconstruct import reconstruct
from .simulate import simulate_scan
from .write import scan_to_scene, scene_from_elements

__all__ = [
    "BOUNDING_OUTSIDE_FRACTION",
    "CLOUD_SUFFIXES",
    "DEFAULT_RULES",
    "EDGE_MIN_COS",
    "MAX_EXTENT_M",
    "MAX_GRID_CELLS",
    "MAX_PLANE_MISSES",
    "MIN_OBJECT_THICKNESS_M",
    "OBJECT_MODES",
    "ORIENTATION_TOL_DEG",
    "RECT_FILL",
    "TIDY_GRID_M",
    "Element",
    "MaterialRules",
    "ScanOptions",
    "floor_level",
    "import_open3d",
    "read_cloud",
    "reconstruct",
    "scan_to_scene",
    "scene_from_elements",
    "simulate_scan",
]
