"""Reading scenes from files: meshes (glb, gltf, obj, ply, stl, off) through trimesh, Collada
(dae) through pycollada (:mod:`.collada`), IFC building models through IfcOpenShell
(:mod:`.ifc`), Mitsuba / Sionna RT scene XML, and the bundled scenes by name; binding a material
to every object."""

from __future__ import annotations

import fnmatch
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import SceneError
from ..core.memory import release_free_heap
from ..core.scale import check_extent
from ..physics.materials import MaterialLibrary
from .budget import CHECK_MIN_TRIANGLES, check_load
from .caches import EMBREE_LOCAL_M
from .construction import check_smooth_angle
from .diskcache import cached_build
from .model import Scene

#: Mesh formats read through trimesh.
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off", ".dae")
#: Mesh formats that store vertex coordinates as float32 numbers.
FLOAT32_SUFFIXES = (".glb", ".gltf", ".stl")
#: The axes of a file that may be up: z (hallray's frame, STL/PLY/OFF, Mitsuba XML as Sionna RT
#: writes it) or y (glTF's convention, and Blender's OBJ export).
UP_AXES = ("z", "y")
#: A y-up file's coordinates into hallray's z-up frame: (x, y, z) -> (x, -z, y), +90 degrees
#: about x. It undoes Blender's glTF and OBJ exports, which write its own z-up frame's
#: (x, y, z) as (x, z, -y), so positions read off Blender are the scene's.
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
#: Length units a file's numbers may be in, metres per unit (``load_scene(unit=...)``).
UNITS = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "km": 1e3, "in": 0.0254, "ft": 0.3048}


