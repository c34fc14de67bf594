"""Hall description (YAML) -> validated :class:`HallSpec` -> trimesh scene -> GLB.

A hall is written as a short YAML file (schema in ``docs/hall.md``): the interior size, user
materials, a list of primitives (boxes, vertical cylinders, open rectangular sheets), reusable
templates placed many times (rows of racks), base stations, points of interest, forklift routes and
an area of interest. :func:`load_hall_spec` validates it strictly (every error is one line naming the
bad entry); :func:`build_scene` turns it into a :class:`trimesh.Scene` with one node per object whose
name carries its material (``rack_a03_frame_itu_metal``, ``rack_a03_boxes_plastic``), which is what
the scene loader binds materials by; :func:`write_glb` writes it reproducibly (same YAML -> same bytes)
and atomically.

Geometry conventions (SI, metres): x east, y north, z up; the hall interior is exactly
``[0, X] x [0, Y] x [0, Z]``; the floor, ceiling and four walls are closed slabs *outside* it. Closed
solids are watertight with outward normals; sheets are two triangles, open and two-sided.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from ..core.errors import HallrayError, MaterialError, SceneError
from ..core.fileio import read_yaml, write_atomic
from ..core.palette import material_colors
from ..core.scale import check_size
from ..physics.materials import MaterialLibrary
from ..scene.model import Scene
from ..scene.motion import ROUTE_MODES, Route

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

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")
_MATERIAL_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_MATERIAL_KEYS = ("eta_real", "sigma", "thickness", "a", "b", "c", "d", "f_range_ghz")


# --------------------------------------------------------------------------------------------
# small validation helpers (every error is one line: "<where>: <what>")
# --------------------------------------------------------------------------------------------


def _fail(where: str, msg: str, cls: type[HallrayError] = SceneError) -> None:
    raise cls(f"{where}: {msg}" if where else msg)


def _mapping(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        _fail(where, f"expected a mapping, got {type(value).__name__}")
    for key in value:
        if not isinstance(key, str):
            _fail(where, f"keys must be strings, got {key!r}")
    return value


def _check_keys(
    value: Mapping[str, Any], where: str, required: Sequence[str], optional: Sequence[str] = ()
) -> None:
    allowed = set(required) | set(optional)
    for key in value:
        if key not in allowed:
            _fail(where, f"unknown key '{key}' (allowed: {', '.join(sorted(allowed))})")
    for key in required:
        if key not in value:
            _fail(where, f"missing key '{key}'")


def _number(value: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _fail(where, f"expected a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        _fail(where, f"expected a finite number, got {value!r}")
    if positive and out <= 0.0:
        _fail(where, f"must be > 0, got {value!r}")
    if nonneg and out < 0.0:
        _fail(where, f"must be >= 0, got {value!r}")
    return out


def _vector(value: Any, where: str, n: int, *, positive: bool = False) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        _fail(where, f"expected a list of {n} numbers, got {value!r}")
    return tuple(_number(v, f"{where}[{i}]", positive=positive) for i, v in enumerate(value))


def _string(value: Any, where: str) -> str:
    if not isinstance(value, str):
        _fail(where, f"expected a string, got {value!r}")
    return value


def _name(value: Any, where: str, *, template: bool = False) -> str:
    name = _string(value, where)
    check = re.sub(r"\{[^{}]*\}", "0", name) if template else name
    if not _NAME_RE.match(check):
        _fail(where, f"bad name {name!r} (letters, digits, '_' and '-' only)")
    return name


def _cos_sin(yaw_deg: float) -> tuple[float, float]:
    """cos and sin of a yaw angle, exact for multiples of 90 degrees (keeps bounds exact)."""
    quarter = yaw_deg / 90.0
    if quarter == round(quarter):
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(round(quarter)) % 4]
    rad = math.radians(yaw_deg)
    return math.cos(rad), math.sin(rad)


def _rotate_xy(xyz: np.ndarray, yaw_deg: float) -> np.ndarray:
    """Rotate ``(n, 3)`` or ``(3,)`` vectors about the z axis by ``yaw_deg`` (counter-clockwise)."""
    c, s = _cos_sin(yaw_deg)
    xyz = np.asarray(xyz, dtype=float)
    out = xyz.copy()
    out[..., 0] = c * xyz[..., 0] - s * xyz[..., 1]
    out[..., 1] = s * xyz[..., 0] + c * xyz[..., 1]
    return out


# --------------------------------------------------------------------------------------------
# primitives
# --------------------------------------------------------------------------------------------


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
        vertices = _rotate_xy(local, self.yaw_deg) + np.asarray(self.center, dtype=float)
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
        local = _rotate_xy(np.atleast_2d(points) - np.asarray(self.center), -self.yaw_deg)
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


def _bounds(prim: Primitive) -> np.ndarray:
    vertices, _ = prim.mesh_arrays()
    return np.array([vertices.min(axis=0), vertices.max(axis=0)])


def _footprint_xy(prim: Primitive) -> np.ndarray:
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


# --------------------------------------------------------------------------------------------
# spec
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# parsing
# --------------------------------------------------------------------------------------------


def _parse_materials(raw: Any) -> dict[str, dict[str, Any]]:
    """Validate the ``materials:`` section (the material YAML format of raytrace.physics.materials)."""
    out: dict[str, dict[str, Any]] = {}
    if raw is None:
        return out
    for name, entry in _mapping(raw, "materials").items():
        where = f"materials.{name}"
        if not _MATERIAL_NAME_RE.match(name):
            _fail(where, "material names are lower-case letters, digits and '_'", MaterialError)
        if not isinstance(entry, Mapping):
            _fail(where, f"expected a mapping, got {entry!r}", MaterialError)
        for key in entry:
            if key not in _MATERIAL_KEYS:
                _fail(
                    where,
                    f"unknown key '{key}' (allowed: {', '.join(_MATERIAL_KEYS)})",
                    MaterialError,
                )
        clean: dict[str, Any] = {}
        try:
            for key in ("eta_real", "thickness"):
                if key in entry:
                    clean[key] = _number(entry[key], f"{where}.{key}", positive=True)
            for key in ("sigma", "c"):
                if key in entry:
                    clean[key] = _number(entry[key], f"{where}.{key}", nonneg=True)
            if "a" in entry:
                clean["a"] = _number(entry["a"], f"{where}.a", positive=True)
            for key in ("b", "d"):
                if key in entry:
                    clean[key] = _number(entry[key], f"{where}.{key}")
            if "f_range_ghz" in entry:
                lo, hi = _vector(entry["f_range_ghz"], f"{where}.f_range_ghz", 2, positive=True)
                if lo >= hi:
                    _fail(f"{where}.f_range_ghz", f"needs lo < hi, got {[lo, hi]}")
                clean["f_range_ghz"] = [lo, hi]
        except SceneError as exc:
            raise MaterialError(str(exc)) from None
        simple = {"eta_real", "sigma"} & set(clean)
        power = {"a", "b", "c", "d"} & set(clean)
        if simple and power:
            _fail(where, "give either eta_real/sigma or a/b/c/d, not both", MaterialError)
        if name not in ITU_MATERIALS:
            if simple and simple != {"eta_real", "sigma"}:
                _fail(where, "needs both eta_real and sigma", MaterialError)
            if power and (power != {"a", "b", "c", "d"} or "f_range_ghz" not in clean):
                _fail(where, "needs all of a, b, c, d and f_range_ghz", MaterialError)
            if not simple and not power:
                _fail(
                    where, "a new material needs eta_real and sigma (or a, b, c, d)", MaterialError
                )
        out[name] = clean
    MaterialLibrary.itu().with_yaml({"materials": out})  # the loader must accept them too
    return out


def _repeat_offsets(raw: Any, where: str) -> list[tuple[dict[str, Any], np.ndarray]]:
    """Offsets ``(3,)`` m and name fields for ``repeat: {count, step}``; one entry if absent."""
    if raw is None:
        return [({}, np.zeros(3))]
    rep = _mapping(raw, where)
    _check_keys(rep, where, ("count", "step"))
    count = rep["count"]
    counts = count if isinstance(count, list) else [count]
    if not 1 <= len(counts) <= 2:
        _fail(f"{where}.count", f"expected n or [n1, n2], got {count!r}")
    for n in counts:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            _fail(f"{where}.count", f"counts must be integers >= 1, got {count!r}")
    step = rep["step"]
    if not isinstance(step, list):
        _fail(f"{where}.step", f"expected a list, got {step!r}")
    if len(counts) == 1:
        if len(step) not in (2, 3):
            _fail(f"{where}.step", f"expected [dx, dy] or [dx, dy, dz], got {step!r}")
        axes = [np.array(_vector(step, f"{where}.step", len(step)) + (0.0,) * (3 - len(step)))]
    elif step and all(isinstance(s, list) for s in step):
        if len(step) != 2:
            _fail(f"{where}.step", "a grid needs two step vectors")
        axes = []
        for k, s in enumerate(step):
            if len(s) not in (2, 3):
                _fail(f"{where}.step[{k}]", f"expected [dx, dy] or [dx, dy, dz], got {s!r}")
            axes.append(np.array(_vector(s, f"{where}.step[{k}]", len(s)) + (0.0,) * (3 - len(s))))
    else:
        dx, dy = _vector(step, f"{where}.step", 2)
        axes = [np.array([dx, 0.0, 0.0]), np.array([0.0, dy, 0.0])]
    out = []
    n_flat = 0
    n2 = counts[1] if len(counts) == 2 else 1
    for i in range(counts[0]):
        for j in range(n2):
            n_flat += 1
            offset = i * axes[0] + (j * axes[1] if len(axes) == 2 else 0.0)
            fields = {"i": i + 1, "j": j + 1, "n": n_flat, "I": _letter(i)}
            if len(counts) == 1:
                fields["grid"] = False
            out.append((fields, offset))
    return out


def _letter(i: int) -> str:
    s = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        s = chr(65 + r) + s
    return s


def _format_name(template: str, fields: Mapping[str, Any], where: str) -> str:
    if not fields:
        if "{" in template:
            _fail(where, f"name template {template!r} needs a 'repeat'")
        return template
    if "{" in template:
        try:
            name = template.format(**{k: v for k, v in fields.items() if k != "grid"})
        except (KeyError, ValueError, IndexError) as exc:
            _fail(where, f"bad name template {template!r} ({exc}); fields: i, j, n, I")
        return _name(name, where)
    if fields.get("grid") is False:
        return f"{template}_{fields['n']:02d}"
    return f"{template}_{fields['I']}{fields['j']}"


_BOX_KEYS = ("name", "type", "material", "size", "center", "min", "yaw_deg", "repeat")
_CYL_KEYS = ("name", "type", "material", "radius", "height", "base", "center", "sections", "repeat")
_SHEET_KEYS = ("name", "type", "material", "origin", "u", "v", "repeat")
_INSTANCE_KEYS = ("name", "type", "template", "at", "yaw_deg", "repeat")


def _parse_primitive(raw: Mapping[str, Any], where: str, materials: Sequence[str]) -> Primitive:
    """One primitive (no repeat), in its own frame."""
    kind = raw.get("type")
    name = _name(raw.get("name"), f"{where}.name", template=True)
    if raw.get("material") is None:
        _fail(where, "missing key 'material'")
    material = _string(raw["material"], f"{where}.material")
    if material not in materials:
        _fail(
            f"{where}.material",
            f"unknown material '{material}' (known: {', '.join(materials)})",
            MaterialError,
        )
    if kind == "box":
        _check_keys(raw, where, ("name", "type", "material", "size"), _BOX_KEYS)
        size = _vector(raw["size"], f"{where}.size", 3, positive=True)
        key, xyz = _position(raw, where, ("center", "min"))
        center = xyz if key == "center" else tuple(xyz[k] + 0.5 * size[k] for k in range(3))
        yaw = _number(raw.get("yaw_deg", 0.0), f"{where}.yaw_deg")
        return Box(name, material, center, size, yaw)
    if kind == "cylinder":
        _check_keys(raw, where, ("name", "type", "material", "radius", "height"), _CYL_KEYS)
        radius = _number(raw["radius"], f"{where}.radius", positive=True)
        height = _number(raw["height"], f"{where}.height", positive=True)
        key, xyz = _position(raw, where, ("center", "base"))
        base = xyz if key == "base" else (xyz[0], xyz[1], xyz[2] - 0.5 * height)
        sections = raw.get("sections", DEFAULT_CYLINDER_SECTIONS)
        if isinstance(sections, bool) or not isinstance(sections, int) or sections < 3:
            _fail(f"{where}.sections", f"expected an integer >= 3, got {sections!r}")
        return Cylinder(name, material, base, radius, height, sections)
    if kind == "sheet":
        _check_keys(raw, where, ("name", "type", "material", "origin", "u", "v"), _SHEET_KEYS)
        origin = _vector(raw["origin"], f"{where}.origin", 3)
        u = _vector(raw["u"], f"{where}.u", 3)
        v = _vector(raw["v"], f"{where}.v", 3)
        if np.linalg.norm(np.cross(u, v)) < 1e-9:
            _fail(where, "sheet edges u and v are parallel or zero (zero area)")
        return Sheet(name, material, origin, u, v)
    _fail(f"{where}.type", f"unknown type {kind!r} (box, cylinder, sheet, instance)")
    raise AssertionError  # unreachable


def _position(
    raw: Mapping[str, Any], where: str, keys: tuple[str, str]
) -> tuple[str, tuple[float, ...]]:
    """The one of two alternative position keys that ``raw`` gives, and its 3-vector (m)."""
    a, b = keys
    if (a in raw) == (b in raw):
        _fail(where, f"give exactly one of '{a}' or '{b}'")
    key = a if a in raw else b
    return key, _vector(raw[key], f"{where}.{key}", 3)


def _place(prim: Primitive, name: str, offset: np.ndarray, yaw_deg: float) -> Primitive:
    """The primitive rotated by ``yaw_deg`` about the origin, then moved by ``offset`` (3,)."""

    def move(p: Sequence[float]) -> tuple[float, float, float]:
        q = _rotate_xy(np.asarray(p, dtype=float), yaw_deg) + offset
        return (float(q[0]), float(q[1]), float(q[2]))

    def turn(p: Sequence[float]) -> tuple[float, float, float]:
        q = _rotate_xy(np.asarray(p, dtype=float), yaw_deg)
        return (float(q[0]), float(q[1]), float(q[2]))

    if isinstance(prim, Box):
        return Box(name, prim.material, move(prim.center), prim.size, prim.yaw_deg + yaw_deg)
    if isinstance(prim, Cylinder):
        return Cylinder(
            name, prim.material, move(prim.base), prim.radius, prim.height, prim.sections
        )
    return Sheet(name, prim.material, move(prim.origin), turn(prim.u), turn(prim.v))


def _parse_templates(raw: Any, materials: Sequence[str]) -> dict[str, list[Primitive]]:
    out: dict[str, list[Primitive]] = {}
    if raw is None:
        return out
    for tname, items in _mapping(raw, "templates").items():
        where = f"templates.{tname}"
        _name(tname, where)
        if not isinstance(items, list) or not items:
            _fail(where, "expected a non-empty list of primitives")
        prims: list[Primitive] = []
        for k, item in enumerate(items):
            iw = f"{where}[{k}]"
            item = _mapping(item, iw)
            if "repeat" in item:
                for fields, off in _repeat_offsets(item["repeat"], f"{iw}.repeat"):
                    prim = _parse_primitive(item, iw, materials)
                    prims.append(_place(prim, _format_name(prim.name, fields, iw), off, 0.0))
            else:
                prim = _parse_primitive(item, iw, materials)
                _format_name(prim.name, {}, iw)  # refuses a name template without a repeat
                prims.append(prim)
        names = [p.name for p in prims]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            _fail(where, f"duplicate item name '{dup[0]}'")
        out[tname] = prims
    return out


def _parse_objects(
    raw: Any, materials: Sequence[str], templates: Mapping[str, list[Primitive]]
) -> list[Primitive]:
    out: list[Primitive] = []
    if raw is None:
        return out
    if not isinstance(raw, list):
        _fail("objects", f"expected a list, got {type(raw).__name__}")
    for k, entry in enumerate(raw):
        where = f"objects[{k}]"
        entry = _mapping(entry, where)
        if isinstance(entry.get("name"), str):
            where = f"objects[{k}] ({entry['name']})"
        if "type" not in entry:
            _fail(where, "missing key 'type' (box, cylinder, sheet, instance)")
        placements = _repeat_offsets(entry.get("repeat"), f"{where}.repeat")
        if entry["type"] == "instance":
            _check_keys(entry, where, ("name", "type", "template", "at"), _INSTANCE_KEYS)
            base = _name(entry["name"], f"{where}.name", template=True)
            tname = _string(entry["template"], f"{where}.template")
            if tname not in templates:
                _fail(f"{where}.template", f"unknown template '{tname}'")
            at = np.array(_vector(entry["at"], f"{where}.at", 3))
            yaw = _number(entry.get("yaw_deg", 0.0), f"{where}.yaw_deg")
            for fields, off in placements:
                inst = _format_name(base, fields, where)
                for prim in templates[tname]:
                    out.append(_place(prim, f"{inst}_{prim.name}", at + off, yaw))
        else:
            prim = _parse_primitive(entry, where, materials)
            for fields, off in placements:
                out.append(_place(prim, _format_name(prim.name, fields, where), off, 0.0))
    return out


def _parse_positions(raw: Any, section: str, *, with_note: bool) -> list[tuple[str, tuple, str]]:
    out: list[tuple[str, tuple, str]] = []
    if raw is None:
        return out
    if not isinstance(raw, list):
        _fail(section, f"expected a list, got {type(raw).__name__}")
    seen: set[str] = set()
    for k, entry in enumerate(raw):
        where = f"{section}[{k}]"
        entry = _mapping(entry, where)
        _check_keys(entry, where, ("name", "xyz"), ("note",) if with_note else ())
        name = _name(entry["name"], f"{where}.name")
        if name in seen:
            _fail(where, f"duplicate name '{name}'")
        seen.add(name)
        xyz = _vector(entry["xyz"], f"{section}.{name}.xyz", 3)
        note = entry.get("note", "")
        if note is None:
            note = ""
        out.append((name, xyz, _string(note, f"{section}.{name}.note")))
    return out


def _parse_routes(raw: Any, materials: Sequence[str]) -> list[Route]:
    out: list[Route] = []
    if raw is None:
        return out
    if not isinstance(raw, list):
        _fail("routes", f"expected a list, got {type(raw).__name__}")
    seen: set[str] = set()
    for k, entry in enumerate(raw):
        where = f"routes[{k}]"
        entry = _mapping(entry, where)
        _check_keys(entry, where, ("name", "size", "waypoints", "speed"), ("material", "mode"))
        name = _name(entry["name"], f"{where}.name")
        where = f"routes.{name}"
        if name in seen:
            _fail(where, "duplicate route name")
        seen.add(name)
        size = _vector(entry["size"], f"{where}.size", 3, positive=True)
        material = _string(entry.get("material", "metal"), f"{where}.material")
        if material not in materials:
            _fail(f"{where}.material", f"unknown material '{material}'", MaterialError)
        wps = entry["waypoints"]
        if not isinstance(wps, list) or len(wps) < 2:
            _fail(f"{where}.waypoints", "expected a list of at least 2 [x, y] points")
        waypoints = tuple(_vector(w, f"{where}.waypoints[{i}]", 2) for i, w in enumerate(wps))
        if any(np.allclose(a, b) for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)):
            _fail(f"{where}.waypoints", "two consecutive waypoints coincide")
        speed = _number(entry["speed"], f"{where}.speed", positive=True)
        mode = entry.get("mode", "loop")
        if mode not in ROUTE_MODES:
            _fail(f"{where}.mode", f"expected one of {', '.join(ROUTE_MODES)}, got {mode!r}")
        if mode == "loop" and len(waypoints) < 3:
            _fail(f"{where}.waypoints", "a loop needs at least 3 waypoints")
        out.append(Route(name, size, material, waypoints, speed, mode))
    return out


def _route_swept_area(route: Route) -> Any:
    """Floor area the forklift may cover (shapely): the path widened by w/2, plus a disc of
    radius l/2 at every waypoint (turns and reversals). An approximation, documented."""
    from shapely.geometry import LineString, Point
    from shapely.ops import unary_union

    poly = route.polyline
    l, w, _ = route.size
    parts = [LineString(poly).buffer(0.5 * w)] + [Point(p).buffer(0.5 * l) for p in poly]
    return unary_union(parts)


def _validate(spec: HallSpec) -> None:
    """Geometric checks across sections (names, bounds, clearances)."""
    from shapely.geometry import Point

    _validate_objects(spec)
    if spec.area_of_interest is not None:
        x0, y0, x1, y1 = spec.area_of_interest
        if not (x0 < x1 and y0 < y1):
            _fail("area_of_interest", "needs min < max in x and y")
        if x0 < 0 or y0 < 0 or x1 > spec.size[0] or y1 > spec.size[1]:
            _fail("area_of_interest", "extends outside the hall")
    swept = {route.name: _validate_route(spec, route) for route in spec.routes}
    _validate_sites(spec, "base station", spec.base_stations)
    _validate_sites(spec, "point", spec.points)
    for route in spec.routes:
        for entry in spec.points:
            if entry.xyz[2] < route.size[2] and swept[route.name].intersects(Point(entry.xyz[:2])):
                _fail(f"point '{entry.name}'", f"lies on forklift route '{route.name}'")


def _validate_objects(spec: HallSpec) -> None:
    """Unique names, not ``shell_``, node names that bind their material, inside the hall."""
    size = np.asarray(spec.size)
    library = spec.material_library
    seen: set[str] = set()
    for prim in spec.objects:
        where = f"object '{prim.name}'"
        if prim.name in seen:
            _fail(where, "duplicate object name")
        seen.add(prim.name)
        if prim.name.startswith("shell_"):
            _fail(where, "names starting with 'shell_' are reserved for the hall shell")
        node = spec.node_name(prim)
        bound = library.match(node)
        if bound != prim.material:
            _fail(
                where,
                f"node name '{node}' would bind material '{bound}', not '{prim.material}'; "
                "rename the object so it contains no other material name",
            )
        lo, hi = _bounds(prim)
        if np.any(lo < -BOUNDS_TOL_M) or np.any(hi > size + BOUNDS_TOL_M):
            _fail(
                where,
                f"extends outside the hall interior (bounds {np.round(lo, 3).tolist()} .. "
                f"{np.round(hi, 3).tolist()}, hall {list(spec.size)})",
            )


def _validate_route(spec: HallSpec, route: Route) -> Any:
    """A forklift route stays inside the hall and clear of every object it cannot drive over;
    returns its swept floor area (shapely)."""
    size = np.asarray(spec.size)
    area = _route_swept_area(route)
    minx, miny, maxx, maxy = area.bounds
    if minx < -BOUNDS_TOL_M or miny < -BOUNDS_TOL_M:
        _fail(f"routes.{route.name}", "the forklift leaves the hall (too close to a wall)")
    if maxx > size[0] + BOUNDS_TOL_M or maxy > size[1] + BOUNDS_TOL_M:
        _fail(f"routes.{route.name}", "the forklift leaves the hall (too close to a wall)")
    if route.size[2] > size[2]:
        _fail(f"routes.{route.name}.size", "forklift taller than the hall")
    for prim in spec.objects:
        lo, hi = _bounds(prim)
        if hi[2] <= DRIVE_OVER_HEIGHT_M or lo[2] >= route.size[2]:
            continue
        geom = _shapely_footprint(prim)
        if geom.intersects(area) and not geom.touches(area):
            _fail(f"routes.{route.name}", f"the forklift's path collides with '{prim.name}'")
    return area


def _validate_sites(
    spec: HallSpec, label: str, entries: Sequence[BaseStation | PointOfInterest]
) -> None:
    """Base stations or points lie inside the hall, clear of every solid and sheet."""
    size = np.asarray(spec.size)
    xyz = np.array([e.xyz for e in entries], dtype=float).reshape(-1, 3)
    for k, entry in enumerate(entries):
        p = xyz[k]
        if np.any(p <= POINT_CLEARANCE_M) or np.any(p >= size - POINT_CLEARANCE_M):
            _fail(f"{label} '{entry.name}'", f"{list(entry.xyz)} is outside the hall interior")
    for prim in spec.objects:
        inside = prim.contains(xyz, POINT_CLEARANCE_M)
        if np.any(inside):
            k = int(np.argmax(inside))
            verb = "is inside" if prim.closed else "lies on"
            _fail(f"{label} '{entries[k].name}'", f"{verb} object '{prim.name}'")


def _shapely_footprint(prim: Primitive) -> Any:
    from shapely.geometry import LineString, MultiPoint, Polygon

    xy = _footprint_xy(prim)
    if len(xy) == 2:
        return LineString(xy)
    if isinstance(prim, Sheet):
        return MultiPoint(xy).convex_hull
    return Polygon(xy)


def parse_hall_spec(data: Any, *, source: str = "") -> HallSpec:
    """Validate a hall description given as a parsed YAML mapping; see :func:`load_hall_spec`."""
    try:
        return _parse(data)
    except HallrayError as exc:
        if source:
            raise type(exc)(f"{source}: {exc}") from None
        raise


def _parse(data: Any) -> HallSpec:
    top = _mapping(data, "hall spec")
    _check_keys(
        top,
        "",
        ("hall",),
        (
            "schema_version",
            "name",
            "description",
            "materials",
            "templates",
            "objects",
            "base_stations",
            "points",
            "routes",
            "area_of_interest",
        ),
    )
    version = top.get("schema_version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        _fail(
            "schema_version", f"unsupported version {version!r} (this build reads {SCHEMA_VERSION})"
        )
    name = _string(top.get("name", "hall"), "name")
    description = _string(top.get("description", ""), "description")
    hall = _mapping(top["hall"], "hall")
    _check_keys(hall, "hall", ("size",), ("material", "wall_thickness"))
    size = _vector(hall["size"], "hall.size", 3, positive=True)
    check_size(max(size), f"hall.size {list(size)}")
    thickness = _number(hall.get("wall_thickness", 0.3), "hall.wall_thickness", positive=True)
    materials = _parse_materials(top.get("materials"))
    names = tuple(dict.fromkeys(ITU_MATERIALS + tuple(materials)))
    shell_material = _string(hall.get("material", "concrete"), "hall.material")
    if shell_material not in names:
        _fail("hall.material", f"unknown material '{shell_material}'", MaterialError)
    templates = _parse_templates(top.get("templates"), names)
    objects = _parse_objects(top.get("objects"), names, templates)
    bss = _parse_positions(top.get("base_stations"), "base_stations", with_note=False)
    pts = _parse_positions(top.get("points"), "points", with_note=True)
    routes = _parse_routes(top.get("routes"), names)
    aoi = None
    if top.get("area_of_interest") is not None:
        raw = _mapping(top["area_of_interest"], "area_of_interest")
        _check_keys(raw, "area_of_interest", ("min", "max"))
        lo = _vector(raw["min"], "area_of_interest.min", 2)
        hi = _vector(raw["max"], "area_of_interest.max", 2)
        aoi = (lo[0], lo[1], hi[0], hi[1])
    spec = HallSpec(
        name=name,
        size=size,
        shell_material=shell_material,
        wall_thickness=thickness,
        objects=tuple(objects),
        materials=materials,
        base_stations=tuple(BaseStation(n, x) for n, x, _ in bss),
        points=tuple(PointOfInterest(n, x, note) for n, x, note in pts),
        routes=tuple(routes),
        area_of_interest=aoi,
        description=description,
    )
    _validate(spec)
    return spec


def load_hall_spec(source: str | os.PathLike[str] | Mapping[str, Any]) -> HallSpec:
    """Read and validate a hall YAML file (or an already parsed mapping).

    Raises
    ------
    HallrayError
        (``SceneError`` or ``MaterialError``) with a one-line message naming the bad entry: unknown
        or missing keys, non-finite or negative sizes, unknown materials, objects outside the hall,
        base stations or points outside the hall or inside an object, routes through obstacles.
    """
    if isinstance(source, Mapping):
        return parse_hall_spec(source)
    path = Path(source)
    return parse_hall_spec(read_yaml(path, "hall description", SceneError), source=path.name)


# --------------------------------------------------------------------------------------------
# scene building and GLB
# --------------------------------------------------------------------------------------------


def _r(x: float) -> float:
    """Round for metadata (µm), normalising -0.0."""
    return float(round(float(x), 6)) + 0.0


def hall_metadata(spec: HallSpec) -> dict[str, Any]:
    """The ``metadata["hallray"]`` block stored in the GLB (JSON-serialisable, plain types)."""
    obstacles = []
    for prim in sorted(spec.objects, key=lambda p: p.name):
        lo, hi = _bounds(prim)
        obstacles.append(
            {
                "name": prim.name,
                "node": spec.node_name(prim),
                "material": prim.material,
                "kind": prim.kind,
                "z": [_r(lo[2]), _r(hi[2])],
                "xy": [[_r(a), _r(b)] for a, b in _footprint_xy(prim)],
            }
        )
    aoi = None
    if spec.area_of_interest is not None:
        x0, y0, x1, y1 = spec.area_of_interest
        aoi = {"min": [_r(x0), _r(y0)], "max": [_r(x1), _r(y1)]}
    return {
        "schema_version": SCHEMA_VERSION,
        "name": spec.name,
        "description": spec.description,
        "hall": {
            "size": [_r(v) for v in spec.size],
            "material": spec.shell_material,
            "wall_thickness": _r(spec.wall_thickness),
        },
        "materials": {k: dict(v) for k, v in spec.materials.items()},
        "base_stations": [
            {"name": b.name, "xyz": [_r(v) for v in b.xyz]} for b in spec.base_stations
        ],
        "points": [
            {"name": p.name, "xyz": [_r(v) for v in p.xyz], "note": p.note} for p in spec.points
        ],
        "routes": [
            {
                "name": r.name,
                "size": [_r(v) for v in r.size],
                "material": r.material,
                "waypoints": [[_r(a), _r(b)] for a, b in r.waypoints],
                "speed": _r(r.speed),
                "mode": r.mode,
            }
            for r in spec.routes
        ],
        "area_of_interest": aoi,
        "obstacles_2d": obstacles,
    }


def paint(mesh: trimesh.Trimesh, material: str, rgb: Sequence[float]) -> None:
    """Give a mesh its glTF material: named after the radio material, base colour ``rgb`` (the
    palette's, :mod:`raytrace.core.palette`), matte and two-sided."""
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    mesh.visual = TextureVisuals(
        material=PBRMaterial(
            name=material,
            baseColorFactor=[*rgb, 1.0],
            metallicFactor=0.0,
            roughnessFactor=1.0,
            doubleSided=True,
        )
    )


def object_mesh(prim: Primitive, rgb: Sequence[float]) -> trimesh.Trimesh:
    """A primitive as a ``trimesh.Trimesh`` (vertices in world coordinates, not merged).

    Its ``metadata`` (stored as glTF mesh extras) holds ``object``, ``material``, ``kind`` and
    ``closed``; its glTF material is named after the radio material, coloured ``rgb``.
    """
    vertices, faces = prim.mesh_arrays()
    mesh = trimesh.Trimesh(vertices=vertices + 0.0, faces=faces, process=False)
    paint(mesh, prim.material, rgb)
    mesh.metadata = {
        "object": prim.name,
        "material": prim.material,
        "kind": prim.kind,
        "closed": bool(prim.closed),
    }
    return mesh


def scene_from_primitives(
    primitives: Sequence[Primitive],
    metadata: Mapping[str, Any],
    *,
    user_materials: Mapping[str, Any] = (),
) -> trimesh.Scene:
    """A scene with one node per primitive, named ``node_name(...)``, sorted by node name, each
    coloured by :func:`raytrace.core.palette.material_colors` over the primitives' materials."""
    nodes = {}
    for prim in primitives:
        name = node_name(prim.name, prim.material, user_materials)
        if name in nodes:
            raise SceneError(f"duplicate node name '{name}'")
        nodes[name] = prim
    colors = material_colors(p.material for p in primitives)
    scene = trimesh.Scene()
    for name in sorted(nodes):
        mesh = object_mesh(nodes[name], colors[nodes[name].material])
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    scene.metadata["hallray"] = dict(metadata)
    return scene


def build_scene(spec: HallSpec) -> trimesh.Scene:
    """The hall as a scene: shell slabs plus every object, one node each (see module doc).

    ``scene.metadata["hallray"]`` holds :func:`hall_metadata`; it is written to the GLB as the
    scene's extras and comes back on load.
    """
    return scene_from_primitives(
        spec.shell() + spec.objects, hall_metadata(spec), user_materials=spec.materials
    )


def glb_bytes(scene: trimesh.Scene) -> bytes:
    """GLB bytes of a scene. trimesh writes nodes in insertion order and no timestamp, so the
    same scene gives the same bytes (checked by the tests)."""
    return bytes(scene.export(file_type="glb"))


def write_glb(spec_or_scene: HallSpec | trimesh.Scene, path: str | os.PathLike[str]) -> bytes:
    """Build (if given a spec) and write the GLB atomically; returns the bytes written."""
    scene = build_scene(spec_or_scene) if isinstance(spec_or_scene, HallSpec) else spec_or_scene
    data = glb_bytes(scene)
    write_atomic(path, data)
    return data


# --------------------------------------------------------------------------------------------
# the tracer's scene and the line-of-sight table (Embree queries of the scene)
# --------------------------------------------------------------------------------------------


def tracer_scene(spec: HallSpec) -> Scene:
    """The tracer's :class:`~raytrace.scene.model.Scene` of a hall, built in memory (no GLB).

    Objects are named and ordered as :func:`raytrace.scene.io.load_scene` names and orders
    them from the GLB; vertices stay float64 (the GLB stores float32, a difference of < 1e-5 m).
    ``scene.metadata["hallray"]`` is :func:`hall_metadata`.
    """
    meshes = []
    for prim in spec.shell() + spec.objects:
        v, f = prim.mesh_arrays()
        meshes.append((spec.node_name(prim), trimesh.Trimesh(v, f, process=False), prim.material))
    meshes.sort(key=lambda m: m[0])
    return Scene.from_meshes(
        meshes, spec.material_library, metadata={"hallray": hall_metadata(spec)}, source=spec.name
    )


def object_name(node: str, material: str) -> str:
    """The object name in a node name: ``clutter_0012_itu_metal`` -> ``clutter_0012`` (the
    inverse of :func:`node_name` for the node's own material)."""
    for suffix in (f"_itu_{material}", f"_{material}"):
        if node.endswith(suffix) and len(node) > len(suffix):
            return node[: -len(suffix)]
    return node


def segment_blockers(
    scene: Scene, start: np.ndarray, end: np.ndarray, *, max_blockers: int | None = None
) -> list[tuple[str, ...]]:
    """Objects crossed by each segment ``start[k] -> end[k]`` (both ``(n, 3)`` m).

    The scene's Embree walk along the segments
    (:meth:`~raytrace.scene.model.Scene.segment_objects`, with the scene's end margin). Returns,
    per segment, the blocking object names (:func:`object_name`) ordered by first hit distance
    from ``start``, at most ``max_blockers`` of them (None: all).
    """
    rows = scene.segment_objects(start, end, max_objects=max_blockers)
    names = [object_name(o.name, o.material) for o in scene.objects]
    return [tuple(names[i] for i in row if i >= 0) for row in rows]


def line_of_sight(
    hall: HallSpec | Scene, *, max_blockers: int | None = None
) -> dict[str, dict[str, tuple[str, ...]]]:
    """``{point: {base_station: blocking object names}}``; an empty tuple means line of sight.

    ``hall`` is a spec (its :func:`tracer_scene` is built) or a scene with
    ``metadata["hallray"]`` (a hall GLB loaded with :func:`raytrace.scene.io.load_scene`),
    whose points and base stations are used. Blockers as in :func:`segment_blockers`.
    """
    scene = tracer_scene(hall) if isinstance(hall, HallSpec) else hall
    if not isinstance(scene, Scene):
        raise SceneError(
            f"line_of_sight needs a HallSpec or a Scene (load_scene), got {type(hall).__name__}"
        )
    meta = scene.metadata.get("hallray", {})
    bss = [(b["name"], b["xyz"]) for b in meta.get("base_stations", [])]
    pts = [(p["name"], p["xyz"]) for p in meta.get("points", [])]
    table: dict[str, dict[str, tuple[str, ...]]] = {p: {} for p, _ in pts}
    if not bss or not pts:
        return table
    start = np.array([b for _, b in bss for _ in pts], dtype=float)
    end = np.array([p for _ in bss for _, p in pts], dtype=float)
    blockers = iter(segment_blockers(scene, start, end, max_blockers=max_blockers))
    for bname, _ in bss:
        for pname, _ in pts:
            table[pname][bname] = next(blockers)
    return table


def los_note(status: Mapping[str, Sequence[str]]) -> str:
    """The machine-readable LoS part of a point's note: ``LoS to BS1, BS2; blocked from BS3 by a``."""
    los = [b for b, blk in status.items() if not blk]
    parts = [f"LoS to {', '.join(los) if los else 'none'}"]
    parts += [f"blocked from {b} by {', '.join(blk)}" for b, blk in status.items() if blk]
    return "; ".join(parts)


def los_markdown(
    spec: HallSpec, table: Mapping[str, Mapping[str, Sequence[str]]] | None = None
) -> str:
    """The LoS table of a hall as markdown: one row per point, LoS/NLoS per base station, the
    blocking objects, and a count of points by number of blocked base stations."""
    if table is None:
        table = line_of_sight(spec)
    bss = [b.name for b in spec.base_stations]
    rows = [
        "| point | x, y, z (m) | " + " | ".join(bss) + " | blocked by |",
        "|" + "---|" * (len(bss) + 3),
    ]
    counts = [0] * (len(bss) + 1)
    for p in spec.points:
        status = table[p.name]
        counts[sum(bool(status[b]) for b in bss)] += 1
        cells = " | ".join("LoS" if not status[b] else "**NLoS**" for b in bss)
        blockers = "; ".join(f"{b}: {', '.join(status[b])}" for b in bss if status[b]) or "-"
        xyz = ", ".join(f"{c:g}" for c in p.xyz)
        rows.append(f"| {p.name} | {xyz} | {cells} | {blockers} |")
    summary = ", ".join(f"{c} blocked from {n}" for n, c in enumerate(counts) if c)
    return "\n".join(rows) + f"\n\nPoints by number of blocked base stations: {summary}.\n"


_NOTE_LOS_RE = re.compile(r"LoS to ([^;]*)")
_NOTE_BLOCKED_RE = re.compile(r"blocked from (\S+) by ([^;]*)")


def parse_los_note(note: str) -> dict[str, tuple[str, ...]] | None:
    """Inverse of :func:`los_note` (reads the clauses anywhere in a note); None if absent."""
    m = _NOTE_LOS_RE.search(note)
    if m is None:
        return None
    out: dict[str, tuple[str, ...]] = {}
    names = m.group(1).strip()
    if names != "none":
        for b in names.split(","):
            out[b.strip()] = ()
    for b, blk in _NOTE_BLOCKED_RE.findall(note):
        out[b] = tuple(x.strip() for x in blk.split(","))
    return out


# --------------------------------------------------------------------------------------------
# top view drawing
# --------------------------------------------------------------------------------------------


def plot_top_view(
    ax: Any,
    spec_or_scene: HallSpec | trimesh.Scene | Mapping[str, Any],
    *,
    show_points: bool = True,
    show_routes: bool = True,
    show_legend: bool = True,
    label_objects: bool = False,
) -> None:
    """Draw a hall seen from above on a matplotlib ``ax``.

    Obstacles are filled by material (taller ones on top; colours of
    :mod:`raytrace.core.palette`), sheets drawn as thick lines, base stations as triangles,
    points of interest as numbered red squares, the area of interest as a dashed rectangle and
    forklift routes as dashed arrows. Accepts a :class:`HallSpec`, a scene with
    ``metadata["hallray"]`` (e.g. a loaded GLB) or that metadata mapping itself.
    """
    if isinstance(spec_or_scene, HallSpec):
        meta: Mapping[str, Any] = hall_metadata(spec_or_scene)
    elif isinstance(spec_or_scene, trimesh.Scene):
        meta = spec_or_scene.metadata["hallray"]
    else:
        meta = spec_or_scene
    sx, sy, _ = meta["hall"]["size"]
    handles = _draw_obstacles(ax, meta, label_objects)
    handles += _draw_area(ax, meta.get("area_of_interest"))
    if show_routes:
        handles += _draw_routes(ax, meta.get("routes") or [])
    points = (meta.get("points") or []) if show_points else []
    handles += _draw_sites(ax, meta.get("base_stations") or [], points)
    ax.set_xlim(-1.5, sx + 1.5)
    ax.set_ylim(-1.5, sy + 1.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if show_legend:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7.5)


def _draw_obstacles(ax: Any, meta: Mapping[str, Any], label_objects: bool) -> list[Any]:
    """The shell, the interior and the obstacles (lowest first); legend patches of their
    materials."""
    from matplotlib.patches import Patch, Polygon, Rectangle

    sx, sy, _ = meta["hall"]["size"]
    t = meta["hall"].get("wall_thickness", 0.3)
    shell = meta["hall"].get("material", "concrete")
    colors = material_colors([shell, *(o["material"] for o in meta["obstacles_2d"])])
    ax.add_patch(
        Rectangle((-t, -t), sx + 2 * t, sy + 2 * t, fc=colors[shell], ec="k", lw=1, zorder=0.4)
    )
    ax.add_patch(Rectangle((0, 0), sx, sy, facecolor="white", edgecolor="k", lw=0.8, zorder=0.5))
    used: dict[str, tuple[float, float, float]] = {}
    for obs in sorted(meta["obstacles_2d"], key=lambda o: (o["z"][1], o["name"])):
        rgb = used[obs["material"]] = colors[obs["material"]]
        xy = np.asarray(obs["xy"], dtype=float)
        z = 1.0 + 0.001 * obs["z"][1]
        if len(xy) == 2:  # vertical sheet: a thick line
            ax.plot(xy[:, 0], xy[:, 1], color=rgb, lw=2.2, solid_capstyle="butt", zorder=z)
        elif obs["kind"] == "sheet":  # horizontal or tilted sheet (a ceiling): hatched, see-through
            ax.add_patch(
                Polygon(xy, closed=True, fill=False, hatch="///", ec=rgb, lw=0.8, zorder=z)
            )
        else:
            ax.add_patch(
                Polygon(xy, closed=True, facecolor=rgb, edgecolor="0.15", lw=0.4, zorder=z)
            )
        if label_objects:
            c = xy.mean(axis=0)
            ax.text(c[0], c[1], obs["name"], fontsize=4, ha="center", va="center", zorder=9)
    return [
        Patch(facecolor=rgb, edgecolor="0.15", label=m.replace("_", " ")) for m, rgb in used.items()
    ]


def _draw_area(ax: Any, aoi: Mapping[str, Any] | None) -> list[Any]:
    """The area of interest as a dashed green rectangle (if any); its legend line."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    if aoi is None:
        return []
    (x0, y0), (x1, y1) = aoi["min"], aoi["max"]
    ax.add_patch(
        Rectangle(
            (x0, y0), x1 - x0, y1 - y0, fill=False, ls=(0, (6, 3)), lw=1.4, ec="green", zorder=6
        )
    )
    return [Line2D([], [], color="green", ls="--", label="area of interest")]


def _draw_routes(ax: Any, routes: Sequence[Mapping[str, Any]]) -> list[Any]:
    """Forklift routes as dashed polylines with an arrow on every leg; one legend line."""
    from matplotlib.lines import Line2D

    for route in routes:
        wp = np.asarray(route["waypoints"], dtype=float)
        if route["mode"] == "loop":
            wp = np.vstack([wp, wp[:1]])
        ax.plot(wp[:, 0], wp[:, 1], ls=(0, (4, 3)), color="0.25", lw=1.2, zorder=5)
        for a, b in zip(wp[:-1], wp[1:], strict=True):
            mid = 0.5 * (a + b)
            d = 0.01 * (b - a) / max(np.linalg.norm(b - a), 1e-9)
            ax.annotate(
                "",
                xy=mid + d,
                xytext=mid - d,
                arrowprops={"arrowstyle": "-|>", "color": "0.25", "lw": 1.0},
                zorder=5,
            )
        ax.text(wp[0, 0], wp[0, 1] + 0.6, route["name"], fontsize=6.5, color="0.2", zorder=7)
    return [Line2D([], [], color="0.25", ls="--", label="forklift route")] if routes else []


def _draw_sites(
    ax: Any, base_stations: Sequence[Mapping[str, Any]], points: Sequence[Mapping[str, Any]]
) -> list[Any]:
    """Base stations (gold triangles, name and height) and points of interest (red squares,
    numbered); their legend markers."""
    from matplotlib.lines import Line2D

    handles: list[Any] = []
    for bs in base_stations:
        x, y, z = bs["xyz"]
        ax.plot(x, y, marker="^", ms=10, mfc="gold", mec="k", zorder=8)
        ax.text(x + 0.5, y + 0.5, f"{bs['name']}\n{z:g} m", fontsize=7, weight="bold", zorder=9)
    if base_stations:
        handles.append(
            Line2D([], [], marker="^", ls="", mfc="gold", mec="k", ms=8, label="base station")
        )
    for p in points:
        x, y, _ = p["xyz"]
        ax.plot(x, y, marker="s", ms=5, mfc="red", mec="darkred", zorder=8)
        label = re.sub(r"^\D*0*(?=\d)", "", p["name"]) or p["name"]
        ax.text(x + 0.35, y - 0.75, label, fontsize=6.5, color="darkred", zorder=9)
    if points:
        handles.append(
            Line2D(
                [], [], marker="s", ls="", mfc="red", mec="darkred", ms=6, label="point of interest"
            )
        )
    return handles
