"""Mitsuba / Sionna RT export (raytrace.scene.mitsuba, hallray-export): the XML Sionna expects, a
round trip through our own reader that gives the same scene and the same traced paths, the
material rules, and safe, one-line-error command behaviour."""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import box, make_scene, quad

from hallray.safe_output import MARKER
from raytrace.cli.export_scene import export_scene_main
from raytrace.core.errors import MaterialError, SceneError
from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.io import load_scene
from raytrace.scene.metadata import SceneMetadata
from raytrace.scene.mitsuba import (
    SIDECAR_FORMAT,
    export_mitsuba,
    ply_bytes,
    sidecar_path,
)
from raytrace.solver.tracer import trace

#: Delays of the same path in the scene and its round trip agree within this, seconds.
DELAY_TOL_S = 1e-12
#: Complex gains of the same path agree within this, relative.
GAIN_RTOL = 1e-9


def _triangles(scene, obj) -> np.ndarray:
    """An object's triangles as a canonical sorted array (each triangle's vertices sorted, then
    the triangles): equal for two meshes that differ only in vertex and face order."""
    tri = scene.vertices[scene.faces[obj.face_start : obj.face_start + obj.face_count]]
    tri = np.sort(tri.view([("x", "f8"), ("y", "f8"), ("z", "f8")]).reshape(-1, 3), axis=1)
    flat = tri.view("f8").reshape(len(tri), 9)
    return flat[np.lexsort(flat.T[::-1])]


def assert_same_scene(a, b) -> None:
    """Same objects (names, materials, open/closed), triangles up to vertex and face order,
    materials (coefficients, ranges, thickness) and metadata."""
    assert [o.name for o in a.objects] == [o.name for o in b.objects]
    assert [o.material for o in a.objects] == [o.material for o in b.objects]
    assert [o.closed for o in a.objects] == [o.closed for o in b.objects]
    for oa, ob in zip(a.objects, b.objects):
        np.testing.assert_array_equal(_triangles(a, oa), _triangles(b, ob), err_msg=oa.name)
    for m in a.material_names:
        ma, mb = a.materials[m], b.materials[m]
        for key in ("a", "b", "c", "d", "f_min_hz", "f_max_hz", "thickness_m"):
            assert getattr(ma, key) == getattr(mb, key), (m, key)
    assert a.metadata == b.metadata


def assert_same_paths(p, q) -> None:
    """The same paths per link: as many, and sorted by delay the same delays (1 ps), gains and
    interaction sequences."""
    assert p.n_paths == q.n_paths
    for link in range(p.n_links):
        i = np.flatnonzero(p.link == link)
        j = np.flatnonzero(q.link == link)
        assert len(i) == len(j), link
        i = i[np.lexsort((np.abs(p.gain[i]), p.delay_s[i]))]
        j = j[np.lexsort((np.abs(q.gain[j]), q.delay_s[j]))]
        np.testing.assert_allclose(q.delay_s[j], p.delay_s[i], rtol=0, atol=DELAY_TOL_S)
        np.testing.assert_allclose(q.gain[j], p.gain[i], rtol=GAIN_RTOL, atol=0)
        assert list(q.kind_label[j]) == list(p.kind_label[i])


@pytest.fixture(scope="module")
def hall():
    return load_scene("hall")


def test_hall_round_trip_same_scene_and_paths(hall, tmp_path):
    res = export_mitsuba(hall, tmp_path / "scene.xml", frequency_hz=3.775e9)
    back = load_scene(tmp_path / "scene.xml")
    assert_same_scene(hall, back)
    # the meshes keep the scene's vertex order: the file format does not change the scene
    assert back.content_hash() == hall.content_hash()
    assert len(res.meshes) == len(hall.objects) and res.n_triangles == len(hall.faces)
    sites = SceneMetadata.from_scene(back)
    assert sites.bs_names == ["BS1", "BS2", "BS3", "BS4"] and len(sites.point_names) == 23
    bs, pts = SceneMetadata.from_scene(hall).bs_xyz, SceneMetadata.from_scene(hall).point_xyz
    assert_same_paths(trace(hall, bs, pts, 3.775e9), trace(back, bs, pts, 3.775e9))


@pytest.mark.parametrize("name", ["canonical/box_on_floor", "canonical/one_wall"])
def test_canonical_round_trip_same_scene_and_paths(name, tmp_path):
    scene = load_scene(name)
    export_mitsuba(scene, tmp_path / "s.xml")
    back = load_scene(tmp_path / "s.xml")
    assert_same_scene(scene, back)
    lo, hi = scene.bounds
    mid = (lo + hi) / 2
    # a transmitter and receivers around the scene's middle, above its lowest point
    tx = np.array([[lo[0] + 0.2 * (hi - lo)[0], mid[1] - 1.3, lo[2] + 1.5]])
    rx = np.array([[hi[0] - 0.2 * (hi - lo)[0], mid[1] + 0.7, lo[2] + 1.2],
                   [mid[0], hi[1] + 2.0, lo[2] + 2.0]])  # fmt: skip
    p, q = trace(scene, tx, rx, 3.5e9), trace(back, tx, rx, 3.5e9)
    assert p.n_paths > 0
    assert_same_paths(p, q)


