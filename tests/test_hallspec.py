"""Hall YAML -> spec -> scene -> GLB: validation, geometry, reproducibility, metadata, LoS table."""

from __future__ import annotations

import io
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from raytrace.cli.build_hall import build_hall_main
from raytrace.core.errors import HallrayError, MaterialError
from raytrace.core.fileio import write_atomic
from raytrace.core.palette import material_colors
from raytrace.halls.spec import (
    ITU_MATERIALS,
    SCHEMA_VERSION,
    Box,
    Cylinder,
    HallSpec,
    Route,
    Sheet,
    build_scene,
    glb_bytes,
    line_of_sight,
    load_hall_spec,
    los_markdown,
    los_note,
    parse_los_note,
    segment_blockers,
    tracer_scene,
    write_glb,
)
from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.io import load_scene

ROOT = Path(__file__).resolve().parent.parent
HALL_YAML = ROOT / "scenes" / "hall.yaml"
HALL_GLB = ROOT / "scenes" / "hall.glb"
HALL_SIZE_M = (42.0, 46.0, 8.8)
#: float32 storage of the GLB vertices: 8.8 m is stored as 8.8000002 m.
GLB_COORD_TOL_M = 1e-5
GEOM_TOL_M = 1e-9
POSE_TOL_M = 1e-9
POSE_TOL_RAD = 1e-12


@pytest.fixture(scope="module")
def hall() -> HallSpec:
    return load_hall_spec(HALL_YAML)


@pytest.fixture(scope="module")
def hall_scene(hall) -> trimesh.Scene:
    return build_scene(hall)


def small_hall() -> dict:
    """A small valid hall exercising every section."""
    return {
        "schema_version": 1,
        "name": "small",
        "hall": {"size": [20.0, 10.0, 5.0], "material": "concrete", "wall_thickness": 0.25},
        "materials": {"plastic": {"eta_real": 2.5, "sigma": 0.002, "thickness": 0.004}},
        "templates": {
            "rack": [
                {"name": "frame", "type": "box", "material": "metal", "min": [0, 0, 0],
                 "size": [2.0, 0.5, 2.0]},
                {"name": "bin", "type": "box", "material": "plastic", "center": [1.0, 0.25, 2.2],
                 "size": [0.5, 0.4, 0.4]},
            ]
        },
        "objects": [
            {"name": "pillar", "type": "box", "material": "concrete", "center": [5, 5, 2.5],
             "size": [0.4, 0.4, 5.0]},
            {"name": "tank", "type": "cylinder", "material": "metal", "base": [15, 8, 0],
             "radius": 0.5, "height": 2.0},
            {"name": "pane", "type": "sheet", "material": "glass", "origin": [8, 5.5, 0],
             "u": [0, 2, 0], "v": [0, 0, 2]},
            {"name": "row{n}", "type": "instance", "template": "rack", "at": [2, 8, 0],
             "repeat": {"count": 2, "step": [3.0, 0]}},
        ],
        "base_stations": [{"name": "BS1", "xyz": [1, 1, 4]}, {"name": "BS2", "xyz": [19, 9, 4]}],
        "points": [{"name": "P1", "xyz": [10, 5, 1], "note": "centre"}],
        "routes": [
            {"name": "fl", "size": [2.0, 1.0, 2.0], "material": "metal",
             "waypoints": [[3, 3], [17, 3]], "speed": 1.0, "mode": "back_and_forth"}
        ],
        "area_of_interest": {"min": [2, 2], "max": [18, 8]},
    }  # fmt: skip


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------


def _set(path: str, value):
    def mutate(d):
        keys = path.split(".")
        target = d
        for k in keys[:-1]:
            target = target[int(k)] if isinstance(target, list) else target[k]
        last = keys[-1]
        if value is KeyError:
            del target[last]
        elif isinstance(target, list):
            target[int(last)] = value
        else:
            target[last] = value

    return mutate