def load_scene(
    path: str | Path,
    materials: MaterialLibrary | str | Path | dict[str, Any] | None = None,
    *,
    default_material: str | None = None,
    smooth_angle_deg: float | None = None,
    surfaces: bool | None = None,
    up: str | None = None,
    unit: str | None = None,
    cache: bool | None = None,
) -> Scene:
    """Read a scene and bind a material to every object.

    Parameters
    ----------
    path : str or Path
        A mesh (.glb, .gltf, .obj, .ply, .stl, .off; .dae through pycollada: its unit and
        up axis as it states them) read through trimesh, a building model in
        IFC (.ifc, through IfcOpenShell: :mod:`raytrace.scene.ifc`), a Mitsuba / Sionna RT
        scene XML, or the name of a bundled scene (``"hall"``).
    materials : MaterialLibrary, YAML path or dict, optional
        User materials, a ``bind`` map of glob patterns on object names to materials (overrides
        name matching), and an optional ``default``. Materials stored in the file's ``hallray``
        metadata are loaded first.
    default_material : str, optional
        Material of objects that no name or pattern binds (otherwise they are an error).
    smooth_angle_deg : float, optional
        Edges whose two faces bend by less than this (degrees; default 1) are smooth, not
        diffracting wedges: the tessellated curves of scanned and CAD meshes (docs/scene.md,
        "Smooth edges", measures the field error of larger angles).
    surfaces : bool, optional
        True: every mesh is a set of surfaces, each face a slab of its material's thickness, a
        closed mesh a hollow shell (Sionna RT's model; points inside a closed mesh are then in
        the open). False: a closed (watertight) mesh is a solid, crossed along its chord
        (hallray's model). Default (None): surfaces for a Mitsuba / Sionna RT XML without a
        hallray sidecar (a scene hallray did not write), solids otherwise (docs/scene.md,
        "Solids or surfaces").
    up : {"z", "y"}, optional
        The file's axis that points up. "y" turns the scene into hallray's z-up frame,
        ``(x, y, z) -> (x, -z, y)`` (:data:`Y_UP_TO_Z_UP`); ``Scene.up`` records it. Default
        (None): the file's convention (:func:`file_up`): y for glTF not written by trimesh
        (hallray's own GLBs are z-up) and for an OBJ that Blender wrote, z otherwise; a glTF
        that is lower along z than along y was stored z-up against its convention and is read
        as it is, with a warning.
    unit : str, optional
        The unit of the file's numbers, a key of :data:`UNITS`: a CAD export in millimetres is
        read with ``"mm"`` and scaled to metres as it is read. Default (None): the unit the
        file states (a Collada file's ``<unit meter=...>``: SketchUp writes inches), else
        metres. A scene beyond the size of a hall is refused with the unit that most likely
        explains it.
    cache : bool, optional
        Keep the scene's preprocessing on disk beside the file (``.hallray-cache/``, keyed by
        the content hash of the file, the materials and these options) and reuse it on the next
        load: :mod:`raytrace.scene.diskcache`. Default (None): for scenes of at least
        :data:`~raytrace.scene.diskcache.CACHE_MIN_TRIANGLES` triangles.

    Returns
    -------
    Scene

    Raises
    ------
    SceneError
        Missing or unreadable file, empty mesh, NaN vertices, objects without a material, or
        a scene too large for the memory available (estimated before it is built:
        :func:`raytrace.scene.budget.check_load`).
    """
    p, up = _checked(path, smooth_angle_deg, up, unit)
    facts = file_facts(p)
    convention = facts.up
    if up is None and convention == "x":
        raise SceneError(f"scene {p.name} states X_UP, which hallray does not turn: read it with "
                         "--up z or --up y")  # fmt: skip
    declared = facts.unit
    # a glTF from a tool other than Blender may be stored against its convention: its
    # geometry decides (:func:`_turned_up`; Blender's exporters follow the convention)
    check_geometry = (up is None and convention == "y" and p.suffix.lower() in (".glb", ".gltf")
                      and "blender" not in facts.writer.lower())  # fmt: skip
    unit_name, scale = (unit, UNITS[unit]) if unit is not None else declared or ("m", 1.0)
    options = _cache_options(default_material, smooth_angle_deg, surfaces, up, convention,
                             check_geometry, unit, declared)  # fmt: skip
    try:
        scene = cached_build(
            p.resolve(), materials, options,
            lambda: _build(p, materials, default_material, smooth_angle_deg, surfaces,
                           up or convention, (unit_name, scale), up is None, check_geometry),
            cache,
        )  # fmt: skip
    except OSError as exc:  # a materials file or a mesh the XML names cannot be read
        raise SceneError(f"cannot read {exc.filename or p.name}: {exc.strerror or exc}") from None
    scene.source = str(p)  # as a fresh build names it, also when read from the cache
    if len(scene.faces) >= CHECK_MIN_TRIANGLES:
        release_free_heap()  # a large load's temporaries, given back before the traces
    lo, hi = scene.bounds
    # a hall in mm (or cm, or km): refused before tracing
    check_extent(tuple(float(v) for v in hi - lo), f"scene {p.name}", option="--unit")
    return scene


def _cache_options(default_material: str | None, smooth_angle_deg: float | None,
                   surfaces: bool | None, up: str | None, convention: str, check_geometry: bool,
                   unit: str | None, declared: tuple[str, float] | None) -> dict[str, Any]:  # fmt: skip
    """What :func:`load_scene`'s built scene depends on besides the file and the materials (the
    disk cache's key). The defaults' key stays that of caches written before these options."""
    options = {"default_material": default_material, "smooth_angle_deg": smooth_angle_deg}
    if surfaces is not None:
        options["surfaces"] = bool(surfaces)
    if check_geometry:  # decided by the geometry, not by the file's statement
        options["up"] = "convention-y"
    elif (up or convention, convention) != ("z", "z"):  # turned, or a file not z-up kept so
        options["up"] = up or convention
    if unit is not None and (unit != "m" or declared is not None):  # a stated one is content
        options["unit"] = unit
    return options