def test_xml_is_what_sionna_rt_reads(hall, tmp_path):
    export_mitsuba(hall, tmp_path / "scene.xml", frequency_hz=3.775e9)
    root = ET.parse(tmp_path / "scene.xml").getroot()
    assert root.tag == "scene" and root.get("version")
    bsdfs = {b.get("id"): b for b in root.findall("bsdf")}
    concrete = bsdfs["mat-itu_concrete"]
    assert concrete.get("type") == "itu-radio-material"
    props = {c.get("name"): (c.tag, c.get("value")) for c in concrete}
    assert props["type"] == ("string", "concrete")
    assert props["thickness"] == ("float", "0.2")
    plastic = {c.get("name"): (c.tag, c.get("value")) for c in bsdfs["mat-plastic"]}
    assert bsdfs["mat-plastic"].get("type") == "radio-material"
    assert plastic["relative_permittivity"] == ("float", "2.5")
    assert plastic["conductivity"] == ("float", "0.002")
    assert plastic["thickness"] == ("float", "0.004")
    shapes = root.findall("shape")
    assert len(shapes) == len(hall.objects)
    ids = [s.get("id") for s in shapes] + list(bsdfs)
    assert len(set(ids)) == len(ids)  # Mitsuba ids share one namespace
    for s in shapes:
        assert s.get("type") == "ply"
        fname = s.find("string[@name='filename']").get("value")
        assert fname.startswith("meshes/") and (tmp_path / fname).is_file()
        assert s.find("ref").get("id") in bsdfs
    side = json.loads(sidecar_path(tmp_path / "scene.xml").read_text())
    assert side["format"] == SIDECAR_FORMAT
    assert side["scene_sha256"] == hall.content_hash()
    assert [b["name"] for b in side["hallray"]["base_stations"]] == ["BS1", "BS2", "BS3", "BS4"]


def test_ply_layout_is_binary_double_vertices_and_int_lists(tmp_path):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0.1234567890123]])
    data = ply_bytes(v, np.array([[0, 1, 2]]), "x")
    head, _, body = data.partition(b"end_header\n")
    assert b"format binary_little_endian 1.0" in head
    assert b"property double x" in head and b"property list uchar int vertex_indices" in head
    assert len(body) == 3 * 3 * 8 + (1 + 3 * 4)
    np.testing.assert_array_equal(np.frombuffer(body[:72], "<f8").reshape(3, 3), v)
    assert body[72] == 3 and list(np.frombuffer(body[73:], "<i4")) == [0, 1, 2]


def _custom_scene():
    """A wall of an ITU material with its own thickness, a sheet of a power-law user material, a
    box of an ITU-named material with other coefficients, and odd object names."""
    lib = MaterialLibrary.itu().with_yaml({"materials": {
        "glass": {"thickness": 0.05},
        "foil": {"a": 2.0, "b": 0.1, "c": 0.01, "d": 1.2, "f_range_ghz": [1, 50],
                 "thickness": 0.001},
        "concrete": {"eta_real": 4.0, "sigma": 0.05, "thickness": 0.3},
    }})  # fmt: skip
    return make_scene(
        [
            ("_hidden wall/1", quad([0, 0, 0], [6, 0, 0], [0, 0, 3]), "glass"),
            ("foil sheet", quad([0, 4, 0], [6, 0, 0], [0, 0, 3]), "foil"),
            ("mat-itu_glass", box([2, 1, 0], [3, 2, 1]), "concrete"),
        ],
        lib,
    )


def test_material_rules_and_exact_round_trip_of_custom_materials(tmp_path):
    scene = _custom_scene()
    with pytest.raises(MaterialError, match="depends on frequency"):
        export_mitsuba(scene, tmp_path / "a.xml")
    with pytest.raises(MaterialError, match="valid for 1-50 GHz"):
        export_mitsuba(scene, tmp_path / "a.xml", frequency_hz=60e9)
    res = export_mitsuba(scene, tmp_path / "a.xml", frequency_hz=10e9)
    assert res.frequency_dependent == ["foil"]
    root = ET.parse(tmp_path / "a.xml").getroot()
    bsdfs = {b.get("id"): b for b in root.findall("bsdf")}
    # an ITU material with its own thickness stays an ITU type; other coefficients under an ITU
    # name become a radio-material whose id Sionna does not take for an ITU one
    assert bsdfs["mat-itu_glass"].get("type") == "itu-radio-material"
    assert bsdfs["mat-custom_concrete"].get("type") == "radio-material"
    foil = {c.get("name"): c.get("value") for c in bsdfs["mat-foil"]}
    assert float(foil["relative_permittivity"]) == pytest.approx(2.0 * 10.0**0.1, rel=1e-15)
    assert float(foil["conductivity"]) == pytest.approx(0.01 * 10.0**1.2, rel=1e-15)
    ids = [s.get("id") for s in root.findall("shape")]
    assert all(i[0].isalpha() and " " not in i and "/" not in i for i in ids)
    assert "mat-itu_glass" not in ids  # the object's name may not take a BSDF's id
    back = load_scene(tmp_path / "a.xml")
    assert_same_scene(scene, back)  # names, power law and thicknesses from the sidecar


