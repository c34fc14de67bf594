"""Building models in IFC (raytrace.scene.ifc): a small hall written with IfcOpenShell's own
authoring API in millimetres (tests/ifc_hall.py) is read in metres with its IFC materials bound to
ITU-R P.2040 materials, and traces as the same boxes built in code: the same paths, delays to
1 ps, and the wall's reflection at its image-source delay."""

from __future__ import annotations

import builtins
import sys

import numpy as np
import pytest
from conftest import assert_same_paths_by_link, box, make_scene
from ifc_hall import ELEMENTS, write_ifc_hall

import raytrace
from raytrace import TraceConfig
from raytrace.cli.trace_scene import trace_scene_main
from raytrace.core.constants import C0
from raytrace.core.errors import SceneError
from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.io import load_scene
from raytrace.solver.paths import PENETRATION, REFLECTION

ifcopenshell = pytest.importorskip("ifcopenshell")

#: Delays of the same path in the IFC hall and in its boxes agree to this, seconds.
DELAY_TOL_S = 1e-12
TX = np.array([[2.0, 2.0, 2.5], [9.0, 6.5, 3.0]])
RX = np.array([[1.5, 6.0, 1.2], [6.0, 1.0, 1.0], [3.0, 5.0, 1.5]])
#: The materials the elements' IFC materials and classes bind to (the proxy has none: default).
EXPECTED = {"IfcSlab": "concrete", "IfcWall": "brick", "IfcColumn": "metal",
            "IfcBuildingElementProxy": "metal"}  # fmt: skip


@pytest.fixture(scope="module")
def hall_ifc(tmp_path_factory):
    return write_ifc_hall(tmp_path_factory.mktemp("ifc") / "hall.ifc")


def test_an_ifc_hall_is_read_in_metres_with_its_materials(hall_ifc):
    """Millimetres converted to metres; one closed solid per element, the IfcSpace not read; the
    slab's concrete by name, the wall's thickest layer (brick, not its gypsum boards), the steel
    column as metal; the proxy has no material: a one-line error naming it, or the default."""
    with pytest.raises(SceneError, match=r"1 object\(s\) without a material: "
                                         r"IfcBuildingElementProxy_press-12_"):  # fmt: skip
        load_scene(hall_ifc)
    scene = load_scene(hall_ifc, default_material="metal")
    assert len(scene.objects) == len(ELEMENTS) and scene.object_closed.all()
    assert {o.name.split("_")[0]: o.material for o in scene.objects} == EXPECTED
    np.testing.assert_allclose(scene.bounds, [[-1, -1, -0.3], [11, 9, 4]], atol=1e-9)
    assert scene.up == "z" and scene.unit == "m"


def test_an_ifc_hall_traces_as_its_boxes(hall_ifc):
    """The same paths as the same boxes built in code (per link, the same interaction sequences,
    delays to 1 ps), and the reflection in the wall's face (y = 8) at the image source's
    delay |tx - rx'| / c."""
    scene = load_scene(hall_ifc, default_material="metal")
    boxes = make_scene([(name, box(lo, np.add(lo, size)), EXPECTED[cls])
                        for cls, name, lo, size, _ in ELEMENTS])  # fmt: skip
    cfg = TraceConfig()
    a = raytrace.trace(boxes, TX, RX, 3.775e9, cfg, threads=1)
    b = raytrace.trace(scene, TX, RX, 3.775e9, cfg, threads=1)
    assert_same_paths_by_link(a, b, DELAY_TOL_S, objects=False)  # IFC names its objects its way
    wall = next(i for i, o in enumerate(scene.objects) if o.name.startswith("IfcWall"))
    image = RX[0] * [1, -1, 1] + [0, 16.0, 0]  # RX[0] mirrored in y = 8
    one = [i for i in range(b.n_paths) if b.tx_index[i] == 0 and b.rx_index[i] == 0
           and b.objects[i][0] == wall and b.interaction[i].tolist() == [REFLECTION, 0, 0, 0]]
    assert len(one) == 1
    assert abs(b.delay_s[one[0]] - np.linalg.norm(TX[0] - image) / C0) < DELAY_TOL_S


def test_material_hints_order(tmp_path):
    """A window's glazing before its frame; a layered wall's thickest layer first; the words of
    CAD material names (steel -> metal); the element's class last."""
    from ifcopenshell.api import material, project, root

    from raytrace.scene.ifc import material_hints

    m = project.create_file(version="IFC4")
    window = root.create_entity(m, ifc_class="IfcWindow", name="W1")
    parts = material.add_material_set(m, name="window", set_type="IfcMaterialConstituentSet")
    for name, category in (("Aluminium frame", "Framing"), ("Float glass", "Glazing")):
        mat = material.add_material(m, name=name)
        c = material.add_constituent(m, constituent_set=parts, material=mat)
        # (edit_constituent unsets the material unless it is given again)
        material.edit_constituent(m, constituent=c, attributes={"Category": category}, material=mat)
    material.assign_material(m, products=[window], type="IfcMaterialConstituentSet",
                             material=parts)  # fmt: skip
    hints = material_hints(window)
    assert hints.index("Float glass") < hints.index("Aluminium frame")
    assert hints[-1] == "glass" and "metal" in hints
    lib = MaterialLibrary.itu()
    assert next(lib.match(h) for h in hints if lib.match(h)) == "glass"
    beam = root.create_entity(m, ifc_class="IfcBeam", name="B7")
    steel = material.add_material(m, name="S235 Steel")
    material.assign_material(m, products=[beam], material=steel)
    assert next(lib.match(h) for h in material_hints(beam) if lib.match(h)) == "metal"
    bare = root.create_entity(m, ifc_class="IfcDoor", name="D1")
    assert material_hints(bare) == ["D1", "wood"]


