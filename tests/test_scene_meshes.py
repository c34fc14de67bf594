"""Meshes from CAD exports and scans, as users bring them (issue 36): triangle soups and welding
gaps, doubled and flipped faces, degenerate triangles, NaN vertices, OBJ objects, survey
coordinates and a hall in millimetres. Each case is compared with the clean hall it was made
from (the same links, interaction sequences and objects, delays to 1 ps), or is refused in one
line naming the file (raytrace.scene.io, raytrace.scene.construction, raytrace.scene.queries).
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest
import trimesh
from conftest import assert_same_paths_by_link, box, make_scene, quad

import raytrace
from raytrace import TraceConfig
from raytrace.cli.trace_scene import trace_scene_main
from raytrace.core.errors import HallrayError, SceneError
from raytrace.scene.io import Y_UP_TO_Z_UP, file_up, load_scene
from raytrace.solver.paths import Paths

#: Delays of the same path in the clean and the repaired (or moved) hall agree to this, seconds.
DELAY_TOL_S = 1e-12
#: Transmitters off every face plane of the hall (a transmitter exactly in the plane of a box's
#: top face makes grazing paths that any 1e-7 m change flips: not what these tests look at).
TX = np.array([[2.1, 2.3, 5.7], [27.9, 17.6, 5.3]])


def hall_objects() -> list[tuple[str, trimesh.Trimesh]]:
    """A 30 x 20 x 8 m hall of closed solids: floor and roof slabs, four walls, three machines,
    named after their materials; in the order of their names (the loader's, from a file)."""
    L, W, H, t = 30.0, 20.0, 8.0, 0.3
    return sorted([
        ("floor_concrete", box((-t, -t, -t), (L + t, W + t, 0))),
        ("roof_concrete", box((-t, -t, H), (L + t, W + t, H + t))),
        ("wall_s_concrete", box((-t, -t, 0), (L + t, 0, H))),
        ("wall_n_concrete", box((-t, W, 0), (L + t, W + t, H))),
        ("wall_w_concrete", box((-t, 0, 0), (0, W, H))),
        ("wall_e_concrete", box((L, 0, 0), (L + t, W, H))),
        ("machine_a_metal", box((5, 4, 0), (8, 7, 3.0))),
        ("machine_b_metal", box((15, 10, 0), (18, 13, 4.5))),
        ("rack_metal", box((22, 3, 0), (23, 15, 6.0))),
    ])


def _scene(objects) -> raytrace.Scene:
    return make_scene([(n, m, n.rsplit("_", 1)[1]) for n, m in objects])


def _rx(scene, n=10, seed=1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    rx = np.column_stack([rng.uniform(1, 29, n), rng.uniform(1, 19, n), rng.uniform(0.5, 2, n)])
    return rx[scene.inside_solid(rx) < 0]


def _trace(scene, tx, rx) -> Paths:
    return raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(), threads=1)


def assert_same_paths(clean: Paths, other: Paths, objects: bool = True) -> None:
    """The same paths: per link, interaction sequence and (with ``objects``) objects, as many,
    with delays equal to :data:`DELAY_TOL_S` (element indices are renumbered by a repair, the
    objects and interactions are not)."""
    assert_same_paths_by_link(clean, other, DELAY_TOL_S, objects)


@pytest.fixture(scope="module")
def clean():
    scene = _scene(hall_objects())
    rx = _rx(scene)
    return scene, rx, _trace(scene, TX, rx)


def _soup(mesh: trimesh.Trimesh, gap: float = 0.0, rng=None) -> trimesh.Trimesh:
    """Every triangle with its own three vertices, each moved by up to ``gap`` (m) per axis."""
    tri = np.asarray(mesh.triangles, float).reshape(-1, 3)
    if gap:
        tri = tri + rng.uniform(-gap, gap, tri.shape)
    return trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3), process=False)


def _write(path, objects):
    sc = trimesh.Scene()
    for name, mesh in objects:
        sc.add_geometry(mesh, node_name=name, geom_name=name)
    sc.export(str(path))
    return path