def test_xml_alone_reads_with_sionna_semantics(tmp_path):
    scene = _custom_scene()
    export_mitsuba(scene, tmp_path / "a.xml", frequency_hz=10e9)
    os.remove(sidecar_path(tmp_path / "a.xml"))
    back = load_scene(tmp_path / "a.xml")
    assert back.metadata == {}
    foil = back.materials["foil"]
    assert (foil.b, foil.d) == (0.0, 0.0)  # the XML's constants at 10 GHz
    assert foil.a == pytest.approx(2.0 * 10.0**0.1, rel=1e-15)
    assert back.materials["custom_concrete"].a == 4.0
    assert back.materials["glass"].thickness_m == 0.05


def test_an_edited_xml_wins_over_its_sidecar(tmp_path):
    scene = _custom_scene()
    export_mitsuba(scene, tmp_path / "a.xml", frequency_hz=10e9)
    text = (tmp_path / "a.xml").read_text().replace('name="thickness" value="0.05"',
                                                     'name="thickness" value="0.07"')  # fmt: skip
    (tmp_path / "a.xml").write_text(text)
    with pytest.warns(UserWarning, match="differs from its sidecar"):
        back = load_scene(tmp_path / "a.xml")
    assert back.materials["glass"].thickness_m == 0.07
    assert back.materials["foil"].b == 0.1  # unchanged ones still come from the sidecar


def test_library_refuses_bad_paths(hall, tmp_path):
    with pytest.raises(SceneError, match=r"must end in \.xml"):
        export_mitsuba(hall, tmp_path / "a.ply")
    with pytest.raises(SceneError, match="does not exist"):
        export_mitsuba(hall, tmp_path / "no" / "a.xml")


def test_bad_sidecar_is_a_one_line_error(tmp_path):
    scene = make_scene([("floor", quad([0, 0, 0], [4, 0, 0], [0, 4, 0]), "concrete")])
    export_mitsuba(scene, tmp_path / "a.xml")
    sidecar_path(tmp_path / "a.xml").write_text('{"format": "other"}')
    with pytest.raises(SceneError, match="not a hallray sidecar"):
        load_scene(tmp_path / "a.xml")


# -- the command -------------------------------------------------------------------------------
def test_command_writes_the_directory_whole(tmp_path, capsys):
    out = tmp_path / "sionna" / "hall.xml"
    assert export_scene_main(["hall", "-o", str(out)]) == 0
    msg = capsys.readouterr().out
    assert "112 meshes" in msg and "hall.hallray.json" in msg
    # and the output layer's marker (issue 40: only an earlier export is ever replaced)
    assert sorted(p.name for p in out.parent.iterdir()) == [MARKER, "hall.hallray.json",
                                                           "hall.xml", "meshes"]  # fmt: skip
    assert len(list((out.parent / "meshes").iterdir())) == 112
    # a previous export is replaced without --force; nothing is left beside it
    assert export_scene_main(["hall", "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sionna"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["missing.glb", "-o", "{d}/x/s.xml"], "scene file not found"),
        (["hall", "-o", "{d}/x/s.ply"], "must be DIR/NAME.xml"),
        (["hall", "-o", "{d}/none/x/s.xml"], "does not exist"),
        (["hall", "-o", "{d}/full/s.xml"], "not empty"),
        (["hall", "--band", "nope", "-o", "{d}/x/s.xml"], "unknown band"),
        (["hall", "--frequency-hz", "-3", "-o", "{d}/x/s.xml"], "positive"),
        (["hall", "--bogus", "-o", "{d}/x/s.xml"], "unrecognized arguments"),
    ],
)
def test_bad_input_one_line_error_and_nothing_written(tmp_path, capsys, args, message):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = [a.replace("{d}", str(tmp_path)) for a in args]
    assert export_scene_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine"


def test_command_refuses_to_export_into_its_input(tmp_path, capsys):
    assert export_scene_main(["hall", "-o", str(tmp_path / "e" / "s.xml"), "-q"]) == 0
    xml = str(tmp_path / "e" / "s.xml")
    assert export_scene_main([xml, "-o", xml]) == 2
    assert "contains an input of this command" in capsys.readouterr().err
    assert load_scene(xml).content_hash() == load_scene("hall").content_hash()
