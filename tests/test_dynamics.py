"""Moving forklifts: route kinematics, boxes, fast snapshot scenes and the incremental retrace."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, quad, shoebox_sheets

from raytrace.core.errors import SceneError
from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.dynamic import extend_scene, posed, yaw_rotations
from raytrace.scene.metadata import routes_from_metadata
from raytrace.scene.model import Scene
from raytrace.scene.motion import FORKLIFT_CLEARANCE_M, Route, snapshot_times
from raytrace.solver.config import TraceConfig
from raytrace.solver.incremental import (
    Boxes,
    PathSegments,
    SnapshotTracer,
    path_segments,
    segments_meet_boxes,
)
from raytrace.solver.paths import Paths
from raytrace.solver.penetration import flat_sheet_arrays
from raytrace.solver.tracer import reevaluate, trace

F_C = 3.775e9
F_MM = 26.85e9
#: Positions and headings from closed forms, m and rad.
POSE_TOL = 1e-12
#: Delays of the same path from two computations, s.
DELAY_TOL_S = 1e-15
#: Gains of the same path from two computations (relative).
GAIN_RTOL = 1e-12
#: Geometry of a rigidly moved scene vs the same mesh processed in place, m.
GEOM_TOL_M = 1e-12


def _route(**kw) -> Route:
    entry = {
        "name": "f",
        "size": [2.0, 1.0, 2.0],
        "material": "metal",
        "waypoints": [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]],
        "speed": 1.0,
        "mode": "loop",
    }
    entry.update(kw)
    return Route.from_dict(entry)


# -- routes -----------------------------------------------------------------------------------
def test_loop_pose_closed_form():
    r = _route()  # 4 m east, 3 m north, 5 m back to the start: 12 m lap
    assert r.length_m == pytest.approx(12.0, abs=POSE_TOL)
    assert r.period_s == pytest.approx(12.0, abs=POSE_TOL)
    t = np.array([0.0, 2.0, 5.5, 9.5, 12.0 + 2.0])
    xy, h = r.pose(t)
    # on the closing segment (4, 3) -> (0, 0) at 2.5 m of 5: the midpoint
    want = np.array([[0, 0], [2, 0], [4, 1.5], [2, 1.5], [2, 0]], dtype=float)
    np.testing.assert_allclose(xy, want, atol=POSE_TOL)
    back = np.arctan2(-3.0, -4.0)
    np.testing.assert_allclose(h, [0, 0, np.pi / 2, back, 0], atol=POSE_TOL)


def test_back_and_forth_pose_closed_form():
    r = _route(waypoints=[[1.0, 2.0], [1.0, 8.0]], speed=2.0, mode="back_and_forth")
    assert r.period_s == pytest.approx(6.0, abs=POSE_TOL)
    xy, h = r.pose(np.array([1.0, 3.0, 4.0, 6.0, 7.5]))
    np.testing.assert_allclose(xy[:, 1], [4.0, 8.0, 6.0, 2.0, 5.0], atol=POSE_TOL)
    np.testing.assert_allclose(xy[:, 0], 1.0, atol=POSE_TOL)
    # northward, then southward on the way back
    np.testing.assert_allclose(h[[0, 4]], np.pi / 2, atol=POSE_TOL)
    np.testing.assert_allclose(h[2], -np.pi / 2, atol=POSE_TOL)


def test_hall_routes_agree_with_hallspec_kinematics():
    """Our kinematics against the hall builder's independent Route.pose."""
    hallspec = pytest.importorskip("raytrace.halls.spec")
    spec = hallspec.load_hall_spec(
        __import__("raytrace.scene.bundled", fromlist=["x"]).scenes_dir() / "hall.yaml"
    )
    meta = {"hallray": hallspec.hall_metadata(spec)}
    ours = {r.name: r for r in routes_from_metadata(meta)}
    t = np.linspace(0.0, 60.0, 601) + 0.0123
    for ref in spec.routes:
        xy_a, h_a = ours[ref.name].pose(t)
        xy_b, h_b = ref.pose(t)
        np.testing.assert_allclose(xy_a, xy_b, atol=1e-9)
        np.testing.assert_allclose(np.cos(h_a - h_b), 1.0, atol=1e-9)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"speed": 0.0}, "speed"),
        ({"speed": "fast"}, "numbers"),
        ({"size": [2.0, 1.0]}, "size"),
        ({"waypoints": [[0.0, 0.0]]}, "waypoints"),
        ({"waypoints": [[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]]}, "coincide"),
        ({"mode": "zigzag"}, "mode"),
        ({"size": [2.0, 1.0, 0.01]}, "clearance"),
    ],
)
def test_bad_routes_raise_one_line(change, message):
    with pytest.raises(SceneError, match=message) as info:
        _route(**change)
    assert "\n" not in str(info.value)