# -- triangle soup and welding gaps --------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_a_triangle_soup_gives_the_welded_halls_paths(clean, tmp_path, suffix):
    scene, rx, ref = clean
    objects = [(n, _soup(m)) for n, m in hall_objects()]
    soup = load_scene(_write(tmp_path / f"soup{suffix}", objects))
    assert len(soup.objects) == 9 and soup.object_closed.all()
    assert (len(soup.facets), len(soup.wedges)) == (len(scene.facets), len(scene.wedges))
    assert_same_paths(ref, _trace(soup, TX, rx))


@pytest.mark.parametrize("gap", [1e-7, 1e-6, 1e-5])
def test_welding_gaps_give_the_welded_halls_paths(clean, tmp_path, gap):
    """Gaps of 1e-7 to 1e-5 m (OBJ keeps them: 8 decimals): every solid closed again, the same
    facets, the same wedges (at 1e-5 m, at most a few sub-millimetre pieces more where slabs
    and walls meet), and the clean hall's paths to 1 ps."""
    scene, rx, ref = clean
    rng = np.random.default_rng(0)
    objects = [(n, _soup(m, gap, rng)) for n, m in hall_objects()]
    with pytest.warns(UserWarning, match=r"repaired: \d+ vertices welded"):
        moved = load_scene(_write(tmp_path / "gaps.obj", objects))
    assert moved.object_closed.all() and len(moved.facets) == len(scene.facets)
    extra = len(moved.wedges) - len(scene.wedges)
    if gap < 1e-5:
        assert extra == 0
    else:
        assert 0 <= extra <= 2 and np.sort(moved.wedges.length)[:extra].max(initial=0) < 1e-3
    assert_same_paths(ref, _trace(moved, TX, rx))


def test_the_weld_leaves_clean_meshes_as_they_are():
    from raytrace.scene.repair import weld_vertices

    b = box((0, 0, 0), (1, 1, 1))
    v, f, n = weld_vertices(np.asarray(b.vertices), np.asarray(b.faces))
    assert n == 0 and v is not None and np.array_equal(f, b.faces)
    # vertices 50 um apart are one; 0.2 mm apart are two
    v = np.array([[0, 0, 0], [5e-5, 0, 0], [1, 0, 0], [1.0002, 0, 0], [0, 1, 0]])
    _, f, n = weld_vertices(v, np.array([[0, 2, 4], [1, 3, 4]]))
    assert n == 1 and f.tolist() == [[0, 2, 4], [0, 3, 4]]


# -- an OBJ's objects ----------------------------------------------------------------------------
def test_obj_objects_and_groups_are_objects(tmp_path):
    p = _write(tmp_path / "hall.obj", hall_objects())
    scene = load_scene(p)
    assert [o.name for o in scene.objects] == [n for n, _ in hall_objects()]
    assert scene.object_closed.all()
    assert {o.name: o.material for o in scene.objects}["rack_metal"] == "metal"
    # groups only (g lines, as many CAD exporters write them)
    text = p.read_text().replace("\no ", "\ng ")
    (tmp_path / "groups.obj").write_text(text)
    assert [o.name for o in load_scene(tmp_path / "groups.obj").objects] == [o.name for o in scene.objects]


# -- duplicate, flipped and degenerate faces -----------------------------------------------------
def _edit(name: str, fn) -> list[tuple[str, trimesh.Trimesh]]:
    return [(n, fn(m) if n == name else m) for n, m in hall_objects()]


def test_duplicate_and_flipped_faces_are_repaired(clean):
    _, rx, ref = clean

    def doubled(m):  # three faces twice, one of them in the other winding
        extra = m.faces[:3].copy()
        extra[0] = extra[0][::-1]
        return trimesh.Trimesh(m.vertices, np.vstack([m.faces, extra]), process=False)

    def flipped(m):  # two faces of a closed box wound the other way
        f = m.faces.copy()
        f[[0, 5]] = f[[0, 5]][:, ::-1]
        return trimesh.Trimesh(m.vertices, f, process=False)

    for fn, said in ((doubled, "3 duplicate triangles dropped"),
                     (flipped, "1 closed objects' faces turned to one winding")):  # fmt: skip
        with pytest.warns(UserWarning, match=said):
            scene = _scene(_edit("machine_a_metal", fn))
        assert scene.object_closed.all()
        assert_same_paths(ref, _trace(scene, TX, rx))


