"""render-scene: pictures of the right size with the chosen paths, link selection, the
perspective cut-away, and one-line errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, quad

from raytrace.cli.render_scene import render_scene_main
from raytrace.core.palette import FALLBACK_COLORS, MATERIAL_COLORS, material_colors
from raytrace.scene.io import load_scene
from raytrace.solver.config import TraceConfig
from raytrace.solver.tracer import trace
from raytrace.viz.export import KIND_COLOURS
from raytrace.viz.render import _camera_cut, link_paths, render_scene
from raytrace.viz.topview import object_arrays

#: A pixel within this (0..255 per channel) of a path colour counts as that colour.
COLOUR_TOL = 12
#: Pixels of a drawn LoS path: at least this many in a 600 x 400 picture.
MIN_PATH_PIXELS = 40


def _png_size(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.size, im.format


def _pixels_near(path, rgb):
    import matplotlib.image as mpimg

    img = (mpimg.imread(path)[..., :3] * 255).astype(int)
    return int((np.abs(img - np.asarray(rgb)).max(axis=2) <= COLOUR_TOL).sum())


@pytest.fixture
def room_file(tmp_path):
    """A 20 x 10 x 4 m room of concrete sheets, a metal machine and stored positions."""
    s = trimesh.Scene()
    ex, ey, ez = np.eye(3)
    s.add_geometry(quad((0, 0, 0), 20 * ex, 10 * ey), node_name="floor_itu_concrete")
    s.add_geometry(quad((0, 0, 4), 20 * ex, 10 * ey), node_name="ceiling_itu_concrete")
    s.add_geometry(quad((0, 0, 0), 20 * ex, 4 * ez), node_name="wall_s_itu_concrete")
    s.add_geometry(quad((0, 10, 0), 20 * ex, 4 * ez), node_name="wall_n_itu_concrete")
    s.add_geometry(quad((0, 0, 0), 10 * ey, 4 * ez), node_name="wall_w_itu_concrete")
    s.add_geometry(quad((20, 0, 0), 10 * ey, 4 * ez), node_name="wall_e_itu_concrete")
    s.add_geometry(box((9, 3, 0), (11, 7, 2.5)), node_name="machine_itu_metal")
    s.metadata["hallray"] = {
        "name": "room",
        "base_stations": [{"name": "BS1", "xyz": [2.0, 5.0, 3.0]}],
        "points": [{"name": "P1", "xyz": [18.0, 5.0, 1.0]}, {"name": "P2", "xyz": [5.0, 8.0, 1.0]}],
    }
    p = tmp_path / "room.glb"
    p.write_bytes(s.export(file_type="glb"))
    return p


def test_picture_has_the_requested_size_and_the_los_path(room_file, tmp_path, capsys):
    out = tmp_path / "room.png"
    argv = [str(room_file), "-o", str(out), "--link", "BS1,P2", "--size", "600x400", "--dpi", "80"]
    assert render_scene_main(argv) == 0
    assert _png_size(out) == ((600, 400), "PNG")
    assert "BS1 -> P2: first arrival LoS" in capsys.readouterr().out
    green = KIND_COLOURS["los"][:3]
    assert _pixels_near(out, green) >= MIN_PATH_PIXELS
    # BS1 -> P1 is behind the machine: no line-of-sight colour in that picture
    out2 = tmp_path / "room2.png"
    argv2 = [
        str(room_file),
        "-o",
        str(out2),
        "--link",
        "BS1,P1",
        "--size",
        "600x400",
        "--dpi",
        "80",
    ]
    assert render_scene_main(argv2) == 0
    assert _pixels_near(out2, green) == 0
    # and a scene without links has no path colours at all
    out3 = tmp_path / "room3.png"
    assert render_scene_main([str(room_file), "-o", str(out3), "--size", "600x400"]) == 0
    assert all(_pixels_near(out3, c[:3]) == 0 for c in KIND_COLOURS.values())


def test_paths_file_and_link_names(room_file, tmp_path, capsys):
    from raytrace.cli.trace_scene import trace_scene_main

    npz = tmp_path / "paths.npz"
    assert trace_scene_main([str(room_file), "-q", "-o", str(npz)]) == 0
    out = tmp_path / "p.png"
    argv = [str(room_file), "--paths", str(npz), "--link", "BS1,P1", "--link", "0,1"]
    assert render_scene_main([*argv, "-o", str(out), "--size", "800x500", "--max-paths", "3"]) == 0
    text = capsys.readouterr().out
    assert _png_size(out) == ((800, 500), "PNG")
    assert "BS1 -> P1" in text and "BS1 -> P2: first arrival LoS" in text
    assert "2 link(s), 8 paths" in text  # first arrival + 3 strongest others, per link


def test_link_paths_first_arrival_and_strongest(room_file):
    scene = load_scene(room_file)
    tx = np.array([[2.0, 5.0, 3.0]])
    rx = np.array([[18.0, 5.0, 1.0], [5.0, 8.0, 1.0]])
    p = trace(scene, tx, rx, 3.775e9)
    (lk,) = link_paths(p, [1], ["BS1"], ["rx0", "P2"], max_paths=2)
    assert lk.rx_name == "P2" and lk.first == 0 and lk.first_kind == "LoS"
    assert lk.categories[0] == "los" and len(lk.lines) == 3
    assert np.allclose(lk.lines[0], [tx[0], rx[1]])  # the LoS polyline: tx -> rx
    assert lk.first_delay_s == pytest.approx(np.linalg.norm(tx[0] - rx[1]) / 299792458.0)
    # the two others are the strongest of the rest, strongest first
    power = p.power_db[p.link == 1]
    assert lk.strongest_power_db == pytest.approx(power.max())
    (all_paths,) = link_paths(p, [1], ["BS1"], ["rx0", "P2"], max_paths=-1)
    assert len(all_paths.lines) == int((p.link == 1).sum())
    # each polyline starts at tx, ends at rx
    assert all(np.allclose(ln[0], tx[0]) and np.allclose(ln[-1], rx[1]) for ln in all_paths.lines)


def test_cut_away_hides_ceiling_and_the_walls_facing_the_camera():
    ex, ey, ez = np.eye(3)
    objs = [
        ("floor", quad((0, 0, 0), 20 * ex, 10 * ey), "concrete"),
        ("ceiling", quad((0, 0, 4), 20 * ex, 10 * ey), "concrete"),
        ("wall_s", quad((0, 0, 0), 20 * ex, 4 * ez), "concrete"),
        ("wall_n", quad((0, 10, 0), 20 * ex, 4 * ez), "concrete"),
        ("wall_w", quad((0, 0, 0), 10 * ey, 4 * ez), "concrete"),
        ("wall_e", quad((20, 0, 0), 10 * ey, 4 * ez), "concrete"),
        ("machine", box((0.2, 3, 0), (2, 7, 2.5)), "metal"),  # near the west wall, not on it
    ]
    scene = make_scene(objs)
    arrays = object_arrays(scene)
    lo, hi = scene.bounds
    names = scene.object_names

    def hidden(azim):
        return sorted(names[i] for i in _camera_cut(arrays, lo, hi, azim))

    assert hidden(-125.0) == ["ceiling", "wall_s", "wall_w"]  # camera south-west
    assert hidden(45.0) == ["ceiling", "wall_e", "wall_n"]  # camera north-east


def test_render_scene_library_call_on_the_hall(tmp_path):
    scene = load_scene("hall")
    meta = scene.metadata["hallray"]
    bs = np.array([b["xyz"] for b in meta["base_stations"]])
    pts = np.array([p["xyz"] for p in meta["points"]])
    p = trace(scene, bs[:1], pts[6:7], 3.775e9, TraceConfig(max_diffractions=0))  # BS1 -> P07
    links = link_paths(p, [0], ["BS1"], ["P07"], max_paths=4)
    info = render_scene(scene, tmp_path / "hall.png", links=links, size_px=(900, 450), dpi=72)
    assert info["size_px"] == [900, 450] and info["paths_drawn"] == 5
    # the ceiling and the south and west walls are cut away from the south-west view
    assert info["objects_drawn"] == len(scene.objects) - 3
    assert _png_size(tmp_path / "hall.png") == ((900, 450), "PNG")


@pytest.mark.parametrize(
    "args, message",
    [
        (["{scene}", "-o", "{tmp}/x.jpg"], "must end in .png"),
        (["{scene}", "-o", "{tmp}/nodir/x.png"], "does not exist"),
        (["{tmp}/nothing.glb", "-o", "{tmp}/x.png"], "scene file not found"),
        (["{scene}", "-o", "{tmp}/x.png", "--link", "BS9,P1"], "not a known name"),
        (["{scene}", "-o", "{tmp}/x.png", "--link", "BS1"], "expects TX,RX"),
        (["{scene}", "-o", "{tmp}/x.png", "--paths", "{tmp}/none.npz"], "paths file not found"),
        (["{scene}", "-o", "{tmp}/x.png", "--paths", "{tmp}/far.npz"], "does not belong"),
        (["{scene}", "-o", "{tmp}/x.png", "--tx", "1,1,1"], "add --link"),
        (["{scene}", "-o", "{tmp}/x.png", "--size", "big"], "expected WIDTHxHEIGHT"),
        (["{scene}", "-o", "{tmp}/x.png", "--size", "20x20"], "picture size must be"),
        (["{scene}", "-o", "{tmp}/x.png", "--link", "0,0", "--tx", "50000,5,1"], "outside"),
        (["{scene}", "-o", "{tmp}/x.png", "--dpi", "5"], "--dpi must be"),
        (["{scene}", "-o", "{tmp}/x.png", "--bogus"], "unrecognized arguments"),
    ],
)
def test_bad_input_one_line_error(room_file, tmp_path, capsys, args, message):
    # a paths file traced in a different place (positions far outside the room)
    far = make_scene([("floor", quad((100, 100, 0), (20, 0, 0), (0, 20, 0)), "concrete")])
    trace(far, np.array([[105.0, 105, 2]]), np.array([[110.0, 110, 1]]), 3.775e9).save(
        tmp_path / "far.npz"
    )
    argv = [a.format(scene=room_file, tmp=tmp_path) for a in args]
    assert render_scene_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not list(tmp_path.glob("*.png")) and not list(tmp_path.glob(".*.tmp"))


def test_palette_named_colours_and_fallbacks_in_turn():
    """material_colors: a named material keeps its colour whatever else is in the scene; the
    others get the fallback colours in their sorted order, independent of order and repeats."""
    got = material_colors(["wet_ground", "metal", "foam", "metal", "aerogel"])
    assert got["metal"] == MATERIAL_COLORS["metal"]
    assert [got[m] for m in ("aerogel", "foam", "wet_ground")] == list(FALLBACK_COLORS[:3])
    assert material_colors(reversed(list(got))) == got
    many = material_colors(f"m{k}" for k in range(len(FALLBACK_COLORS) + 1))
    assert many[f"m{len(FALLBACK_COLORS)}"] == FALLBACK_COLORS[0]  # the fallbacks repeat
    assert all(0.0 <= c <= 1.0 for rgb in got.values() for c in rgb)