BAD_INPUTS = [
    ("unknown top key", _set("colour", "red"), "unknown key 'colour'"),
    ("unknown object key", _set("objects.0.colour", "red"), "unknown key 'colour'"),
    ("missing hall", _set("hall", KeyError), "missing key 'hall'"),
    ("missing size", _set("objects.0.size", KeyError), "missing key 'size'"),
    ("negative size", _set("objects.0.size", [0.4, -0.4, 5.0]), "size[1]: must be > 0"),
    ("zero hall size", _set("hall.size", [20, 0, 5]), "hall.size[1]: must be > 0"),
    ("nan", _set("objects.0.center", [5, float("nan"), 2.5]), "finite"),
    ("string number", _set("objects.0.center", [5, "5", 2.5]), "expected a number"),
    ("bool number", _set("hall.wall_thickness", True), "expected a number"),
    ("object outside", _set("objects.0.center", [19.9, 5, 2.5]), "outside the hall"),
    ("object below floor", _set("objects.1.base", [15, 8, -0.1]), "outside the hall"),
    ("both center and min", _set("objects.0.min", [0, 0, 0]), "exactly one of"),
    ("unknown type", _set("objects.0.type", "sphere"), "unknown type 'sphere'"),
    ("unknown material", _set("objects.0.material", "unobtainium"), "unknown material"),
    ("zero-area sheet", _set("objects.2.v", [0, 4, 0]), "zero area"),
    ("bad template", _set("objects.3.template", "nope"), "unknown template 'nope'"),
    ("bad repeat", _set("objects.3.repeat", {"count": 0, "step": [1, 0]}), "integers >= 1"),
    ("point outside", _set("points.0.xyz", [10, 11, 1]), "outside the hall"),
    ("point inside", _set("points.0.xyz", [5, 5, 1]), "is inside object 'pillar'"),
    ("point on sheet", _set("points.0.xyz", [8, 6, 1]), "lies on object 'pane'"),
    ("bs inside", _set("base_stations.0.xyz", [15, 8, 1]), "is inside object 'tank'"),
    ("bs below floor", _set("base_stations.0.xyz", [1, 1, -1]), "outside the hall"),
    ("duplicate point", _set("points", [{"name": "P1", "xyz": [10, 5, 1]}] * 2), "duplicate"),
    ("point missing xyz", _set("points.0.xyz", KeyError), "missing key 'xyz'"),
    ("route into pillar", _set("routes.0.waypoints", [[3, 5], [17, 5]]), "collides with"),
    ("route leaves hall", _set("routes.0.waypoints", [[3, 0.3], [17, 0.3]]), "leaves the hall"),
    ("route mode", _set("routes.0.mode", "zigzag"), "expected one of"),
    ("route speed", _set("routes.0.speed", 0), "must be > 0"),
    ("point on route", _set("points.0.xyz", [10, 3, 1]), "lies on forklift route 'fl'"),
    ("aoi outside", _set("area_of_interest.max", [25, 8]), "outside the hall"),
    ("aoi inverted", _set("area_of_interest.max", [1, 8]), "min < max"),
    ("bad name", _set("objects.0.name", "pillar 1"), "bad name"),
    ("schema", _set("schema_version", 2), "unsupported version"),
    ("new material incomplete", _set("materials.plastic", {"eta_real": 2.5}), "eta_real and sigma"),
    ("material key", _set("materials.plastic.colour", 1), "unknown key 'colour'"),
    ("material negative", _set("materials.plastic.sigma", -1), "must be >= 0"),
    (
        "power law without range",
        _set("materials.plastic", {"a": 2, "b": 0, "c": 0.1, "d": 0}),
        "f_range_ghz",
    ),
    ("itu thickness override", _set("materials.concrete", {"thickness": 0.25}), None),
    ("misleading name", _set("objects.1.name", "metal_tank"), None),  # valid: binds to metal
    ("wrong binding", _set("objects.2.name", "metal_pane"), "would bind material 'metal'"),
    ("reserved name", _set("objects.0.name", "shell_x"), "reserved"),
    ("duplicate object", _set("objects.1.name", "pillar"), "duplicate object name"),
]