def test_a_doubled_object_is_dropped_and_z_fighting_is_named(clean):
    """The same machine twice (a CAD export's doubled instance, another name, faces in another
    order): dropped, the clean hall's paths (it added 107 of 805 and 8 wedges). A crate
    overlapping a machine (their top and bottom faces in one plane, facing the same way): both
    kept, one warning naming them."""
    _, rx, ref = clean
    m = dict(hall_objects())["machine_a_metal"]
    copy = trimesh.Trimesh(m.vertices, m.faces[::-1][:, [1, 2, 0]], process=False)
    hall = [(n, x, n.rsplit("_", 1)[1]) for n, x in hall_objects()]
    with pytest.warns(UserWarning, match="1 objects dropped that repeat another object's"):
        scene = make_scene(hall + [("machine_a_copy", copy, "metal")])
    assert [o.name for o in scene.objects] == [n for n, _, _ in hall]
    assert_same_paths(ref, _trace(scene, TX, rx))
    with pytest.warns(UserWarning, match=r"2 facet pair\(s\) .* \(z-fighting: crate_wood and "
                                         r"machine_a_metal\)"):
        make_scene(hall + [("crate_wood", box((6, 5, 0), (9, 6, 3.0)), "wood")])


def test_degenerate_triangles_are_dropped(clean):
    _, rx, ref = clean

    def degenerate(m):  # a repeated index, a collinear triangle, one point three times
        k = len(m.vertices)
        v = np.vstack([m.vertices, [[5, 4, 3.0], [6, 4, 3.0], [7, 4, 3.0]]])
        f = np.vstack([m.faces, [[0, 0, 1], [k, k + 1, k + 2], [2, 2, 2]]])
        return trimesh.Trimesh(v, f, process=False)

    with pytest.warns(UserWarning, match="3 degenerate"):
        scene = _scene(_edit("machine_a_metal", degenerate))
    assert_same_paths(ref, _trace(scene, TX, rx))


def test_sub_millimetre_triangles_beside_10_m_walls(clean):
    """A machine cut into slivers: a vertex 0.3 mm from its top face's edge fans that face into
    triangles 0.3 mm wide; the facets and paths are the clean hall's."""
    scene, rx, ref = clean

    def slivers(m):
        tri = [t for t in np.asarray(m.triangles) if not np.allclose(t[:, 2], 4.5)]
        a, b, c, d = (np.array(p) for p in ([15, 10, 4.5], [18, 10, 4.5], [18, 13, 4.5], [15, 13, 4.5]))
        s = np.array([16.5, 10.0003, 4.5])
        tri += [np.array(t) for t in ((a, b, s), (b, c, s), (c, d, s), (d, a, s))]
        tri = np.array(tri).reshape(-1, 3)
        return trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3))

    sliver = _scene(_edit("machine_b_metal", slivers))
    assert sliver.object_closed.all() and len(sliver.facets) == len(scene.facets)
    assert_same_paths(ref, _trace(sliver, TX, rx))


def test_nan_vertex_is_one_line_naming_the_file(tmp_path, capsys):
    m = box((0, 0, 0), (10, 10, 3))
    m.vertices[2, 1] = np.nan
    p = tmp_path / "scan.stl"
    p.write_text(trimesh.exchange.stl.export_stl_ascii(m))
    with pytest.raises(SceneError, match="scan.stl.*NaN"):
        load_scene(p, default_material="concrete")
    argv = [str(p), "--default-material", "concrete", "--tx", "1,1,1", "--rx", "2,2,1", "-q"]
    assert trace_scene_main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert "scan.stl" in line and "NaN" in line


def test_a_t_junction_in_a_closed_box_is_split(clean):
    """A machine whose top face is three triangles meeting at a vertex on the middle of its
    south edge, where the side face below is not split (a T-junction): closed again, the clean
    hall's paths."""
    _, rx, ref = clean

    def t_junction(m):
        tri = [t for t in np.asarray(m.triangles) if not np.allclose(t[:, 2], 3.0)]
        a, b, c, d, t = ([5, 4, 3.0], [8, 4, 3.0], [8, 7, 3.0], [5, 7, 3.0], [6.5, 4, 3.0])
        tri += [np.array(x) for x in ((a, t, d), (t, b, c), (t, c, d))]
        tri = np.array(tri).reshape(-1, 3)
        return trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3))

    with pytest.warns(UserWarning, match="1 T-junctions closed"):
        scene = _scene(_edit("machine_a_metal", t_junction))
    assert scene.object_closed.all()
    assert_same_paths(ref, _trace(scene, TX, rx))


