"""Hall YAML -> :class:`HallSpec`: the strict validation of every section (schema in
docs/hall.md), each error one line naming the bad entry (``<where>: <what>``), templates placed
many times, and the checks of the whole (objects inside the hall and apart, sites clear of
solids, routes clear of obstacles).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hallray.errors import brief
from hallray.limits import check_size

from ...core.errors import HallrayError, MaterialError, SceneError
from ...core.fileio import read_yaml
from ...core.scale import check_extent
from ...physics.materials import MaterialLibrary
from ...scene.motion import ROUTE_MODES, Route
from .model import (
    BOUNDS_TOL_M,
    DEFAULT_CYLINDER_SECTIONS,
    DRIVE_OVER_HEIGHT_M,
    ITU_MATERIALS,
    POINT_CLEARANCE_M,
    SCHEMA_VERSION,
    BaseStation,
    Box,
    Cylinder,
    HallSpec,
    PointOfInterest,
    Primitive,
    Sheet,
    footprint_xy,
    primitive_bounds,
    rotate_xy,
)

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")
_MATERIAL_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_MATERIAL_KEYS = ("eta_real", "sigma", "thickness", "a", "b", "c", "d", "f_range_ghz")


def _fail(where: str, msg: str, cls: type[HallrayError] = SceneError) -> None:
    raise cls(f"{where}: {msg}" if where else msg)


def _mapping(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        _fail(where, f"expected a mapping, got {type(value).__name__}")
    for key in value:
        if not isinstance(key, str):
            _fail(where, f"keys must be strings, got {brief(key)}")
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
        _fail(where, f"expected a number, got {brief(value)}")
    out = float(value)
    if not math.isfinite(out):
        _fail(where, f"expected a finite number, got {brief(value)}")
    if positive and out <= 0.0:
        _fail(where, f"must be > 0, got {brief(value)}")
    if nonneg and out < 0.0:
        _fail(where, f"must be >= 0, got {brief(value)}")
    return out


def _vector(value: Any, where: str, n: int, *, positive: bool = False) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        _fail(where, f"expected a list of {n} numbers, got {brief(value)}")
    return tuple(_number(v, f"{where}[{i}]", positive=positive) for i, v in enumerate(value))


def _string(value: Any, where: str) -> str:
    if not isinstance(value, str):
        _fail(where, f"expected a string, got {brief(value)}")
    return value


def _name(value: Any, where: str, *, template: bool = False) -> str:
    name = _string(value, where)
    check = re.sub(r"\{[^{}]*\}", "0", name) if template else name
    if not _NAME_RE.match(check):
        _fail(where, f"bad name {brief(name)} (letters, digits, '_' and '-' only)")
    return name


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
            _fail(where, f"expected a mapping, got {brief(entry)}", MaterialError)
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
        _fail(f"{where}.count", f"expected n or [n1, n2], got {brief(count)}")
    for n in counts:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            _fail(f"{where}.count", f"counts must be integers >= 1, got {brief(count)}")
    check_size("hall objects", float(np.prod(np.array(counts, dtype=float))), f"{where}.count {counts}")
    step = rep["step"]
    if not isinstance(step, list):
        _fail(f"{where}.step", f"expected a list, got {brief(step)}")
    if len(counts) == 1:
        if len(step) not in (2, 3):
            _fail(f"{where}.step", f"expected [dx, dy] or [dx, dy, dz], got {brief(step)}")
        axes = [np.array(_vector(step, f"{where}.step", len(step)) + (0.0,) * (3 - len(step)))]
    elif step and all(isinstance(s, list) for s in step):
        if len(step) != 2:
            _fail(f"{where}.step", "a grid needs two step vectors")
        axes = []
        for k, s in enumerate(step):
            if len(s) not in (2, 3):
                _fail(f"{where}.step[{k}]", f"expected [dx, dy] or [dx, dy, dz], got {brief(s)}")
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
            _fail(where, f"name template {brief(template)} needs a 'repeat'")
        return template
    if "{" in template:
        try:
            name = template.format(**{k: v for k, v in fields.items() if k != "grid"})
        except (KeyError, ValueError, IndexError) as exc:
            _fail(where, f"bad name template {brief(template)} ({exc}); fields: i, j, n, I")
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
            _fail(f"{where}.sections", f"expected an integer >= 3, got {brief(sections)}")
        check_size("cylinder sections", sections, f"{where}.sections")
        return Cylinder(name, material, base, radius, height, sections)
    if kind == "sheet":
        _check_keys(raw, where, ("name", "type", "material", "origin", "u", "v"), _SHEET_KEYS)
        origin = _vector(raw["origin"], f"{where}.origin", 3)
        u = _vector(raw["u"], f"{where}.u", 3)
        v = _vector(raw["v"], f"{where}.v", 3)
        if np.linalg.norm(np.cross(u, v)) < 1e-9:
            _fail(where, "sheet edges u and v are parallel or zero (zero area)")
        return Sheet(name, material, origin, u, v)
    _fail(f"{where}.type", f"unknown type {brief(kind)} (box, cylinder, sheet, instance)")
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
        q = rotate_xy(np.asarray(p, dtype=float), yaw_deg) + offset
        return (float(q[0]), float(q[1]), float(q[2]))

    def turn(p: Sequence[float]) -> tuple[float, float, float]:
        q = rotate_xy(np.asarray(p, dtype=float), yaw_deg)
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
            check_size("hall objects", len(out) + len(placements) * len(templates[tname]),
                       f"objects after {where}")  # fmt: skip
            for fields, off in placements:
                inst = _format_name(base, fields, where)
                for prim in templates[tname]:
                    out.append(_place(prim, f"{inst}_{prim.name}", at + off, yaw))
        else:
            check_size("hall objects", len(out) + len(placements), f"objects after {where}")
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
            _fail(f"{where}.mode", f"expected one of {', '.join(ROUTE_MODES)}, got {brief(mode)}")
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
    _validate_overlaps(spec)
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
        lo, hi = primitive_bounds(prim)
        if np.any(lo < -BOUNDS_TOL_M) or np.any(hi > size + BOUNDS_TOL_M):
            _fail(
                where,
                f"extends outside the hall interior (bounds {np.round(lo, 3).tolist()} .. "
                f"{np.round(hi, 3).tolist()}, hall {list(spec.size)})",
            )


#: Overlap of two closed solids tolerated (touching is fine): height, m, and footprint, m^2.
OVERLAP_TOL_M = 1e-6
OVERLAP_TOL_M2 = 1e-6


def _validate_overlaps(spec: HallSpec) -> None:
    """Closed solids may touch but not overlap (docs/hall.md: the tracer counts the solids a path
    crosses). Every closed primitive is a vertical prism, so two overlap exactly when their
    height ranges and their footprints overlap."""
    from shapely import STRtree

    solids = [p for p in spec.objects if p.closed]
    if len(solids) < 2:
        return
    feet = [_shapely_footprint(p) for p in solids]
    bounds = [primitive_bounds(p) for p in solids]
    pairs = STRtree(feet).query(feet, predicate="intersects")
    for i, j in zip(*pairs):
        if i >= j:
            continue
        (lo_i, hi_i), (lo_j, hi_j) = bounds[i], bounds[j]
        if min(hi_i[2], hi_j[2]) - max(lo_i[2], lo_j[2]) <= OVERLAP_TOL_M:
            continue
        if feet[i].intersection(feet[j]).area > OVERLAP_TOL_M2:
            _fail(
                f"object '{solids[i].name}'",
                f"overlaps object '{solids[j].name}': closed solids may touch but not overlap "
                "(the tracer counts the solids a path crosses); move or shrink one",
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
        lo, hi = primitive_bounds(prim)
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
        # at least POINT_CLEARANCE_M: exactly 1 cm is allowed (up to rounding)
        if np.any(p < POINT_CLEARANCE_M - BOUNDS_TOL_M) or np.any(
            p > size - POINT_CLEARANCE_M + BOUNDS_TOL_M
        ):
            _fail(f"{label} '{entry.name}'", f"{list(entry.xyz)} is outside the hall interior")
    for prim in spec.objects:
        inside = prim.contains(xyz, POINT_CLEARANCE_M - BOUNDS_TOL_M)
        if np.any(inside):
            k = int(np.argmax(inside))
            verb = "is inside" if prim.closed else "lies on"
            _fail(f"{label} '{entries[k].name}'", f"{verb} object '{prim.name}'")


def _shapely_footprint(prim: Primitive) -> Any:
    from shapely.geometry import LineString, MultiPoint, Polygon

    xy = footprint_xy(prim)
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
            "schema_version", f"unsupported version {brief(version)} (this build reads {SCHEMA_VERSION})"
        )
    name = _string(top.get("name", "hall"), "name")
    description = _string(top.get("description", ""), "description")
    hall = _mapping(top["hall"], "hall")
    _check_keys(hall, "hall", ("size",), ("material", "wall_thickness"))
    size = _vector(hall["size"], "hall.size", 3, positive=True)
    check_extent(size, f"hall.size {list(size)}")
    thickness = _number(hall.get("wall_thickness", 0.3), "hall.wall_thickness", positive=True)
    materials = _parse_materials(top.get("materials"))
    names = tuple(dict.fromkeys(ITU_MATERIALS + tuple(materials)))
    shell_material = _string(hall.get("material", "concrete"), "hall.material")
    if shell_material not in names:
        _fail("hall.material", f"unknown material '{shell_material}'", MaterialError)
    templates = _parse_templates(top.get("templates"), names)
    objects = _parse_objects(top.get("objects"), names, templates)
    triangles = sum(12 if o.kind == "box" else 4 * o.sections if o.kind == "cylinder" else 2
                    for o in objects)  # fmt: skip
    check_size("hall triangles", triangles, "the hall's objects")
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
