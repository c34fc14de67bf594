"""Mitsuba 3 / Sionna RT scene XML: writing a scene, and what the reader needs to read it back.

:func:`export_mitsuba` writes, beside ``scene.xml``:

* ``meshes/<shape>.ply``: one binary PLY per object (float64 vertices, int32 triangles; Mitsuba's
  ``ply`` shape reads both), its triangles as the scene holds them (closed solids outward);
* ``scene.xml``: one ``<shape type="ply">`` per object referencing one BSDF per material:

  - an ITU-R P.2040 material as hallray has it built in (``concrete``, ``metal``, ... with our
    Table 3 coefficients, any thickness) -> ``<bsdf type="itu-radio-material"
    id="mat-itu_concrete">`` with ``type`` and ``thickness``. The ``mat-itu_`` id is the one
    both Sionna RT 0.x (which names materials by id) and 1.x (``itu-radio-material``) read;
  - any other material (the hall's ``plastic``, a user YAML material, an ITU name with other
    coefficients) -> ``<bsdf type="radio-material" id="mat-NAME">`` with
    ``relative_permittivity``, ``conductivity`` and ``thickness`` (Sionna RT 1.x's
    ``RadioMaterial`` properties). A frequency-dependent (power-law) material is evaluated at the
    export's reference frequency: Sionna's XML has no power law. An id whose name Sionna would
    take for an ITU material (``concrete``, ``itu_...``) becomes ``mat-custom_NAME``.

  Every BSDF carries the material's drawing colour (``<rgb name="color">``, our palette).
* ``scene.hallray.json`` (the *sidecar*, :data:`SIDECAR_SUFFIX`): what Mitsuba XML has no place
  for: the scene's ``hallray`` metadata (base stations, points, routes, hall size, ...), every
  material exactly as hallray defines it (power laws included), the object names behind the
  shape ids, and the scene's :meth:`~raytrace.scene.model.Scene.content_hash`.

Every file is written atomically and the XML last, so a reader that finds the XML finds every
mesh it names. :func:`read_bsdfs` is the part of the XML reader (:mod:`raytrace.scene.io`) that
knows the BSDF kinds and the sidecar: with the sidecar, a scene read back is the scene written
(same triangles, object names, materials, thicknesses and metadata).
"""

from __future__ import annotations

import json
import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hallray import strict_json

from ..core.errors import MaterialError, SceneError
from ..core.fileio import write_atomic
from ..core.palette import material_colors
from ..physics.materials import MaterialLibrary
from .model import Scene

#: The sidecar of ``NAME.xml`` is ``NAME`` + this suffix, beside it.
SIDECAR_SUFFIX = ".hallray.json"
#: Name and version of the sidecar's format (its ``format`` and ``format_version`` keys).
SIDECAR_FORMAT = "hallray-mitsuba-sidecar"
SIDECAR_VERSION = 1
#: Folder of the PLY meshes, relative to the XML.
MESH_DIR = "meshes"
#: The ``version`` of the ``<scene>`` element (the one Sionna RT's own scenes carry).
SCENE_XML_VERSION = "2.1.0"
#: Sionna RT's ``RadioMaterial`` defaults where a ``radio-material`` BSDF omits a property.
SIONNA_DEFAULT_PERMITTIVITY = 1.0
SIONNA_DEFAULT_CONDUCTIVITY = 0.0

_ITU: MaterialLibrary | None = None


def _itu() -> MaterialLibrary:
    global _ITU  # an immutable table, built once
    if _ITU is None:
        _ITU = MaterialLibrary.itu()
    return _ITU


def sidecar_path(xml_path: str | Path) -> Path:
    """The sidecar beside an XML: ``dir/scene.xml`` -> ``dir/scene.hallray.json``."""
    p = Path(xml_path)
    return p.with_name(p.stem + SIDECAR_SUFFIX)


# -- materials -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BsdfPlan:
    """One material's BSDF: its id, Mitsuba type and properties (name -> (tag, value text))."""

    material: str
    bsdf_id: str
    bsdf_type: str
    props: dict[str, tuple[str, str]]
    spec: dict[str, Any]  # the material in hallray's YAML form (exact)
    frequency_dependent: bool


def _number(x: float) -> str:
    """A float as text that reads back to the same double."""
    return repr(float(x))