@pytest.mark.parametrize("gap", [0.0, 1e-6])
def test_a_hall_in_one_stl_is_split_into_its_solids(tmp_path, gap):
    """The whole hall as one STL (one object, a triangle soup; walls touching the slabs along
    edges of four faces): split into its nine closed solids, the paths of the nine objects
    (per link, the same interaction sequences with delays to 1 ps; the objects are named
    hall.stl#1 .. hall.stl#9: an STL names its one object after the file)."""
    rng = np.random.default_rng(0)
    metal = [(n.rsplit("_", 1)[0] + "_metal", m) for n, m in hall_objects()]
    ref_scene = _scene(metal)
    rx = _rx(ref_scene)
    mesh = trimesh.util.concatenate([_soup(m, gap, rng) for _, m in metal])
    mesh.export(str(tmp_path / "hall.stl"))
    with pytest.warns(UserWarning, match="9 closed solids split out"):
        scene = load_scene(tmp_path / "hall.stl", default_material="metal")
    assert scene.object_closed.all() and len(scene.objects) == 9
    assert sorted(o.name for o in scene.objects) == sorted(f"hall.stl#{k}" for k in range(1, 10))
    assert (len(scene.facets), len(scene.wedges)) == (len(ref_scene.facets), len(ref_scene.wedges))

    # the split objects are numbered by the file, not as the separate ones: objects not compared
    assert_same_paths(_trace(ref_scene, TX, rx), _trace(scene, TX, rx), objects=False)


def test_solids_and_a_sheet_in_one_mesh_are_split_into_both(tmp_path):
    """The hall's nine solids and a free-standing concrete screen (an open sheet) in one STL, as
    a CAD export that joins every object of a material gives them: the solids split out of it
    and the screen left as one sheet (``hall.stl#sheet``) trace as the ten separate objects (per
    link, the same interaction sequences with delays to 1 ps). Left as one open sheet, the walls
    were two-sided sheets and every path through them crossed two slabs."""
    rng = np.random.default_rng(3)
    concrete = [(n.rsplit("_", 1)[0] + "_concrete", m) for n, m in hall_objects()]
    screen = quad((12, 2, 0.5), (0, 6, 0), (0, 0, 3.5))
    ref_scene = _scene(concrete + [("screen_concrete", screen)])
    rx = _rx(ref_scene)
    mesh = trimesh.util.concatenate([_soup(m, 1e-6, rng) for _, m in concrete] + [_soup(screen)])
    mesh.export(str(tmp_path / "hall.stl"))
    with pytest.warns(UserWarning, match="9 closed solids split out of open meshes"):
        scene = load_scene(tmp_path / "hall.stl", default_material="concrete")
    names = [o.name for o in scene.objects]
    assert sorted(names) == sorted([f"hall.stl#{k}" for k in range(1, 10)] + ["hall.stl#sheet"])
    assert scene.object_closed.tolist() == [n != "hall.stl#sheet" for n in names]
    assert (len(scene.facets), len(scene.wedges)) == (len(ref_scene.facets), len(ref_scene.wedges))

    # the split objects are numbered by the file, not as the separate ones: objects not compared
    assert_same_paths(_trace(ref_scene, TX, rx), _trace(scene, TX, rx), objects=False)


# -- the file's up axis ---------------------------------------------------------------------------
def _blender_glb(objects, generator="Khronos glTF Blender I/O v4.2.70", y_up=True) -> bytes:
    """``objects`` as Blender's glTF export writes them: its z-up frame's (x, y, z) stored as
    (x, z, -y), +y up as glTF specifies, and its exporter named in ``asset.generator`` (with
    ``y_up=False``, stored as they are, as a tool that ignores the convention writes them)."""
    import json
    import struct

    to_file = np.linalg.inv(Y_UP_TO_Z_UP) if y_up else np.eye(4)
    sc = trimesh.Scene()
    for name, mesh in objects:
        sc.add_geometry(mesh.copy().apply_transform(to_file), node_name=name, geom_name=name)
    data = sc.export(file_type="glb")
    n = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20 : 20 + n])
    gltf["asset"]["generator"] = generator
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + n :]
    head = struct.pack("<III", 0x46546C67, 2, 20 + len(text) + len(rest))
    return head + struct.pack("<II", len(text), 0x4E4F534A) + text + rest


