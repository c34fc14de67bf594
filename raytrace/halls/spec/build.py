"""A :class:`HallSpec` as a trimesh scene (one node per object, its material in the node
name) and its GLB, written reproducibly (same YAML -> same bytes) and atomically, with the
``metadata["hallray"]`` block (:func:`hall_metadata`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import trimesh

from ...core.errors import SceneError
from ...core.fileio import write_atomic
from ...core.palette import material_colors
from .model import SCHEMA_VERSION, HallSpec, Primitive, footprint_xy, node_name, primitive_bounds


def _r(x: float) -> float:
    """Round for metadata (µm), normalising -0.0."""
    return float(round(float(x), 6)) + 0.0


def hall_metadata(spec: HallSpec) -> dict[str, Any]:
    """The ``metadata["hallray"]`` block stored in the GLB (JSON-serialisable, plain types)."""
    obstacles = []
    for prim in sorted(spec.objects, key=lambda p: p.name):
        lo, hi = primitive_bounds(prim)
        obstacles.append(
            {
                "name": prim.name,
                "node": spec.node_name(prim),
                "material": prim.material,
                "kind": prim.kind,
                "z": [_r(lo[2]), _r(hi[2])],
                "xy": [[_r(a), _r(b)] for a, b in footprint_xy(prim)],
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