@pytest.mark.parametrize("label, mutate, message", BAD_INPUTS, ids=[b[0] for b in BAD_INPUTS])
def test_validation_errors_are_one_line_and_name_the_problem(label, mutate, message):
    data = small_hall()
    mutate(data)
    if message is None:
        load_hall_spec(data)  # must be accepted
        return
    with pytest.raises(HallrayError) as err:
        load_hall_spec(data)
    text = str(err.value)
    assert "\n" not in text
    assert message in text, text


def test_material_errors_are_material_errors():
    data = small_hall()
    data["objects"][0]["material"] = "unobtainium"
    with pytest.raises(MaterialError):
        load_hall_spec(data)


def test_yaml_file_errors(tmp_path):
    with pytest.raises(HallrayError, match="cannot read"):
        load_hall_spec(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("hall: {size: [1, 2\n")
    with pytest.raises(HallrayError, match="invalid YAML") as err:
        load_hall_spec(bad)
    assert "\n" not in str(err.value)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump({**small_hall(), "extra": 1}))
    with pytest.raises(HallrayError, match=r"^wrong\.yaml: .*unknown key 'extra'"):
        load_hall_spec(wrong)


def test_repeat_names_and_template_placement_with_yaw():
    data = small_hall()
    data["objects"] = [
        {"name": "pillar", "type": "box", "material": "concrete", "center": [2, 2, 2.5],
         "size": [0.4, 0.4, 5.0], "repeat": {"count": [2, 3], "step": [4.0, 3.0]}},
        {"name": "r{I}{j}_{n}", "type": "box", "material": "metal", "min": [12, 1, 0],
         "size": [0.5, 0.5, 1], "repeat": {"count": [2, 2], "step": [[1, 0, 0], [0, 1, 0.5]]}},
        {"name": "cell", "type": "instance", "template": "rack", "at": [16, 4, 0], "yaw_deg": 90},
    ]  # fmt: skip
    data["points"] = [{"name": "P1", "xyz": [9, 5, 1]}]
    data["routes"] = []
    spec = load_hall_spec(data)
    by_name = {p.name: p for p in spec.objects}
    pillars = sorted(n for n in by_name if n.startswith("pillar"))
    assert pillars == ["pillar_A1", "pillar_A2", "pillar_A3", "pillar_B1", "pillar_B2", "pillar_B3"]
    np.testing.assert_allclose(by_name["pillar_B3"].center, (6, 8, 2.5), atol=GEOM_TOL_M)
    assert {"rA1_1", "rA2_2", "rB1_3", "rB2_4"} <= set(by_name)
    np.testing.assert_allclose(by_name["rB2_4"].center, (13.25, 2.25, 1.0), atol=GEOM_TOL_M)
    # rotating the template by 90 degrees about 'at' maps local (x, y) to (-y, x)
    frame = by_name["cell_frame"]
    np.testing.assert_allclose(frame.center, (16 - 0.25, 4 + 1.0, 1.0), atol=GEOM_TOL_M)
    lo, hi = frame.mesh_arrays()[0].min(axis=0), frame.mesh_arrays()[0].max(axis=0)
    np.testing.assert_allclose(hi - lo, (0.5, 2.0, 2.0), atol=GEOM_TOL_M)
    np.testing.assert_allclose(by_name["cell_bin"].center, (16 - 0.25, 5.0, 2.2), atol=GEOM_TOL_M)


def test_node_names_carry_the_material_and_bind_back(hall):
    library = hall.material_library
    for prim in hall.shell() + hall.objects:
        node = hall.node_name(prim)
        suffix = f"_itu_{prim.material}" if prim.material in ITU_MATERIALS else f"_{prim.material}"
        assert node == prim.name + suffix
        assert library.match(node) == prim.material


# --------------------------------------------------------------------------------------------
# primitives (independent checks with trimesh)
# --------------------------------------------------------------------------------------------


