"""A reconstruction as a scene: the trimesh scene of its elements, named by material, and
:func:`scan_to_scene`, the whole pipeline from a cloud file to a GLB with its summary.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ...core.errors import HallrayError, SceneError
from ...core.fileio import read_yaml, write_atomic
from ...core.palette import material_colors
from .cloud import read_cloud
from .element import Element
from .options import MaterialRules, ScanOptions
from .reconstruct import reconstruct


def scene_from_elements(
    elements: Sequence[Element], metadata: Mapping[str, Any], rules: MaterialRules
) -> Any:
    """A ``trimesh.Scene`` with one node per element, named after its material, the glTF
    material named after the radio material, and ``metadata["hallray"]``."""
    import trimesh

    from ..spec.build import paint

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
    from ..spec.build import glb_bytes

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
