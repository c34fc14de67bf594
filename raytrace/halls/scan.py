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
"""

from __future__ import annotations

import io
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import HallrayError, MaterialError, SceneError
from ..core.fileio import read_yaml, write_atomic
from ..core.palette import material_colors
from ..physics.materials import MaterialLibrary
from ..scene.facts import floor_level

#: Point-cloud formats read by :func:`read_cloud`.
CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".pts", ".las", ".laz")
#: Object representations of the clusters left after plane extraction.
OBJECT_MODES = ("box", "hull", "mesh", "none")
#: A plane is horizontal when its normal is within this angle of vertical (deg); the same angle
#: from horizontal makes it vertical. Used by the material rules and for the slab joints.
ORIENTATION_TOL_DEG = 10.0
#: A plane is *bounding* when at most this fraction of the points lies beyond it (on the far side
#: by more than 3 plane distances): the floor, the ceiling, the outer walls.
BOUNDING_OUTSIDE_FRACTION = 1e-3
#: Consecutive RANSAC planes rejected (too small or scattered) before the search stops.
MAX_PLANE_MISSES = 30
#: Points near a plane's edge join its outline unless their normals are this close to
#: perpendicular to it (|cos| below): clean normals of another surface running past the edge.
EDGE_MIN_COS = 0.2
#: A plane piece filling at least this share of its (spur-free) minimum rotated rectangle is
#: taken to be that rectangle.
RECT_FILL = 0.9
#: A cloud larger than this (bounding-box diagonal, m) is refused: not metres, or not a hall.
MAX_EXTENT_M = 5000.0
#: Largest raster (cells) for one plane's outline: a 500 m x 500 m plane at 0.1 m.
MAX_GRID_CELLS = 25_000_000
#: Polygons are snapped to this grid before triangulation, m.
TIDY_GRID_M = 1e-4
#: Smallest dimension given to a box or slab made from a flat cluster, m.
MIN_OBJECT_THICKNESS_M = 0.02
#: Default material rules (``docs/scan.md``).
DEFAULT_RULES: dict[str, Any] = {
    "rules": [
        {"bounding": True, "material": "concrete"},
        {"floor_to_ceiling": True, "material": "concrete"},
    ],
    "default": "metal",
}

_ORIENTATIONS = ("horizontal", "vertical", "inclined")
_RULE_RANGE_KEYS = ("area", "size", "height", "top", "bottom", "volume")
_RULE_KEYS = (
    ("kind", "bounding", "orientation", "floor_to_ceiling", "material")
    + tuple(f"min_{k}" for k in _RULE_RANGE_KEYS)
    + tuple(f"max_{k}" for k in _RULE_RANGE_KEYS)
)


# --------------------------------------------------------------------------------------------
# options and material rules
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MaterialRules:
    """Material assignment by rules: the first rule whose conditions all hold gives the material.

    Conditions (all optional) on an element (a plane piece or an object):
    ``kind`` (``plane`` or ``object``), ``bounding`` (bool), ``orientation`` (planes:
    ``horizontal``, ``vertical``, ``inclined``), ``floor_to_ceiling`` (bool: bottom at the floor
    and top at the ceiling, within the join tolerance), and ``min_``/``max_`` bounds on ``area``
    (m^2: polygon area of a plane, footprint of an object), ``size`` (m, largest extent),
    ``height`` (m, vertical extent), ``top``, ``bottom`` (m above the floor), ``volume`` (m^3,
    objects; 0 for planes).

    Attributes
    ----------
    rules : tuple of dict, each with ``material`` and conditions
    default : str, the material when no rule matches
    materials : dict, user materials in the material YAML format (stored in the GLB's metadata)
    library : MaterialLibrary, the ITU materials plus the user ones
    """

    rules: tuple[dict[str, Any], ...]
    default: str
    materials: dict[str, Any] = field(default_factory=dict)
    library: MaterialLibrary = field(default_factory=MaterialLibrary.itu, repr=False)

    @classmethod
    def load(
        cls, source: str | os.PathLike[str] | Mapping[str, Any] | None = None
    ) -> MaterialRules:
        """Rules from a YAML file or mapping (``materials``, ``rules``, ``default``); the built-in
        :data:`DEFAULT_RULES` when ``source`` is None. Raises :class:`MaterialError` (one line)."""

        if source is None:
            data: Any = DEFAULT_RULES
            origin = "default rules"
        elif isinstance(source, Mapping):
            data, origin = source, "rules"
        else:
            p = Path(source)
            origin = p.name
            data = read_yaml(p, "material rules file", MaterialError)
        if not isinstance(data, Mapping):
            raise MaterialError(f"{origin}: expected a mapping with 'rules' and 'default'")
        unknown = sorted(set(map(str, data)) - {"materials", "rules", "default"})
        if unknown:
            raise MaterialError(
                f"{origin}: unknown key(s) {', '.join(unknown)} (allowed: materials, rules, default)"
            )
        user = dict(data.get("materials") or {})
        library = MaterialLibrary.itu()
        if user:
            library = library.with_yaml({"materials": user})
        default = data.get("default", "metal")
        if not isinstance(default, str) or default not in library:
            raise MaterialError(f"{origin}: default: unknown material {default!r}")
        raw_rules = data.get("rules") or []
        if not isinstance(raw_rules, list):
            raise MaterialError(f"{origin}: 'rules' must be a list")
        rules = []
        for k, rule in enumerate(raw_rules):
            rules.append(_check_rule(rule, f"{origin}: rules[{k}]", library))
        return cls(tuple(rules), default, user, library)

    def assign(self, features: Mapping[str, Any]) -> str:
        """Material of an element with ``features`` (see :func:`_element_features`)."""
        for rule in self.rules:
            if _rule_matches(rule, features):
                return str(rule["material"])
        return self.default


def _check_rule(rule: Any, where: str, library: MaterialLibrary) -> dict[str, Any]:
    if not isinstance(rule, Mapping):
        raise MaterialError(f"{where}: expected a mapping, got {rule!r}")
    for key in rule:
        if key not in _RULE_KEYS:
            raise MaterialError(
                f"{where}: unknown condition '{key}' (allowed: {', '.join(_RULE_KEYS)})"
            )
    mat = rule.get("material")
    if not isinstance(mat, str) or mat not in library:
        raise MaterialError(f"{where}: material: unknown material {mat!r}")
    if "kind" in rule and rule["kind"] not in ("plane", "object"):
        raise MaterialError(f"{where}: kind must be 'plane' or 'object', got {rule['kind']!r}")
    if "orientation" in rule and rule["orientation"] not in _ORIENTATIONS:
        raise MaterialError(
            f"{where}: orientation must be one of {', '.join(_ORIENTATIONS)}, "
            f"got {rule['orientation']!r}"
        )
    for key in ("bounding", "floor_to_ceiling"):
        if key in rule and not isinstance(rule[key], bool):
            raise MaterialError(f"{where}: {key} must be true or false, got {rule[key]!r}")
    for key in rule:
        if key.startswith(("min_", "max_")):
            val = rule[key]
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise MaterialError(f"{where}: {key} must be a number, got {val!r}")
    return dict(rule)


def _rule_matches(rule: Mapping[str, Any], feat: Mapping[str, Any]) -> bool:
    for key, want in rule.items():
        if key == "material":
            continue
        if key.startswith("min_"):
            if not feat[key[4:]] >= want:
                return False
        elif key.startswith("max_"):
            if not feat[key[4:]] <= want:
                return False
        elif feat.get(key) != want:
            return False
    return True


@dataclass(frozen=True)
class ScanOptions:
    """Settings of :func:`scan_to_scene` (the fidelity / triangle-count trade-off).

    Attributes
    ----------
    voxel_size_m : voxel downsampling size, m; sets the scale of everything else by default
    outlier_neighbors, outlier_std_ratio : statistical outlier removal (open3d)
    normal_radius_m : normal estimation radius, m (default 3 voxels)
    plane_distance_m : RANSAC inlier distance, m (about 2.5 x the scanner's noise)
    plane_normal_deg : a point joins a plane only if its normal is within this angle, degrees
    plane_min_points : smallest plane (points after downsampling)
    plane_min_area_m2 : smallest plane piece kept as a polygon, m^2
    max_planes : at most this many RANSAC planes
    ransac_iterations : RANSAC iterations per plane
    ransac_sample : RANSAC runs on at most this many random points (inliers use all)
    grid_cell_m : raster cell for plane outlines, m (default one voxel)
    close_gaps_m : gaps narrower than this in a plane are closed, m
    max_hole_area_m2 : holes smaller than this in non-bounding planes are filled, m^2
    simplify_m : outline simplification tolerance, m (default 1.5 voxels)
    snap_m : bounding planes are grown by this much, then cut where they meet, m
    hidden_fill_m : unseen strips of a bounding plane (under or behind things along a wall) are
        filled where no disc of this radius fits in them, m
    wall_thickness_m : bounding planes become closed slabs this thick (0: open sheets), m
    cluster_eps_m : DBSCAN neighbourhood of the residual points, m (default 3 voxels)
    cluster_min_points : DBSCAN core-point count
    object_min_points : smallest cluster turned into an object
    objects : ``box`` (upright oriented boxes), ``hull`` (convex hull), ``mesh`` (alpha shape,
        decimated) or ``none``
    box_fill : a cluster whose box is filled less than this (height map volume / box volume) is
        cut in two, recursively
    max_box_depth : at most this many levels of cuts (up to 2**depth boxes per cluster)
    mesh_alpha_m : alpha of the alpha shapes, m (default 4 voxels)
    max_object_triangles : decimation target per object (``mesh``) and cap for ``hull``
    seed : seed of the random subsamples and of open3d's RANSAC
    """

    voxel_size_m: float = 0.1
    outlier_neighbors: int = 20
    outlier_std_ratio: float = 2.5
    normal_radius_m: float | None = None
    plane_distance_m: float = 0.05
    plane_normal_deg: float = 30.0
    plane_min_points: int = 200
    plane_min_area_m2: float = 1.0
    max_planes: int = 200
    ransac_iterations: int = 300
    ransac_sample: int = 20_000
    grid_cell_m: float | None = None
    close_gaps_m: float = 0.2
    max_hole_area_m2: float = 1.0
    simplify_m: float | None = None
    snap_m: float = 0.5
    hidden_fill_m: float = 3.0
    wall_thickness_m: float = 0.3
    cluster_eps_m: float | None = None
    cluster_min_points: int = 10
    object_min_points: int = 30
    objects: str = "box"
    box_fill: float = 0.5
    max_box_depth: int = 4
    mesh_alpha_m: float | None = None
    max_object_triangles: int = 200
    seed: int = 0

    def resolved(self) -> ScanOptions:
        """A copy with the defaults that depend on the voxel size filled in, validated."""
        v = self.voxel_size_m
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise HallrayError(f"voxel size must be > 0 m, got {v}")
        out = replace(
            self,
            normal_radius_m=self.normal_radius_m or 3.0 * v,
            grid_cell_m=self.grid_cell_m or v,
            simplify_m=self.simplify_m if self.simplify_m is not None else 1.5 * v,
            cluster_eps_m=self.cluster_eps_m or 3.0 * v,
            mesh_alpha_m=self.mesh_alpha_m or 4.0 * v,
        )
        positive = (
            "normal_radius_m",
            "plane_distance_m",
            "plane_normal_deg",
            "grid_cell_m",
            "cluster_eps_m",
            "mesh_alpha_m",
            "outlier_std_ratio",
        )
        for name in positive:
            val = getattr(out, name)
            if not (math.isfinite(val) and val > 0):
                raise HallrayError(f"{name.replace('_', ' ')} must be > 0, got {val}")
        nonneg = (
            "plane_min_area_m2",
            "close_gaps_m",
            "max_hole_area_m2",
            "simplify_m",
            "snap_m",
            "hidden_fill_m",
            "wall_thickness_m",
        )
        for name in nonneg:
            val = getattr(out, name)
            if not (math.isfinite(val) and val >= 0):
                raise HallrayError(f"{name.replace('_', ' ')} must be >= 0, got {val}")
        ints = (
            "outlier_neighbors",
            "plane_min_points",
            "max_planes",
            "ransac_iterations",
            "ransac_sample",
            "cluster_min_points",
            "object_min_points",
            "max_object_triangles",
        )
        for name in ints:
            val = getattr(out, name)
            if int(val) != val or val < 1:
                raise HallrayError(f"{name.replace('_', ' ')} must be an integer >= 1, got {val}")
        if out.plane_min_points < 3:
            raise HallrayError("plane min points must be >= 3")
        if out.plane_normal_deg >= 90:
            raise HallrayError(f"plane normal angle must be < 90 deg, got {out.plane_normal_deg}")
        if out.objects not in OBJECT_MODES:
            raise HallrayError(
                f"objects must be one of {', '.join(OBJECT_MODES)}, got {out.objects!r}"
            )
        return out


# --------------------------------------------------------------------------------------------
# reading clouds
# --------------------------------------------------------------------------------------------


def _open3d() -> Any:
    """Import open3d or raise a one-line :class:`HallrayError` saying how to get it."""
    try:
        import open3d as o3d
    except (ImportError, OSError) as exc:
        raise HallrayError(
            "scan-to-scene needs open3d: pip install 'hallray[scan]' (on Debian/Ubuntu also "
            f"apt-get install libusb-1.0-0); import failed: {exc}".splitlines()[0]
        ) from None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def read_cloud(path: str | os.PathLike[str]) -> np.ndarray:
    """Points of a point-cloud file.

    Parameters
    ----------
    path : .ply or .pcd (read with open3d), .xyz (``x y z [...]`` per line), .pts (optional count
        line, then ``x y z [intensity r g b]``), .las / .laz (with laspy; .laz also needs a LAZ
        backend such as lazrs)

    Returns
    -------
    (N, 3) float64, metres (non-finite rows included; :func:`reconstruct` drops them)

    Raises
    ------
    HallrayError
        Missing file, unknown format, a file that is not a point cloud, an empty cloud.
    """
    p = Path(path)
    if not p.is_file():
        raise HallrayError(f"point cloud not found: {path}")
    suffix = p.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise HallrayError(
            f"unsupported point-cloud format {suffix or '(none)'!r} for {p.name}; "
            f"use one of {', '.join(CLOUD_SUFFIXES)}"
        )
    if suffix in (".xyz", ".pts"):
        pts = _read_text_cloud(p, skip_count=suffix == ".pts")
    elif suffix in (".las", ".laz"):
        pts = _read_las(p)
    else:
        pts = _read_open3d_cloud(p, suffix)
    if len(pts) == 0:
        raise HallrayError(f"point cloud {p.name} has no points")
    return pts


def _read_text_cloud(p: Path, *, skip_count: bool) -> np.ndarray:
    try:
        text = p.read_text()
    except UnicodeDecodeError:
        raise HallrayError(f"{p.name} is not a text point cloud (binary content)") from None
    lines = text.splitlines()
    start = 0
    # a .pts file starts with the number of points on a line of its own
    while start < len(lines) and not lines[start].strip():
        start += 1
    if skip_count and start < len(lines) and len(lines[start].split()) == 1:
        start += 1
    body = "\n".join(ln for ln in lines[start:] if ln.strip() and not ln.lstrip().startswith("#"))
    if not body:
        return np.zeros((0, 3))
    try:
        data = np.loadtxt(io.StringIO(body.replace(",", " ")), ndmin=2, usecols=(0, 1, 2))
    except (ValueError, IndexError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HallrayError(f"{p.name} is not a point cloud (x y z per line): {first}") from None
    return np.asarray(data, dtype=float)


def _read_open3d_cloud(p: Path, suffix: str) -> np.ndarray:
    with open(p, "rb") as fh:
        head = fh.read(4096)
    if suffix == ".ply" and not head.startswith(b"ply"):
        raise HallrayError(f"{p.name} is not a PLY file (no 'ply' header)")
    if suffix == ".pcd" and (b"FIELDS" not in head or b"DATA" not in head):
        raise HallrayError(f"{p.name} is not a PCD point cloud (no FIELDS/DATA header)")
    o3d = _open3d()
    cloud = o3d.io.read_point_cloud(str(p))
    pts = np.asarray(cloud.points, dtype=float).reshape(-1, 3)
    if len(pts) == 0 and b"element vertex 0" not in head and b"POINTS 0" not in head:
        raise HallrayError(f"cannot read points from {p.name} (damaged or not a point cloud)")
    return pts


def _read_las(p: Path) -> np.ndarray:
    try:
        import laspy
    except ImportError:
        raise HallrayError(f"reading {p.name} needs laspy: pip install laspy") from None
    try:
        las = laspy.read(str(p))
    except Exception as exc:  # laspy raises many types (LaspyException, ValueError, OSError)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HallrayError(f"cannot read {p.name}: {first}") from None
    return np.column_stack([las.x, las.y, las.z]).astype(float)


# --------------------------------------------------------------------------------------------
# simulated scans (tests, benchmarks, trying the pipeline on a known scene)
# --------------------------------------------------------------------------------------------


def simulate_scan(
    scene: Any,
    n_points: int,
    *,
    stations: np.ndarray | None = None,
    noise_m: float = 0.02,
    n_gaps: int = 0,
    gap_radius_m: float = 0.25,
    seed: int = 0,
) -> np.ndarray:
    """A synthetic terrestrial laser scan of a :class:`~raytrace.scene.model.Scene`.

    Points are drawn uniformly over the triangles (``trimesh.sample``); a point is kept when at
    least one scanner station sees it (an Embree segment test), which removes the outer faces of
    the shell and leaves realistic occlusion shadows; then ``n_gaps`` spheres of
    ``gap_radius_m`` around random kept points are cut out (drop-outs) and Gaussian noise of
    ``noise_m`` (standard deviation per coordinate) is added.

    Parameters
    ----------
    scene : Scene
    n_points : int, points drawn before the visibility test
    stations : (S, 3) float, scanner positions, metres; default a 4 x 4 grid over the middle
        70 % of the scene's bounding box at 1.6 m above its floor, those inside solids dropped
    noise_m, n_gaps, gap_radius_m, seed : see above

    Returns
    -------
    (N, 3) float64, metres, N <= n_points
    """
    import trimesh

    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds
    if stations is None:
        gx = np.linspace(lo[0] + 0.15 * (hi[0] - lo[0]), hi[0] - 0.15 * (hi[0] - lo[0]), 4)
        gy = np.linspace(lo[1] + 0.15 * (hi[1] - lo[1]), hi[1] - 0.15 * (hi[1] - lo[1]), 4)
        z0 = floor_level(scene) + 1.6
        stations = np.array([[x, y, z0] for x in gx for y in gy])
        stations = stations[scene.inside_solid(stations) < 0]
    stations = np.asarray(stations, dtype=float).reshape(-1, 3)
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, int(n_points), seed=int(rng.integers(2**31)))
    pts = np.asarray(pts, dtype=float)
    seen = np.zeros(len(pts), dtype=bool)
    for s in stations:
        idx = np.flatnonzero(~seen)
        if idx.size == 0:
            break
        seen[idx] = ~scene.occluded(np.broadcast_to(s, (idx.size, 3)), pts[idx])
    pts = pts[seen]
    if n_gaps > 0 and len(pts):
        from scipy.spatial import cKDTree

        centres = pts[rng.choice(len(pts), size=min(n_gaps, len(pts)), replace=False)]
        near = cKDTree(centres).query(pts, distance_upper_bound=gap_radius_m)[0]
        pts = pts[~np.isfinite(near)]
    return pts + rng.normal(0.0, noise_m, size=pts.shape)


# --------------------------------------------------------------------------------------------
# geometry helpers
# --------------------------------------------------------------------------------------------


def _plane_frame(n: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origin (3,) and in-plane axes u, v (3,) of the plane ``n . x = d``: u along x for a
    horizontal plane, v vertical for any other, so outlines of upright objects are aligned."""
    n = n / np.linalg.norm(n)
    if abs(n[2]) > 0.9:
        u = np.array([1.0, 0.0, 0.0]) - n[0] * n
    else:
        v = np.array([0.0, 0.0, 1.0]) - n[2] * n
        v /= np.linalg.norm(v)
        u = np.cross(v, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return n * d, u, v


def _reframe(poly: Any, old: tuple[np.ndarray, float], new: tuple[np.ndarray, float]) -> Any:
    """A polygon traced in the frame of plane ``old`` = (n, d), projected onto plane ``new`` and
    expressed in its frame (after a refit the plane moves a little)."""
    import shapely

    o0, u0, v0 = _plane_frame(*old)
    o1, u1, v1 = _plane_frame(*new)

    def move(ab: np.ndarray) -> np.ndarray:
        x = o0 + ab[:, :1] * u0 + ab[:, 1:] * v0
        return np.column_stack([(x - o1) @ u1, (x - o1) @ v1])

    out = shapely.transform(poly, move)
    return out if out.is_valid else shapely.make_valid(out)


def _fit_plane(pts: np.ndarray, n_hint: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal on the side of ``n_hint``, offset) through points."""
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[2]
    if n @ n_hint < 0:
        n = -n
    return n, float(n @ c)


def _polygons_from_mask(mask: np.ndarray, lo: np.ndarray, cell: float) -> list[Any]:
    """Shapely polygons (with holes) of a boolean raster (rows along v, columns along u) whose
    cell (i, j) has its centre at ``lo + (j + 0.5, i + 0.5) * cell``: marching squares at 0.5,
    which runs along the outer boundary of the occupied cells."""
    import contourpy
    import shapely

    m = np.pad(mask, 1).astype(float)
    xs = lo[0] + (np.arange(m.shape[1]) - 0.5) * cell
    ys = lo[1] + (np.arange(m.shape[0]) - 0.5) * cell
    gen = contourpy.contour_generator(xs, ys, m, fill_type="OuterOffset", corner_mask=False)
    points, offsets = gen.filled(0.5, 2.0)
    polys = []
    for pts, off in zip(points, offsets):
        rings = [pts[off[k] : off[k + 1]] for k in range(len(off) - 1)]
        if not rings or len(rings[0]) < 4:
            continue
        poly = shapely.Polygon(rings[0], [r for r in rings[1:] if len(r) >= 4])
        if not poly.is_valid:
            poly = shapely.make_valid(poly)
        polys.extend(_polygon_parts(poly))
    return polys


def _polygon_parts(geom: Any) -> list[Any]:
    """The polygons of a shapely geometry (Polygon, MultiPolygon, collection)."""
    if geom is None or geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    if hasattr(geom, "geoms"):
        return [p for g in geom.geoms for p in _polygon_parts(g)]
    return []


def _clean_polygon(poly: Any, *, fill_all: bool, max_hole_area: float, simplify: float) -> Any:
    """Fill holes (all, or those smaller than ``max_hole_area``), simplify, make valid."""
    import shapely

    holes = (
        [] if fill_all else [h for h in poly.interiors if shapely.Polygon(h).area > max_hole_area]
    )
    out = shapely.Polygon(poly.exterior, holes)
    if simplify > 0:
        out = out.simplify(simplify, preserve_topology=True)
    if not out.is_valid:
        out = shapely.make_valid(out)
    return out


def _tidy(poly: Any) -> Any:
    """A polygon ready to triangulate: vertices on a 0.1 mm grid, nearly collinear vertices
    (within 0.1 mm) removed, so that no sliver triangle (which the scene loader would drop as
    degenerate, opening a closed slab) comes out."""
    import shapely

    out = shapely.set_precision(poly, TIDY_GRID_M)
    out = out.simplify(TIDY_GRID_M, preserve_topology=True)
    parts = _polygon_parts(out)
    return max(parts, key=lambda p: p.area) if parts else shapely.Polygon()


def _rectangle_fit(poly: Any, cell: float) -> Any:
    """The polygon's rectangle when it is one (raster outlines zig-zag by a cell along straight
    edges): the minimum rotated rectangle of the polygon opened by 1.5 cells (spurs gone), if
    the polygon fills at least RECT_FILL of it; otherwise the polygon itself."""
    if len(poly.interiors):
        return poly
    opened = poly.buffer(-1.5 * cell, join_style="mitre").buffer(1.5 * cell, join_style="mitre")
    if opened.is_empty or opened.geom_type != "Polygon":
        return poly
    rect = opened.minimum_rotated_rectangle
    if rect.geom_type != "Polygon" or poly.area < RECT_FILL * rect.area:
        return poly
    return rect


def _triangulate(poly: Any) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay triangulation of a polygon (with holes): vertices (V, 2) and
    counter-clockwise faces (F, 3), vertices shared (exactly the polygon's vertices)."""
    import shapely

    tris = shapely.constrained_delaunay_triangles(poly)
    coords = [np.asarray(t.exterior.coords)[:3] for t in _polygon_parts(tris)]
    if not coords:
        return np.zeros((0, 2)), np.zeros((0, 3), dtype=np.int64)
    c = np.stack(coords)  # (F, 3, 2)
    verts, inv = np.unique(c.reshape(-1, 2), axis=0, return_inverse=True)
    faces = inv.reshape(-1, 3).astype(np.int64)
    # counter-clockwise in (u, v): the face normal is +n
    e1 = verts[faces[:, 1]] - verts[faces[:, 0]]
    e2 = verts[faces[:, 2]] - verts[faces[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    faces[cw] = faces[cw][:, ::-1]
    return verts, faces


def _sheet_mesh(poly: Any, origin: np.ndarray, u: np.ndarray, v: np.ndarray) -> Any:
    """An open, flat mesh of a polygon lying in the plane (origin, u, v)."""
    import trimesh

    v2, f = _triangulate(_tidy(poly))
    v3 = origin + v2[:, :1] * u + v2[:, 1:] * v
    return trimesh.Trimesh(v3, f, process=True)


def _slab_mesh(poly: Any, origin: np.ndarray, u: np.ndarray, v: np.ndarray, t: np.ndarray) -> Any:
    """A closed slab: the polygon in the plane (origin, u, v) extruded by the vector ``t``."""
    import trimesh

    poly = _tidy(poly)
    v2, f = _triangulate(poly)
    top = origin + v2[:, :1] * u + v2[:, 1:] * v
    nv = len(v2)
    faces = [f[:, ::-1], f + nv]  # base faces away from t, the far cap towards t (fixed below)
    lookup = {tuple(p): i for i, p in enumerate(v2)}
    rings = [poly.exterior, *poly.interiors]
    for ring in rings:
        rc = np.asarray(ring.coords)[:-1]
        idx = np.array([lookup[tuple(p)] for p in rc])
        a, b = idx, np.roll(idx, -1)
        faces.append(np.column_stack([a, b, b + nv]))
        faces.append(np.column_stack([a, b + nv, a + nv]))
    mesh = trimesh.Trimesh(np.vstack([top, top + t]), np.vstack(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _half_plane(g: np.ndarray, c0: float, bounds: tuple[float, float, float, float]) -> Any:
    """The half-plane ``g . x + c0 >= 0`` clipped to a generous square around ``bounds``."""
    import shapely

    x0, y0, x1, y1 = bounds
    size = 10.0 * max(x1 - x0, y1 - y0, 1.0) + 100.0
    gn = g / np.linalg.norm(g)
    p0 = -c0 * g / (g @ g)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    p0 = p0 + (centre - p0) - ((centre - p0) @ gn) * gn  # foot of the centre on the line
    tdir = np.array([-gn[1], gn[0]])
    corners = [
        p0 - size * tdir,
        p0 + size * tdir,
        p0 + size * tdir + size * gn,
        p0 - size * tdir + size * gn,
    ]
    return shapely.Polygon(corners)


def _box_mesh(rect_xy: np.ndarray, z0: float, z1: float) -> Any:
    """Closed upright box over a rectangle (4, 2) from z0 to z1."""
    import trimesh

    v = np.vstack(
        [np.column_stack([rect_xy, np.full(4, z0)]), np.column_stack([rect_xy, np.full(4, z1)])]
    )
    f = np.array(
        [
            [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7],
            [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
            [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
        ]
    )  # fmt: skip
    mesh = trimesh.Trimesh(v, f, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _upright_box(pts: np.ndarray, min_thickness: float) -> tuple[np.ndarray, float, float]:
    """Minimum-area rectangle of the points seen from above (4, 2), grown to ``min_thickness``,
    and the z range."""
    import shapely

    z0, z1 = float(pts[:, 2].min()), float(pts[:, 2].max())
    if z1 - z0 < min_thickness:
        zc = 0.5 * (z0 + z1)
        z0, z1 = zc - 0.5 * min_thickness, zc + 0.5 * min_thickness
    hull = shapely.MultiPoint(pts[:, :2]).convex_hull
    rect = hull.minimum_rotated_rectangle if hull.geom_type == "Polygon" else None
    if rect is None or rect.geom_type != "Polygon":
        # collinear or a single point: a thin rectangle along the points' main direction
        xy = pts[:, :2]
        c = xy.mean(axis=0)
        d = xy - c
        if np.allclose(d, 0):
            axis = np.array([1.0, 0.0])
        else:
            axis = np.linalg.svd(d, full_matrices=False)[2][0]
        s = d @ axis
        lo_, hi_ = min(s.min(), -0.5 * min_thickness), max(s.max(), 0.5 * min_thickness)
        perp = np.array([-axis[1], axis[0]]) * 0.5 * min_thickness
        corners = np.array(
            [
                c + lo_ * axis - perp,
                c + hi_ * axis - perp,
                c + hi_ * axis + perp,
                c + lo_ * axis + perp,
            ]
        )
        return corners, z0, z1
    corners = np.asarray(rect.exterior.coords)[:4]
    # grow thin sides to min_thickness
    e1, e2 = corners[1] - corners[0], corners[3] - corners[0]
    c = corners.mean(axis=0)
    out = []
    l1, l2 = np.linalg.norm(e1), np.linalg.norm(e2)
    a1 = e1 / l1 * max(l1, min_thickness) / 2
    a2 = e2 / l2 * max(l2, min_thickness) / 2
    for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        out.append(c + s1 * a1 + s2 * a2)
    return np.array(out), z0, z1


def _fit_box_sides(
    pts: np.ndarray, rect: np.ndarray, noise: float, thick: float
) -> tuple[np.ndarray, float, float]:
    """An upright box in the frame of ``rect`` (4, 2) with each side at the median of the points
    within four noise deviations of the outermost one: on a scanned face that is the face
    itself (the outermost points lie about two deviations beyond it), at an edge seen only
    from one side about the edge. Returns the footprint (4, 2) and the z range, no side
    shorter than ``thick``."""
    c = rect.mean(axis=0)
    e1, e2 = rect[1] - rect[0], rect[3] - rect[0]
    a1, a2 = e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)
    coords = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2, pts[:, 2]])
    band = 4.0 * max(noise, 0.005)
    lo, hi = np.empty(3), np.empty(3)
    for k in range(3):
        x = coords[:, k]
        lo[k] = np.median(x[x < x.min() + band])
        hi[k] = np.median(x[x > x.max() - band])
        if hi[k] - lo[k] < thick:
            mid = 0.5 * (lo[k] + hi[k])
            lo[k], hi[k] = mid - 0.5 * thick, mid + 0.5 * thick
    corners = [c + lo[0] * a1 + lo[1] * a2, c + hi[0] * a1 + lo[1] * a2]
    corners += [c + hi[0] * a1 + hi[1] * a2, c + lo[0] * a1 + hi[1] * a2]
    return np.array(corners), float(lo[2]), float(hi[2])


def _height_fill(
    pts: np.ndarray, frame: tuple[np.ndarray, np.ndarray, np.ndarray], cell: float
) -> float:
    """How much of an upright box the points explain: the volume under their height map (the
    highest point per footprint cell) over the box volume. ``frame`` is (centre (2,), axis a1
    (2,), axis a2 (2,)) of the box footprint. Cells without points count as empty, also when
    enclosed: a fence around a robot cell is not a solid block (a cabinet seen only from its
    sides comes out as its sides, which block the same rays)."""
    c, a1, a2 = frame
    st = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2])
    z0, z1 = pts[:, 2].min(), pts[:, 2].max()
    lo = st.min(axis=0)
    ij = np.floor((st - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), pts[:, 2])
    height = np.where(np.isfinite(top), top, z0) - z0
    extent = (st.max(axis=0) - lo).clip(min=cell)
    box = extent[0] * extent[1] * max(z1 - z0, cell)
    return float(min(1.0, height.sum() * cell * cell / box))


def _box_decomposition(
    pts: np.ndarray, opt: ScanOptions, noise: float, depth: int = 0
) -> list[tuple[Any, int]]:
    """Upright boxes for a cluster: one box, or, when it explains the points poorly (a height-map
    fill below ``box_fill``), the cluster cut in two where the two child boxes are smallest
    (along either footprint axis or in height), recursively up to ``max_box_depth`` levels.
    Returns (box mesh, number of points) pairs; sibling boxes do not overlap."""
    thick = max(MIN_OBJECT_THICKNESS_M, 0.5 * opt.voxel_size_m)
    rect, z0, z1 = _upright_box(pts, thick)
    whole = [(_box_mesh(*_fit_box_sides(pts, rect, noise, thick)), len(pts))]
    if depth >= opt.max_box_depth or len(pts) < 2 * opt.object_min_points:
        return whole
    c = rect.mean(axis=0)
    e1, e2 = rect[1] - rect[0], rect[3] - rect[0]
    a1, a2 = e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)
    if _height_fill(pts, (c, a1, a2), float(opt.grid_cell_m)) >= opt.box_fill:
        return whole
    coords = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2, pts[:, 2]])
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    parent = float(np.prod((hi - lo).clip(min=thick)))
    best: tuple[float, np.ndarray] | None = None
    for axis in range(3):
        for q in np.linspace(0.0, 1.0, 18)[1:-1]:
            left = coords[:, axis] < lo[axis] + q * (hi[axis] - lo[axis])
            n_left = int(left.sum())
            if min(n_left, len(pts) - n_left) < opt.object_min_points:
                continue
            vol = 0.0
            for side in (left, ~left):
                sub = coords[side]
                vol += float(np.prod((sub.max(axis=0) - sub.min(axis=0)).clip(min=thick)))
            if best is None or vol < best[0]:
                best = (vol, left)
    if best is None or best[0] > 0.9 * parent:
        return whole
    left = best[1]
    return _box_decomposition(pts[left], opt, noise, depth + 1) + _box_decomposition(
        pts[~left], opt, noise, depth + 1
    )


# --------------------------------------------------------------------------------------------
# the reconstruction
# --------------------------------------------------------------------------------------------


@dataclass
class Element:
    """One reconstructed element: a plane piece or an object.

    Attributes
    ----------
    kind : ``plane`` or ``object``
    mesh : trimesh.Trimesh, world coordinates, metres
    closed : bool, a closed solid (slab, box, hull) rather than an open sheet
    material : str
    name : str, node name carrying the material (set when written)
    n_points : int, points explained
    normal, offset : plane ``normal . x = offset`` (planes; normal towards the points)
    bounding : bool, every point on one side (floor, ceiling, outer walls)
    features : dict, the quantities the material rules test
    """

    kind: str
    mesh: Any
    closed: bool
    n_points: int
    normal: np.ndarray | None = None
    offset: float | None = None
    bounding: bool = False
    area_m2: float = 0.0
    polygon: Any = None
    frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    material: str = ""
    name: str = ""
    features: dict[str, Any] = field(default_factory=dict)


@dataclass
class _PlanePiece:
    n: np.ndarray
    d: float
    polygons: list[Any]  # in the plane frame (u, v)
    members: np.ndarray  # point indices
    bounding: bool


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
    o3d = _open3d()
    opt = (options or ScanOptions()).resolved()
    rules = rules or MaterialRules.load()
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    pts, nrm, counts = _prepare(points, opt, o3d)  # 2. downsample, outliers, normals
    times["prepare_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    pieces = _find_planes(pts, nrm, opt, o3d)  # 3. planes
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
    elements = _plane_elements(pieces, pts, opt)  # 4. slabs and sheets
    times["outlines_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()  # 5. residual: absorb edge points, cluster into objects
    residual = np.flatnonzero(~assigned)
    residual = residual[~_near_planes(pts[residual], elements, opt)]
    objects, counts["object_points"] = _object_elements(pts[residual], opt, o3d, noise)
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


def _find_planes(pts: np.ndarray, nrm: np.ndarray, opt: ScanOptions, o3d: Any) -> list[_PlanePiece]:
    """RANSAC planes, largest first, split into connected pieces (see the module docstring)."""
    rng = np.random.default_rng(opt.seed)
    o3d.utility.random.seed(int(opt.seed))
    pool = np.ones(len(pts), dtype=bool)
    pieces: list[_PlanePiece] = []
    misses = 0
    n_planes = 0
    while n_planes < opt.max_planes and misses < MAX_PLANE_MISSES:
        idx = np.flatnonzero(pool)
        if len(idx) < opt.plane_min_points:
            break
        plane = _ransac_plane(pts, nrm, idx, opt, o3d, rng)
        if plane is None:
            break
        n, d, members, tried = plane
        if len(members) < opt.plane_min_points:
            # too small: take these points out of the search (they stay in the residual)
            pool[members] = False
            pool[tried] = False
            misses += 1
            continue
        pool[members] = False
        found = _split_plane(pts, nrm, members, n, d, opt)
        if not found:
            misses += 1
            continue
        misses = 0
        n_planes += 1
        pieces += _plane_pieces(pts, nrm, pool, (n, d), found, opt)
    # largest first (total polygon area)
    pieces.sort(key=lambda p: -sum(q.area for q in p.polygons))
    return pieces


def _ransac_plane(
    pts: np.ndarray,
    nrm: np.ndarray,
    idx: np.ndarray,
    opt: ScanOptions,
    o3d: Any,
    rng: np.random.Generator,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray] | None:
    """One RANSAC plane among the points ``idx`` still free: ``(n, d, members, tried)`` with
    the unit normal and offset of ``n . x = d`` after a least-squares refit, its inliers by
    distance and normal agreement, and RANSAC's own inliers (to take out of the search when the
    plane is too small); None when RANSAC returns no plane."""
    cos_tol = math.cos(math.radians(opt.plane_normal_deg))
    # RANSAC among the points whose normals share the pool's dominant orientation: a plane
    # then cannot collect inliers from the strips where it slices perpendicular surfaces
    pts_p, nrm_p = pts[idx], nrm[idx]
    cand = idx[np.abs(nrm_p @ _dominant_direction(nrm_p, cos_tol, rng)) >= cos_tol]
    if len(cand) < opt.plane_min_points:
        cand = idx
    if len(cand) > opt.ransac_sample:
        cand = np.unique(cand[rng.integers(0, len(cand), opt.ransac_sample)])
    sub_pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[cand]))
    model, ransac_inliers = sub_pcd.segment_plane(opt.plane_distance_m, 3, opt.ransac_iterations)
    n = np.asarray(model[:3], dtype=float)
    scale = np.linalg.norm(n)
    if not np.isfinite(scale) or scale == 0:
        return None
    n, d = n / scale, -float(model[3]) / scale
    members = idx
    for _ in range(2):  # inliers by distance and normal, then a least-squares refit
        near = np.abs(pts_p @ n - d) < opt.plane_distance_m
        near &= np.abs(nrm_p @ n) >= cos_tol
        members = idx[near]
        if len(members) < opt.plane_min_points:
            break
        n, d = _fit_plane(pts[members], n)
    return n, d, members, cand[np.asarray(ransac_inliers, dtype=np.int64)]


def _plane_pieces(
    pts: np.ndarray,
    nrm: np.ndarray,
    pool: np.ndarray,
    traced: tuple[np.ndarray, float],
    found: list[tuple[np.ndarray, list[Any]]],
    opt: ScanOptions,
) -> list[_PlanePiece]:
    """The pieces of one plane ``traced`` = (n, d) (the frame its outlines were traced in):
    oriented towards the bulk of the points, refitted, joined by their noise tail; one piece
    for a bounding plane. Takes their points out of ``pool`` (updated in place)."""
    cos_tol = math.cos(math.radians(opt.plane_normal_deg))
    n, d = traced
    # orient towards the bulk of the points; bounding if almost nothing lies beyond
    side = pts @ n - d
    if np.count_nonzero(side > 0) < np.count_nonzero(side < 0):
        n, d, side = -n, -d, -side
    outside = np.count_nonzero(side < -3.0 * opt.plane_distance_m)
    bounding = outside <= BOUNDING_OUTSIDE_FRACTION * len(pts)
    # the noise tail beyond the inlier distance (within twice it, over the piece) belongs
    # to the plane too: left alone it would make a ghost plane or flat objects beside it
    tail = np.flatnonzero(pool)
    tail = tail[np.abs(pts[tail] @ traced[0] - traced[1]) < 2.0 * opt.plane_distance_m]
    tail = tail[np.abs(nrm[tail] @ traced[0]) >= cos_tol]
    tails = [_inside_polygons(pts[tail], traced, ps, opt.grid_cell_m) for _, ps in found]
    if bounding:
        mem = np.concatenate([m for m, _ in found])
        n_b, d_b = _fit_plane(pts[mem], n)
        polys = [_reframe(p, traced, (n_b, d_b)) for _, ps in found for p in ps]
        mem = np.union1d(mem, tail[np.logical_or.reduce(tails)])
        pool[mem] = False
        return [_PlanePiece(n_b, d_b, polys, mem, True)]
    out = []
    for (mem, polys), in_tail in zip(found, tails):
        n_p, d_p = _fit_plane(pts[mem], n)
        polys = [_reframe(p, traced, (n_p, d_p)) for p in polys]
        mem = np.union1d(mem, tail[in_tail])
        pool[mem] = False
        out.append(_PlanePiece(n_p, d_p, polys, mem, False))
    return out


def _inside_polygons(
    pts: np.ndarray, plane: tuple[np.ndarray, float], polys: Sequence[Any], grow: float
) -> np.ndarray:
    """(n,) bool, points whose projection on the plane (n, d) falls in the polygons (in the
    plane's frame) grown by ``grow`` m."""
    import shapely

    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    origin, u, v = _plane_frame(*plane)
    region = shapely.unary_union(list(polys)).buffer(grow, join_style="mitre")
    rel = pts - origin
    return np.asarray(shapely.contains_xy(region, rel @ u, rel @ v), dtype=bool)


def _dominant_direction(
    normals: np.ndarray, cos_tol: float, rng: np.random.Generator
) -> np.ndarray:
    """The unit direction (up to sign) shared by the most normals within ``acos(cos_tol)``,
    among 64 of the normals themselves, scored on at most 20 000 of them."""
    m = normals[rng.integers(0, len(normals), min(len(normals), 20_000))]
    cand = m[rng.integers(0, len(m), 64)]
    score = (np.abs(m @ cand.T) >= cos_tol).sum(axis=0)
    return cand[int(np.argmax(score))]


def _split_plane(
    pts: np.ndarray,
    nrm: np.ndarray,
    members: np.ndarray,
    n: np.ndarray,
    d: float,
    opt: ScanOptions,
) -> list[tuple[np.ndarray, list[Any]]]:
    """Connected pieces (>= min area) of a plane's inliers: (point indices, outline polygons in
    the frame of (n, d)). Rasterise at ``grid_cell_m``, close gaps, label 8-connected pieces,
    trace the outlines along the cells' boundary and pull them in by the expected overshoot
    (half a cell, less half the point spacing, plus the points' noise: their RMS distance to
    the plane)."""
    from scipy import ndimage

    noise = min(float(np.sqrt(np.mean((pts[members] @ n - d) ** 2))), 0.5 * opt.plane_distance_m)
    cell = float(opt.grid_cell_m)
    grid, ij, lo = _plane_raster(pts, nrm, members, n, d, opt)
    labels, n_lab = ndimage.label(grid, structure=np.ones((3, 3), dtype=bool))
    if n_lab == 0:
        return []
    counts = np.bincount(labels.ravel(), minlength=n_lab + 1)
    min_cells = max(opt.plane_min_area_m2 / cell**2, 1.0)
    point_label = labels[ij[:, 1], ij[:, 0]]
    out = []
    slices = ndimage.find_objects(labels)
    for k in range(1, n_lab + 1):
        if counts[k] < min_cells:
            continue
        sl = slices[k - 1]
        sub_lo = lo + np.array([sl[1].start, sl[0].start]) * cell
        # the outline runs on average half a cell beyond the outermost points, which lie half a
        # point spacing inside the true edge plus about one noise deviation outside it
        spacing = math.sqrt(counts[k] * cell * cell / max(np.count_nonzero(point_label == k), 1))
        shrink = noise + 0.5 * max(0.0, cell - spacing)
        polys = _piece_outlines(labels[sl] == k, sub_lo, shrink, opt)
        if polys and sum(p.area for p in polys) >= opt.plane_min_area_m2:
            out.append((members[point_label == k], polys))
    return out


def _plane_raster(
    pts: np.ndarray,
    nrm: np.ndarray,
    members: np.ndarray,
    n: np.ndarray,
    d: float,
    opt: ScanOptions,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The occupancy raster of a plane's inliers in its frame (rows along v, columns along u,
    cells of ``grid_cell_m``): the inliers' cells, the edge band (below) and gaps closed.
    Returns the raster, the inliers' cells (m, 2) as (column, row), and the (u, v) of the
    raster's corner, m."""
    from scipy import ndimage

    origin, u, v = _plane_frame(n, d)
    rel = pts[members] - origin
    uv = np.column_stack([rel @ u, rel @ v])
    cell = float(opt.grid_cell_m)
    r = int(math.ceil(opt.close_gaps_m / (2.0 * cell)))
    r_edge = int(math.ceil(float(opt.normal_radius_m) / cell))
    pad = r + r_edge + 2
    lo = uv.min(axis=0) - pad * cell
    ij = np.floor((uv - lo) / cell).astype(np.int64)
    shape = (int(ij[:, 1].max()) + pad + 1, int(ij[:, 0].max()) + pad + 1)
    if shape[0] * shape[1] > MAX_GRID_CELLS:
        raise HallrayError(
            f"a plane of {shape[1] * cell:.0f} m x {shape[0] * cell:.0f} m is too large for "
            f"outline cells of {cell} m; are the coordinates in metres? (else use a larger voxel)"
        )
    grid = np.zeros(shape, dtype=bool)
    grid[ij[:, 1], ij[:, 0]] = True
    # near the edges the normals are blurred (they mix both faces), so the normal test leaves a
    # band of about one normal radius out: there, points near the plane count unless their
    # normals are clean perpendicular ones (a floor running past the foot of a face), which
    # brings the outline out to the true edge
    near = np.flatnonzero(
        (np.abs(pts @ n - d) < opt.plane_distance_m) & (np.abs(nrm @ n) >= EDGE_MIN_COS)
    )
    rel_n = pts[near] - origin
    ij_n = np.floor((np.column_stack([rel_n @ u, rel_n @ v]) - lo) / cell).astype(np.int64)
    ok = (ij_n >= 0).all(axis=1) & (ij_n[:, 1] < shape[0]) & (ij_n[:, 0] < shape[1])
    edge = np.zeros(shape, dtype=bool)
    edge[ij_n[ok, 1], ij_n[ok, 0]] = True
    yy, xx = np.mgrid[-r_edge : r_edge + 1, -r_edge : r_edge + 1]
    grid |= edge & ndimage.binary_dilation(grid, structure=xx**2 + yy**2 <= r_edge * r_edge)
    if r > 0:
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        grid = ndimage.binary_closing(grid, structure=xx**2 + yy**2 <= r * r)
    return grid, ij, lo


def _piece_outlines(mask: np.ndarray, lo: np.ndarray, shrink: float, opt: ScanOptions) -> list:
    """Outline polygons of one connected piece of a plane raster (corner ``lo`` (2,) m): traced,
    small holes filled, simplified, snapped to a rectangle when it is one, pulled in by
    ``shrink`` m; parts under a quarter of the smallest plane area dropped."""
    cell = float(opt.grid_cell_m)
    polys = []
    for poly in _polygons_from_mask(mask, lo, cell):
        poly = _clean_polygon(
            poly, fill_all=False, max_hole_area=opt.max_hole_area_m2, simplify=opt.simplify_m
        )
        poly = _rectangle_fit(poly, cell)
        shrunk = poly.buffer(-shrink, join_style="mitre")
        polys.extend(q for q in _polygon_parts(shrunk) if q.area >= 0.25 * opt.plane_min_area_m2)
    return polys


def _plane_elements(pieces: list[_PlanePiece], pts: np.ndarray, opt: ScanOptions) -> list[Element]:
    """Elements of the plane pieces: bounding planes closed, grown, cut where they meet and
    extruded outward; the others open sheets."""
    elements = []
    for i, piece in enumerate(pieces):
        frame = _plane_frame(piece.n, piece.d)
        if piece.bounding:
            polys = _bounding_polygons(pieces, i, opt)
        else:
            polys = piece.polygons
        counts = _points_per_polygon(pts[piece.members], (piece.n, piece.d), polys)
        for poly, count in zip(polys, counts):
            if piece.bounding and opt.wall_thickness_m > 0:
                mesh = _slab_mesh(poly, *frame, -opt.wall_thickness_m * piece.n)
                closed = True
            else:
                mesh = _sheet_mesh(poly, *frame)
                closed = False
            if len(mesh.faces):
                elements.append(
                    Element(
                        "plane", mesh, closed, count, piece.n, piece.d,
                        piece.bounding, poly.area, poly, frame,
                    )
                )  # fmt: skip
    return elements


def _bounding_polygons(pieces: list[_PlanePiece], i: int, opt: ScanOptions) -> list[Any]:
    """The outline of bounding plane ``i`` in its frame: holes filled (unseen floor under
    machines), grown by ``snap_m``, cut where the other bounding planes meet it, unseen strips
    along it filled; its polygons (no holes) of at least a quarter of the smallest plane area."""
    import shapely

    piece = pieces[i]
    origin, u, v = _plane_frame(piece.n, piece.d)
    tol = math.sin(math.radians(ORIENTATION_TOL_DEG))
    seen = shapely.unary_union(
        [
            _clean_polygon(p, fill_all=True, max_hole_area=0.0, simplify=opt.simplify_m)
            for p in piece.polygons
        ]
    )
    grown = seen.buffer(opt.snap_m, join_style="mitre")
    region = shapely.box(*grown.bounds)
    horizontal_i = abs(piece.n[2]) > 0.5
    for j, other in enumerate(pieces):
        if j == i or not other.bounding:
            continue
        g = np.array([other.n @ u, other.n @ v])
        if np.linalg.norm(g) < tol:
            continue  # parallel
        # which one runs through the joint: horizontal planes pass under/over vertical ones,
        # between two vertical planes the earlier (larger) one
        horizontal_j = abs(other.n[2]) > 0.5
        through = horizontal_i if horizontal_i != horizontal_j else i < j
        d_cut = other.d - (opt.wall_thickness_m if through else 0.0)
        c0 = float(other.n @ origin - d_cut)
        region = region.intersection(_half_plane(g, c0, region.bounds))
    geom = grown.intersection(region)
    # strips the scanner could not see (floor under racks along a wall, a wall behind
    # them): parts of the region left uncovered in which no disc of radius hidden_fill_m fits
    missing = _polygon_parts(region.difference(geom))
    hidden = [m for m in missing if m.buffer(-opt.hidden_fill_m).is_empty]
    if hidden:
        geom = shapely.unary_union([geom, *hidden])
    geom = geom.simplify(opt.simplify_m, preserve_topology=True)
    return [
        shapely.Polygon(p.exterior)  # no holes in a bounding plane
        for p in _polygon_parts(geom)
        if p.area >= 0.25 * opt.plane_min_area_m2
    ]


def _points_per_polygon(
    pts: np.ndarray, plane: tuple[np.ndarray, float], polys: Sequence[Any]
) -> list[int]:
    """How many of a piece's points each of its polygons explains (the nearest polygon in the
    plane; all of them when there is one polygon)."""
    import shapely

    if len(polys) <= 1:
        return [len(pts)] * len(polys)
    origin, u, v = _plane_frame(*plane)
    rel = pts - origin
    xy = shapely.points(rel @ u, rel @ v)
    dist = np.stack([shapely.distance(p, xy) for p in polys])
    return np.bincount(np.argmin(dist, axis=0), minlength=len(polys)).tolist()


def _near_planes(pts: np.ndarray, elements: list[Element], opt: ScanOptions) -> np.ndarray:
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


def _object_elements(
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
        parts = [(mesh, len(idx))] if mesh is not None else _box_decomposition(cp, opt, noise)
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
    from .spec.model import node_name

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


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


def scene_from_elements(
    elements: Sequence[Element], metadata: Mapping[str, Any], rules: MaterialRules
) -> Any:
    """A ``trimesh.Scene`` with one node per element, named after its material, the glTF
    material named after the radio material, and ``metadata["hallray"]``."""
    import trimesh

    from .spec.build import paint

    colors = material_colors(e.material for e in elements)
    scene = trimesh.Scene()
    for e in sorted(elements, key=lambda e: e.name):
        mesh = e.mesh.copy()
        paint(mesh, e.material, colors[e.material])
        mesh.metadata = {
            "object": e.name.rsplit("_itu_", 1)[0] if "_itu_" in e.name else e.name,
            "material": e.material,
            "kind": e.kind,
            "closed": bool(e.closed),
            "bounding": bool(e.bounding),
        }
        scene.add_geometry(mesh, geom_name=e.name, node_name=e.name)
    scene.metadata["hallray"] = dict(metadata)
    return scene


def _load_positions(source: str | os.PathLike[str]) -> dict[str, list[dict[str, Any]]]:
    """``base_stations`` and ``points`` (``[{name, xyz}]``) from a YAML/JSON file (a hall YAML
    works) or from a scene file's ``hallray`` metadata."""

    p = Path(source)
    if not p.is_file():
        raise HallrayError(f"positions file not found: {source}")
    if p.suffix.lower() in (".glb", ".gltf"):
        import trimesh

        try:
            data = dict(trimesh.load(str(p), force="scene").metadata.get("hallray", {}))
        except Exception as exc:  # trimesh raises many types
            raise HallrayError(
                f"cannot read positions from {p.name}: {exc}".splitlines()[0]
            ) from None
    else:
        data = read_yaml(p, "positions file")
    if not isinstance(data, Mapping):
        raise HallrayError(f"{p.name}: expected a mapping with base_stations and/or points")
    out: dict[str, list[dict[str, Any]]] = {}
    for key in ("base_stations", "points"):
        items = data.get(key) or []
        clean = []
        for k, it in enumerate(items):
            try:
                xyz = [float(x) for x in it["xyz"]]
                name = str(it.get("name", f"{key}{k}"))
            except (TypeError, KeyError, ValueError):
                raise HallrayError(f"{p.name}: {key}[{k}] needs name and xyz: [x, y, z]") from None
            if len(xyz) != 3 or not all(math.isfinite(x) for x in xyz):
                raise HallrayError(f"{p.name}: {key}[{k}].xyz must be 3 finite numbers")
            entry = {"name": name, "xyz": xyz}
            if "note" in it:
                entry["note"] = str(it["note"])
            clean.append(entry)
        out[key] = clean
    if not out["base_stations"] and not out["points"]:
        raise HallrayError(f"{p.name}: no base_stations or points")
    return out


def scan_to_scene(
    cloud_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    options: ScanOptions | None = None,
    *,
    rules: MaterialRules | str | os.PathLike[str] | Mapping[str, Any] | None = None,
    positions: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Reconstruct a point cloud into a traceable scene and write it as a GLB.

    Parameters
    ----------
    cloud_path : point cloud (see :func:`read_cloud`)
    out_path : output .glb (written atomically; nothing is written on error)
    options : ScanOptions
    rules : MaterialRules, or a rules YAML path / mapping (default :data:`DEFAULT_RULES`)
    positions : optional file with ``base_stations`` and ``points`` to store in the scene's
        metadata (so ``trace-scene`` and ``render-scene`` use them)

    Returns
    -------
    dict, the summary of :func:`reconstruct` plus ``output`` and ``bytes``

    Raises
    ------
    HallrayError
        Bad input of any kind (one-line message).
    """
    from .spec.build import glb_bytes

    out = Path(out_path)
    if out.suffix.lower() != ".glb":
        raise HallrayError(f"output {out} must end in .glb")
    if not out.parent.is_dir():
        raise HallrayError(f"output directory {out.parent} does not exist")
    if not isinstance(rules, MaterialRules):
        rules = MaterialRules.load(rules)
    opt = (options or ScanOptions()).resolved()
    pos = _load_positions(positions) if positions is not None else {}
    pts = read_cloud(cloud_path)
    try:
        elements, summary = reconstruct(pts, opt, rules)
    except (RuntimeError, MemoryError) as exc:  # open3d and qhull report failures this way
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise HallrayError(f"reconstruction of {Path(cloud_path).name} failed: {first}") from None
    meta = {
        "schema_version": 1,
        "name": out.stem,
        "description": f"reconstructed from the point cloud {Path(cloud_path).name} by scan-to-scene",
        "materials": dict(rules.materials),
        "base_stations": pos.get("base_stations", []),
        "points": pos.get("points", []),
        "scan": {
            "cloud": Path(cloud_path).name,
            "options": asdict(opt),
            "summary": {k: v for k, v in summary.items() if k != "elements"},
        },
    }
    scene = scene_from_elements(elements, meta, rules)
    data = glb_bytes(scene)
    try:
        write_atomic(out, data)
    except OSError as exc:
        raise SceneError(f"cannot write {out}: {exc}") from None
    summary["output"] = str(out)
    summary["bytes"] = len(data)
    return summary