def test_routes_from_metadata_without_routes_is_empty():
    assert routes_from_metadata({"hallray": {"points": []}}) == []
    assert routes_from_metadata({}) == []
    with pytest.raises(SceneError, match="duplicate"):
        routes_from_metadata({"hallray": {"routes": [_dict("a"), _dict("a")]}})


def _dict(name):
    return {
        "name": name,
        "size": [1, 1, 1],
        "material": "metal",
        "waypoints": [[0, 0], [1, 0]],
        "speed": 1,
    }


def test_snapshot_times():
    t = snapshot_times(60.0, 10.0)
    assert len(t) == 600
    assert t[0] == 0.0 and t[-1] == pytest.approx(59.9, abs=1e-12)
    assert len(snapshot_times(1.0, 3.0)) == 3
    for d, r in [(0.0, 10.0), (-1.0, 10.0), (float("nan"), 10.0), (60.0, 0.0), (0.05, 10.0)]:
        with pytest.raises(SceneError):
            snapshot_times(d, r)


# -- boxes and segments -------------------------------------------------------------------------
def _random_boxes(rng, n):
    centre = rng.uniform(-2, 2, (n, 3))
    rot = yaw_rotations(rng.uniform(-np.pi, np.pi, n))
    half = rng.uniform(0.3, 1.5, (n, 3))
    return Boxes(centre, rot, half)


def test_segment_box_test_against_sampling():
    """Analytic slab test vs dense sampling of the segments: a segment that meets the box shrunk
    by delta has a chord of length >= 2 delta inside the box, which samples closer than that
    find; a segment with a sample inside the box meets the box grown by any margin."""
    rng = np.random.default_rng(7)
    boxes = _random_boxes(rng, 1)
    a = rng.uniform(-5, 5, (1500, 3))
    b = rng.uniform(-5, 5, (1500, 3))
    n_s = 1001
    delta = 0.01
    u = np.linspace(0, 1, n_s)
    pts = a[:, None, :] + u[None, :, None] * (b - a)[:, None, :]
    sampled = boxes.contains(pts.reshape(-1, 3)).reshape(len(a), n_s).any(axis=1)
    spacing = np.linalg.norm(b - a, axis=1) / (n_s - 1)
    assert spacing.max() < 2 * delta
    inner = segments_meet_boxes(a, b, boxes, grow=-delta)
    outer = segments_meet_boxes(a, b, boxes, grow=delta)
    assert np.all(~inner | sampled)
    assert np.all(~sampled | outer)
    assert 50 < sampled.sum() < 1450  # both outcomes are exercised


def test_affected_paths_equal_the_slab_test_per_segment():
    """The compiled per-path test (prefilter, slab test, early exit per path) against
    :func:`segments_meet_boxes` of every segment, path by path: random segments, some axis-
    parallel in the boxes' frame (the flat slab case), paths of 1-4 segments, 3 boxes."""
    rng = np.random.default_rng(11)
    boxes = _random_boxes(rng, 3)
    a = rng.uniform(-6, 6, (4000, 3))
    b = rng.uniform(-6, 6, (4000, 3))
    # segments parallel to a box's axis: the flat branch of the slab test
    flat = slice(0, 400)
    b[flat] = a[flat] + rng.uniform(-4, 4, (400, 1)) * boxes.rotation[0][:, 0]
    path = np.sort(rng.integers(0, 1500, len(a)))
    seg = PathSegments.__new__(PathSegments)
    seg.n_paths, seg.a, seg.b, seg.path = 1500, a, b, path
    seg.lo, seg.hi = np.minimum(a, b), np.maximum(a, b)
    for grow in (0.0, 1e-3, 0.3):
        got = seg.affected(boxes, grow)
        want = np.zeros(1500, bool)
        want[path[segments_meet_boxes(a, b, boxes, grow)]] = True
        np.testing.assert_array_equal(got, want)
        assert 100 < got.sum() < 1400