def _is_builtin_itu(mat: Any) -> bool:
    """Whether a material is one of our built-in ITU-R P.2040 ones with their coefficients (its
    thickness may differ)."""
    ref = _itu().get(mat.name)
    if ref is None:
        return False
    keys = ("a", "b", "c", "d", "f_min_hz", "f_max_hz")
    return all(getattr(mat, k) == getattr(ref, k) for k in keys)


def material_spec(mat: Any) -> dict[str, Any]:
    """A material in the YAML form :meth:`MaterialLibrary.with_yaml` reads back to the same
    :class:`~raytrace.physics.materials.Material` (a built-in ITU one: its thickness only)."""
    if _is_builtin_itu(mat):
        return {"thickness": mat.thickness_m}
    spec: dict[str, Any]
    if mat.b == 0.0 and mat.d == 0.0:
        spec = {"eta_real": mat.a, "sigma": mat.c}
        if mat.f_min_hz > 0.0 or math.isfinite(mat.f_max_hz):
            spec["f_range_ghz"] = [mat.f_min_hz / 1e9, mat.f_max_hz / 1e9]
    else:
        spec = {"a": mat.a, "b": mat.b, "c": mat.c, "d": mat.d,
                "f_range_ghz": [mat.f_min_hz / 1e9, mat.f_max_hz / 1e9]}  # fmt: skip
    spec["thickness"] = mat.thickness_m
    return spec


def _radio_id(name: str) -> str:
    """BSDF id of a non-ITU material: ``mat-NAME``, or ``mat-custom_NAME`` where Sionna RT would
    take ``NAME`` for an ITU material (an ITU name, or one starting with ``itu``)."""
    if name in _itu() or name.startswith("itu"):
        return f"mat-custom_{name}"
    return f"mat-{name}"


def plan_bsdf(mat: Any, frequency_hz: float | None, rgb: tuple[float, float, float]) -> BsdfPlan:
    """The BSDF of one material (see the module docstring for the rules).

    Parameters
    ----------
    mat : Material
    frequency_hz : float or None, Hz: where a frequency-dependent non-ITU material is evaluated
    rgb : drawing colour, 0..1

    Raises
    ------
    MaterialError
        A frequency-dependent non-ITU material without ``frequency_hz``, or outside its range.
    """
    colour = ("rgb", ", ".join(f"{c:.4f}" for c in rgb))
    thickness = ("float", _number(mat.thickness_m))
    spec = material_spec(mat)
    if _is_builtin_itu(mat):
        props = {"type": ("string", mat.name), "thickness": thickness, "color": colour}
        return BsdfPlan(mat.name, f"mat-itu_{mat.name}", "itu-radio-material", props, spec, False)
    dependent = not (mat.b == 0.0 and mat.d == 0.0)
    if dependent:
        if frequency_hz is None:
            raise MaterialError(
                f"material '{mat.name}' depends on frequency and Sionna's XML has no power law: "
                "give the frequency to evaluate it at"
            )
        if not mat.f_min_hz <= frequency_hz <= mat.f_max_hz:
            raise MaterialError(
                f"material '{mat.name}' ({mat.source}) is valid for {mat.range_text}, not at the "
                f"export's reference frequency {frequency_hz / 1e9:.6g} GHz"
            )
        eta, sigma = mat.properties(frequency_hz)
    else:
        eta, sigma = mat.a, mat.c
    props = {
        "relative_permittivity": ("float", _number(eta)),
        "conductivity": ("float", _number(sigma)),
        "thickness": thickness,
        "color": colour,
    }
    return BsdfPlan(mat.name, _radio_id(mat.name), "radio-material", props, spec, dependent)


# -- shapes ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ShapePlan:
    """One object's shape: its id in the XML, its mesh file, the object's name and material."""

    shape_id: str
    file: str  # relative to the XML, with '/'
    name: str
    material: str
    vertices: np.ndarray = field(repr=False)  # (V, 3) float64, metres
    faces: np.ndarray = field(repr=False)  # (F, 3) int, into vertices


_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")


def _shape_ids(names: list[str], taken: set[str]) -> list[str]:
    """Unique shape ids (also as file names on a case-insensitive disk): the object's name where
    it is made of letters, digits, ``_`` and ``-`` and starts with a letter (Mitsuba reserves a
    leading ``_``), else a cleaned form of it."""
    used = {t.lower() for t in taken}
    out = []
    for name in names:
        sid = _UNSAFE.sub("_", name).strip("_")[:80] or "object"
        if not sid[0].isalpha():
            sid = f"obj-{sid}"
        base, k = sid, 2
        while sid.lower() in used:
            sid = f"{base}-{k}"
            k += 1
        used.add(sid.lower())
        out.append(sid)
    return out