def _checked(path: str | Path, smooth_angle_deg: float | None, up: str | None,
             unit: str | None) -> tuple[Path, str | None]:  # fmt: skip
    """:func:`load_scene`'s file and its up axis as given, with the options checked: a one-line
    :class:`SceneError` for a missing file or format, a wrong smooth angle, axis or unit."""
    from .bundled import resolve_scene

    p = resolve_scene(path)
    if not p.exists():
        raise SceneError(f"scene file not found: {path}")
    if p.is_dir():
        raise SceneError(f"scene path is a directory, not a file: {path}")
    suffix = p.suffix.lower()
    if suffix not in (".xml", ".ifc") and suffix not in MESH_SUFFIXES:
        raise SceneError(
            f"unsupported scene format {suffix or '(none)'!r} for {p.name}; "
            f"use one of {', '.join(MESH_SUFFIXES)}, .ifc or .xml"
        )
    check_smooth_angle(smooth_angle_deg)
    if up is not None and up not in UP_AXES:
        raise SceneError(f"up axis must be one of {', '.join(UP_AXES)}, not {up!r}")
    if unit is not None and unit not in UNITS:
        raise SceneError(f"unit must be one of {', '.join(UNITS)}, not {unit!r}")
    if unit not in (None, "m") and suffix == ".ifc":
        raise SceneError(f"scene {p.name} is IFC, which states its own length unit (read as "
                         f"metres): --unit {unit} does not apply to it")  # fmt: skip
    return p, up


def _build(
    p: Path,
    materials: Any,
    default_material: str | None,
    smooth_angle_deg: float | None,
    surfaces: bool | None = None,
    up: str = "z",
    unit: tuple[str, float] = ("m", 1.0),
    by_convention: bool = False,
    check_geometry: bool = False,
) -> Scene:
    """:func:`load_scene` without the cache: read (``unit``: the unit's name and metres per
    unit), turn a y-up file to z up, estimate the memory, bind the materials, build."""
    unit_name, scale = unit
    if p.suffix.lower() == ".xml":
        named, metadata, xml_materials, xml_surfaces = _read_mitsuba(p)
        if surfaces is None:  # Sionna RT's model, unless hallray wrote it as solids (its sidecar)
            surfaces = xml_surfaces
    elif p.suffix.lower() == ".ifc":
        from .ifc import read_ifc

        named, metadata, xml_materials = read_ifc(p, _threads()), {}, {}
        check_extent(_extent(named), f"scene {p.name}")
    elif p.suffix.lower() == ".dae":  # trimesh's reader drops the names that bind materials
        from .collada import read_collada

        named, metadata, xml_materials = read_collada(p, scale), {}, {}
        check_extent(_extent(named), f"scene {p.name}", option="--unit")
    else:
        named, metadata = _read_trimesh(p, "z" if by_convention else up, unit_name, scale)
        xml_materials = {}
    _check_own(p, metadata, "z" if by_convention else up, unit_name)
    if up == "y" and check_geometry:  # hallray's own files are z-up whoever wrote them
        own = isinstance(metadata, dict) and bool(metadata.get("hallray"))
        up = "z" if own else _turned_up(p, named)
    if up == "y":
        for _, mesh, _ in named:
            mesh.apply_transform(Y_UP_TO_Z_UP)
    if scale != 1.0 and p.suffix.lower() == ".xml":  # a mesh file's are scaled as it is read
        for _, mesh, _ in named:
            mesh.apply_scale(scale)
    check_load(sum(len(m.faces) for _, m, _ in named), p.name)
    library = MaterialLibrary.itu()
    meta_h = metadata.get("hallray", {}) if isinstance(metadata, dict) else {}
    if isinstance(meta_h, dict) and meta_h.get("materials"):
        library = library.with_yaml({"materials": meta_h["materials"]})
    if xml_materials:
        library = library.with_yaml({"materials": xml_materials})
    if isinstance(materials, MaterialLibrary):
        library = materials
    elif materials is not None:
        library = library.with_yaml(materials)
    default = default_material or getattr(library, "default", None)
    if default is not None and default not in library:
        raise SceneError(f"default material {default!r} is not a known material")
    bind = dict(getattr(library, "bind", {}) or {})

    bound: list[tuple[str, Any, str]] = []
    unbound: list[str] = []
    for name, mesh, hints in named:
        mat = None
        for pattern, m in bind.items():
            if fnmatch.fnmatchcase(name, pattern) or fnmatch.fnmatchcase(
                name.lower(), pattern.lower()
            ):
                mat = m
                break
        if mat is None:
            for h in hints:
                mat = library.match(h)
                if mat is not None:
                    break
        if mat is None:
            mat = default
        if mat is None:
            unbound.append(name)
            continue
        if mat not in library:
            raise SceneError(f"object {name!r} is bound to unknown material {mat!r}")
        bound.append((name, mesh, mat))
    if unbound:
        shown = ", ".join(unbound[:8]) + (
            f" (+{len(unbound) - 8} more)" if len(unbound) > 8 else ""
        )
        raise SceneError(
            f"{len(unbound)} object(s) without a material: {shown}; name them after a material, "
            "add a 'bind' pattern, or give a default material"
        )
    scene = Scene.from_meshes(bound, library, metadata=metadata, source=str(p),
                              smooth_angle_deg=smooth_angle_deg,
                              surfaces=bool(surfaces))  # fmt: skip
    scene.up, scene.unit = up, unit_name
    return scene


