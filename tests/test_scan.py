"""scan-to-scene: point clouds -> planes and objects -> a GLB that the tracer loads and traces like
the original scene; readers, material rules, options, and one-line errors for bad input.

These tests need open3d (the ``scan`` extra, and libusb-1.0-0 on Debian/Ubuntu). They fail, not
skip, when it is missing: CI installs it.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh

from raytrace.cli.scan_to_scene import scan_to_scene_main
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError, MaterialError
from raytrace.halls.scan import (
    MaterialRules,
    ScanOptions,
    read_cloud,
    reconstruct,
    scan_to_scene,
    simulate_scan,
)
from raytrace.scene.io import load_scene
from raytrace.solver.config import TraceConfig
from raytrace.solver.tracer import trace

#: Reconstructed floor, ceiling and walls within this of the originals (offset and tilt), m.
PLANE_TOL_M = 0.05
#: First-arrival delays agree within the delay of this path length, m.
DELAY_TOL_M = 0.10
#: Share of the hall's links whose LoS status and first-arrival delay must agree.
MIN_LINK_AGREEMENT = 0.90
#: Box-room test: scan noise (m), plane and box-edge tolerances (m).
ROOM_NOISE_M = 0.005
ROOM_PLANE_TOL_M = 0.01
ROOM_EDGE_TOL_M = 0.06
#: Points on a node name: plane_07_itu_concrete, object_12_plastic.
NAME_RE = re.compile(r"^(plane|object)_\d{2,}_(itu_)?[a-z_]+$")


@pytest.fixture(scope="module", autouse=True)
def _needs_open3d():
    try:
        import open3d  # noqa: F401
    except (ImportError, OSError) as exc:  # pragma: no cover - the CI installs it
        pytest.fail(
            "open3d is required for the scan tests: pip install '.[scan]' (and apt-get install "
            f"libusb-1.0-0 on Debian/Ubuntu); import failed: {exc}",
            pytrace=False,
        )


def _write_ply(path, pts):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(pts, dtype=float)))
    assert o3d.io.write_point_cloud(str(path), pcd)
    return path


# ---------------------------------------------------------------------------------------------
# a box room with one box on the floor: closed-form planes and box edges
# ---------------------------------------------------------------------------------------------

ROOM = (10.0, 8.0, 3.0)
BOX_LO, BOX_HI = np.array([4.0, 3.0, 0.0]), np.array([6.0, 4.0, 1.5])


def _faces_points(faces, density, rng):
    out = []
    for o, u, v in faces:
        o, u, v = (np.asarray(x, dtype=float) for x in (o, u, v))
        n = int(np.linalg.norm(np.cross(u, v)) * density)
        st = rng.random((n, 2))
        out.append(o + st[:, :1] * u + st[:, 1:] * v)
    return np.vstack(out)


def room_cloud(seed=3, density=300.0, noise=ROOM_NOISE_M):
    """Points on the inside of a 10 x 8 x 3 m room and on the visible faces of a 2 x 1 x 1.5 m
    box standing on its floor (none under the box), with Gaussian noise."""
    rng = np.random.default_rng(seed)
    lx, ly, lz = ROOM
    room = [
        ((0, 0, 0), (lx, 0, 0), (0, ly, 0)),
        ((0, 0, lz), (lx, 0, 0), (0, ly, 0)),
        ((0, 0, 0), (lx, 0, 0), (0, 0, lz)),
        ((0, ly, 0), (lx, 0, 0), (0, 0, lz)),
        ((0, 0, 0), (0, ly, 0), (0, 0, lz)),
        ((lx, 0, 0), (0, ly, 0), (0, 0, lz)),
    ]
    (x0, y0, _), (x1, y1, z1) = BOX_LO, BOX_HI
    box = [
        ((x0, y0, z1), (x1 - x0, 0, 0), (0, y1 - y0, 0)),
        ((x0, y0, 0), (x1 - x0, 0, 0), (0, 0, z1)),
        ((x0, y1, 0), (x1 - x0, 0, 0), (0, 0, z1)),
        ((x0, y0, 0), (0, y1 - y0, 0), (0, 0, z1)),
        ((x1, y0, 0), (0, y1 - y0, 0), (0, 0, z1)),
    ]
    pts = _faces_points(room + box, density, rng)
    under = (pts[:, 2] < 1e-9) & np.all((pts[:, :2] > BOX_LO[:2]) & (pts[:, :2] < BOX_HI[:2]), 1)
    pts = pts[~under]
    return pts + rng.normal(0.0, noise, pts.shape)


@pytest.fixture(scope="module")
def room():
    opt = ScanOptions(voxel_size_m=0.05, plane_distance_m=0.02)
    return reconstruct(room_cloud(), opt)


def test_room_shell_is_six_closed_slabs_on_the_true_planes(room):
    elements, summary = room
    shell = [e for e in elements if e.bounding]
    assert len(shell) == 6 and summary["bounding_planes"] == 6
    lx, ly, lz = ROOM
    truth = {  # inward normal -> offset (n . x = d on the inner face)
        (0, 0, 1): 0.0,
        (0, 0, -1): -lz,
        (1, 0, 0): 0.0,
        (-1, 0, 0): -lx,
        (0, 1, 0): 0.0,
        (0, -1, 0): -ly,
    }
    found = {}
    for e in shell:
        key = tuple(int(round(c)) for c in e.normal)
        assert np.linalg.norm(e.normal - np.array(key)) < 1e-3
        assert abs(e.offset - truth[key]) < ROOM_PLANE_TOL_M
        assert e.closed and e.mesh.is_watertight and e.mesh.volume > 0
        assert e.material == "concrete"
        found[key] = e
    assert set(found) == set(truth)
    # the slabs meet: the floor runs under the walls to their outer faces, a wall runs from
    # the floor to the ceiling
    t = ScanOptions().wall_thickness_m
    floor = found[(0, 0, 1)]
    top = floor.mesh.vertices[np.abs(floor.mesh.vertices @ floor.normal - floor.offset) < 1e-6]
    assert np.all(np.abs(top[:, :2].min(axis=0) + t) <= ROOM_PLANE_TOL_M)
    assert np.all(np.abs(top[:, :2].max(axis=0) - np.array(ROOM[:2]) - t) <= ROOM_PLANE_TOL_M)
    west = np.asarray(found[(1, 0, 0)].mesh.bounds)
    assert abs(west[0, 2]) <= ROOM_PLANE_TOL_M and abs(west[1, 2] - lz) <= ROOM_PLANE_TOL_M


def test_room_box_faces_have_their_true_outlines(room):
    elements, summary = room
    faces = [e for e in elements if e.kind == "plane" and not e.bounding]
    assert len(faces) == 5  # top and four sides; the bottom is not seen
    lo, hi = BOX_LO, BOX_HI
    for e in faces:
        axis = int(np.argmax(np.abs(e.normal)))
        side = hi[axis] if abs(e.offset * np.sign(e.normal[axis]) - hi[axis]) < 0.1 else lo[axis]
        assert abs(e.offset * np.sign(e.normal[axis]) - side) < ROOM_PLANE_TOL_M
        b = np.asarray(e.mesh.bounds)
        others = [k for k in range(3) if k != axis]
        assert np.all(np.abs(b[0, others] - lo[others]) < ROOM_EDGE_TOL_M), (e.name, b)
        assert np.all(np.abs(b[1, others] - hi[others]) < ROOM_EDGE_TOL_M), (e.name, b)
        assert e.material == "metal" and not e.closed
    assert summary["objects"] == 0
    # the residual is the noise: the mesh explains the points
    assert summary["residual_mean_m"] < 2 * ROOM_NOISE_M
    assert summary["unexplained_points"] < 0.01 * summary["points_used"]
    assert abs(summary["noise_estimate_m"] - ROOM_NOISE_M) < 0.3 * ROOM_NOISE_M


def test_room_without_box_planes_becomes_objects():
    # with a plane area threshold above the box faces, the box is left to clustering and comes
    # back as one upright box around its faces
    opt = ScanOptions(voxel_size_m=0.05, plane_distance_m=0.02, plane_min_area_m2=5.0)
    elements, summary = reconstruct(room_cloud(), opt)
    objs = [e for e in elements if e.kind == "object"]
    assert summary["planes"] == 6 and len(objs) == 1
    b = np.asarray(objs[0].mesh.bounds)
    assert np.all(np.abs(b[0] - BOX_LO) < ROOM_EDGE_TOL_M) and np.all(
        np.abs(b[1] - BOX_HI) < ROOM_EDGE_TOL_M
    )
    assert objs[0].closed and objs[0].mesh.is_watertight


@pytest.mark.parametrize("mode", ["hull", "mesh"])
def test_object_modes_give_loadable_meshes(mode, tmp_path):
    opt = ScanOptions(voxel_size_m=0.05, plane_distance_m=0.02, plane_min_area_m2=5.0, objects=mode)
    ply = _write_ply(tmp_path / "room.ply", room_cloud(density=150.0))
    out = tmp_path / "room.glb"
    summary = scan_to_scene(ply, out, opt)
    assert summary["objects"] == 1
    scene = load_scene(out)
    obj = [o for o in scene.objects if o.name.startswith("object_")]
    assert len(obj) == 1 and obj[0].material == "metal"
    f = scene.faces[obj[0].face_start : obj[0].face_start + obj[0].face_count]
    v = scene.vertices[np.unique(f)]
    assert np.all(v.min(axis=0) > BOX_LO - 0.1) and np.all(v.max(axis=0) < BOX_HI + 0.1)
    assert obj[0].face_count <= opt.max_object_triangles


# ---------------------------------------------------------------------------------------------
# the bundled hall: scan it, reconstruct it, trace both
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def hall_scan(tmp_path_factory):
    """A simulated scan of the bundled hall (16 stations, 2 cm noise, 30 drop-out holes of
    25 cm), reconstructed with the default options through the command-line path."""
    hall = load_scene("hall")
    pts = simulate_scan(hall, 1_200_000, noise_m=0.02, n_gaps=30, gap_radius_m=0.25, seed=11)
    d = tmp_path_factory.mktemp("hall_scan")
    ply = _write_ply(d / "hall.ply", pts)
    out = d / "hall_scan.glb"
    summary = scan_to_scene(ply, out, ScanOptions(), positions=hall.source)
    return hall, load_scene(out), summary, out


def test_hall_shell_planes_within_5cm(hall_scan):
    hall, rec, summary, _ = hall_scan
    sx, sy, sz = hall.metadata["hallray"]["hall"]["size"]
    corners = np.array([[x, y, z] for x in (0, sx) for y in (0, sy) for z in (0, sz)])
    shell = {  # interior faces of the original shell: inward normal, offset
        "floor": ((0, 0, 1), 0.0),
        "ceiling": ((0, 0, -1), -sz),
        "west": ((1, 0, 0), 0.0),
        "east": ((-1, 0, 0), -sx),
        "south": ((0, 1, 0), 0.0),
        "north": ((0, -1, 0), -sy),
    }
    bounding = [e for e in summary["elements"] if e["bounding"]]
    assert summary["bounding_planes"] == len(bounding) == 6
    for name, (n0, d0) in shell.items():
        n0 = np.asarray(n0, dtype=float)
        match = [e for e in bounding if np.dot(e["normal"], n0) > 0.99]
        assert len(match) == 1, name
        n, d = np.asarray(match[0]["normal"]), match[0]["offset_m"]
        on_face = corners[np.abs(corners @ n0 - d0) < 1e-9]  # the face's 4 corners
        # the reconstructed plane passes within PLANE_TOL_M of every corner of the original
        assert np.all(np.abs(on_face @ n - d) < PLANE_TOL_M), name
        assert match[0]["material"] == "concrete"
        # and its inner face lies on the original plane
        obj = next(o for o in rec.objects if o.name == match[0]["name"])
        v = rec.vertices[np.unique(rec.faces[obj.face_start : obj.face_start + obj.face_count])]
        inner = v[np.abs(v @ n - d) < 1e-3]
        assert len(inner) >= 3 and np.all(np.abs(inner @ n0 - d0) < PLANE_TOL_M), name


def test_hall_first_arrivals_agree_with_the_original(hall_scan):
    # geometry only (max_penetrations=0): a scan carries no material, so links through plastic
    # boxes would differ by the material rules, not by the reconstruction; no diffraction, to
    # keep the default run fast
    hall, rec, _, _ = hall_scan
    meta = hall.metadata["hallray"]
    bs = np.array([b["xyz"] for b in meta["base_stations"]])
    pts = np.array([p["xyz"] for p in meta["points"]])
    cfg = TraceConfig(max_reflections=2, max_penetrations=0, max_diffractions=0)
    a = trace(hall, bs, pts, 3.775e9, cfg)
    b = trace(rec, bs, pts, 3.775e9, cfg)
    fa, fb = a.first_arrival(), b.first_arrival()
    los_a = np.zeros(a.n_links, bool)
    los_a[a.link[a.los]] = True
    los_b = np.zeros(b.n_links, bool)
    los_b[b.link[b.los]] = True
    da = np.where(fa >= 0, a.delay_s[np.maximum(fa, 0)], np.nan)
    db = np.where(fb >= 0, b.delay_s[np.maximum(fb, 0)], np.nan)
    ok = (los_a == los_b) & (np.abs(da - db) * C0 <= DELAY_TOL_M)
    assert ok.mean() >= MIN_LINK_AGREEMENT, f"{ok.sum()} of {len(ok)} links agree"
    assert (los_a == los_b).mean() >= MIN_LINK_AGREEMENT


def test_hall_scene_file_names_metadata_and_budget(hall_scan):
    hall, rec, summary, out = hall_scan
    # every object bound by its name alone (load_scene was given no materials or default)
    assert all(NAME_RE.match(o.name) for o in rec.objects)
    assert {o.material for o in rec.objects} <= {"concrete", "metal"}
    meta = trimesh.load(str(out), force="scene").metadata["hallray"]
    assert meta["scan"]["cloud"] == "hall.ply"
    assert meta["scan"]["options"]["voxel_size_m"] == ScanOptions().voxel_size_m
    assert [b["name"] for b in meta["base_stations"]] == ["BS1", "BS2", "BS3", "BS4"]
    assert len(meta["points"]) == 23
    # summary: what was found, and a mesh that explains the points to within the noise
    brief = {k: v for k, v in summary.items() if k != "elements"}
    assert summary["triangles"] == len(rec.faces) < 5000, brief
    assert summary["planes"] >= 40 and summary["objects"] >= 10, brief
    assert summary["residual_mean_m"] < 2.5 * 0.02 and summary["residual_p95_m"] < 0.1, brief
    assert summary["unexplained_points"] < 0.02 * summary["points_used"], brief


# ---------------------------------------------------------------------------------------------
# readers
# ---------------------------------------------------------------------------------------------


def test_readers_agree(tmp_path):
    import open3d as o3d

    pts = np.random.default_rng(0).uniform(-5, 5, (50, 3)).round(6)
    (tmp_path / "a.xyz").write_text("\n".join(" ".join(f"{c:.6f}" for c in p) for p in pts))
    rows = [f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 17 120 130 140" for p in pts]
    (tmp_path / "a.pts").write_text(f"{len(pts)}\n" + "\n".join(rows) + "\n")
    _write_ply(tmp_path / "a.ply", pts)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    assert o3d.io.write_point_cloud(str(tmp_path / "a.pcd"), pcd)
    for suffix in ("xyz", "pts", "ply", "pcd"):
        got = read_cloud(tmp_path / f"a.{suffix}")
        assert got.shape == (50, 3) and np.allclose(got, pts, atol=1e-6), suffix


def test_las_reader(tmp_path):
    try:
        import laspy
    except ImportError as exc:  # pragma: no cover - part of the scan extra
        pytest.fail(f"laspy is required for the .las reader (the scan extra): {exc}", pytrace=False)
    pts = np.random.default_rng(1).uniform(-5, 5, (50, 3))
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.full(3, 0.001)
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(str(tmp_path / "a.las"))
    assert np.allclose(read_cloud(tmp_path / "a.las"), pts, atol=0.0005 + 1e-9)  # LAS scale
    (tmp_path / "bad.las").write_bytes(b"LASFxxxx")
    with pytest.raises(HallrayError, match="cannot read bad.las"):
        read_cloud(tmp_path / "bad.las")


def test_millimetre_coordinates_are_refused():
    # a cloud in millimetres: the floor would need a raster of 10^10 cells at 0.1 m
    with pytest.raises(HallrayError, match="are the coordinates in metres"):
        reconstruct(room_cloud(density=30.0) * 1000.0, ScanOptions(voxel_size_m=0.1))


def test_huge_plane_is_refused_not_rasterised():
    # 2 km x 200 m of flat ground at 0.1 m cells would be 4 * 10^7 cells: refused in one line
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(0, 2000, 20_000), rng.uniform(0, 200, 20_000)])
    pts = np.column_stack([pts, rng.normal(0, 0.005, 20_000)])
    with pytest.raises(HallrayError, match="too large for outline cells"):
        reconstruct(pts, ScanOptions(voxel_size_m=0.1))


def test_nonfinite_points_are_dropped_and_counted():
    pts = room_cloud(density=100.0)
    pts[:7] = np.nan
    _, summary = reconstruct(pts, ScanOptions(voxel_size_m=0.05, plane_distance_m=0.02))
    assert summary["nonfinite_points_dropped"] == 7


# ---------------------------------------------------------------------------------------------
# material rules
# ---------------------------------------------------------------------------------------------


def test_material_rules_first_match_wins_and_default():
    rules = MaterialRules.load(
        {
            "materials": {"plastic": {"eta_real": 2.5, "sigma": 0.002, "thickness": 0.004}},
            "rules": [
                {"bounding": True, "material": "concrete"},
                {"kind": "object", "max_top": 0.5, "material": "wood"},
                {"kind": "object", "max_volume": 0.2, "material": "plastic"},
                {"kind": "plane", "orientation": "horizontal", "material": "glass"},
            ],
            "default": "metal",
        }
    )
    base = {
        "kind": "object",
        "bounding": False,
        "orientation": None,
        "floor_to_ceiling": False,
        "area": 1.0,
        "size": 1.0,
        "height": 1.0,
        "top": 1.0,
        "bottom": 0.0,
        "volume": 1.0,
    }
    assert rules.assign({**base, "bounding": True, "kind": "plane"}) == "concrete"
    assert rules.assign({**base, "top": 0.4}) == "wood"
    assert rules.assign({**base, "top": 0.4, "volume": 0.1}) == "wood"  # first match wins
    assert rules.assign({**base, "volume": 0.1}) == "plastic"
    assert rules.assign({**base, "kind": "plane", "orientation": "horizontal"}) == "glass"
    assert rules.assign({**base, "kind": "plane", "orientation": "vertical"}) == "metal"
    assert rules.materials["plastic"]["eta_real"] == 2.5 and "plastic" in rules.library


def test_user_material_names_and_metadata_round_trip(tmp_path):
    rules = tmp_path / "rules.yaml"
    rules.write_text(
        "materials:\n  plastic: {eta_real: 2.5, sigma: 0.002, thickness: 0.004}\n"
        "rules:\n  - {bounding: true, material: concrete}\n"
        "  - {kind: plane, orientation: horizontal, material: plastic}\n"
        "default: wood\n"
    )
    ply = _write_ply(tmp_path / "room.ply", room_cloud())
    out = tmp_path / "room.glb"
    assert scan_to_scene_main([str(ply), "-o", str(out), "--voxel", "0.05",
                               "--plane-distance", "0.02", "--materials", str(rules)]) == 0  # fmt: skip
    scene = load_scene(out)  # plastic comes from the file's metadata
    mats = {o.name: o.material for o in scene.objects}
    assert sum(m == "concrete" for m in mats.values()) == 6
    (top,) = [n for n, m in mats.items() if m == "plastic"]  # the box top, by its rule
    assert re.match(r"^plane_\d\d_plastic$", top)
    obj = next(o for o in scene.objects if o.name == top)
    z = scene.vertices[scene.faces[obj.face_start : obj.face_start + obj.face_count]][..., 2]
    assert np.allclose(z, BOX_HI[2], atol=ROOM_PLANE_TOL_M)
    assert sum(m == "wood" for n, m in mats.items() if n.startswith("plane")) == 4  # box sides


@pytest.mark.parametrize(
    "rules, message",
    [
        ({"rules": [{"material": "unobtainium"}]}, "unknown material 'unobtainium'"),
        ({"rules": [{"colour": "red", "material": "metal"}]}, "unknown condition 'colour'"),
        ({"rules": [{"kind": "tree", "material": "metal"}]}, "kind must be"),
        ({"rules": [{"min_top": "high", "material": "metal"}]}, "min_top must be a number"),
        ({"default": "cheese"}, "default: unknown material"),
        ({"rulez": []}, "unknown key(s) rulez"),
    ],
)
def test_bad_rules_are_one_line_errors(rules, message):
    with pytest.raises(MaterialError, match=re.escape(message)) as exc:
        MaterialRules.load(rules)
    assert "\n" not in str(exc.value)


def test_bad_options_are_refused():
    for opt, message in [
        (ScanOptions(voxel_size_m=0), "voxel size"),
        (ScanOptions(objects="blobs"), "objects must be one of"),
        (ScanOptions(plane_normal_deg=95), "plane normal angle"),
        (ScanOptions(max_planes=0), "max planes"),
    ]:
        with pytest.raises(HallrayError, match=message):
            opt.resolved()


# ---------------------------------------------------------------------------------------------
# the command line: summary, JSON, bad input
# ---------------------------------------------------------------------------------------------


def test_cli_json_summary(tmp_path, capsys):
    ply = _write_ply(tmp_path / "room.ply", room_cloud())
    out = tmp_path / "room.glb"
    argv = [str(ply), "-o", str(out), "--voxel", "0.05", "--plane-distance", "0.02", "--json"]
    assert scan_to_scene_main(argv) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["planes"] == 11 and s["bounding_planes"] == 6 and s["output"] == str(out)
    assert s["triangles"] == len(load_scene(out).faces)
    assert 0 < s["residual_mean_m"] <= s["residual_p95_m"]
    assert set(s["time_s"]) >= {"prepare_s", "planes_s", "objects_s", "total_s"}


EMPTY_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
    "property float z\nend_header\n"
)


def _text(path, text):
    path.write_text(text)
    return path


def _bytes(path, data):
    path.write_bytes(data)
    return path


def _sphere(n=20_000, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: _text(d / "empty.xyz", ""), "has no points"),
        (lambda d: _text(d / "empty.ply", EMPTY_PLY), "has no points"),
        (lambda d: _write_ply(d / "ball.ply", _sphere()), "no plane found"),
        (lambda d: _text(d / "words.xyz", "hello world\nfoo bar\n"), "not a point cloud"),
        (lambda d: _bytes(d / "junk.ply", b"\x00\x01garbage" * 50), "not a PLY file"),
        (lambda d: _bytes(d / "junk.pcd", b"\x00\x01garbage" * 50), "not a PCD point cloud"),
        (lambda d: _bytes(d / "scene.glb", b"glTF"), "unsupported point-cloud format '.glb'"),
        (lambda d: d / "missing.ply", "point cloud not found"),
        (lambda d: _bytes(d / "binary.xyz", bytes(range(256))), "not a text point cloud"),
        (lambda d: _write_ply(d / "few.ply", np.random.default_rng(1).random((20, 3))), "too few"),
    ],
)
def test_bad_input_one_line_error_no_output(make, message, tmp_path, capsys):
    cloud = make(tmp_path)
    out = tmp_path / "out" / "scene.glb"
    out.parent.mkdir()
    assert scan_to_scene_main([str(cloud), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not any(out.parent.iterdir())  # no output, no temporary file


def test_bad_output_and_rules_paths(tmp_path, capsys):
    ply = _write_ply(tmp_path / "room.ply", room_cloud(density=50.0))
    for extra, message in [
        (["-o", str(tmp_path / "scene.obj")], "must end in .glb"),
        (["-o", str(tmp_path / "nodir" / "scene.glb")], "does not exist"),
        (["-o", str(tmp_path / "s.glb"), "--materials", str(tmp_path / "no.yaml")], "not found"),
        (["-o", str(tmp_path / "s.glb"), "--positions", str(tmp_path / "no.yaml")], "not found"),
        (["-o", str(tmp_path / "s.glb"), "--objects", "blobs"], "invalid choice"),
    ]:
        assert scan_to_scene_main([str(ply), *extra]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.ply"]
