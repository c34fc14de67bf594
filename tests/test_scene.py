"""Scene loading, material binding, facets, wedges and Embree queries."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, quad

from raytrace.core.errors import SceneError
from raytrace.scene.io import load_scene

ANGLE_TOL = 1e-9
AREA_TOL_M2 = 1e-9


def _write_glb(tmp_path, objects, name="s.glb", metadata=None):
    s = trimesh.Scene()
    for node, mesh in objects:
        s.add_geometry(mesh, node_name=node, geom_name=node)
    if metadata:
        s.metadata["hallray"] = metadata
    p = tmp_path / name
    p.write_bytes(s.export(file_type="glb"))
    return p


def test_box_facets_and_wedges():
    sc = make_scene([("b", box((0, 0, 0), (2, 3, 4)), "metal")])
    assert len(sc.facets) == 6
    np.testing.assert_allclose(
        np.sort(sc.facets.area), np.sort([6, 6, 8, 8, 12, 12]), atol=AREA_TOL_M2
    )
    # outward normals: the box centre is behind every facet
    centre = np.array([1.0, 1.5, 2.0])
    assert (sc.facets.normal @ centre - sc.facets.offset < 0).all()
    assert not sc.facets.two_sided.any()
    assert len(sc.wedges) == 12
    np.testing.assert_allclose(sc.wedges.n, 1.5, atol=ANGLE_TOL)
    np.testing.assert_allclose(np.sort(sc.wedges.length), np.sort([2] * 4 + [3] * 4 + [4] * 4))


def test_inward_box_is_reoriented():
    b = box((0, 0, 0), (1, 1, 1))
    b.invert()
    sc = make_scene([("b", b, "concrete")])
    assert (sc.facets.normal @ np.array([0.5, 0.5, 0.5]) - sc.facets.offset < 0).all()


def test_sheet_is_two_sided_with_half_plane_edges():
    sc = make_scene([("s", quad((0, 0, 0), (4, 0, 0), (0, 2, 0)), "glass")])
    assert len(sc.facets) == 1 and sc.facets.two_sided[0]
    assert sc.facets.area[0] == pytest.approx(8.0)
    assert len(sc.wedges) == 4  # the diagonal is not an edge
    np.testing.assert_allclose(sc.wedges.n, 2.0, atol=ANGLE_TOL)


def test_collinear_edge_pieces_are_merged():
    # a sheet made of two quads side by side: the long free edges come in two pieces each
    verts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], float)
    faces = [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]]
    sc = make_scene([("s", trimesh.Trimesh(verts, faces, process=False), "glass")])
    assert len(sc.wedges) == 4
    np.testing.assert_allclose(np.sort(sc.wedges.length), [1, 1, 2, 2])


def test_shoebox_facets(shoebox):
    assert len(sc_f := shoebox.facets) == 6
    assert sc_f.two_sided.all()
    np.testing.assert_allclose(
        np.sort(sc_f.area), np.sort([80, 80, 30, 30, 24, 24]), atol=AREA_TOL_M2
    )


def test_occlusion_against_pure_python_intersector():
    b1 = box((0, 0, 0), (1, 1, 1))
    b2 = box((3, 0, 0), (4, 2, 1))
    sc = make_scene([("b1", b1, "metal"), ("b2", b2, "concrete")])
    rng = np.random.default_rng(7)
    a = rng.uniform(-2, 6, (400, 3))
    c = rng.uniform(-2, 6, (400, 3))
    got = sc.occluded(a, c, margin=0.0)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(trimesh.util.concatenate([b1, b2]))
    d = c - a
    length = np.linalg.norm(d, axis=1)
    locs, idx, _ = ref.intersects_location(a, d / length[:, None], multiple_hits=True)
    expected = np.zeros(len(a), bool)
    hit_dist = np.linalg.norm(locs - a[idx], axis=1)
    expected[idx[hit_dist < length[idx]]] = True
    # rays that graze an edge or a vertex within float32 noise may differ: allow none here
    assert (got == expected).mean() == 1.0


def test_intersect_names_object_and_face():
    sc = make_scene(
        [("b1", box((0, 0, 0), (1, 1, 1)), "metal"), ("b2", box((3, 0, 0), (4, 1, 1)), "concrete")]
    )
    t, face, obj = sc.intersect(
        np.array([[2.0, 0.5, 0.5], [2.0, 0.5, 0.5]]), np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    )
    np.testing.assert_allclose(t, [1.0, 1.0], atol=1e-6)
    assert obj.tolist() == [1, 0]
    assert sc.face_object[face].tolist() == [1, 0]


def test_inside_solid():
    sc = make_scene(
        [
            ("b1", box((0, 0, 0), (1, 1, 1)), "metal"),
            ("s", quad((5, 5, 0), (1, 0, 0), (0, 1, 0)), "glass"),
        ]
    )
    got = sc.inside_solid(np.array([[0.5, 0.5, 0.5], [2, 2, 2], [5.5, 5.5, 0.5]]))
    assert got.tolist() == [0, -1, -1]


def test_load_glb_binds_by_name(tmp_path):
    p = _write_glb(
        tmp_path,
        [
            ("pillar_03_itu_concrete", box((0, 0, 0), (1, 1, 3))),
            ("wall-glass", quad((3, 0, 0), (1, 0, 0), (0, 0, 2))),
        ],
        metadata={"base_stations": [{"name": "BS1", "xyz": [5, 5, 2]}]},
    )
    sc = load_scene(p)
    mats = {o.name: o.material for o in sc.objects}
    assert mats == {"pillar_03_itu_concrete": "concrete", "wall-glass": "glass"}
    assert sc.metadata["hallray"]["base_stations"][0]["name"] == "BS1"


def test_user_material_from_yaml_and_bind_patterns(tmp_path):
    p = _write_glb(
        tmp_path, [("crate_1", box((0, 0, 0), (1, 1, 1))), ("thing", box((2, 0, 0), (3, 1, 1)))]
    )
    y = tmp_path / "m.yaml"
    y.write_text(
        "materials:\n  plastic: {eta_real: 2.5, sigma: 0.002, thickness: 0.004}\n"
        "bind:\n  'crate_*': plastic\n"
    )
    with pytest.raises(SceneError, match="1 object.*without a material: thing"):
        load_scene(p, y)
    sc = load_scene(p, y, default_material="metal")
    assert {o.name: o.material for o in sc.objects} == {"crate_1": "plastic", "thing": "metal"}


def test_mitsuba_xml(tmp_path):
    mesh = box((0, 0, 0), (1, 2, 3))
    (tmp_path / "meshes").mkdir()
    mesh.export(tmp_path / "meshes" / "cube.ply")
    (tmp_path / "scene.xml").write_text(
        """<scene version="2.1.0">
  <bsdf type="itu-radio-material" id="mat-concrete">
    <string name="type" value="concrete"/>
    <float name="thickness" value="0.25"/>
  </bsdf>
  <shape type="ply" id="mesh-cube">
    <string name="filename" value="meshes/cube.ply"/>
    <ref id="mat-concrete" name="bsdf"/>
  </shape>