def _extent(named: list[tuple[str, Any, list[str]]]) -> tuple[float, float, float]:
    """(x, y, z) extent (file units scaled as read) of the meshes of ``named``."""
    lo = np.min([m.bounds[0] for _, m, _ in named], axis=0)
    hi = np.max([m.bounds[1] for _, m, _ in named], axis=0)
    return tuple(float(v) for v in hi - lo)


def _turned_up(p: Path, named: list[tuple[str, Any, list[str]]]) -> str:
    """The up axis of a glTF that a tool other than Blender wrote, by its geometry: a hall is
    lower than it is long and wide, so a file lower along z than along y was written z-up
    against the convention (by a tool that ignores it): "z", with a warning naming ``--up y``;
    else "y"."""
    size = _extent(named)
    if size[2] < size[1]:
        warnings.warn(f"scene {p.name} is glTF, +y up by its specification, but it is lower along "
                      f"z ({size[2]:.3g} m) than along y ({size[1]:.3g} m): read with z up as it "
                      "is stored; --up y turns it", stacklevel=4)  # fmt: skip
        return "z"
    return "y"


@dataclass(frozen=True)
class FileFacts:
    """What a scene file says of itself, from its first 64 KiB (:func:`file_facts`).

    Attributes
    ----------
    up : the axis that is up by the format's convention or the file's statement: "y" for glTF
        (the specification's +y up) unless trimesh wrote it (hallray's own GLBs, and scenes
        written with trimesh, keep z up), for an OBJ whose header says Blender wrote it (its
        exporter's default) and for a Collada file that states ``Y_UP`` or nothing; a Collada
        file's ``X_UP`` is "x"; "z" otherwise.
    unit : the length unit the file states, as (name, metres per unit): a Collada file's
        ``<unit meter=...>`` (named after :data:`UNITS` when it is one of them, e.g. SketchUp's
        inches ``"in"``); None for formats that do not state one (glTF is metres by its
        specification, IFC's unit is converted by IfcOpenShell).
    writer : what wrote it, as it says: a glTF's ``asset.generator``, an OBJ's header comments;
        "" if it does not say.
    """

    up: str
    unit: tuple[str, float] | None
    writer: str


def file_facts(p: Path) -> FileFacts:
    """:class:`FileFacts` of the file ``p``, reading its first 64 KiB once (glTF's ``asset``
    comes first in its JSON, Collada's ``<asset>`` first in its XML)."""
    suffix = p.suffix.lower()
    if suffix not in (".glb", ".gltf", ".obj", ".dae"):
        return FileFacts("z", None, "")
    with open(p, "rb") as fh:
        head = fh.read(65536)
    if suffix == ".dae":
        axis = re.search(rb"<up_axis>\s*([XYZ])_UP\s*</up_axis>", head)
        return FileFacts("y" if axis is None else axis.group(1).decode().lower(),
                         _stated_unit(head), "")  # fmt: skip
    if suffix == ".obj":
        lines = [ln[1:].strip() for ln in head.splitlines()[:5] if ln.startswith(b"#")]
        writer = b" ".join(lines).decode("utf-8", "replace")
        return FileFacts("y" if "blender" in writer.lower() else "z", None, writer)
    m = re.search(rb'"generator"\s*:\s*"([^"]*)"', head)
    writer = "" if m is None else m.group(1).decode("utf-8", "replace")
    return FileFacts("z" if "trimesh" in writer.lower() else "y", None, writer)


