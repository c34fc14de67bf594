"""The tracer's scene of a hall (built in memory) and the line-of-sight table of its points
and base stations (Embree queries), with the notes that record it in a hall YAML.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np
import trimesh

from ...core.errors import SceneError
from ...scene.model import Scene
from .build import hall_metadata
from .model import HallSpec


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