</scene>"""
    )
    sc = load_scene(tmp_path / "scene.xml")
    assert [o.material for o in sc.objects] == ["concrete"]
    assert sc.materials["concrete"].thickness_m == pytest.approx(0.25)
    assert len(sc.facets) == 6


def test_bad_inputs(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_scene(tmp_path / "nope.glb")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"this is not a glb file")
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(bad)
    txt = tmp_path / "x.txt"
    txt.write_text("hello")
    with pytest.raises(SceneError, match="unsupported scene format"):
        load_scene(txt)
    with pytest.raises(SceneError, match="NaN"):
        make_scene(
            [
                (
                    "n",
                    trimesh.Trimesh(
                        [[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]], process=False
                    ),
                    "metal",
                )
            ]
        )
    with pytest.raises(SceneError, match="no triangles"):
        make_scene(
            [
                (
                    "d",
                    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False),
                    "metal",
                )
            ]
        )
    with pytest.warns(UserWarning, match="1 degenerate"):
        verts = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]
        make_scene([("d", trimesh.Trimesh(verts, [[0, 1, 2], [0, 1, 3]], process=False), "metal")])
    p = _write_glb(tmp_path, [("x_itu_unobtainium", box((0, 0, 0), (1, 1, 1)))], name="u.glb")
    with pytest.raises(SceneError, match="without a material"):
        load_scene(p)


def test_summary_counts(shoebox):
    s = shoebox.summary()
    assert s["objects"] == 6 and s["open_sheets"] == 6 and s["triangles"] == 12
    # the 12 room edges: the inside is a concave corner (dropped); the outside of each L of two
    # sheets is a convex 270-degree corner, kept once
    assert s["facets"] == 6 and s["wedges"] == 12 and s["composite_wedges"] == 12
    assert s["size_m"] == [10.0, 8.0, 3.0]


def test_edges_buried_against_another_solid_are_not_wedges():
    floor = box((-5, -5, -0.3), (5, 5, 0.0))
    crate = box((0, 0, 0), (1, 1, 1))
    sc = make_scene([("floor", floor, "concrete"), ("crate", crate, "wood")])
    crate_w = sc.wedges.object == 1
    # the crate's four bottom edges rest on the floor slab; its 8 other edges are free
    assert crate_w.sum() == 8
    assert (sc.wedges.start[crate_w, 2] + sc.wedges.end[crate_w, 2] > 0).all()
    assert (sc.wedges.object == 0).sum() == 12
    assert sc.n_buried_wedges == 4


def test_bundled_name_is_not_hidden_by_a_directory(tmp_path, monkeypatch):
    from raytrace.scene.bundled import resolve_scene

    (tmp_path / "hall").mkdir()
    monkeypatch.chdir(tmp_path)
    assert resolve_scene("hall").name == "hall.glb"


def test_inside_solid_exact_for_convex_solids_sharing_faces():
    """Slabs that touch along a face (a hall's shell): parity rays can miss an exit hidden
    behind the next entry; the half-space test for convex solids cannot."""
    slabs = [
        ("floor", box((-0.3, -0.3, -0.3), (10.3, 8.3, 0.0)), "concrete"),
        ("ceiling", box((-0.3, -0.3, 4.0), (10.3, 8.3, 4.3)), "concrete"),
        ("wall_w", box((-0.3, -0.3, 0.0), (0.0, 8.3, 4.0)), "concrete"),
        ("wall_e", box((10.0, -0.3, 0.0), (10.3, 8.3, 4.0)), "concrete"),
        ("wall_s", box((0.0, -0.3, 0.0), (10.0, 0.0, 4.0)), "concrete"),
        ("wall_n", box((0.0, 8.0, 0.0), (10.0, 8.3, 4.0)), "concrete"),
    ]
    sc = make_scene(slabs)
    assert sc.convex_objects().all()
    rng = np.random.default_rng(5)
    interior = rng.uniform([0, 0, 0], [10, 8, 4], (20_000, 3))
    assert (sc.inside_solid(interior) == -1).all()
    in_walls = np.array([[-0.15, 4.0, 2.0], [5.0, 8.15, 3.9], [5.0, 4.0, 4.2], [10.1, 8.1, 1.0]])
    assert sc.inside_solid(in_walls).tolist() == [2, 5, 1, 3]


def test_bounds_are_the_vertices_extremes_kept_read_only_and_left_out_of_a_pickle():
    import pickle

    sc = make_scene([("a", box((0, 0, 0), (2, 1, 3)), "metal"),
                     ("b", box((-1, 4, 0.5), (0, 5, 1)), "glass")])  # fmt: skip
    fresh = pickle.dumps(sc)
    np.testing.assert_array_equal(sc.bounds, [sc.vertices.min(axis=0), sc.vertices.max(axis=0)])
    assert sc.bounds is sc.bounds and sc.extent == pytest.approx(np.sqrt(9 + 25 + 9))
    with pytest.raises(ValueError):
        sc.bounds[0, 0] = 5.0
    assert pickle.dumps(sc) == fresh


def test_inside_solid_of_convex_solids_is_every_plane_behind():
    """The compiled test against the definition, computed independently: a point is inside a
    convex solid when it is behind every one of its facet planes by the tolerance, and the
    solid reported is the first such in object order (two overlapping boxes: the first one),
    on random points over the hall, over overlapping boxes and on their faces."""
    hall = load_scene("hall")
    over = make_scene([("a", box((0, 0, 0), (2, 2, 2)), "metal"),
                       ("b", box((1, 1, 1), (3, 3, 3)), "metal")])  # fmt: skip
    rng = np.random.default_rng(11)
    for sc, pts in ((hall, rng.uniform(*hall.bounds, (30_000, 3))),
                    (over, np.concatenate([rng.uniform(-0.5, 3.5, (5_000, 3)),
                                           rng.integers(0, 4, (500, 3)).astype(float)]))):  # fmt: skip
        convex = sc.convex_objects()
        assert not (sc.object_closed & ~convex).any()  # (open sheets contain nothing)
        fc, tol = sc.facets, 1e-9 * max(sc.extent, 1.0)
        s = np.einsum("pc,fc->pf", pts, fc.normal) - fc.offset  # every point, every plane
        inside = np.stack([convex[o] & (s[:, fc.object == o] < -tol).all(axis=1)
                           for o in range(len(sc.objects))], axis=1)  # fmt: skip
        want = np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)
        got = sc.inside_solid(pts)
        assert got.tolist() == want.tolist()
        assert (got >= 0).any() and (got < 0).any()
    both = over.inside_solid(np.array([[1.5, 1.5, 1.5], [2.5, 2.5, 2.5], [2.0, 1.5, 1.5]]))
    assert both.tolist() == [0, 1, 1]  # in both: the first; on a's face: b's only


@pytest.mark.parametrize(
    "name, facets, wedges, wedge_n",
    [
        ("one_wall", 6, 12, {1.5}),
        ("one_sheet", 1, 4, {2.0}),
        ("floor", 1, 4, {2.0}),
        # six sheets meeting at the 12 room edges: only the outer 270-degree corners of the
        # L-shaped sheet pairs remain
        ("shoebox", 6, 12, {1.5}),
        # the box's bottom edges lie on the floor sheet (concave junctions, dropped): the box's
        # 8 other edges and the sheet's 4 free edges
        ("box_on_floor", 7, 12, {1.5, 2.0}),
        ("half_plane", 1, 4, {2.0}),
        ("two_boxes", 12, 24, {1.5}),
    ],
)
def test_canonical_scenes_load_with_their_facets_and_wedges(name, facets, wedges, wedge_n):
    sc = load_scene(f"canonical/{name}")
    assert len(sc.facets) == facets
    assert set(np.round(sc.wedges.n, 9)) == wedge_n
    assert len(sc.wedges) == wedges
    np.testing.assert_allclose(np.linalg.norm(sc.facets.normal, axis=1), 1.0, atol=1e-12)


def test_first_hit_among_a_subset_of_objects():
    sc = make_scene(
        [
            ("near", box((2, -1, -1), (3, 1, 1)), "wood"),
            ("far", box((6, -1, -1), (7, 1, 1)), "metal"),
        ]
    )
    o = np.array([[0.0, 0, 0], [0.0, 5, 0], [0.0, 0, 0]])
    d = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    length = np.array([10.0, 10.0, 4.0])
    np.testing.assert_array_equal(sc.first_hit_among([True, True], o, d, length), [0, -1, 0])
    # only the far box counts: the near one is transparent to this query
    np.testing.assert_array_equal(sc.first_hit_among([False, True], o, d, length), [1, -1, -1])
    np.testing.assert_array_equal(sc.first_hit_among([False, False], o, d, length), [-1, -1, -1])
    with pytest.raises(SceneError, match="one flag per object"):
        sc.first_hit_among([True], o, d, length)
    # with some rays of no length (they hit nothing; the others are asked)
    np.testing.assert_array_equal(
        sc.first_hit_among([True, True], o, d, np.array([10.0, 0.0, 4.0])), [0, -1, 0]
    )
    # the cached subset scenes (native Embree objects) are left out of a pickled scene's state
    assert sc.caches.subset_embree
    assert "caches" not in sc.__getstate__()


def _ring_area(ring: np.ndarray) -> float:
    """Signed area of a polygon ring (shoelace): positive when counter-clockwise."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def test_floor_outline_inside_the_walls():
    """An L-shaped concrete slab (top at z = 0) with a wall solid along one side, a pillar inside
    and a low machine: the outline is the L minus the wall's footprint, counter-clockwise, with
    no hole for the pillar and nothing removed for the machine."""
    slab = [box((0, 0, -0.3), (20, 10, 0)), box((0, 10, -0.3), (8, 25, 0))]
    objects = [
        ("floor_a", slab[0], "concrete"),
        ("floor_b", slab[1], "concrete"),
        ("wall_south", box((0, 0, 0), (20, 0.5, 6)), "concrete"),  # full height: removed
        ("pillar", box((4, 4, 0), (4.5, 4.5, 6)), "concrete"),  # inside: no hole
        ("machine", box((12, 4, 0), (14, 6, 2)), "metal"),  # low: kept
    ]
    ring = make_scene(objects).floor_outline()
    assert ring is not None and _ring_area(ring) > 0
    expected_area = 20 * 9.5 + 8 * 15  # the L above y = 0.5
    assert _ring_area(ring) == pytest.approx(expected_area, rel=1e-6)
    assert ring[:, 1].min() == pytest.approx(0.5)
    assert ring[:, 1].max() == pytest.approx(25.0)
    # an open sheet floor counts with either orientation; a scene without a floor has no outline
    sheet = make_scene([("floor", quad((0, 0, 0), (0, 5, 0), (5, 0, 0)), "concrete")])
    assert _ring_area(sheet.floor_outline()) == pytest.approx(25.0)
    wall = make_scene([("wall", box((0, 0, 0), (5, 0.2, 3)), "concrete")])
    assert wall.floor_outline() is None


def test_floor_outline_of_the_bundled_hall():
    ring = load_scene("hall").floor_outline()
    np.testing.assert_allclose(ring, [[0, 0], [42, 0], [42, 46], [0, 46]], atol=1e-5)


# -- junctions: edges lying on another object's surface --------------------------------------
def _wedge_set(sc):
    """Set of (object name, rounded end points, rounded n) of the scene's wedges."""
    out = set()
    for i in range(len(sc.wedges)):
        a, b = (tuple(np.round(x, 6)) for x in (sc.wedges.start[i], sc.wedges.end[i]))
        out.add(
            (sc.objects[sc.wedges.object[i]].name, min(a, b), max(a, b), round(sc.wedges.n[i], 6))
        )
    return out


def test_box_on_floor_sheet_bottom_edges_are_not_wedges():
    floor = quad((-5, -5, 0), (10, 0, 0), (0, 10, 0))
    sc = make_scene([("floor", floor, "concrete"), ("crate", box((0, 0, 0), (1, 1, 1)), "wood")])
    crate = sc.wedges.object == 1
    assert crate.sum() == 8 and (sc.wedges.start[crate, 2] + sc.wedges.end[crate, 2] > 0).all()
    assert (sc.wedges.object == 0).sum() == 4  # the floor's own free edges stay
    assert sc.n_junction_wedges == 4 and sc.n_composite_wedges == 0
    # either winding of the floor sheet, the same wedges
    flipped = quad((-5, -5, 0), (0, 10, 0), (10, 0, 0))
    sc2 = make_scene([("floor", flipped, "concrete"), ("crate", box((0, 0, 0), (1, 1, 1)), "wood")])
    assert _wedge_set(sc2) == _wedge_set(sc)


def test_slab_flush_with_the_wall_below_has_no_edge_there():
    """A ceiling slab whose side is flush with the wall's outer face: the ceiling's lower outer
    edge lies on the wall's face (flat, 180 degrees of air): not a wedge. Its upper outer edge and
    the wall's outer bottom edge are free convex edges."""
    wall = box((-0.3, 0, 0), (0, 5, 3))
    ceiling = box((-0.3, 0, 3), (5, 5, 3.3))
    sc = make_scene([("wall", wall, "concrete"), ("ceiling", ceiling, "concrete")])
    ws = _wedge_set(sc)
    lower_outer = ("ceiling", (-0.3, 0.0, 3.0), (-0.3, 5.0, 3.0), 1.5)
    upper_outer = ("ceiling", (-0.3, 0.0, 3.3), (-0.3, 5.0, 3.3), 1.5)
    assert lower_outer not in ws and upper_outer in ws
    # the wall's top edges lie on the ceiling's bottom face: buried / concave, gone
    assert not any(w[0] == "wall" and w[1][2] == 3.0 and w[2][2] == 3.0 for w in ws)
    assert sc.n_junction_wedges >= 1


def test_partly_covered_edge_is_cut_where_the_other_object_touches_it():
    """A shelf board flush with a rack frame's face covers a piece of the frame's vertical edge:
    that piece is a flat junction; the edge stays a wedge above and below the board."""
    frame = box((0, 0, 0), (0.1, 1, 2))
    shelf = box((0.1, 0, 0.9), (3, 1, 0.95))
    sc = make_scene([("frame", frame, "metal"), ("shelf", shelf, "metal")])
    w = sc.wedges
    edge = (w.object == 0) & np.all(np.isclose(w.start[:, :2], [0.1, 0.0]), axis=1)
    edge &= np.all(np.isclose(w.end[:, :2], [0.1, 0.0]), axis=1)
    z = np.sort(np.stack([w.start[edge, 2], w.end[edge, 2]], axis=1), axis=1)
    z = z[np.argsort(z[:, 0])]
    np.testing.assert_allclose(z, [[0.0, 0.9], [0.95, 2.0]], atol=1e-6)


def test_sheets_meeting_in_an_l_keep_one_outer_corner():
    """Two sheets meeting along a common border (a fence corner, a room corner): the inside is a
    concave right angle (no wedge), the outside a convex 270-degree corner, kept once."""
    a = quad((0, 0, 0), (4, 0, 0), (0, 0, 2))  # plane y = 0, x in [0, 4]
    b = quad((0, 0, 0), (0, 3, 0), (0, 0, 2))  # plane x = 0, y in [0, 3]
    sc = make_scene([("a", a, "metal"), ("b", b, "metal")])
    w = sc.wedges
    corner = np.isclose(w.start[:, 0], 0) & np.isclose(w.start[:, 1], 0)
    corner &= np.isclose(w.end[:, 0], 0) & np.isclose(w.end[:, 1], 0)
    assert corner.sum() == 1 and np.isclose(w.n[corner][0], 1.5)
    assert sc.n_composite_wedges == 1
    # its exterior is the outside of the L: the quadrant x > 0, y > 0 is inside the wedge
    from raytrace.physics.utd import wedge_geometry

    i = np.flatnonzero(corner)[0]
    args = (w.direction[i], w.normal0[i], w.normal1[i], w.face0_dir[i])
    pts = np.array([[2.0, 1.5, 1.0], [-2.0, -1.0, 1.0], [-2.0, 1.0, 1.0], [2.0, -1.0, 1.0]])
    q = np.array([0.0, 0.0, 1.0])
    valid = [bool(wedge_geometry(p, p, q, *args).valid[0]) for p in pts]
    assert valid == [False, True, True, True]


def test_hit_records_read_embree_answers_as_the_numpy_rule():
    """Embree's geomID, primID, tfar to (distance, face, object): inf, -1, -1 for a miss, for a
    hit the face that the object's Embree triangle primID is part of (``prim_face[prim_start[g]
    + primID]``); a subset scene's geomID to its member object."""
    from raytrace.scene import accel

    rng = np.random.default_rng(9)
    n = 300
    geom = rng.integers(-1, 5, n).astype(np.int32)
    prim = np.where(geom >= 0, rng.integers(0, 12, n), -1).astype(np.int32)
    tfar = rng.uniform(0, 50, n).astype(np.float32)
    prim_start = np.arange(5, dtype=np.int64) * 12
    prim_face = rng.permutation(60).astype(np.int64)
    t, face, obj = accel.hit_records(geom, prim, tfar, prim_start, prim_face)
    hit = geom >= 0
    np.testing.assert_array_equal(t, np.where(hit, tfar.astype(float), np.inf))
    want = np.where(hit, prim_face[prim_start[np.maximum(geom, 0)] + np.maximum(prim, 0)], -1)
    np.testing.assert_array_equal(face, want)
    np.testing.assert_array_equal(obj, np.where(hit, geom, -1))
    members = np.array([3, 7, 8, 11, 20], dtype=np.int64)
    np.testing.assert_array_equal(accel.subset_hits(geom, members),
                                  np.where(hit, members[np.maximum(geom, 0)], -1))  # fmt: skip



def test_embree_mesh_cuts_each_triangle_into_watertight_pieces():
    """An object's triangles cut n x n for Embree: the pieces of each face cover it (areas sum
    to its area, every corner on its plane, the face's orientation), each piece names its face,
    and the two triangles that share an edge (given in opposite directions) cut it at the same
    float32 points, so Embree's watertight hit test has no crack between them."""
    from raytrace.scene import accel

    rng = np.random.default_rng(4)
    v = rng.uniform(-30, 30, (5, 3))
    faces = np.array([[0, 1, 2], [2, 1, 3], [0, 2, 4]])
    for n in (1, 2, 3, 5):
        points, tri, face = accel.embree_mesh(v, faces, n)
        assert points.dtype == np.float32 and tri.dtype == np.int32
        assert len(tri) == len(faces) * n * n and len(face) == len(tri)
        p = points[tri].astype(float)
        cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        whole = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
        area = np.bincount(face, 0.5 * np.linalg.norm(cross, axis=1), minlength=len(faces))
        np.testing.assert_allclose(area, 0.5 * np.linalg.norm(whole, axis=1), rtol=1e-5)
        assert np.all(np.einsum("ij,ij->i", cross, whole[face]) > 0)
        unit = whole / np.linalg.norm(whole, axis=1)[:, None]
        off = np.einsum("tkj,tj->tk", p, unit[face]) - np.einsum("ij,ij->i", v[faces[:, 0]],
                                                                  unit)[face, None]  # fmt: skip
        assert np.abs(off).max() < 1e-5
        # the shared edge 1-2 (faces 0 and 1) and 0-2 (faces 0 and 2): the same points
        for f0, f1, (i, j) in ((0, 1, (1, 2)), (0, 2, (0, 2))):
            on = []
            for f in (f0, f1):
                q = np.unique(points[tri[face == f]].reshape(-1, 3), axis=0).astype(float)
                e = v[j] - v[i]
                w = q - v[i]
                u = w @ e / (e @ e)
                dist = np.linalg.norm(w - u[:, None] * e, axis=1)
                on.append({tuple(x) for x in q[(dist < 1e-4) & (u > -1e-6) & (u < 1 + 1e-6)]})
            assert on[0] == on[1] and len(on[0]) == n + 1


def test_intersect_names_the_same_faces_with_large_objects_cut():
    """A hall-sized floor and wall (cut for Embree: longer than a quarter of the scene's
    extent) and small boxes: ``intersect`` gives the face, object and distance that the uncut
    scene gives (float32 distances), for random rays; a subset query the same objects."""
    from raytrace.scene import accel

    objs = [("floor", box((0, 0, -0.3), (60, 50, 0)), "concrete"),
            ("wall", box((0, 0, 0), (60, 0.3, 9)), "concrete")]  # fmt: skip
    rng = np.random.default_rng(12)
    for i, p in enumerate(rng.uniform([1, 1, 0], [59, 49, 3], (20, 3))):
        objs.append((f"b{i}", box(p, p + rng.uniform(0.2, 2.0, 3)), "metal"))
    cut = make_scene(objs)
    assert [len(t) for _, t, _ in cut.embree_meshes()[:2]] != [12, 12]
    n = 4000
    o = rng.uniform([0.5, 0.5, 0.1], [59.5, 49.5, 8], (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    got = cut.intersect(o, d, 100.0)
    sub = cut.first_hit_among(np.arange(len(objs)) < 2, o, d, np.full(n, 100.0))
    saved = accel.EMBREE_SPLIT_FRACTION
    try:
        accel.EMBREE_SPLIT_FRACTION = np.inf
        whole = make_scene(objs)
        assert [len(t) for _, t, _ in whole.embree_meshes()[:2]] == [12, 12]
        want = whole.intersect(o, d, 100.0)
        want_sub = whole.first_hit_among(np.arange(len(objs)) < 2, o, d, np.full(n, 100.0))
    finally:
        accel.EMBREE_SPLIT_FRACTION = saved
    assert np.isin(want[2], [0, 1]).mean() > 0.3 and (want[2] >= 2).sum() > 40
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[2], want[2])
    np.testing.assert_allclose(got[0], want[0], rtol=1e-5)
    np.testing.assert_array_equal(sub, want_sub)


def test_inside_solid_of_a_non_convex_solid_by_parity():
    # a sphere with a dent (not convex): points in its box but outside it get -1, also when no
    # point of the batch is inside (that batch was an IndexError)
    ball = trimesh.creation.icosphere(2, 1.0)
    top = int(np.argmax(ball.vertices[:, 2]))
    ball.vertices[top] *= 0.3  # the dent
    sc = make_scene([("ball", ball, "metal")])
    assert not sc.convex_objects()[0]
    outside = np.array([[0.9, 0.9, 0.9], [-0.9, 0.8, -0.85], [0.0, 0.0, 0.95]])  # last: in the dent
    assert sc.inside_solid(outside).tolist() == [-1, -1, -1]
    both = np.vstack([outside, [[0.0, 0.0, 0.0], [0.5, -0.3, 0.2]]])
    assert sc.inside_solid(both).tolist() == [-1, -1, -1, 0, 0]


def test_a_closed_mesh_read_as_surfaces_diffracts_whichever_way_it_is_wound():
    """Read as surfaces (Sionna RT's model), a closed box is a folded sheet: its fold edges
    diffract on their convex side whatever the file's winding (an inward-wound box lost every
    edge's diffraction), and the same as the box read as a solid (the metal slab's R for the
    faces' terms instead of the half-space's: within 1e-12)."""
    import raytrace
    from raytrace.physics.materials import MaterialLibrary
    from raytrace.scene.model import Scene

    lib = MaterialLibrary.itu()
    tx, rx = np.array([[-8.0, 1.0, 1.0]]), np.array([[1.5, 2.5, 1.5]])  # round the (-2, 2) edge

    def gain(surfaces: bool, inward: bool) -> np.ndarray:
        m = trimesh.creation.box(extents=(4.0, 4.0, 4.0))
        m.apply_translation((0.0, 0.0, 2.0))
        if inward:
            m.invert()
        s = Scene.from_meshes([("box", m, "metal")], lib, surfaces=surfaces)
        assert s.surfaces == surfaces and np.all(s.wedges.n == 1.5)
        with pytest.warns(UserWarning, match="far outside"):
            p = raytrace.trace(s, tx, rx, 3.5e9, raytrace.TraceConfig(max_penetrations=0))
        assert p.to_pandas()["kind"].tolist() == ["D"]
        return p.gain

    outward, inward = gain(True, False), gain(True, True)
    assert len(outward) == 1
    np.testing.assert_array_equal(inward, outward)
    np.testing.assert_allclose(gain(False, False), outward, rtol=1e-12)