def test_a_blender_gltf_is_turned_to_z_up(clean, tmp_path, capsys):
    """A hall exported from Blender to glTF (+y up, as the specification says) is read in
    Blender's own z-up frame, so positions read off Blender are the scene's: the clean hall's
    paths, delays to 1 ps. ``up="z"`` keeps the file's axes (the hall on its side); a GLB that
    trimesh wrote (hallray's own) stays z-up."""
    _, rx, ref = clean
    path = tmp_path / "hall.glb"
    path.write_bytes(_blender_glb(hall_objects()))
    assert file_up(path) == "y"
    scene = load_scene(path)
    assert scene.up == "y" and scene.summary()["up"] == "y"
    np.testing.assert_allclose(scene.bounds, [[-0.3, -0.3, -0.3], [30.3, 20.3, 8.3]], atol=1e-6)
    assert_same_paths(ref, _trace(scene, TX, rx))
    side = load_scene(path, up="z")
    assert side.up == "z"
    np.testing.assert_allclose(side.bounds, [[-0.3, -0.3, -20.3], [30.3, 8.3, 0.3]], atol=1e-6)
    assert file_up(_write(tmp_path / "mine.glb", hall_objects())) == "z"
    assert load_scene("hall").up == "z"
    assert trace_scene_main([str(path), "--default-material", "concrete"]) == 0
    assert "up         the file's +y, turned to z up" in capsys.readouterr().out


def test_a_gltf_stored_z_up_against_its_convention_is_read_as_stored(clean, tmp_path):
    """A glTF from a tool that stores the hall z-up (lower along z than along y) is read as it
    is, with a warning naming --up y; the clean hall's paths; ``up="y"`` still turns it."""
    _, rx, ref = clean
    path = tmp_path / "hall.glb"
    path.write_bytes(_blender_glb(hall_objects(), generator="SomeExporter 1.0", y_up=False))
    assert file_up(path) == "y"
    with pytest.warns(UserWarning, match=r"lower along z \(8.6 m\) than along y \(20.6 m\): read "
                                         r"with z up as it is stored; --up y turns it"):  # fmt: skip
        scene = load_scene(path, cache=False)
    assert scene.up == "z"
    assert_same_paths(ref, _trace(scene, TX, rx))
    turned = load_scene(path, up="y", cache=False)
    assert turned.up == "y"
    np.testing.assert_allclose(turned.bounds, [[-0.3, -8.3, -0.3], [30.3, 0.3, 20.3]], atol=1e-6)


def _write_dae(path, objects, meter=1.0, unit_name="meter", up="Z_UP", to_file=None,
               polylist=False):  # fmt: skip
    """``objects`` as a Collada file with pycollada, in a unit of ``meter`` metres and the given
    ``<up_axis>``, the vertices transformed by ``to_file`` first; each material named after
    the object's; as ``<polylist>`` instead of ``<triangles>`` with ``polylist``."""
    import collada
    from collada import asset, geometry, material, scene, source

    to_file = np.eye(4) if to_file is None else to_file
    c = collada.Collada()
    c.assetInfo.unitmeter, c.assetInfo.unitname = meter, unit_name
    c.assetInfo.upaxis = getattr(asset.UP_AXIS, up)
    nodes = []
    for k, (name, m) in enumerate(objects):
        v = (np.c_[m.vertices, np.ones(len(m.vertices))] @ to_file.T)[:, :3] / meter
        effect = material.Effect(f"e{k}", [], "phong", diffuse=(0.5, 0.5, 0.5))
        mat = material.Material(f"m{k}", name.rsplit("_", 1)[1], effect)
        c.effects.append(effect)
        c.materials.append(mat)
        geom = geometry.Geometry(c, f"g{k}", name, [source.FloatSource(f"v{k}", v.ravel(),
                                                                       ("X", "Y", "Z"))])
        inputs = source.InputList()
        inputs.addInput(0, "VERTEX", f"#v{k}")
        faces = np.asarray(m.faces).ravel()
        geom.primitives.append(
            geom.createPolylist(faces, np.full(len(m.faces), 3), inputs, f"ref{k}") if polylist
            else geom.createTriangleSet(faces, inputs, f"ref{k}"))  # fmt: skip
        c.geometries.append(geom)
        bound = scene.MaterialNode(f"ref{k}", mat, inputs=[])
        nodes.append(scene.Node(name, children=[scene.GeometryNode(geom, [bound])]))
    c.scene = scene.Scene("hall", nodes)
    c.scenes.append(c.scene)
    c.write(str(path))
    return path