def plan_shapes(scene: Scene, taken: set[str]) -> list[ShapePlan]:
    """One shape per object of the scene, its vertices in the scene's order."""
    ids = _shape_ids([o.name for o in scene.objects], taken)
    out = []
    for sid, o in zip(ids, scene.objects):
        f = scene.faces[o.face_start : o.face_start + o.face_count]
        used, inv = np.unique(f, return_inverse=True)  # an object's vertices are one sorted run
        out.append(ShapePlan(sid, f"{MESH_DIR}/{sid}.ply", o.name, o.material,
                             scene.vertices[used], inv.reshape(-1, 3)))  # fmt: skip
    return out


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, comment: str = "") -> bytes:
    """A binary little-endian PLY: float64 ``x y z`` vertices, ``uchar``-counted ``int`` triangle
    lists (``vertex_indices``).

    Parameters
    ----------
    vertices : (V, 3) float, metres
    faces : (F, 3) int, indices into ``vertices``
    comment : one line for the header
    """
    v = np.ascontiguousarray(vertices, dtype="<f8")
    f = np.asarray(faces)
    comment = " ".join(comment.split())
    head = ["ply", "format binary_little_endian 1.0"]
    if comment:
        head.append(f"comment {comment}")
    head += [f"element vertex {len(v)}", "property double x", "property double y",
             "property double z", f"element face {len(f)}",
             "property list uchar int vertex_indices", "end_header"]  # fmt: skip
    rec = np.zeros(len(f), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    rec["n"] = 3
    rec["idx"] = f
    return ("\n".join(head) + "\n").encode("ascii") + v.tobytes() + rec.tobytes()


# -- the XML and the sidecar -----------------------------------------------------------------------
def scene_xml(bsdfs: list[BsdfPlan], shapes: list[ShapePlan], comment: str) -> bytes:
    """The Mitsuba scene XML: the BSDFs, then one ``ply`` shape per object."""
    root = ET.Element("scene", {"version": SCENE_XML_VERSION})
    root.append(ET.Comment(f" {comment} "))
    root.append(ET.Comment(" Materials "))
    ids = {}
    for b in bsdfs:
        el = ET.SubElement(root, "bsdf", {"type": b.bsdf_type, "id": b.bsdf_id})
        for name, (tag, value) in b.props.items():
            ET.SubElement(el, tag, {"name": name, "value": value})
        ids[b.material] = b.bsdf_id
    root.append(ET.Comment(" Shapes "))
    for s in shapes:
        el = ET.SubElement(root, "shape", {"type": "ply", "id": s.shape_id})
        ET.SubElement(el, "string", {"name": "filename", "value": s.file})
        ET.SubElement(el, "boolean", {"name": "face_normals", "value": "true"})
        ET.SubElement(el, "ref", {"id": ids[s.material], "name": "bsdf"})
    ET.indent(root, space="    ")
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def sidecar_dict(
    scene: Scene, xml_name: str, bsdfs: list[BsdfPlan], shapes: list[ShapePlan],
    frequency_hz: float | None,
) -> dict[str, Any]:  # fmt: skip
    """The sidecar's content (see the module docstring)."""
    meta = scene.metadata.get("hallray", {}) if isinstance(scene.metadata, dict) else {}
    return {
        "format": SIDECAR_FORMAT,
        "format_version": SIDECAR_VERSION,
        "xml": xml_name,
        "source": scene.source,
        "scene_sha256": scene.content_hash(),
        "reference_frequency_hz": frequency_hz,
        "materials": {
            b.material: {
                "bsdf": b.bsdf_id,
                "bsdf_type": b.bsdf_type,
                "xml": {k: v for k, (_, v) in b.props.items() if k != "color"},
                "frequency_dependent": b.frequency_dependent,
                "spec": b.spec,
            }
            for b in bsdfs
        },
        "objects": [
            {
                "shape": s.shape_id,
                "name": s.name,
                "material": s.material,
                "file": s.file,
                "triangles": int(len(s.faces)),
            }
            for s in shapes
        ],  # fmt: skip
        "hallray": meta if isinstance(meta, dict) else {},
        # how the meshes are read back: closed meshes as solids (hallray's model) or every mesh
        # as surfaces (Sionna RT's, a scene first read from a foreign XML)
        "surfaces": bool(getattr(scene, "surfaces", False)),
    }


@dataclass
class ExportResult:
    """What :func:`export_mitsuba` wrote."""

    xml: Path
    sidecar: Path
    meshes: list[Path]
    n_triangles: int
    bsdfs: list[BsdfPlan]
    reference_frequency_hz: float | None

    @property
    def frequency_dependent(self) -> list[str]:
        """Materials evaluated at the reference frequency (Sionna gets constants for them)."""
        return [b.material for b in self.bsdfs if b.frequency_dependent]


def export_mitsuba(
    scene: Scene,
    xml_path: str | Path,
    *,
    frequency_hz: float | None = None,
    progress: Any = None,
) -> ExportResult:
    """Write a scene as Mitsuba 3 / Sionna RT XML with PLY meshes and the hallray sidecar.

    Parameters
    ----------
    scene : Scene
    xml_path : the XML to write (``.xml``); its folder must exist. The meshes go to
        ``meshes/`` beside it, the sidecar to ``NAME.hallray.json``.
    frequency_hz : float, Hz, optional
        Reference frequency at which frequency-dependent non-ITU materials are evaluated for
        Sionna (ITU ones stay ITU types; constant ones need none). Required only if the scene
        has such a material.
    progress : callable ``progress(n_done, n_total)``, optional, called after each mesh

    Returns
    -------
    ExportResult

    Raises
    ------
    SceneError
        The path does not end in ``.xml``, or its folder does not exist.
    MaterialError
        A frequency-dependent material without ``frequency_hz`` or outside its range there.
    """
    xml = Path(xml_path)
    if xml.suffix.lower() != ".xml":
        raise SceneError(f"Mitsuba scene {xml} must end in .xml")
    if not xml.parent.is_dir():
        raise SceneError(f"output directory does not exist: {xml.parent}")
    colours = material_colors(scene.material_names)
    bsdfs = [plan_bsdf(scene.materials[m], frequency_hz, colours[m]) for m in scene.material_names]
    shapes = plan_shapes(scene, {b.bsdf_id for b in bsdfs})
    (xml.parent / MESH_DIR).mkdir(exist_ok=True)
    written = []
    for k, s in enumerate(shapes):
        out = xml.parent / s.file
        write_atomic(out, ply_bytes(s.vertices, s.faces, f"hallray object {s.name}"))
        written.append(out)
        if progress is not None:
            progress(k + 1, len(shapes))
    side = sidecar_path(xml)
    doc = sidecar_dict(scene, xml.name, bsdfs, shapes, frequency_hz)
    write_atomic(side, (json.dumps(doc, indent=1) + "\n").encode())
    where = f" at {frequency_hz / 1e9:.6g} GHz" if frequency_hz else ""
    comment = (f"written by hallray from {Path(scene.source).name or 'a scene'}; "
               f"non-ITU materials as radio-material{where}; positions and exact materials in "
               f"{side.name}")  # fmt: skip
    write_atomic(xml, scene_xml(bsdfs, shapes, comment))
    return ExportResult(xml, side, written, int(len(scene.faces)), bsdfs, frequency_hz)


# -- reading ---------------------------------------------------------------------------------------
@dataclass
class BsdfReading:
    """What the reader takes from an XML's BSDFs and its sidecar.

    Attributes
    ----------
    material_of : BSDF id -> material name (or a name hint for BSDFs of other types)
    materials : material name -> YAML spec (overrides of, or additions to, the library)
    shape_names : shape id -> object name (from the sidecar)
    metadata : the scene's metadata (``{"hallray": ...}`` from the sidecar, else ``{}``)
    surfaces : every mesh read as surfaces (:func:`raytrace.scene.io.load_scene`'s default for
        the XML): Sionna RT's model without a sidecar, the sidecar's record with one
    """

    material_of: dict[str, str]
    materials: dict[str, Any]
    shape_names: dict[str, str]
    metadata: dict[str, Any]
    surfaces: bool = True


def _material_name(bsdf_id: str) -> str:
    """A material name from a ``radio-material`` BSDF id: ``mat-`` dropped, made canonical."""
    name = bsdf_id[4:] if bsdf_id.startswith("mat-") else bsdf_id
    name = re.sub(r"[^a-z0-9_]+", "_", name.strip().lower()).strip("_") or "material"
    return name if name[0].isalpha() else f"m_{name}"


def read_sidecar(xml_path: Path) -> dict[str, Any] | None:
    """The sidecar beside an XML, or None if there is none.

    Raises
    ------
    SceneError
        A sidecar that is not JSON, or of another format or version.
    """
    side = sidecar_path(xml_path)
    if not side.is_file():
        return None
    try:
        doc = strict_json.loads(side.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # a duplicate key is a ValueError
        raise SceneError(f"cannot read {side.name}: {' '.join(str(exc).split())}") from None
    if not isinstance(doc, dict) or doc.get("format") != SIDECAR_FORMAT:
        raise SceneError(f"{side.name} is not a hallray sidecar (format {SIDECAR_FORMAT!r})")
    if doc.get("format_version") != SIDECAR_VERSION:
        raise SceneError(
            f"{side.name}: sidecar version {doc.get('format_version')!r} is not supported "
            f"(this hallray reads {SIDECAR_VERSION})"
        )
    return doc


def _xml_props(bsdf: ET.Element) -> dict[str, str]:
    return {str(c.get("name")): str(c.get("value")) for c in bsdf if c.get("name")}


def _same_props(xml: dict[str, str], recorded: dict[str, str]) -> bool:
    """Whether a BSDF's properties are the ones the sidecar recorded (numbers compared as such)."""
    for key, value in recorded.items():
        got = xml.get(key)
        if got is None:
            return False
        try:
            if float(got) != float(value):
                return False
        except ValueError:
            if got != value:
                return False
    return True


def read_bsdfs(root: ET.Element, xml_path: Path) -> BsdfReading:
    """The materials of a Mitsuba / Sionna RT scene XML and, if present, its sidecar.

    * ``itu-radio-material``: the ITU ``type`` (default: the id), with its ``thickness`` if given;
    * ``radio-material`` (Sionna RT 1.x): a material named after the id (``mat-`` dropped) with
      ``relative_permittivity`` (or ``eta_r``), ``conductivity`` (or ``sigma``) and
      ``thickness``, frequency-independent;
    * any other BSDF: its id is a name hint for the object's material (a Sionna 0.x
      ``mat-itu_concrete``).

    A BSDF that the sidecar recorded, unchanged since, gets the sidecar's material (its name and
    exact definition, e.g. a power law that the XML holds at one frequency); a changed one keeps
    the XML's reading, with a warning. The sidecar also gives the object names behind the shape
    ids and the scene's metadata.
    """
    side = read_sidecar(xml_path)
    recorded = {}
    if side is not None:
        for name, entry in (side.get("materials") or {}).items():
            if isinstance(entry, dict) and entry.get("bsdf"):
                recorded[str(entry["bsdf"])] = (str(name), entry)
    material_of: dict[str, str] = {}
    materials: dict[str, Any] = {}
    for bsdf in root.iter("bsdf"):
        bid = bsdf.get("id")
        if not bid:
            continue
        params = _xml_props(bsdf)
        btype = bsdf.get("type")
        if bid in recorded and btype == recorded[bid][1].get("bsdf_type"):
            name, entry = recorded[bid]
            if _same_props(params, entry.get("xml") or {}):
                material_of[bid] = name
                materials[name] = entry.get("spec") or {}
                continue
            warnings.warn(
                f"{xml_path.name}: material {bid} differs from its sidecar's record: "
                "using the XML's values",
                stacklevel=3,
            )
        if btype == "itu-radio-material":
            mtype = str(params.get("type", bid))
            material_of[bid] = mtype
            if params.get("thickness") is not None:
                materials[mtype] = {"thickness": float(params["thickness"])}
        elif btype == "radio-material":
            name = _material_name(bid)
            material_of[bid] = name
            spec = {
                "eta_real": float(params.get("relative_permittivity", params.get("eta_r",
                                  SIONNA_DEFAULT_PERMITTIVITY))),
                "sigma": float(params.get("conductivity", params.get("sigma",
                               SIONNA_DEFAULT_CONDUCTIVITY))),
            }  # fmt: skip
            if params.get("thickness") is not None:
                spec["thickness"] = float(params["thickness"])
            materials[name] = spec
        else:
            material_of[bid] = bid
    shape_names: dict[str, str] = {}
    metadata: dict[str, Any] = {}
    if side is not None:
        for obj in side.get("objects") or []:
            if isinstance(obj, dict) and obj.get("shape") and obj.get("name"):
                shape_names[str(obj["shape"])] = str(obj["name"])
        block = side.get("hallray")
        if isinstance(block, dict) and block:
            metadata = {"hallray": block}
    surfaces = side is None or side.get("surfaces") is True
    return BsdfReading(material_of, materials, shape_names, metadata, surfaces)
