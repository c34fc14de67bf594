"""Reading a Collada file (.dae: SketchUp's export, also Blender's and many CAD tools') through
pycollada: one object per placed geometry and material, in world coordinates, with the geometry's
and the material's names as the hints that bind it to an ITU-R P.2040 material.

trimesh's own Collada loader drops the names of nodes and materials, so a SketchUp hall's
``Concrete`` and ``Glass`` reached the binding as ``g0``, ``g1``: this reader keeps them. The unit
and up axis the file states (``<unit meter=...>``, ``<up_axis>``) are applied by
:func:`raytrace.scene.io.load_scene`.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import SceneError

__all__ = ["read_collada"]


def read_collada(p: Path, scale: float = 1.0) -> list[tuple[str, Any, list[str]]]:
    """The placed geometries of a Collada file as ``(name, trimesh.Trimesh, hints)``.

    Parameters
    ----------
    p : Path, the .dae file
    scale : float, metres per unit of the file's numbers

    Returns
    -------
    list of (name, mesh, hints): one entry per placed geometry and material. ``name`` is the
    geometry's name (``#k`` for its k-th placement after the first, ``/material`` for each
    material when it has several); the mesh in metres and world coordinates; ``hints`` the
    material's name and id, then the geometry's name and id.

    Raises
    ------
    SceneError
        pycollada missing, a file it cannot read, NaN vertices, or no triangles.
    """
    try:
        import collada
    except ImportError:
        raise SceneError(f"reading {p.name} (Collada) needs pycollada: pip install "
                         "'hallray[dae]' (or pip install pycollada)") from None  # fmt: skip
    import trimesh

    with warnings.catch_warnings():
        # pycollada's transforms are numpy matrices, which numpy marks as pending deprecation
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        try:
            doc = collada.Collada(str(p), ignore=[collada.common.DaeUnsupportedError,
                                                  collada.common.DaeBrokenRefError])  # fmt: skip
        except Exception as exc:  # pycollada raises many types for unreadable files
            raise SceneError(f"cannot read scene {p.name}: {type(exc).__name__}: "
                             f"{exc}".splitlines()[0]) from None  # fmt: skip
        if doc.scene is None:
            raise SceneError(f"scene {p.name} has no <scene> to place its geometries")
        parts = _placed_parts(doc, scale)
    named = []
    for key, (verts, faces, hints, _) in parts.items():
        v, f = np.concatenate(verts), np.concatenate(faces)
        if not np.isfinite(v).all():
            raise SceneError(f"scene {p.name}: object {key!r} has NaN or infinite vertex "
                             "coordinates")  # fmt: skip
        named.append((key, trimesh.Trimesh(vertices=v, faces=f, process=True, validate=False),
                      [str(h) for h in hints if h]))  # fmt: skip
    if not named:
        raise SceneError(f"scene {p.name} contains no triangles")
    return sorted(named, key=lambda t: t[0])


def _placed_parts(doc: Any, scale: float) -> dict[str, list]:
    """Every placement of every geometry of ``doc`` in world coordinates and metres, by object
    name: ``[vertex blocks, face blocks, hints, vertices so far]``."""
    placed: dict[str, int] = {}
    parts: dict[str, list] = {}
    for bound in doc.scene.objects("geometry"):
        geom = bound.original
        base = _label(geom.name or geom.id)
        k = placed[base] = placed.get(base, 0) + 1
        name = base if k == 1 else f"{base}#{k}"
        # polygon lists (Blender's export without triangulation) as their triangles; lines
        # carry no surface
        triangles = [t if type(t).__name__ == "BoundTriangleSet" else t.triangleset()
                     for t in bound.primitives() if hasattr(t, "triangleset")
                     or type(t).__name__ == "BoundTriangleSet"]  # fmt: skip
        mats = {_material_name(t.material) for t in triangles}
        for tri in triangles:
            if tri.vertex is None or not len(tri.vertex_index):
                continue
            mat = _material_name(tri.material)
            key = name if len(mats) == 1 else f"{name}/{_label(mat)}"
            entry = parts.setdefault(key, [[], [], [mat, getattr(tri.material, "id", ""),
                                                    geom.name or "", geom.id or ""], 0])  # fmt: skip
            v = np.asarray(tri.vertex, dtype=np.float64).reshape(-1, 3) * scale
            # this block's indices follow the vertices of the object's earlier blocks
            entry[1].append(np.asarray(tri.vertex_index, dtype=np.int64).reshape(-1, 3) + entry[3])
            entry[0].append(v)
            entry[3] += len(v)
    return parts


def _material_name(material: Any) -> str:
    """A bound material's name (or id; "" for none)."""
    return str(getattr(material, "name", None) or getattr(material, "id", None) or "")


def _label(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", str(text)).strip("-") or "unnamed"