def test_an_element_without_triangles_is_named_in_a_warning(tmp_path):
    """A wall of zero height has a body but no triangles: it is named, not silently missing."""
    flat = ("IfcWall", "flat wall", (0.0, 0.0, 0.0), (5.0, 0.2, 0.0), "Concrete")
    path = write_ifc_hall(tmp_path / "flat.ifc", ELEMENTS + [flat])
    with pytest.warns(UserWarning, match=r"1 element\(s\) with a body gave no triangles and are "
                                         r"not in the scene: IfcWall_flat-wall_"):  # fmt: skip
        scene = load_scene(path, default_material="metal", cache=False)
    assert len(scene.objects) == len(ELEMENTS)


def test_a_window_in_its_walls_opening(tmp_path):
    """A wall with an opening (IfcOpeningElement, a void feature) and a window in it, neither
    with an IFC material: the opening is cut (the wall is a box with a hole: 32 triangles), the
    direct path through it crosses the window's glass only and one beside it the wall only; both
    are bound by their class, which a warning says."""
    from ifcopenshell.api import feature

    elements = [
        ("IfcWall", "w", (0.0, 5.0, 0.0), (10.0, 0.2, 4.0), None),
        ("IfcOpeningElement", "hole", (4.0, 4.9, 1.0), (2.0, 0.4, 1.5), None),
        ("IfcWindow", "win", (4.0, 5.08, 1.0), (2.0, 0.04, 1.5), None),
    ]

    def cut(m, made):
        feature.add_feature(m, feature=made["hole"], element=made["w"])

    path = write_ifc_hall(tmp_path / "window.ifc", elements, space=False, then=cut)
    said = (r"2 element\(s\) have no IFC material and are bound by their class .*"
            r"IfcWall -> concrete \(1\), IfcWindow -> glass")
    with pytest.warns(UserWarning, match=said):
        scene = load_scene(path, cache=False)
    names = [o.name.split("_")[0] for o in scene.objects]
    assert names == ["IfcWall", "IfcWindow"]
    assert [o.material for o in scene.objects] == ["concrete", "glass"]
    assert scene.objects[0].face_count == 32
    for x, crossed in ((5.0, 1), (1.0, 0)):  # through the opening, beside it
        p = raytrace.trace(scene, np.array([[x, 3.0, 1.75]]), np.array([[x, 7.0, 1.75]]),
                           3.775e9, TraceConfig(max_reflections=0, max_diffractions=0), threads=1)
        (direct,) = [i for i in range(p.n_paths) if p.interaction[i][0] == PENETRATION]
        assert p.objects[direct][0] == crossed and (p.objects[direct][1:] == -1).all()


def test_classes_missing_from_an_older_schema_are_skipped_quietly():
    """IFC2X3 (Revit's default export) has no IfcSpatialZone: nothing of it to skip."""
    from raytrace.scene.ifc import IFC_SKIPPED, _by_type

    old = ifcopenshell.file(schema="IFC2X3")
    old.createIfcSpace(ifcopenshell.guid.new())
    assert "IfcSpatialZone" in IFC_SKIPPED and _by_type(old, "IfcSpatialZone") == []
    assert len(_by_type(old, "IfcSpace")) == 1


def test_ifc_errors_are_one_line(hall_ifc, tmp_path, capsys, monkeypatch):
    """An unreadable file, --unit on IFC (which states its own unit), and a missing IfcOpenShell
    are one line each; trace-scene reads IFC."""
    bad = tmp_path / "broken.ifc"
    bad.write_text("ISO-10303-21;\nnot an IFC file\n")
    with pytest.raises(SceneError, match="cannot read scene broken.ifc"):
        load_scene(bad)
    with pytest.raises(SceneError, match="states its own length unit .* --unit mm does not apply"):
        load_scene(hall_ifc, unit="mm")
    assert trace_scene_main([str(hall_ifc), "--default-material", "metal", "--summary-only"]) == 0
    assert "objects    4 (4 closed solids, 0 open sheets)" in capsys.readouterr().out
    real_import = builtins.__import__

    def no_ifcopenshell(name, *args, **kwargs):
        if name.startswith("ifcopenshell"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    for mod in [m for m in sys.modules if m.startswith("ifcopenshell")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setattr(builtins, "__import__", no_ifcopenshell)
    with pytest.raises(SceneError, match=r"needs IfcOpenShell: pip install 'hallray\[ifc\]'"):
        load_scene(hall_ifc, cache=False)
