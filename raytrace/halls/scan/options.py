"""The settings of a scan's reconstruction (:class:`ScanOptions`, the fidelity / triangle
count trade-off, defaults scaled by the voxel size) and the material rules (:class:`MaterialRules`:
the first rule whose conditions an element meets gives its material).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hallray.errors import brief

from ...core.errors import HallrayError, MaterialError
from ...core.fileio import read_yaml
from ...physics.materials import MaterialLibrary

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
            raise MaterialError(f"{origin}: default: unknown material {brief(default)}")
        raw_rules = data.get("rules") or []
        if not isinstance(raw_rules, list):
            raise MaterialError(f"{origin}: 'rules' must be a list")
        rules = []
        for k, rule in enumerate(raw_rules):
            rules.append(_check_rule(rule, f"{origin}: rules[{k}]", library))
        return cls(tuple(rules), default, user, library)

    def assign(self, features: Mapping[str, Any]) -> str:
        """Material of an element with ``features``: the quantities of the class docstring, as
        :func:`raytrace.halls.scan.reconstruct.reconstruct` computes them per element."""
        for rule in self.rules:
            if _rule_matches(rule, features):
                return str(rule["material"])
        return self.default


def _check_rule(rule: Any, where: str, library: MaterialLibrary) -> dict[str, Any]:
    if not isinstance(rule, Mapping):
        raise MaterialError(f"{where}: expected a mapping, got {brief(rule)}")
    for key in rule:
        if key not in _RULE_KEYS:
            raise MaterialError(
                f"{where}: unknown condition '{key}' (allowed: {', '.join(_RULE_KEYS)})"
            )
    mat = rule.get("material")
    if not isinstance(mat, str) or mat not in library:
        raise MaterialError(f"{where}: material: unknown material {brief(mat)}")
    if "kind" in rule and rule["kind"] not in ("plane", "object"):
        raise MaterialError(f"{where}: kind must be 'plane' or 'object', got {brief(rule['kind'])}")
    if "orientation" in rule and rule["orientation"] not in _ORIENTATIONS:
        raise MaterialError(
            f"{where}: orientation must be one of {', '.join(_ORIENTATIONS)}, "
            f"got {brief(rule['orientation'])}"
        )
    for key in ("bounding", "floor_to_ceiling"):
        if key in rule and not isinstance(rule[key], bool):
            raise MaterialError(f"{where}: {key} must be true or false, got {brief(rule[key])}")
    for key in rule:
        if key.startswith(("min_", "max_")):
            val = rule[key]
            if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
                raise MaterialError(f"{where}: {key} must be a number, got {brief(val)}")
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
                f"objects must be one of {', '.join(OBJECT_MODES)}, got {brief(out.objects)}"
            )
        return out