def test_a_collada_file_is_read_in_the_unit_and_up_axis_it_states(clean, tmp_path, monkeypatch):
    """SketchUp's Collada export states inches and Z_UP: read in metres with the materials its
    names bind, the clean hall's paths (delays to 1 ps); a file in metres stating Y_UP, its
    faces as polygon lists, is turned; a given --unit wins over the stated one; a malformed
    file, X_UP and a missing pycollada are one-line errors."""
    pytest.importorskip("collada")
    _, rx, ref = clean
    inches = _write_dae(tmp_path / "hall_in.dae", hall_objects(), meter=0.0254, unit_name="inch")
    scene = load_scene(inches)
    assert (scene.unit, scene.up) == ("in", "z")
    np.testing.assert_allclose(scene.bounds, [[-0.3, -0.3, -0.3], [30.3, 20.3, 8.3]], atol=1e-5)
    assert_same_paths(ref, _trace(scene, TX, rx))
    feet = load_scene(inches, unit="ft", cache=False)  # the given unit, not the stated one
    assert feet.unit == "ft"
    np.testing.assert_allclose(feet.bounds, scene.bounds * (0.3048 / 0.0254), rtol=1e-12)
    y_up = _write_dae(tmp_path / "hall_y.dae", hall_objects(), up="Y_UP",
                      to_file=np.linalg.inv(Y_UP_TO_Z_UP), polylist=True)  # fmt: skip
    turned = load_scene(y_up)
    assert (turned.unit, turned.up) == ("m", "y")
    assert_same_paths(ref, _trace(turned, TX, rx))
    broken = tmp_path / "broken.dae"
    broken.write_text("<COLLADA><broken")
    with pytest.raises(SceneError, match="cannot read scene broken.dae: DaeMalformedError"):
        load_scene(broken)
    sideways = _write_dae(tmp_path / "hall_x.dae", hall_objects(), up="X_UP")
    with pytest.raises(SceneError, match="states X_UP, which hallray does not turn"):
        load_scene(sideways)
    monkeypatch.setitem(sys.modules, "collada", None)  # as if not installed
    with pytest.raises(SceneError, match=r"needs pycollada: pip install 'hallray\[dae\]'"):
        load_scene(inches, cache=False)


def test_a_blender_obj_is_y_up_and_up_can_be_given(tmp_path):
    """An OBJ whose header names Blender is +y up (its exporter's default); another OBJ is z-up
    unless ``up="y"`` says otherwise; a file hallray wrote (its metadata) refuses ``up="y"``
    in one line; a wrong axis is a one-line error."""
    box_y = box((0, 0, -2), (4, 3, 0))  # 4 x 2 x 3 m high, stored y-up
    text = box_y.export(file_type="obj")
    (tmp_path / "blender.obj").write_text("# Blender 4.2.0\n# www.blender.org\n" + text)
    (tmp_path / "other.obj").write_text(text)
    assert (file_up(tmp_path / "blender.obj"), file_up(tmp_path / "other.obj")) == ("y", "z")
    up = load_scene(tmp_path / "blender.obj", default_material="metal")
    np.testing.assert_allclose(up.bounds, [[0, 0, 0], [4, 2, 3]], atol=1e-9)
    given = load_scene(tmp_path / "other.obj", default_material="metal", up="y")
    np.testing.assert_allclose(given.bounds, up.bounds, atol=1e-9)
    with pytest.raises(SceneError, match="written by hallray, in metres with z up: --up y does not apply"):
        load_scene("hall", up="y")
    with pytest.raises(SceneError, match="up axis must be one of z, y, not 'x'"):
        load_scene("hall", up="x")