def test_primitives_closed_outward_and_contains_agrees_with_trimesh():
    rng = np.random.default_rng(7)
    prims = [
        Box("b", "metal", (1.0, 2.0, 3.0), (2.0, 1.0, 0.5), 0.0),
        Box("r", "metal", (0.5, -1.0, 1.0), (3.0, 1.5, 2.0), 33.0),
        Cylinder("c", "metal", (0.0, 0.0, -1.0), 0.8, 2.5, 12),
    ]
    for prim in prims:
        v, f = prim.mesh_arrays()
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0  # outward normals
        lo, hi = mesh.bounds
        pts = rng.uniform(lo - 0.3, hi + 0.3, size=(400, 3))
        np.testing.assert_array_equal(prim.contains(pts), mesh.contains(pts))
    box = prims[0]
    np.testing.assert_allclose(trimesh.Trimesh(*box.mesh_arrays()).volume, 1.0, rtol=1e-12)
    # a 12-gon prism: area of the inscribed polygon times height
    cyl = prims[2]
    expected = 0.5 * 12 * 0.8**2 * math.sin(2 * math.pi / 12) * 2.5
    np.testing.assert_allclose(trimesh.Trimesh(*cyl.mesh_arrays()).volume, expected, rtol=1e-12)


def test_sheet_is_two_open_triangles_and_contains_is_a_distance():
    sheet = Sheet("s", "glass", (0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    v, f = sheet.mesh_arrays()
    assert f.shape == (2, 3)
    assert not trimesh.Trimesh(v, f, process=False).is_watertight
    pts = np.array([[1.0, 0.005, 0.5], [1.0, 0.02, 0.5], [2.005, 0.0, 0.5], [2.5, 0.0, 0.5]])
    np.testing.assert_array_equal(sheet.contains(pts, 0.01), [True, False, True, False])


# --------------------------------------------------------------------------------------------
# the reference hall
# --------------------------------------------------------------------------------------------


def test_reference_hall_layout(hall):
    assert hall.size == HALL_SIZE_M
    x0, y0, x1, y1 = hall.area_of_interest
    assert abs((x1 - x0) - 29.0) < 1.0 and abs((y1 - y0) - 25.0) < 1.0
    assert [b.name for b in hall.base_stations] == ["BS1", "BS2", "BS3", "BS4"]
    corners = {(x0, y0), (x1, y0), (x1, y1), (x0, y1)}
    assert {b.xyz[:2] for b in hall.base_stations} == corners
    assert all(b.xyz[2] == 4.0 for b in hall.base_stations)
    assert [p.name for p in hall.points] == [f"P{k:02d}" for k in range(1, 24)]
    assert all(p.xyz[2] == 1.0 for p in hall.points)
    assert all(x0 < p.xyz[0] < x1 and y0 < p.xyz[1] < y1 for p in hall.points)
    assert 2 <= len(hall.routes) <= 3
    assert {p.material for p in hall.objects} >= {"metal", "concrete", "plastic", "glass", "wood"}
    n_tri = sum(len(p.mesh_arrays()[1]) for p in hall.objects)
    assert 100 <= len(hall.objects) <= 200 and n_tri <= 3000


def test_built_hall_extent_interior_and_watertight(hall_scene):
    meshes = {name: g for name, g in hall_scene.geometry.items()}
    shell = {n: m for n, m in meshes.items() if n.startswith("shell_")}
    assert len(shell) == 6
    # the interior is exactly [0, 42] x [0, 46] x [0, 8.8]: inner faces of the six slabs
    b = {n.split("_itu_")[0]: m.bounds for n, m in shell.items()}
    inner = [
        b["shell_floor"][1, 2], b["shell_ceiling"][0, 2], b["shell_wall_west"][1, 0],
        b["shell_wall_east"][0, 0], b["shell_wall_south"][1, 1], b["shell_wall_north"][0, 1],
    ]  # fmt: skip
    np.testing.assert_allclose(inner, [0, 8.8, 0, 42, 0, 46], atol=GEOM_TOL_M)
    np.testing.assert_allclose(hall_scene.bounds, [[-0.3] * 3, [42.3, 46.3, 9.1]], atol=GEOM_TOL_M)
    for name, mesh in meshes.items():
        assert mesh.metadata["material"] in name
        if name.startswith("shell_"):
            continue
        lo, hi = mesh.bounds
        assert (lo >= -GEOM_TOL_M).all() and (hi <= np.array(HALL_SIZE_M) + GEOM_TOL_M).all()
        if mesh.metadata["closed"]:
            assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, name
        else:
            assert len(mesh.faces) == 2 and not mesh.is_watertight, name


def test_hall_solids_do_not_overlap(hall):
    # no point of a dense random sample lies strictly inside two closed solids (touching is fine)
    rng = np.random.default_rng(11)
    pts = rng.uniform((0, 0, 0), HALL_SIZE_M, size=(200_000, 3))
    count = np.zeros(len(pts), dtype=int)
    for prim in hall.objects:
        if prim.closed:
            count += prim.contains(pts)
    assert count.max() <= 1, pts[count > 1][:3]


def test_glb_is_reproducible_and_committed_files_are_fresh(hall, tmp_path):
    a = write_glb(hall, tmp_path / "a.glb")
    b = write_glb(load_hall_spec(HALL_YAML), tmp_path / "b.glb")
    assert (tmp_path / "a.glb").read_bytes() == a == b == (tmp_path / "b.glb").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "b.glb"]  # no temp files
    assert HALL_GLB.read_bytes() == a, "scenes/hall.glb is stale: run tools/build_scenes.py"


def test_committed_scenes_and_notes_are_what_the_tool_builds():
    """``tools/build_scenes.py --check`` (as a maintainer runs it) rebuilds the hall's GLB, the 8
    canonical scenes and the LoS part of the points' notes in scenes/hall.yaml, and compares them
    with the committed files: exit 0 and nothing on stderr when every one is fresh."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "build_scenes.py"), "--check"],
        capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert (proc.returncode, proc.stderr) == (0, ""), "stale (run tools/build_scenes.py):\n" + proc.stderr
    assert len(list((ROOT / "scenes" / "canonical").glob("*.glb"))) == 8
    assert re.search(r"note: \"[^\"]*LoS to", HALL_YAML.read_text(encoding="utf-8"))


def test_metadata_round_trip_through_glb(hall):
    loaded = trimesh.load(io.BytesIO(glb_bytes(build_scene(hall))), file_type="glb")
    meta = loaded.metadata["hallray"]
    assert meta["schema_version"] == SCHEMA_VERSION
    assert meta["hall"]["size"] == list(HALL_SIZE_M)
    assert meta["materials"] == {"plastic": {"eta_real": 2.5, "sigma": 0.002, "thickness": 0.004}}
    assert meta["base_stations"] == [
        {"name": b.name, "xyz": list(b.xyz)} for b in hall.base_stations
    ]
    assert meta["points"] == [
        {"name": p.name, "xyz": list(p.xyz), "note": p.note} for p in hall.points
    ]
    assert [r["name"] for r in meta["routes"]] == [r.name for r in hall.routes]
    assert meta["area_of_interest"] == {"min": [6.5, 10.5], "max": [35.5, 35.5]}
    assert len(meta["obstacles_2d"]) == len(hall.objects)
    expected_nodes = {hall.node_name(p) for p in hall.shell() + hall.objects}
    assert set(loaded.geometry) == expected_nodes
    assert set(loaded.graph.nodes_geometry) == expected_nodes
    for mesh in loaded.geometry.values():
        assert mesh.visual.material.name == mesh.metadata["material"]
    # vertices survive (float32) and the hall still spans its interior
    np.testing.assert_allclose(loaded.bounds, [[-0.3] * 3, [42.3, 46.3, 9.1]], atol=GLB_COORD_TOL_M)


def _reference_blockers(scene: trimesh.Scene, start, end, margin=1e-4):
    """Independent segment test: trimesh's pure-Python ray-triangle intersector on the built
    trimesh scene, all hits with a distance in (margin, length - margin), per segment the
    objects (mesh extras ``object``) by first hit distance."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    vertices, faces, owner, names = [], [], [], []
    offset = 0
    for node in sorted(scene.graph.nodes_geometry):
        transform, geom_name = scene.graph[node]
        mesh = scene.geometry[geom_name]
        vertices.append(trimesh.transformations.transform_points(mesh.vertices, transform))
        faces.append(mesh.faces + offset)
        offset += len(mesh.vertices)
        owner.append(np.full(len(mesh.faces), len(names)))
        names.append(str(mesh.metadata["object"]))
    mesh = trimesh.Trimesh(np.vstack(vertices), np.vstack(faces), process=False)
    owner = np.concatenate(owner)
    start, end = np.atleast_2d(start).astype(float), np.atleast_2d(end).astype(float)
    length = np.linalg.norm(end - start, axis=1)
    direction = (end - start) / length[:, None]
    loc, ray, tri = RayMeshIntersector(mesh).intersects_location(
        start, direction, multiple_hits=True
    )
    dist = np.einsum("ij,ij->i", loc - start[ray], direction[ray])
    keep = (dist > margin) & (dist < length[ray] - margin)
    out = []
    for k in range(len(start)):
        sel = np.flatnonzero(keep & (ray == k))
        order = sel[np.argsort(dist[sel], kind="stable")]
        out.append(tuple(dict.fromkeys(names[owner[t]] for t in tri[order])))
    return out


def _reference_los(hall):
    bs, pts = hall.base_station_xyz, hall.point_xyz
    start, end = np.repeat(bs, len(pts), axis=0), np.tile(pts, (len(bs), 1))
    blockers = iter(_reference_blockers(build_scene(hall), start, end))
    table = {p.name: {} for p in hall.points}
    for b in hall.base_stations:
        for p in hall.points:
            table[p.name][b.name] = next(blockers)
    return table


def test_loaded_glb_line_of_sight_equals_spec(hall, tmp_path):
    write_glb(hall, tmp_path / "hall.glb")
    assert line_of_sight(load_scene(tmp_path / "hall.glb")) == line_of_sight(hall)
    with pytest.raises(HallrayError, match="needs a HallSpec or a Scene"):
        line_of_sight(trimesh.load(tmp_path / "hall.glb"))


def test_documented_los_table_matches_fresh_segment_tests(hall):
    embree = line_of_sight(hall)
    python = _reference_los(hall)
    assert embree == python
    for p in hall.points:
        assert parse_los_note(p.note) == embree[p.name], p.name
    counts = [sum(1 for s in embree.values() if sum(map(bool, s.values())) == n) for n in range(5)]
    assert 12 <= counts[0] <= 15 and 6 <= counts[1] <= 8 and 2 <= counts[2] <= 4, counts
    assert any("pillar" in " ".join(sum(s.values(), ())) for s in embree.values())
    docs = (ROOT / "docs" / "hall.md").read_text(encoding="utf-8")
    assert los_markdown(hall, embree) in docs, "docs/hall.md LoS table is stale"


def test_los_note_round_trip():
    status = {"BS1": (), "BS2": ("a", "b"), "BS3": (), "BS4": ("c",)}
    note = "near the press; " + los_note(status)
    assert note.endswith("LoS to BS1, BS3; blocked from BS2 by a, b; blocked from BS4 by c")
    assert parse_los_note(note) == status
    assert parse_los_note("no status here") is None


def test_segment_blockers_closed_form():
    spec = load_hall_spec(small_hall())
    start = np.array([[3.0, 5.0, 1.0], [3.0, 5.0, 1.0], [3.0, 5.0, 1.0], [4.7, 5.0, 1.0]])
    end = np.array([[7.0, 5.0, 1.0], [7.0, 6.0, 1.0], [7.0, 5.0, 4.0], [4.8, 5.0, 1.0]])
    # through the pillar (x 4.8..5.2 at y 5); beside it (at x = 5 the segment is at y 5.5);
    # over it? no: rising to 4 m it crosses x 4.8..5.2 at 2.2..2.5 m; the last one stops at the face
    expected = [("pillar",), (), ("pillar",), ()]
    assert segment_blockers(tracer_scene(spec), start, end) == expected
    assert _reference_blockers(build_scene(spec), start, end) == expected


def test_segment_objects_order_limit_and_occluded(hall):
    """Scene.segment_objects: objects in the order met, each once, cut at max_objects; a segment
    names an object exactly when Scene.occluded says it is blocked."""
    scene = tracer_scene(load_hall_spec(small_hall()))
    start = np.array([[4.0, 5.0, 1.0], [9.0, 6.0, 1.0], [1.0, 8.25, 1.0], [10.0, 2.0, 1.0]])
    end = np.array([[9.0, 6.0, 1.0], [4.0, 5.0, 1.0], [8.0, 8.25, 1.0], [12.0, 2.0, 1.0]])
    # pillar (x 4.8..5.2, y < 5.2) then the pane at x = 8 (y 5.8 there); both rack frames; nothing
    expected = [("pillar", "pane"), ("pane", "pillar"), ("row1_frame", "row2_frame"), ()]
    assert segment_blockers(scene, start, end) == expected
    assert segment_blockers(scene, start, end, max_blockers=1) == [e[:1] for e in expected]
    assert _reference_blockers(build_scene(load_hall_spec(small_hall())), start, end) == expected
    big = tracer_scene(hall)
    rng = np.random.default_rng(3)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array(HALL_SIZE_M)
    a, b = rng.uniform(lo, hi, (3000, 3)), rng.uniform(lo, hi, (3000, 3))
    rows = big.segment_objects(a, b)
    np.testing.assert_array_equal(rows[:, 0] >= 0 if rows.shape[1] else False, big.occluded(a, b))
    for row in rows:  # each object once, -1 only as padding at the end
        met = row[row >= 0]
        assert len(set(met.tolist())) == len(met) and np.all(row[len(met) :] == -1)


def test_glb_colours_are_the_palette(hall):
    """Every node's glTF base colour is the palette colour of its material (one palette for the
    GLB, the top view and the rendered pictures)."""
    scene = build_scene(hall)
    colors = material_colors({p.material for p in hall.shell() + hall.objects})
    for name, mesh in scene.geometry.items():
        rgba = np.asarray(mesh.visual.material.baseColorFactor, dtype=float)
        if rgba.max() > 1.0:  # trimesh may hold the factor as 0..255
            rgba = rgba / 255.0
        np.testing.assert_allclose(
            rgba[:3], colors[mesh.metadata["material"]], atol=1 / 255, err_msg=name
        )


# --------------------------------------------------------------------------------------------
# routes, CLI, drawing, atomic writes
# --------------------------------------------------------------------------------------------


def test_route_pose_closed_form():
    loop = Route("l", (2, 1, 2), "metal", ((0, 0), (4, 0), (4, 3)), 1.0, "loop")
    assert loop.length_m == pytest.approx(12.0) and loop.period_s == pytest.approx(12.0)
    xy, heading = loop.pose([0.0, 2.0, 5.5, 10.0, 14.0])
    np.testing.assert_allclose(xy, [[0, 0], [2, 0], [4, 1.5], [1.6, 1.2], [2, 0]], atol=POSE_TOL_M)
    back = math.atan2(-3, -4)
    np.testing.assert_allclose(heading, [0, 0, math.pi / 2, back, 0], atol=POSE_TOL_RAD)
    bf = Route("b", (2, 1, 2), "metal", ((0, 0), (10, 0)), 2.0, "back_and_forth")
    assert bf.period_s == pytest.approx(10.0)
    xy, heading = bf.pose(np.array([1.0, 6.0, 9.0]))
    np.testing.assert_allclose(xy, [[2, 0], [8, 0], [2, 0]], atol=POSE_TOL_M)
    np.testing.assert_allclose(np.abs(heading), [0, math.pi, math.pi], atol=POSE_TOL_RAD)


def test_build_hall_main(tmp_path, capsys):
    good = tmp_path / "h.yaml"
    good.write_text(yaml.safe_dump(small_hall()))
    out = tmp_path / "h.glb"
    assert build_hall_main([str(good), "-o", str(out), "--los"]) == 0
    stdout = capsys.readouterr().out
    assert "P1: LoS to" in stdout
    loaded = trimesh.load(out, file_type="glb")
    assert loaded.metadata["hallray"]["name"] == "small"

    bad = tmp_path / "bad.yaml"
    data = small_hall()
    data["points"][0]["xyz"] = [5, 5, 1]
    bad.write_text(yaml.safe_dump(data))
    for argv in ([str(bad), "-o", str(tmp_path / "bad.glb")],
                 [str(tmp_path / "none.yaml"), "-o", str(tmp_path / "none.glb")],
                 [str(good), "-o", str(tmp_path / "nodir" / "x.glb")],
                 [str(good), "--frobnicate"]):  # fmt: skip
        assert build_hall_main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml", "h.glb", "h.yaml"]


def test_write_atomic_keeps_old_file_on_failure(tmp_path, monkeypatch):
    target = tmp_path / "x.bin"
    write_atomic(target, b"old")

    def boom(*args):
        raise OSError("disk full")

    monkeypatch.setattr("os.replace", boom)
    with pytest.raises(OSError):
        write_atomic(target, b"new")
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.bin"]


# --------------------------------------------------------------------------------------------
# canonical scenes
# --------------------------------------------------------------------------------------------

CANONICAL = ROOT / "scenes" / "canonical"


def _load(name):
    return trimesh.load(CANONICAL / f"{name}.glb", file_type="glb")


def test_canonical_scenes_geometry_and_metadata():
    library = MaterialLibrary.itu()
    expected_objects = {
        "one_wall": {"wall_itu_concrete"},
        "one_sheet": {"sheet_itu_metal"},
        "floor": {"floor_itu_concrete"},
        "shoebox": {f"{n}_itu_concrete" for n in
                    ("floor", "ceiling", "wall_south", "wall_north", "wall_west", "wall_east")},
        "box_on_floor": {"box_itu_metal", "floor_itu_concrete"},
        "box_on_floor_concrete": {"box_itu_concrete", "floor_itu_concrete"},
        "half_plane": {"screen_itu_metal"},
        "two_boxes": {"box_a_itu_metal", "box_b_itu_metal"},
    }  # fmt: skip
    for name, nodes in expected_objects.items():
        scene = _load(name)
        assert set(scene.geometry) == nodes, name
        meta = scene.metadata["hallray"]
        assert meta["name"] == name and meta["tx"] and meta["rx"]
        for node, mesh in scene.geometry.items():
            assert library.match(node) == mesh.metadata["material"]
            if mesh.metadata["closed"]:
                assert mesh.is_watertight and mesh.volume > 0
            else:
                assert len(mesh.faces) == 2
    wall = _load("one_wall").geometry["wall_itu_concrete"]
    np.testing.assert_allclose(wall.bounds, [[-5, -0.1, 0], [5, 0.1, 3]], atol=GLB_COORD_TOL_M)
    room = _load("shoebox")
    np.testing.assert_allclose(room.bounds, [[0, 0, 0], [10, 8, 3]], atol=GLB_COORD_TOL_M)
    screen = _load("half_plane").geometry["screen_itu_metal"]
    np.testing.assert_allclose(screen.bounds, [[0, -50, -50], [0, 50, 0]], atol=GLB_COORD_TOL_M)
    rx_z = [r["xyz"][2] for r in _load("half_plane").metadata["hallray"]["rx"]]
    assert min(rx_z) < 0 < max(rx_z)  # from the shadow to the lit side of the edge