def file_up(p: Path) -> str:
    """The axis that is up in the file ``p`` by its format's convention (:class:`FileFacts`)."""
    return file_facts(p).up


def _stated_unit(head: bytes) -> tuple[str, float] | None:
    """A Collada header's ``<unit meter=...>`` as (name, metres per unit), or None."""
    m = re.search(rb"<unit\b[^>]*\bmeter\s*=\s*[\"']([^\"']+)[\"']", head)
    try:
        meter = float(m.group(1)) if m is not None else None
    except ValueError:
        meter = None
    if meter is None or not np.isfinite(meter) or meter <= 0:
        return None
    name = next((k for k, v in UNITS.items() if np.isclose(v, meter, rtol=1e-6)), f"{meter:g} m")
    return name, meter


def _threads() -> int:
    """The cores this process may use."""
    import os

    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _check_own(p: Path, metadata: Any, up: str, unit: str) -> None:
    """Refuse another up axis or unit for a file hallray wrote (its ``hallray`` metadata: its
    positions are in metres, z up)."""
    if isinstance(metadata, dict) and metadata.get("hallray") and (up != "z" or unit != "m"):
        raise SceneError(f"scene {p.name} was written by hallray, in metres with z up: "
                         f"{'--up y' if up != 'z' else f'--unit {unit}'} does not apply to it")


def _read_trimesh(
    p: Path, up: str = "z", unit: str = "m", scale: float = 1.0
) -> tuple[list[tuple[str, Any, list[str]]], dict[str, Any]]:
    """Objects of a mesh file as (name, mesh in world coordinates, name hints), its numbers
    in ``unit`` (``scale`` metres each) scaled to metres (the turn to z ``up`` is
    :func:`_build`'s)."""
    import trimesh

    try:
        # unprocessed: trimesh's processing silently drops NaN/inf vertices (and the faces using
        # them), turning a closed wall into an open sheet; each mesh is processed below. An OBJ's
        # objects (o) and groups (g) are objects here: trimesh's default joins every object of
        # one material into one mesh, and a CAD hall's walls, floor and machines, welded into
        # one, are no longer closed solids
        kwargs = {"split_objects": True, "split_groups": True} if p.suffix.lower() == ".obj" else {}
        loaded = trimesh.load(str(p), force="scene", process=False, **kwargs)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise SceneError(
            f"cannot read scene {p.name}: {type(exc).__name__}: {exc}".splitlines()[0]
        ) from None
    _check_own(p, loaded.metadata, up, unit)  # before its size is weighed in that unit
    named: list[tuple[str, Any, list[str]]] = []
    rounded = 0.0  # the largest float32 rounding of a vertex far from the origin, m
    for node in sorted(loaded.graph.nodes_geometry):
        transform, geom_name = loaded.graph[node]
        geom = loaded.geometry.get(geom_name)
        if geom is None or not hasattr(geom, "faces") or len(geom.faces) == 0:
            continue
        if not np.isfinite(np.asarray(geom.vertices, dtype=float)).all():
            raise SceneError(
                f"scene {p.name}: object {node!r} has NaN or infinite vertex coordinates"
            )
        if p.suffix.lower() in FLOAT32_SUFFIXES:
            rounded = max(rounded, float32_rounding(np.asarray(geom.vertices, dtype=float), scale))
        mesh = geom.copy()
        if hasattr(mesh, "process"):
            mesh.process()
        mesh.apply_transform(transform)
        if scale != 1.0:
            mesh.apply_scale(scale)
        hints = [node, geom_name]
        mat = getattr(getattr(geom, "visual", None), "material", None)
        if mat is not None and getattr(mat, "name", None):
            hints.append(str(mat.name))
        named.append((str(node), mesh, hints))
    if not named:
        raise SceneError(f"scene {p.name} contains no triangles")
    # a hall in mm is refused before it is repaired and built (and before the rounding of its
    # float32 numbers, which are not metres, is worth a word)
    check_extent(_extent(named), f"scene {p.name}", option="--unit")
    if rounded:
        warnings.warn(
            f"scene {p.name} stores its vertices as float32 numbers (as STL and glTF do) far from "
            f"the origin, where they are rounded by up to {rounded * 1e3:.2g} mm: export it "
            "with the origin in the hall (or as OBJ, or with the offset in a glTF node)",
            stacklevel=3,
        )
    return named, dict(loaded.metadata or {})