def test_a_closed_fold_glued_to_a_sheet_stays_in_it():
    """A tetrahedron that shares an edge with an open sheet (the folds a scan's reconstruction
    makes) is part of that surface: the mesh comes back whole. The same tetrahedron apart from
    the sheet is a solid of its own."""
    from raytrace.scene.repair import split_bodies

    sheet = quad((0, 0, 0), (2, 0, 0), (0, 2, 0))
    v = np.array([[0, 0, 0], [2, 0, 0], [1, 0.5, 1], [1, -0.5, 0.5]], float)
    tet = trimesh.Trimesh(v, [[0, 1, 2], [0, 3, 1], [1, 3, 2], [0, 2, 3]], process=True)
    assert tet.is_watertight
    glued = trimesh.util.concatenate([sheet, tet])
    glued.merge_vertices()
    assert [n for n, _ in split_bodies("scan", glued)] == ["scan"]
    apart = trimesh.util.concatenate([sheet, tet.copy().apply_translation([0, 0, 3])])
    parts = dict(split_bodies("scan", apart))
    assert sorted(parts) == ["scan#1", "scan#sheet"]
    assert parts["scan#1"].is_watertight and len(parts["scan#sheet"].faces) == 2


def test_a_shelf_on_its_wall_in_one_sheet_has_no_edge_there(clean):
    """A wall sheet and a shelf sheet standing out of it, as one object (the shelf's edge on the
    wall's faces, or on an edge the wall shares with it: three faces) traced as the two
    objects: no diffraction at the T, where the air is 90, 180 and 90 degrees."""
    _, rx, _ = clean
    shelf = quad((12, 2, 2), (2, 0, 0), (0, 6, 0))
    wall = quad((12, 2, 0), (0, 6, 0), (0, 0, 4))
    split_wall = trimesh.util.concatenate([quad((12, 2, 0), (0, 6, 0), (0, 0, 2)),
                                           quad((12, 2, 2), (0, 6, 0), (0, 0, 2))])  # fmt: skip
    hall = [(n, m, n.rsplit("_", 1)[1]) for n, m in hall_objects()]
    two = make_scene(hall + [("shelf", shelf, "metal"), ("wall", wall, "metal")])
    ref = _trace(two, TX, rx)
    ref.objects[ref.objects == len(hall) + 1] = len(hall)  # the two as one object
    for w in (wall, split_wall):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            one = make_scene(hall + [("tee", trimesh.util.concatenate([shelf, w]), "metal")])
        # the shelf's corners on the whole wall's side edges are T-junctions too
        assert [str(x.message) for x in said] == (["scene repaired: 2 T-junctions closed (a vertex "
                                                   "on another triangle's edge)"] if w is wall else [])
        assert len(one.wedges) == len(two.wedges)
        assert_same_paths(ref, _trace(one, TX, rx))


def test_nan_vertex_in_a_mitsuba_scenes_mesh_is_refused(tmp_path):
    """trimesh's processing dropped the NaN vertex and its faces silently: the cube was an open
    sheet."""
    m = box((0, 0, 0), (10, 10, 3))
    m.vertices[1, 0] = np.nan
    (tmp_path / "meshes").mkdir()
    m.export(tmp_path / "meshes" / "cube.ply")
    (tmp_path / "scene.xml").write_text(
        '<scene version="2.1.0"><bsdf type="itu-radio-material" id="mat-concrete">'
        '<string name="type" value="concrete"/></bsdf><shape type="ply" id="mesh-cube">'
        '<string name="filename" value="meshes/cube.ply"/><ref id="mat-concrete" name="bsdf"/>'
        "</shape></scene>"
    )
    with pytest.raises(SceneError, match="scene.xml: mesh meshes/cube.ply has NaN"):
        load_scene(tmp_path / "scene.xml")


# -- survey coordinates and units ----------------------------------------------------------------
@pytest.mark.parametrize("shift", [(1e5, 1e5, 0.0), (1e6, 1e6, 0.0), (4.5e5, 5.4e6, 120.0)])
def test_a_hall_in_survey_coordinates_gives_the_same_paths(clean, shift):
    _, rx, ref = clean
    s = np.array(shift)
    moved = []
    for n, m in hall_objects():
        m = m.copy()
        m.apply_translation(s)
        moved.append((n, m))
    scene = _scene(moved)
    assert_same_paths(ref, _trace(scene, TX + s, rx + s))


