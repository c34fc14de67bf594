"""Reading a building model in IFC (Industry Foundation Classes, the BIM exchange format that
Revit, ArchiCAD, Tekla and Allplan write) through IfcOpenShell: one object per building element,
in metres, in the model's world coordinates, with the element's IFC materials and class as the
hints that bind it to an ITU-R P.2040 material (docs/scene.md, "Building models in IFC").

IfcOpenShell (``pip install 'hallray[ifc]'``) tessellates each element's geometry (extrusions,
Booleans with their openings cut, B-reps) and converts the file's length unit to metres; IFC is
z-up. Spaces, openings and other elements without a physical body are not read.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import SceneError

__all__ = ["IFC_SKIPPED", "IFC_CLASS_MATERIALS", "IFC_MATERIAL_WORDS", "read_ifc", "material_hints"]

#: IFC classes that are not a physical body (rooms, the voids cut for windows and doors,
#: annotations, grids, virtual boundaries) or not part of the hall (the terrain of its site).
IFC_SKIPPED = ("IfcSpace", "IfcOpeningElement", "IfcVirtualElement", "IfcAnnotation", "IfcGrid",
               "IfcSite", "IfcSpatialZone", "IfcExternalSpatialElement")  # fmt: skip
#: Words of CAD and BIM material names (whole words, any case) -> the ITU-R P.2040 material
#: they mean, where the name is not one of the library's own (``Steel, Galvanized``).
IFC_MATERIAL_WORDS = {
    "steel": "metal", "aluminium": "metal", "aluminum": "metal", "iron": "metal",
    "stainless": "metal", "copper": "metal", "zinc": "metal", "metallic": "metal",
    "gypsum": "plasterboard", "drywall": "plasterboard", "plaster": "plasterboard",
    "timber": "wood", "masonry": "brick", "glazing": "glass", "cement": "concrete",
}  # fmt: skip
#: The material of an element whose IFC materials name none of the library's, by IFC class
#: (the last hint; a ``bind`` pattern on the object name, which starts with the class, or a
#: named material wins over it). Classes not listed need a material name, a pattern or a default.
IFC_CLASS_MATERIALS = {
    "IfcWindow": "glass", "IfcCurtainWall": "glass", "IfcDoor": "wood",
    "IfcWall": "concrete", "IfcWallStandardCase": "concrete", "IfcSlab": "concrete",
    "IfcRoof": "concrete", "IfcColumn": "concrete", "IfcBeam": "concrete",
    "IfcFooting": "concrete", "IfcPile": "concrete", "IfcStair": "concrete",
    "IfcStairFlight": "concrete", "IfcRamp": "concrete", "IfcRampFlight": "concrete",
    "IfcMember": "metal", "IfcRailing": "metal", "IfcFlowSegment": "metal",
    "IfcDuctSegment": "metal", "IfcPipeSegment": "metal", "IfcCableCarrierSegment": "metal",
}  # fmt: skip


def read_ifc(p: Path, threads: int = 1) -> list[tuple[str, Any, list[str]]]:
    """The building elements of an IFC file as ``(name, trimesh.Trimesh, hints)``.

    Parameters
    ----------
    p : Path, the .ifc file
    threads : int, IfcOpenShell's tessellation threads

    Returns
    -------
    list of (name, mesh, hints): ``name`` is ``{IfcClass}_{Name}_{GlobalId}`` (unique: the
    GlobalId), the mesh in metres and world coordinates, ``hints`` :func:`material_hints`.

    Raises
    ------
    SceneError
        IfcOpenShell missing, a file it cannot read, or no element with a body.
    """
    try:
        import ifcopenshell
        import ifcopenshell.geom
    except ImportError:
        raise SceneError(f"reading {p.name} (IFC) needs IfcOpenShell: pip install "
                         "'hallray[ifc]' (or pip install ifcopenshell)") from None  # fmt: skip
    import trimesh

    try:
        model = ifcopenshell.open(str(p))
    except Exception as exc:  # IfcOpenShell raises its own types for unreadable files
        raise SceneError(f"cannot read scene {p.name}: {type(exc).__name__}: {exc}".splitlines()[0]
                         ) from None  # fmt: skip
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    skipped = [e for c in IFC_SKIPPED for e in _by_type(model, c)]
    iterator = ifcopenshell.geom.iterator(settings, model, max(1, int(threads)), exclude=skipped)
    named: list[tuple[str, Any, list[str]]] = []
    read: set[int] = set()
    by_class: dict[str, int] = {}  # elements without IFC materials, by the class guess
    if iterator.initialize():
        while True:
            shape = iterator.get()
            element = model.by_id(shape.id)
            v = np.asarray(shape.geometry.verts, dtype=np.float64).reshape(-1, 3)
            f = np.asarray(shape.geometry.faces, dtype=np.int64).reshape(-1, 3)
            if len(f):
                if not np.isfinite(v).all():
                    raise SceneError(f"scene {p.name}: element {element.GlobalId} has NaN or "
                                     "infinite vertex coordinates")  # fmt: skip
                mesh = trimesh.Trimesh(vertices=v, faces=f, process=True, validate=False)
                hints, n_materials = _hints(element)
                named.append((_object_name(element), mesh, hints))
                read.add(element.id())
                guess = _class_material(element)
                if guess is not None and not n_materials:
                    key = f"{element.is_a()} -> {guess}"
                    by_class[key] = by_class.get(key, 0) + 1
            if not iterator.next():
                break
    if not named:
        raise SceneError(f"scene {p.name} has no building element with a body (walls, slabs, "
                         "columns, ...)")  # fmt: skip
    lost = [_object_name(e) for e in model.by_type("IfcProduct")
            if e.id() not in read and _has_body(e) and not any(e.is_a(c) for c in IFC_SKIPPED)]
    if lost:  # IfcOpenShell logs why; the user needs to know that they are missing
        more = f" (+{len(lost) - 5} more)" if len(lost) > 5 else ""
        warnings.warn(f"scene {p.name}: {len(lost)} element(s) with a body gave no triangles and "
                      f"are not in the scene: {', '.join(sorted(lost)[:5])}{more}", stacklevel=3)
    if by_class:  # a guess the user should see, unless the element's name says better
        shown = ", ".join(f"{k} ({n})" for k, n in sorted(by_class.items()))
        warnings.warn(f"scene {p.name}: {sum(by_class.values())} element(s) have no IFC material "
                      f"and are bound by their class unless their name names one: {shown}; a "
                      "'bind' pattern on the class (IfcWall_*) chooses another", stacklevel=3)
    return sorted(named, key=lambda t: t[0])


def _has_body(element: Any) -> bool:
    """Whether ``element`` has a 3D body representation (``Body``), which the reader tessellates."""
    shape = getattr(element, "Representation", None)
    return shape is not None and any(r.RepresentationIdentifier == "Body"
                                     for r in shape.Representations)  # fmt: skip


def material_hints(element: Any) -> list[str]:
    """Names to bind ``element`` to a material with, in order: its IFC materials (the thickest
    layer of a layered wall first; a window's glazing first), each followed by the library
    material that :data:`IFC_MATERIAL_WORDS` reads in it, its name and type, and last the
    material of its class (:data:`IFC_CLASS_MATERIALS`)."""
    return _hints(element)[0]


def _hints(element: Any) -> tuple[list[str], int]:
    """:func:`material_hints` and the number of IFC materials among them."""
    names: list[str] = []
    materials = _ordered_materials(element, _material_of(element))
    for mat in materials:
        for text in (getattr(mat, "Name", None), getattr(mat, "Category", None)):
            if text:
                names.append(str(text))
                words = re.findall(r"[a-z]+", str(text).lower())
                names += [IFC_MATERIAL_WORDS[w] for w in words if w in IFC_MATERIAL_WORDS]
    names += [str(t) for t in (element.Name, getattr(element, "ObjectType", None)) if t]
    guess = _class_material(element)
    return names + ([guess] if guess is not None else []), len(materials)


def _class_material(element: Any) -> str | None:
    """:data:`IFC_CLASS_MATERIALS` of the element's class (or a superclass), or None."""
    cls = next((c for c in IFC_CLASS_MATERIALS if element.is_a(c)), None)
    return None if cls is None else IFC_CLASS_MATERIALS[cls]


def _material_of(element: Any) -> Any:
    """The element's material definition (its type's where it has none of its own), or None."""
    import ifcopenshell.util.element as util

    return util.get_material(element, should_skip_usage=True)


def _ordered_materials(element: Any, definition: Any) -> list[Any]:
    """The ``IfcMaterial`` entities of a material definition: a layer set's by thickness, the
    largest first; a constituent set's by fraction (a window's glazing first); a list's in its
    order."""
    if definition is None:
        return []
    kind = definition.is_a()
    if kind == "IfcMaterial":
        return [definition]
    if kind == "IfcMaterialLayerSet":
        layers = sorted(definition.MaterialLayers, key=lambda ly: -float(ly.LayerThickness or 0))
        return [ly.Material for ly in layers if ly.Material is not None]
    if kind == "IfcMaterialConstituentSet":
        parts = list(definition.MaterialConstituents or [])
        if element.is_a("IfcWindow") or element.is_a("IfcCurtainWall"):
            glazing = re.compile(r"glaz|glass")
            parts.sort(key=lambda c: not glazing.search(str(c.Category or c.Name or "").lower()))
        else:
            parts.sort(key=lambda c: -float(getattr(c, "Fraction", None) or 0))
        return [c.Material for c in parts if c.Material is not None]
    if kind == "IfcMaterialProfileSet":
        return [pr.Material for pr in definition.MaterialProfiles if pr.Material is not None]
    if kind == "IfcMaterialList":
        return list(definition.Materials)
    return []


def _object_name(element: Any) -> str:
    label = re.sub(r"[^A-Za-z0-9]+", "-", str(element.Name or "")).strip("-") or "unnamed"
    return f"{element.is_a()}_{label}_{element.GlobalId}"


def _by_type(model: Any, ifc_class: str) -> list[Any]:
    """The entities of ``ifc_class`` (and its subtypes); none if the schema has no such class
    (IFC2X3 has no IfcSpatialZone)."""
    try:
        return list(model.by_type(ifc_class))
    except RuntimeError:
        return []