def test_segment_box_axis_parallel_and_contained_cases():
    boxes = Boxes(np.zeros((1, 3)), np.eye(3)[None], np.ones((1, 3)))
    a = np.array([[-3, 0.5, 0.5], [-3, 1.5, 0.0], [-0.5, 0, 0], [2, 2, 2], [-3, 1.0, 1.0]])
    b = np.array([[3, 0.5, 0.5], [3, 1.5, 0.0], [0.5, 0, 0], [3, 3, 3], [3, 1.0, 1.0]])
    np.testing.assert_array_equal(
        segments_meet_boxes(a, b, boxes, grow=0.0), [True, False, True, False, True]
    )
    # a segment along an edge is "near": grown boxes catch it, shrunk ones do not
    assert not segments_meet_boxes(a[4:], b[4:], boxes, grow=-1e-6)[0]


def test_path_segments_follow_the_vertices(shoebox):
    tx = np.array([[2.0, 3.0, 1.5]])
    rx = np.array([[7.0, 5.0, 1.2], [5.0, 5.0, 2.0]])
    p = trace(shoebox, tx, rx, F_C, TraceConfig(max_diffractions=0))
    a, b, path = path_segments(p)
    n_seg = np.bincount(path, minlength=p.n_paths)
    np.testing.assert_array_equal(n_seg, p.n_reflections + 1)
    # segment lengths add up to the path length
    length = np.bincount(path, weights=np.linalg.norm(b - a, axis=1), minlength=p.n_paths)
    np.testing.assert_allclose(length, p.length_m, rtol=1e-12)
    first = np.flatnonzero(np.r_[True, path[1:] != path[:-1]])
    np.testing.assert_allclose(a[first], tx[p.tx_index], atol=0)


# -- fast snapshot scenes ----------------------------------------------------------------------
def _static_objects():
    return shoebox_sheets((12.0, 10.0, 4.0)) + [
        ("machine", box((6.0, 6.0, 0.0), (8.0, 8.0, 2.0)), "metal")
    ]


def test_extend_scene_equals_from_meshes():
    lib = MaterialLibrary.itu()
    static = _static_objects()
    extra = [
        ("fork_a", box((2.0, 2.0, 0.05), (4.0, 3.0, 2.0)), "metal"),
        ("fork_b", box((9.0, 1.0, 0.05), (10.0, 3.5, 2.2)), "wood"),
    ]
    whole = Scene.from_meshes(static + extra, lib)
    joined = extend_scene(Scene.from_meshes(static, lib), Scene.from_meshes(extra, lib))
    for name in ("vertices", "faces", "face_object", "face_normal"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name))
    assert joined.material_names == whole.material_names
    assert [vars(o) for o in joined.objects] == [vars(o) for o in whole.objects]
    for part in ("facets", "wedges"):
        a, b = getattr(joined, part), getattr(whole, part)
        assert len(a) == len(b)
        for k, v in b.arrays().items():
            np.testing.assert_array_equal(getattr(a, k), v, err_msg=f"{part}.{k}")
    # the Embree scene names the added objects
    hit = joined.occluded(np.array([[3.0, 0.5, 1.0]]), np.array([[3.0, 4.5, 1.0]]))
    assert hit[0]
    # the triangles Embree is given (the static objects' taken from the base when the extent
    # is the same; the large ones cut), and with an object beyond the base's bounds
    far = [("far", box((40.0, 1.0, 0.0), (41.0, 2.0, 1.0)), "wood")]
    wider = Scene.from_meshes(static + far, lib)
    for got, want in ((joined, whole),
                      (extend_scene(Scene.from_meshes(static, lib), Scene.from_meshes(far, lib)),
                       wider)):  # fmt: skip
        np.testing.assert_array_equal(got.convex_objects(), want.convex_objects())
        for x, y in zip(flat_sheet_arrays(got), flat_sheet_arrays(want), strict=True):
            np.testing.assert_array_equal(x, y)
        got_m, want_m = got.embree_meshes(), want.embree_meshes()
        assert len(got_m) == len(want_m)
        for g, w in zip(got_m, want_m, strict=True):
            for x, y in zip(g, w, strict=True):
                np.testing.assert_array_equal(x, y)
    assert any(len(t) > o.face_count for (_, t, _), o in zip(whole.embree_meshes(), whole.objects))


