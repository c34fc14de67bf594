"""What a hall is made of: the primitives (boxes, vertical cylinders, open rectangular
sheets; their meshes, bounds and footprints seen from above), base stations, points of
interest and the validated :class:`HallSpec`. SI units, metres; x east, y north, z up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...physics.materials import MaterialLibrary
from ...scene.motion import Route

#: Version of the hall YAML schema and of the ``metadata["hallray"]`` block of the built GLB.
SCHEMA_VERSION = 1

#: ITU-R P.2040-3 Table 3 material names (those of ``MaterialLibrary.itu()``).
ITU_MATERIALS: tuple[str, ...] = MaterialLibrary.itu().names

#: A point or base station closer than this to a solid or a sheet counts as inside it (m). Ray
#: casting in float32 needs such a margin anyway (see DESIGN.md).
POINT_CLEARANCE_M = 0.01
#: Tolerance for "object inside the hall" (m).
BOUNDS_TOL_M = 1e-6
#: Objects whose top is below this height do not obstruct a forklift route (floor markings), m.
DRIVE_OVER_HEIGHT_M = 0.05
#: Default number of sides of a cylinder.
DEFAULT_CYLINDER_SECTIONS = 16


def _cos_sin(yaw_deg: float) -> tuple[float, float]:
    """cos and sin of a yaw angle, exact for multiples of 90 degrees (keeps bounds exact)."""
    quarter = yaw_deg / 90.0
    if quarter == round(quarter):
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(round(quarter)) % 4]
    rad = math.radians(yaw_deg)
    return math.cos(rad), math.sin(rad)


def rotate_xy(xyz: np.ndarray, yaw_deg: float) -> np.ndarray:
    """Rotate ``(n, 3)`` or ``(3,)`` vectors about the z axis by ``yaw_deg`` (counter-clockwise)."""
    c, s = _cos_sin(yaw_deg)
    xyz = np.asarray(xyz, dtype=float)
    out = xyz.copy()
    out[..., 0] = c * xyz[..., 0] - s * xyz[..., 1]
    out[..., 1] = s * xyz[..., 0] + c * xyz[..., 1]
    return out


@dataclass(frozen=True)
class Box:
    """Closed box: ``center`` (3,) m, ``size`` (3,) m (x, y, z extents before yaw), ``yaw_deg``
    rotation about the vertical axis through the centre, counter-clockwise seen from above."""

    name: str
    material: str
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw_deg: float = 0.0

    kind = "box"
    closed = True

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices ``(8, 3)`` float64 m and outward-wound faces ``(12, 3)`` int64."""
        half = 0.5 * np.asarray(self.size, dtype=float)
        # corner k has x sign bit 0, y sign bit 1, z sign bit 2
        signs = np.array([[(k >> b) & 1 for b in range(3)] for k in range(8)], dtype=float)
        local = (2.0 * signs - 1.0) * half
        vertices = rotate_xy(local, self.yaw_deg) + np.asarray(self.center, dtype=float)
        faces = np.array(
            [
                [0, 2, 3], [0, 3, 1],  # z-
                [4, 5, 7], [4, 7, 6],  # z+
                [0, 1, 5], [0, 5, 4],  # y-
                [2, 6, 7], [2, 7, 3],  # y+
                [0, 4, 6], [0, 6, 2],  # x-
                [1, 3, 7], [1, 7, 5],  # x+
            ],
            dtype=np.int64,
        )  # fmt: skip
        return vertices, faces

    def contains(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """``(n,)`` bool: points ``(n, 3)`` inside the box grown by ``clearance`` m."""
        local = rotate_xy(np.atleast_2d(points) - np.asarray(self.center), -self.yaw_deg)
        return np.all(np.abs(local) < 0.5 * np.asarray(self.size) + clearance, axis=1)


@dataclass(frozen=True)
class Cylinder:
    """Closed vertical cylinder (a prism of ``sections`` sides): bottom centre ``base`` (3,) m."""

    name: str
    material: str
    base: tuple[float, float, float]
    radius: float
    height: float
    sections: int = DEFAULT_CYLINDER_SECTIONS

    kind = "cylinder"
    closed = True

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices ``(2n, 3)`` float64 m and outward-wound faces ``(4n - 4, 3)`` int64."""
        n = self.sections
        angle = 2.0 * np.pi * np.arange(n) / n
        ring = np.column_stack([self.radius * np.cos(angle), self.radius * np.sin(angle)])
        bx, by, bz = self.base
        bottom = np.column_stack([ring + (bx, by), np.full(n, bz)])
        top = np.column_stack([ring + (bx, by), np.full(n, bz + self.height)])
        vertices = np.vstack([bottom, top])
        k = np.arange(n)
        k1 = (k + 1) % n
        side = np.vstack(
            [np.column_stack([k, k1, n + k1]), np.column_stack([k, n + k1, n + k])]
        )  # counter-clockwise ring seen from outside
        fan = np.arange(1, n - 1)
        cap_bottom = np.column_stack([np.zeros(n - 2, dtype=np.int64), fan + 1, fan])
        cap_top = np.column_stack([np.full(n - 2, n), n + fan, n + fan + 1])
        faces = np.vstack([side, cap_bottom, cap_top]).astype(np.int64)
        return vertices, faces

    def contains(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """``(n,)`` bool: points inside the prism (as meshed) grown by ``clearance`` m."""
        p = np.atleast_2d(points)
        n = self.sections
        # side k joins ring vertices k and k+1; its outward normal points at angle 2 pi (k+1/2)/n
        # and it lies at the apothem r cos(pi/n) from the axis
        angle = 2.0 * np.pi * (np.arange(n) + 0.5) / n
        normals = np.column_stack([np.cos(angle), np.sin(angle)])
        radial = (p[:, :2] - np.asarray(self.base[:2])) @ normals.T
        apothem = self.radius * np.cos(np.pi / n)
        dz = p[:, 2] - self.base[2]
        inside_xy = np.all(radial < apothem + clearance, axis=1)
        return inside_xy & (dz > -clearance) & (dz < self.height + clearance)


@dataclass(frozen=True)
class Sheet:
    """Open parallelogram (a zero-thickness sheet, two-sided): corners ``origin``,
    ``origin + u``, ``origin + u + v``, ``origin + v`` (all (3,) m)."""

    name: str
    material: str
    origin: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]

    kind = "sheet"
    closed = False

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices ``(4, 3)`` float64 m and faces ``(2, 3)`` int64."""
        o, u, v = (np.asarray(x, dtype=float) for x in (self.origin, self.u, self.v))
        vertices = np.array([o, o + u, o + u + v, o + v])
        return vertices, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)

    def contains(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """``(n,)`` bool: points within ``clearance`` m of the sheet."""
        p = np.atleast_2d(points) - np.asarray(self.origin)
        u, v = np.asarray(self.u), np.asarray(self.v)
        normal = np.cross(u, v)
        normal = normal / np.linalg.norm(normal)
        # coordinates in the sheet's (u, v) basis, then the distance to the clamped foot point
        gram = np.array([[u @ u, u @ v], [u @ v, v @ v]])
        st = np.linalg.solve(gram, np.vstack([p @ u, p @ v]))
        st = np.clip(st, 0.0, 1.0)
        foot = st[0][:, None] * u + st[1][:, None] * v
        dist = np.linalg.norm(p - foot, axis=1)
        return (dist < clearance) & (np.abs(p @ normal) < clearance)


Primitive = Box | Cylinder | Sheet


def primitive_arrays(prim: Primitive) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a primitive (see each class's ``mesh_arrays``)."""
    return prim.mesh_arrays()


def primitive_bounds(prim: Primitive) -> np.ndarray:
    """(2, 3) float, m: the primitive's axis-aligned bounds, lowest then highest corner."""
    vertices, _ = prim.mesh_arrays()
    return np.array([vertices.min(axis=0), vertices.max(axis=0)])


def footprint_xy(prim: Primitive) -> np.ndarray:
    """Convex outline ``(k, 2)`` of the primitive seen from above (a segment for a vertical sheet)."""
    vertices, _ = prim.mesh_arrays()
    if isinstance(prim, Box):
        return vertices[[0, 1, 3, 2], :2]
    if isinstance(prim, Cylinder):
        return vertices[: prim.sections, :2]
    xy = vertices[:, :2]
    e1, e2 = xy[1] - xy[0], xy[3] - xy[0]
    area2 = e1[0] * e2[1] - e1[1] * e2[0]
    if abs(area2) < 1e-12:  # vertical sheet: its two extreme points
        d = xy - xy.mean(axis=0)
        axis = d[np.argmax(np.linalg.norm(d, axis=1))]
        proj = d @ axis
        return xy[[int(np.argmin(proj)), int(np.argmax(proj))]]
    return xy


@dataclass(frozen=True)
class BaseStation:
    """A base station: ``xyz`` (3,) m."""

    name: str
    xyz: tuple[float, float, float]


@dataclass(frozen=True)
class PointOfInterest:
    """A point of interest (device position): ``xyz`` (3,) m; ``note`` free text (LoS status)."""

    name: str
    xyz: tuple[float, float, float]
    note: str = ""


@dataclass(frozen=True)
class HallSpec:
    """A validated hall description (see :func:`load_hall_spec`). Lengths in m."""

    name: str
    size: tuple[float, float, float]
    shell_material: str
    wall_thickness: float
    objects: tuple[Primitive, ...]
    materials: dict[str, dict[str, Any]] = field(default_factory=dict)
    base_stations: tuple[BaseStation, ...] = ()
    points: tuple[PointOfInterest, ...] = ()
    routes: tuple[Route, ...] = ()
    area_of_interest: tuple[float, float, float, float] | None = None
    description: str = ""

    @property
    def material_names(self) -> tuple[str, ...]:
        """ITU names plus the user materials of this hall."""
        return tuple(dict.fromkeys(ITU_MATERIALS + tuple(self.materials)))

    @property
    def material_library(self) -> MaterialLibrary:
        """The ITU library with this hall's user materials and overrides."""
        return MaterialLibrary.itu().with_yaml({"materials": self.materials})

    @property
    def base_station_xyz(self) -> np.ndarray:
        """``(B, 3)`` float64 m."""
        return np.array([b.xyz for b in self.base_stations], dtype=float).reshape(-1, 3)

    @property
    def point_xyz(self) -> np.ndarray:
        """``(N, 3)`` float64 m."""
        return np.array([p.xyz for p in self.points], dtype=float).reshape(-1, 3)

    def shell(self) -> tuple[Box, ...]:
        """Floor, ceiling and four walls: closed slabs outside the interior, not overlapping."""
        x, y, z = self.size
        t = self.wall_thickness
        m = self.shell_material

        def slab(name: str, lo: Sequence[float], hi: Sequence[float]) -> Box:
            lo_, hi_ = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
            return Box(name, m, tuple(0.5 * (lo_ + hi_)), tuple(hi_ - lo_))

        return (
            slab("shell_floor", (-t, -t, -t), (x + t, y + t, 0.0)),
            slab("shell_ceiling", (-t, -t, z), (x + t, y + t, z + t)),
            slab("shell_wall_south", (-t, -t, 0.0), (x + t, 0.0, z)),
            slab("shell_wall_north", (-t, y, 0.0), (x + t, y + t, z)),
            slab("shell_wall_west", (-t, 0.0, 0.0), (0.0, y, z)),
            slab("shell_wall_east", (x, 0.0, 0.0), (x + t, y, z)),
        )

    def node_name(self, prim: Primitive) -> str:
        """Scene node name carrying the material: ``<name>_itu_<m>`` (ITU) or ``<name>_<m>``."""
        return node_name(prim.name, prim.material, user_materials=self.materials)


def node_name(
    name: str, material: str, user_materials: Mapping[str, Any] | Sequence[str] = ()
) -> str:
    """``<name>_itu_<material>`` for ITU materials, ``<name>_<material>`` for user ones."""
    if material in ITU_MATERIALS and material not in _new_materials(user_materials):
        return f"{name}_itu_{material}"
    return f"{name}_{material}"


def _new_materials(user_materials: Mapping[str, Any] | Sequence[str]) -> set[str]:
    return {m for m in user_materials if m not in ITU_MATERIALS}