def float32_rounding(vertices: np.ndarray, scale: float = 1.0) -> float:
    """Half the float32 spacing (m) at the largest coordinate of ``vertices`` (V, 3), in the
    file's unit of ``scale`` metres, of a file that stores float32 numbers
    (:data:`FLOAT32_SUFFIXES`; each exactly a float32) beyond
    :data:`~raytrace.scene.caches.EMBREE_LOCAL_M` from the origin, where that exceeds 0.1 mm;
    else 0. (The tracer itself keeps such a scene exact: :func:`~raytrace.scene.caches.
    embree_origin_of`; the file has rounded it already.)"""
    if not len(vertices):
        return 0.0
    far = float(np.abs(vertices).max())
    if far * scale <= EMBREE_LOCAL_M or not np.array_equal(vertices, vertices.astype(np.float32)):
        return 0.0
    half = 0.5 * float(np.spacing(np.float32(far))) * scale
    return half if half > 1e-4 else 0.0


def _read_mitsuba(
    p: Path,
) -> tuple[list[tuple[str, Any, list[str]]], dict[str, Any], dict[str, Any], bool]:
    """A Mitsuba 3 / Sionna RT scene: ply/obj shapes referencing radio materials (ITU types,
    Sionna RT 1.x radio-materials, or BSDF ids naming a material); with the hallray sidecar of
    :mod:`.mitsuba` beside it, also the object names, exact materials and metadata. The last
    value: whether its meshes are surfaces (:class:`~raytrace.scene.mitsuba.BsdfReading`)."""
    import trimesh

    from .mitsuba import read_bsdfs

    try:
        root = ET.parse(p).getroot()
    except (ET.ParseError, OSError) as exc:
        raise SceneError(f"cannot read scene XML {p.name}: {exc}") from None
    reading = read_bsdfs(root, p)
    bsdf_material = reading.material_of
    named: list[tuple[str, Any, list[str]]] = []
    for i, shape in enumerate(root.iter("shape")):
        stype = shape.get("type")
        if stype not in ("ply", "obj"):
            continue
        fname = None
        ref = None
        for c in shape:
            if c.tag == "string" and c.get("name") == "filename":
                fname = c.get("value")
            if c.tag == "ref":
                ref = c.get("id")
            if c.tag == "bsdf" and c.get("id"):
                ref = c.get("id")
        if fname is None:
            continue
        fpath = (p.parent / fname).resolve()
        try:
            # processed below, once checked: trimesh's processing drops NaN vertices silently
            mesh = trimesh.load(str(fpath), force="mesh", process=False)
        except Exception as exc:
            raise SceneError(
                f"cannot read mesh {fname} of {p.name}: {exc}".splitlines()[0]
            ) from None
        if not np.isfinite(np.asarray(mesh.vertices, dtype=float)).all():
            raise SceneError(
                f"scene {p.name}: mesh {fname} has NaN or infinite vertex coordinates"
            )
        mesh.process()
        name = shape.get("id") or Path(fname).stem or f"shape_{i}"
        name = reading.shape_names.get(name, name)
        hints = [name]
        if ref is not None:
            hints = [bsdf_material.get(ref, ref), ref, name]
        named.append((name, mesh, hints))
    if not named:
        raise SceneError(f"scene XML {p.name} has no ply/obj shapes")
    return named, reading.metadata, reading.materials, reading.surfaces