def _sorted_rows(x, decimals=9):
    x = np.round(np.asarray(x, dtype=float).reshape(len(x), -1), decimals) + 0.0
    return x[np.lexsort(x.T[::-1])]


def test_posed_template_equals_processing_the_moved_mesh():
    lib = MaterialLibrary.itu()
    ext = np.array([2.5, 1.2, 2.15])
    template = Scene.from_meshes([("f", trimesh.creation.box(extents=ext), "metal")], lib)
    for yaw in (0.0, np.pi / 2, 0.7, -2.9):
        rot = yaw_rotations(np.array([yaw]))
        centre = np.array([[11.0, -3.0, 1.125]])
        moved = posed(template, rot, centre)
        mesh = trimesh.creation.box(extents=ext)
        tf = np.eye(4)
        tf[:3, :3], tf[:3, 3] = rot[0], centre[0]
        mesh.apply_transform(tf)
        ref = Scene.from_meshes([("f", mesh, "metal")], lib)
        np.testing.assert_allclose(
            _sorted_rows(moved.vertices), _sorted_rows(ref.vertices), atol=GEOM_TOL_M
        )
        fa, fb = moved.facets, ref.facets
        np.testing.assert_allclose(
            _sorted_rows(np.column_stack([fa.normal, fa.offset])),
            _sorted_rows(np.column_stack([fb.normal, fb.offset])),
            atol=GEOM_TOL_M,
        )
        wa, wb = moved.wedges, ref.wedges
        key = lambda w: np.column_stack(  # noqa: E731
            [np.minimum(w.start, w.end), np.maximum(w.start, w.end), w.n]
        )
        np.testing.assert_allclose(_sorted_rows(key(wa)), _sorted_rows(key(wb)), atol=GEOM_TOL_M)
        # normals stay outward: every facet plane has the box centre behind it
        assert np.all(fa.normal @ centre[0] - fa.offset < 0)


# -- incremental retrace ----------------------------------------------------------------------
def _key(p: Paths):
    kinds = p.kind_label
    order = np.lexsort((p.gain.imag, p.gain.real, kinds, p.delay_s, p.link))
    return p.link[order], p.delay_s[order], kinds[order], p.gain[order], order