def test_trace_scene_in_survey_coordinates(clean, tmp_path, capsys):
    """Through the command: an OBJ at (1e5, 1e5, 0) m (OBJ keeps 8 decimals), positions given
    in the same coordinates: the untranslated hall's paths."""
    _, rx, ref = clean
    s = np.array([1e5, 1e5, 0.0])
    moved = []
    for n, m in hall_objects():
        m = m.copy()
        m.apply_translation(s)
        moved.append((n, m))
    p = _write(tmp_path / "survey.obj", moved)
    argv = [str(p), "-q", "-o", str(tmp_path / "p.npz")]
    for t in TX + s:
        argv += ["--tx", ",".join(f"{x:.6f}" for x in t)]
    for r in rx + s:
        argv += ["--rx", ",".join(f"{x:.6f}" for x in r)]
    assert trace_scene_main(argv) == 0
    assert_same_paths(ref, Paths.load(tmp_path / "p.npz"))


def test_float32_files_far_from_the_origin_say_how_much_they_rounded(tmp_path):
    """GLB and STL store float32 numbers: at 1e5 m they are 7.8 mm apart, and the file has
    rounded the hall by up to 3.9 mm before the tracer sees it (which then keeps it exact). OBJ
    keeps its decimals, and a hall near the origin loses nothing: no warning."""
    moved = []
    for n, m in hall_objects():
        m = m.copy()
        m.apply_translation([1e5, 1e5, 0.0])
        moved.append((n, m))
    with pytest.warns(UserWarning, match="rounded by up to 3.9 mm"):
        load_scene(_write(tmp_path / "survey.glb", moved))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_scene(_write(tmp_path / "survey.obj", moved))
        load_scene(_write(tmp_path / "local.glb", hall_objects()))


def test_an_stl_in_millimetres_is_refused_in_one_line(tmp_path, capsys):
    m = trimesh.util.concatenate([m for _, m in hall_objects()])
    m.apply_scale(1000.0)
    p = tmp_path / "hall_mm.stl"
    m.export(str(p))
    with pytest.raises(HallrayError, match="millimetres"):
        load_scene(p, default_material="concrete")
    assert trace_scene_main([str(p), "--default-material", "concrete", "--summary-only"]) == 2
    err = capsys.readouterr().err
    assert "warning" not in err  # refused before it is repaired or its rounding is weighed
    (line,) = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert "hall_mm.stl" in line and "millimetres" in line and "Traceback" not in err
    assert line.endswith("read it with --unit mm")


def test_a_hall_in_millimetres_read_with_its_unit_gives_the_halls_paths(clean, tmp_path, capsys):
    """The hall exported in millimetres (an STL as CAD writes it, and an OBJ) and read with
    ``unit="mm"``: the metre hall's facets, and its paths (delays to 1 ps) from the OBJ's
    objects; ``--unit mm`` on the command line; a file hallray wrote refuses another unit."""
    _, rx, ref = clean
    mm = [(n, m.copy().apply_scale(1000.0)) for n, m in hall_objects()]
    scene = load_scene(_write(tmp_path / "hall_mm.obj", mm), unit="mm")
    assert scene.unit == "mm" and scene.summary()["unit"] == "mm"
    np.testing.assert_allclose(scene.bounds, [[-0.3, -0.3, -0.3], [30.3, 20.3, 8.3]], atol=1e-9)
    assert_same_paths(ref, _trace(scene, TX, rx))
    stl = tmp_path / "hall_mm.stl"
    trimesh.util.concatenate([m for _, m in mm]).export(str(stl))
    with pytest.warns(UserWarning, match="9 closed solids split out"):
        one = load_scene(stl, default_material="concrete", unit="mm")
    np.testing.assert_allclose(one.bounds, scene.bounds, atol=1e-4)  # float32 mm: 1e-6 m
    assert len(one.facets) == len(scene.facets)
    assert trace_scene_main([str(stl), "--default-material", "concrete", "--unit", "mm",
                             "--summary-only"]) == 0  # fmt: skip
    assert "unit       the file's numbers are millimetres, scaled to metres" in capsys.readouterr().out
    with pytest.raises(SceneError, match="in metres with z up: --unit mm does not apply"):
        load_scene("hall", unit="mm")
    with pytest.raises(SceneError, match="unit must be one of m, mm, cm, km, in, ft, not 'yd'"):
        load_scene("hall", unit="yd")


def test_clean_scenes_raise_no_repair_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _scene(hall_objects())
        load_scene("hall")