def assert_same_paths(inc: Paths, full: Paths, static_scene=None, snap_scene=None) -> int:
    """Path-for-path equality of an incremental and a full retrace.

    Link, kind and delay must match exactly (to DELAY_TOL_S); gains to GAIN_RTOL. A gain may
    differ only where Embree's answer for a ray that grazes an edge exactly depends on its BVH
    (the static and the snapshot scene build different ones): then re-evaluating that path in
    the static scene must give the incremental gain and in the snapshot scene the full one.
    Returns the number of such paths.
    """
    assert inc.n_paths == full.n_paths
    a, b = _key(inc), _key(full)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=DELAY_TOL_S)
    np.testing.assert_array_equal(a[2], b[2])
    bad = np.flatnonzero(~np.isclose(a[3], b[3], rtol=GAIN_RTOL, atol=0))
    if len(bad):
        assert static_scene is not None and len(bad) <= max(2, full.n_paths // 1000), bad
        one = full.select(b[4][bad])
        np.testing.assert_allclose(
            reevaluate(snap_scene, one).gain, b[3][bad], rtol=GAIN_RTOL, atol=0
        )
        np.testing.assert_allclose(
            np.sort_complex(reevaluate(static_scene, inc.select(a[4][bad])).gain),
            np.sort_complex(a[3][bad]),
            rtol=GAIN_RTOL,
            atol=0,
        )
    return len(bad)


def _crossing_route(speed=2.0):
    # x(t) = 2.05 + 2 t along y = 10 and back: box x in [x-1, x+1], y in [9.5, 10.5]
    return Route.from_dict(
        {
            "name": "forklift_1",
            "size": [2.0, 1.0, 2.0],
            "material": "metal",
            "waypoints": [[2.05, 10.0], [17.95, 10.0]],
            "speed": speed,
            "mode": "back_and_forth",
        }
    )


def test_forklift_blocks_line_of_sight_exactly_when_in_the_way():
    floor = [("floor", quad((0, 0, 0), (20, 0, 0), (0, 20, 0)), "concrete")]
    scene = make_scene(floor)
    tx = np.array([[10.0, 2.0, 1.0]])
    rx = np.array([[10.0, 18.0, 1.0]])
    route = _crossing_route()
    st = SnapshotTracer(scene, tx, rx, [route], [F_C], TraceConfig(max_reflections=1))
    times = snapshot_times(16.0, 10.0)
    x, _ = route.pose(times)
    # the LoS (x = 10, z = 1 within the box's height) crosses y = 10; blocked iff |x - 10| < 1
    gap = np.abs(x[:, 0] - 10.0) - 1.0
    assert np.abs(gap).min() > 1e-6  # no snapshot grazes the box
    blocked = gap < 0
    assert blocked.sum() == 20  # 10 snapshots on the way out, 10 on the way back
    # every snapshot within 1 s of a change, and some others
    near = np.convolve(np.diff(blocked.astype(int)) != 0, np.ones(21), mode="same") > 0
    check = np.flatnonzero(np.r_[near, False] | (np.arange(len(times)) % 10 == 0))
    for t, want in zip(times[check], blocked[check]):
        p = st.paths_at(float(t))[0]
        assert p.los.any() == (not want), t
    # the box sits where the route says, lifted by the clearance
    snap = st.scene_at(4.0)
    v = snap.vertices[snap.faces[snap.face_object == len(floor)]].reshape(-1, 3)
    np.testing.assert_allclose(
        v.min(axis=0), [x[40, 0] - 1.0, 9.5, FORKLIFT_CLEARANCE_M], atol=1e-12
    )
    np.testing.assert_allclose(v.max(axis=0), [x[40, 0] + 1.0, 10.5, 2.0], atol=1e-12)


def _loop_route_and_links():
    """A forklift looping around the small scene's machine, 2 base stations, 3 points."""
    route = Route.from_dict(
        {
            "name": "forklift_1",
            "size": [2.0, 1.0, 2.0],
            "material": "metal",
            "waypoints": [[2.0, 3.5], [10.0, 3.5], [10.0, 8.5], [3.0, 8.5]],
            "speed": 1.5,
            "mode": "loop",
        }
    )
    tx = np.array([[1.0, 1.0, 3.0], [11.0, 9.0, 3.0]])
    rx = np.array([[11.0, 5.5, 1.0], [4.0, 9.5, 1.0], [6.0, 2.0, 1.0]])
    return route, tx, rx


@pytest.mark.parametrize("t", [0.0, 3.9, 7.2, 9.95, 13.3])
def test_incremental_equals_full_retrace_small_scene(t):
    scene = make_scene(_static_objects())
    route, tx, rx = _loop_route_and_links()
    st = SnapshotTracer(scene, tx, rx, [route], [F_C, F_MM])
    snap = st.scene_at(t)
    inc = st.paths_at(t, snap)
    full = st.full_retrace(t, snap)
    for a, b in zip(inc, full):
        assert_same_paths(a, b, scene, snap)
    # the selection is a real subset: some static paths are kept untouched
    aff = st._segments[0].affected(st.boxes_at(t), st.grow_m)
    assert 0 < aff.sum() < st.static_paths[0].n_paths


def test_incremental_equals_full_retrace_when_bands_block_differently(monkeypatch):
    """Objects opaque in one band only (a material that blocks at mmWave but not at C-band) do
    not block the shared geometric trace; each band still equals its full retrace."""
    import raytrace.solver.context as context_mod
    import raytrace.solver.incremental as dyn

    real = context_mod.opaque_objects

    def mmwave_only(scene, frequency_hz, *a, **kw):
        return real(scene, frequency_hz, *a, **kw) & (frequency_hz > 10e9)

    monkeypatch.setattr(context_mod, "opaque_objects", mmwave_only)
    monkeypatch.setattr(dyn, "opaque_objects", mmwave_only)
    scene = make_scene(_static_objects())
    route, tx, rx = _loop_route_and_links()
    for bands in ([F_C, F_MM], [F_MM, F_C]):
        st = SnapshotTracer(scene, tx, rx, [route], bands)
        snap = st.scene_at(3.9)
        for a, b in zip(st.paths_at(3.9, snap), st.full_retrace(3.9, snap)):
            assert_same_paths(a, b, scene, snap)


def test_no_routes_gives_the_static_paths(shoebox):
    tx = np.array([[2.0, 3.0, 1.5]])
    rx = np.array([[7.0, 5.0, 1.2]])
    st = SnapshotTracer(shoebox, tx, rx, [], [F_C])
    assert st.scene_at(3.0) is shoebox
    assert st.paths_at(3.0)[0] is st.static_paths[0]


def test_antenna_inside_a_forklift_is_refused():
    scene = make_scene([("floor", quad((0, 0, 0), (20, 0, 0), (0, 20, 0)), "concrete")])
    st = SnapshotTracer(
        scene,
        [[10.0, 2.0, 1.0]],
        [[10.0, 10.0, 1.0]],
        [_crossing_route()],
        [F_C],
        TraceConfig(max_reflections=0, max_diffractions=0),
    )
    with pytest.raises(SceneError, match="inside forklift 'forklift_1' at t = 3.5 s"):
        st.check_clear(snapshot_times(16.0, 10.0), ["BS1"], ["P1"])


def _hall_links(all_links: bool):
    from raytrace import load_scene

    scene = load_scene("hall")
    meta = scene.metadata["hallray"]
    tx = np.array([b["xyz"] for b in meta["base_stations"]])
    rx = np.array([p["xyz"] for p in meta["points"]])
    if not all_links:
        tx, rx = tx[[0, 2]], rx[[0, 6, 12, 20]]
    return scene, tx, rx, routes_from_metadata(scene.metadata)


def test_incremental_equals_full_retrace_hall_few_links():
    scene, tx, rx, routes = _hall_links(False)
    st = SnapshotTracer(scene, tx, rx, routes, [F_C])
    for t in (4.2, 23.7):
        snap = st.scene_at(t)
        assert_same_paths(st.paths_at(t, snap)[0], st.full_retrace(t, snap)[0], scene, snap)


@pytest.mark.slow
def test_incremental_equals_full_retrace_hall_all_links_both_bands():
    scene, tx, rx, routes = _hall_links(True)
    st = SnapshotTracer(scene, tx, rx, routes, [F_C, F_MM])
    for t in (0.0, 7.3, 41.8):
        snap = st.scene_at(t)
        for a, b in zip(st.paths_at(t, snap), st.full_retrace(t, snap)):
            assert_same_paths(a, b, scene, snap)


def test_points_beside_a_forklift_are_not_inside_it():
    """Regression: at t = 37.9 s forklift_2's box (x 23.4..24.6, y 10.3..12.8) is 0.4 m from P03
    (23, 12, 1); a parity ray with an x:y slope of 1:2 grazed its vertical edge and reported P03
    inside. Also a point just outside a cabinet whose ray left the hall through the overlapping,
    coplanar top faces of two shell slabs."""
    scene, tx, rx, routes = _hall_links(True)
    st = SnapshotTracer(scene, tx, rx, routes, [F_C], static_paths=[Paths.empty(tx, rx, F_C)])
    snap = st.scene_at(37.9)
    assert not st.boxes_at(37.9).contains(rx, grow=0.39).any()
    np.testing.assert_array_equal(snap.inside_solid(np.vstack([tx, rx])), -1)
    assert scene.inside_solid(np.array([[39.1965, 1.1965, 1.0]]))[0] == -1


def test_a_posed_copy_does_not_share_the_templates_derived_arrays():
    """Regression: ``posed`` copies the template's facets and wedges with
    ``dataclasses.replace``, which shared their ``cache`` dicts, so the tree (and boxes, spheres)
    of one pose answered for the next: a snapshot's full retrace lost 28 of 3856 paths."""
    from raytrace.scene import accel

    template = make_scene([("box", box((-1, -1, 0), (1, 1, 1)), "metal")])
    first = accel.facet_tree(template.facets)
    moved = posed(template, yaw_rotations(np.array([0.3])), np.array([[5.0, 2.0, 0.0]]))
    assert moved.facets.cache is not template.facets.cache
    assert moved.wedges.cache is not template.wedges.cache
    tree = accel.facet_tree(moved.facets)
    corners = moved.facets.triangles.reshape(-1, 3)
    assert (tree.node_lo[0] <= corners.min(axis=0)).all()
    assert (tree.node_hi[0] >= corners.max(axis=0)).all()
    np.testing.assert_allclose(tree.node_centre[0][:2] - first.node_centre[0][:2], [5.0, 2.0],
                               atol=0.5)  # fmt: skip
    assert accel.facet_tree(template.facets) is first
