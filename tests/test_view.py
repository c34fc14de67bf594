"""The interactive view (raytrace.viz.interactive, hallray-view): what the figure holds (objects by
material, a see-through shell, labelled positions, paths by kind with the first arrival bold and
hover texts that agree with closed forms), decimation, the accuracy map, one-line errors without
a file, and the page in a real headless browser (Chromium): no console errors, no network, the
expected traces rendered, a picture that is not blank."""

from __future__ import annotations

import json
import math
import shutil
import subprocess

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, quad

from raytrace.cli.view import view_main
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.scene.io import load_scene
from raytrace.solver.paths import Paths
from raytrace.solver.tracer import trace
from raytrace.viz import preview, view_html
from raytrace.viz.interactive import (
    SHELL_OPACITY,
    VIEW_KIND_COLOURS,
    cluster_decimate,
    interaction_text,
    object_roles,
    scene_traces,
    view_category,
)

#: Hover texts print delays in ns with 3 decimals and power in dB with 1.
DELAY_TEXT_TOL_NS = 0.0005
POWER_TEXT_TOL_DB = 0.05
#: A page picture is not blank: grey-level standard deviation and distinct colours at least.
MIN_PIXEL_STD = 20.0
MIN_COLOURS = 200
#: Seconds the headless browser may take to load, lay out and draw the page.
BROWSER_TIMEOUT_S = 180


def _room():
    """A 20 x 16 x 6 m room (floor and ceiling slabs, four walls) with a metal box inside and a
    base station and two points in its metadata."""
    lib = None
    objs = [
        ("floor", box([0, 0, -0.2], [20, 16, 0]), "concrete"),
        ("ceiling", box([0, 0, 6], [20, 16, 6.2]), "concrete"),
        ("wall_s", box([0, -0.2, 0], [20, 0, 6]), "concrete"),
        ("wall_n", box([0, 16, 0], [20, 16.2, 6]), "concrete"),
        ("wall_w", box([-0.2, 0, 0], [0, 16, 6]), "brick"),
        ("wall_e", box([20, 0, 0], [20.2, 16, 6]), "brick"),
        ("machine", box([9, 6, 0], [11, 10, 2.5]), "metal"),
        ("pane", quad([4, 12, 0], [3, 0, 0], [0, 0, 2]), "glass"),
    ]
    scene = make_scene(objs, lib)
    scene.metadata = {"hallray": {
        "name": "test_room",
        "base_stations": [{"name": "BS1", "xyz": [2.0, 2.0, 4.0]}],
        "points": [{"name": "P1", "xyz": [18.0, 3.0, 1.0]}, {"name": "P2", "xyz": [15.0, 8.0, 1.0]}],
    }}  # fmt: skip
    return scene


@pytest.fixture(scope="module")
def room():
    return _room()


@pytest.fixture
def room_file(tmp_path):
    """The room as a GLB with its metadata, for the command."""
    scene = _room()
    out = trimesh.Scene()
    for o in scene.objects:
        f = scene.faces[o.face_start : o.face_start + o.face_count]
        used, inv = np.unique(f, return_inverse=True)
        name = f"{o.name}_itu_{o.material}"
        out.add_geometry(trimesh.Trimesh(scene.vertices[used], inv.reshape(-1, 3)),
                         node_name=name, geom_name=name)  # fmt: skip
    out.metadata["hallray"] = scene.metadata["hallray"]
    path = tmp_path / "room.glb"
    out.export(path)
    return path


def _trace_names(fig) -> list[str]:
    return [t.name for t in fig.data]


def test_roles_shell_and_solids(room):
    roles = dict(zip(room.object_names, object_roles(room)))
    assert roles == {"floor": "floor", "ceiling": "ceiling", "wall_s": "wall", "wall_n": "wall",
                     "wall_w": "wall", "wall_e": "wall", "machine": "solid", "pane": "solid"}  # fmt: skip


def test_scene_drawn_by_material_with_a_see_through_shell(room):
    fig = preview(room)
    meshes = [t for t in fig.data if t.type == "mesh3d"]
    # one legend entry per material, every triangle drawn once
    shown = sorted(t.name for t in meshes if t.showlegend)
    assert shown == sorted(m.replace("_", " ") for m in room.material_names)
    assert sum(len(t.i) for t in meshes) == len(room.faces)
    for t in meshes:
        assert t.legendgroup == f"material:{t.name.replace(' ', '_')}"
    walls = [t for t in meshes if t.name == "brick"]
    assert walls and all(t.opacity == SHELL_OPACITY["wall"] < 1 for t in walls)
    metal = [t for t in meshes if t.name == "metal"]
    assert [t.opacity for t in metal] == [1.0]
    # hovering a face names its object
    assert set(metal[0].text) == {"machine"}
    sites = {t.name: t for t in fig.data if t.type == "scatter3d"}
    assert list(sites["base stations"].text) == ["BS1"]
    assert list(sites["points"].text) == ["P1", "P2"]
    assert fig.layout.meta["paths"] == 0 and fig.layout.meta["decimation_m"] == 0


def test_scene_without_positions_still_draws(room):
    bare = make_scene([("floor", quad([0, 0, 0], [5, 0, 0], [0, 5, 0]), "concrete")])
    fig = preview(bare)
    assert [t.type for t in fig.data] == ["mesh3d"]


def _hand_paths() -> Paths:
    """Five paths of one link with known interaction sequences: LoS, R, T, D, R then D."""
    seq = [[0, 0], [1, 0], [2, 0], [3, 0], [1, 3]]
    inter = np.array(seq, dtype=np.int8)
    n = len(seq)
    pts = np.full((n, 2, 3), np.nan)
    pts[inter > 0] = [5.0, 5.0, 1.0]
    objs = np.where(inter > 0, np.array([[6, 0]] * n) + np.array([0, 7]) * (inter > 0), -1)
    objs[4] = [2, 6]
    return Paths(
        tx=np.array([[2.0, 2.0, 4.0]]), rx=np.array([[18.0, 3.0, 1.0]]), frequency_hz=3.5e9,
        link=np.zeros(n, np.int64), tx_index=np.zeros(n, np.int64), rx_index=np.zeros(n, np.int64),
        delay_s=np.linspace(70e-9, 90e-9, n), gain=np.full(n, 1e-4 + 0j),
        n_reflections=(inter == 1).sum(1).astype(np.int16),
        n_penetrations=(inter == 2).sum(1).astype(np.int16),
        n_diffractions=(inter == 3).sum(1).astype(np.int16),
        interaction=inter, points=pts, objects=objs.astype(np.int64),
        elements=np.full((n, 2), -1, np.int64),
    )  # fmt: skip


def test_categories_and_interaction_sequences(room):
    p = _hand_paths()
    assert list(view_category(p)) == ["los", "reflection", "penetration", "diffraction", "mixed"]
    names = room.object_names
    assert interaction_text(p, 0, names) == "LoS"
    assert interaction_text(p, 1, names) == "R(machine)"
    assert interaction_text(p, 4, names) == "R(wall_s) D(machine)"
    fig = preview(room, p)
    lines = {t.name: t for t in fig.data if t.type == "scatter3d" and t.mode == "lines"}
    assert set(lines) == {"line of sight (first arrival)", "reflection", "penetration",
                          "diffraction", "mixed"}  # fmt: skip
    for cat, colour in VIEW_KIND_COLOURS.items():
        t = next(t for t in lines.values() if t.legendgroup == f"kind:{cat}")
        assert t.line.color == "rgb({},{},{})".format(*colour)
    assert lines["line of sight (first arrival)"].line.width > lines["reflection"].line.width


def test_hover_texts_match_the_closed_form_of_a_line_of_sight_link(room):
    tx, rx = np.array([[2.0, 2.0, 4.0]]), np.array([[18.0, 3.0, 1.0]])
    f = 3.5e9
    paths = trace(room, tx, rx, f)
    fig = preview(room, paths, ["BS1,P1"], max_paths=-1)
    first = next(t for t in fig.data if t.name == "line of sight (first arrival)")
    text = first.text[0]
    d = float(np.linalg.norm(rx - tx))
    delay_ns = float(text.split("delay ")[1].split(" ns")[0])
    excess_ns = float(text.split("excess ")[1].split(" ns")[0])
    power_db = float(text.split("power ")[1].split(" dB")[0])
    assert abs(delay_ns - d / C0 * 1e9) <= DELAY_TEXT_TOL_NS
    assert abs(excess_ns) <= DELAY_TEXT_TOL_NS
    lam = C0 / f
    assert abs(power_db - 20 * math.log10(lam / (4 * math.pi * d))) <= POWER_TEXT_TOL_DB
    assert "BS1 \u2192 P1" in text and "LoS" in text
    # every drawn path's hover: its sequence names objects of the scene
    drawn = sum(1 for t in fig.data if t.type == "scatter3d" and t.mode == "lines"
                for s in t.text if s is not None and "delay" in s)  # fmt: skip
    assert drawn >= paths.n_paths  # hover points along every path
    seqs = {s.split("<br>")[1] for t in fig.data if t.type == "scatter3d" and t.mode == "lines"
            for s in t.text if s}  # fmt: skip
    for seq in seqs - {"LoS"}:
        for part in seq.split():
            assert part[0] in "RTD" and part[2:-1] in room.object_names
    assert fig.layout.meta["paths"] == paths.n_paths


def test_links_choose_what_is_drawn(room):
    tx = np.array([[2.0, 2.0, 4.0]])
    rx = np.array([[18.0, 3.0, 1.0], [15.0, 8.0, 1.0]])
    paths = trace(room, tx, rx, 3.5e9)
    fig = preview(room, paths, ["BS1,P2"], max_paths=0)
    assert fig.layout.meta["links"] == 1 and fig.layout.meta["paths"] == 1
    assert preview(room, paths, max_paths=2).layout.meta["links"] == 2
    with pytest.raises(HallrayError, match="'P9' is not a known name"):
        preview(room, paths, ["BS1,P9"])


def test_decimation_keeps_the_budget_and_the_shape():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=3.0)  # 20480 triangles
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    v2, f2 = cluster_decimate(v, f, 0.5)
    assert 0 < len(f2) < len(f) / 4
    r = np.linalg.norm(v2, axis=1)
    assert r.max() <= 3.0 + 1e-9 and r.min() > 3.0 - 0.5  # merged vertices stay near the surface
    small = trimesh.creation.icosphere(subdivisions=3, radius=3.0)  # 1280 triangles
    scene = make_scene([("ball", small, "metal")])
    traces, info = scene_traces(scene, max_triangles=300)
    assert 0 < info["triangles"] <= 300 < info["triangles_in_scene"] == len(small.faces)
    assert info["decimation_m"] > 0
    assert sum(len(t.i) for t in traces) == info["triangles"]


def _fake_map(scene, sha=None):
    from positioning.twin.fingerprint import FingerprintMap

    xs, ys = np.meshgrid(np.arange(1.0, 20.0, 2.0), np.arange(1.0, 16.0, 2.0))
    cells = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.0)])
    n = len(cells)
    err = np.linspace(0.005, 30.0, n)
    return FingerprintMap(
        cell_xyz=cells, bs_xyz=np.array([[2.0, 2.0, 4.0]]), bs_names=np.array(["BS1"]),
        los=np.ones((n, 1), bool), first_kind=np.full((n, 1), "LoS"),
        excess_m=np.zeros((n, 1)), toa_s=np.zeros((n, 1)), toa_std_s=np.zeros((n, 1)),
        detected_fraction=np.ones((n, 1)), gdop=np.linspace(1, 5, n), methods=np.array(["ls"]),
        err_p90_m=err[None], err_mean_m=err[None] / 2, availability=np.ones((1, n)),
        meta={"step_m": 2.0, "scene_sha256": sha or scene.content_hash()},
    )  # fmt: skip


def test_accuracy_map_cells_on_the_floor_with_a_menu(room):
    fmap = _fake_map(room)
    fig = preview(room, accuracy_map=fmap)
    cells = [t for t in fig.data if t.name == "accuracy map"]
    assert len(cells) == 5  # p90, mean, GDOP, LoS count, availability
    assert [t.visible for t in cells] == [True] + [False] * 4
    assert len(cells[0].i) == 2 * fmap.n_cells and cells[0].intensitymode == "cell"
    z = np.asarray(cells[0].z)
    assert np.all((z > 0) & (z < 0.1))  # just above the floor's top at z = 0
    # errors on a log scale from 1 cm: the colour of a 30 m cell is log10(30)
    assert np.nanmax(cells[0].intensity) == pytest.approx(math.log10(30.0))
    assert np.nanmin(cells[0].intensity) == pytest.approx(-2.0)
    buttons = fig.layout.updatemenus[0].buttons
    assert [b.label for b in buttons][0].startswith("p90 2D error")
    with pytest.raises(HallrayError, match="another scene"):
        preview(room, accuracy_map=_fake_map(room, sha="0" * 64))


def test_page_is_self_contained(room):
    html = view_html(preview(room))
    assert len(html) > 3_000_000  # plotly's JavaScript is in the page
    assert 'src="http' not in html and "cdn.plot.ly" not in html.split("<body>")[1][:2000]


# -- the command -------------------------------------------------------------------------------
def test_command_draws_the_scene_without_tracing(room_file, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert view_main([str(room_file), "-o", str(out), "-q"]) == 0
    html = out.read_text()
    assert '"name":"metal"' in html.replace(" ", "") and "BS1" in html
    assert capsys.readouterr().out == ""


def test_command_traces_links_and_reads_paths(room_file, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert view_main([str(room_file), "--link", "BS1,P1", "--link", "BS1,P2", "-o", str(out)]) == 0
    msg = capsys.readouterr().out
    assert "2 link(s)" in msg and "MB" in msg
    scene = load_scene(room_file)
    paths = trace(scene, np.array([[2.0, 2.0, 4.0]]), np.array([[18.0, 3.0, 1.0],
                                                                [15.0, 8.0, 1.0]]), 3.5e9)  # fmt: skip
    paths.save(tmp_path / "p.npz")
    out2 = tmp_path / "v2.html"
    assert view_main([str(room_file), "--paths", str(tmp_path / "p.npz"), "--link", "BS1,P2",
                      "--max-paths", "-1", "-o", str(out2)]) == 0  # fmt: skip
    assert f"{int((paths.link == 1).sum())} paths" in capsys.readouterr().out


def _save_with_hash(paths, path, sha):
    data = {k: getattr(paths, k) for k in paths.PER_PATH}
    np.savez(path, format_version=1, frequency_hz=paths.frequency_hz, tx=paths.tx, rx=paths.rx,
             scene_sha256=np.array(sha), **data)  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--paths", "{d}/none.npz"], "paths file not found"),
        (["--paths", "{d}/far.npz"], "does not belong to this scene"),
        (["--paths", "{d}/other.npz"], "traced in another scene"),
        (["--link", "BS1,P9"], "'P9' is not a known name"),
        (["--link", "BS1"], "TX,RX"),
        (["--map", "{d}"], "no accuracy map there"),
        (["--max-triangles", "5"], "at least 100"),
        (["--tx", "1,1,1"], "add --link"),
    ],
)
def test_bad_input_one_line_error_and_no_file(room_file, tmp_path, capsys, extra, message):
    scene = load_scene(room_file)
    tx, rx = np.array([[2.0, 2.0, 4.0]]), np.array([[18.0, 3.0, 1.0]])
    paths = trace(scene, tx, rx, 3.5e9)
    far = trace(scene, tx + [0, 0, 0], rx, 3.5e9)
    far.rx = far.rx + 500.0
    far.save(tmp_path / "far.npz")
    _save_with_hash(paths, tmp_path / "other.npz", "f" * 64)
    out = tmp_path / "v.html"
    argv = [str(room_file), *[a.replace("{d}", str(tmp_path)) for a in extra], "-o", str(out)]
    assert view_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not out.exists() and not list(tmp_path.glob(".v.html*"))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["missing.glb", "-o", "{d}/v.html"], "scene file not found"),
        (["hall", "-o", "{d}/v.png"], "must end in .html"),
        (["hall", "-o", "{d}/no/v.html"], "does not exist"),
    ],
)
def test_bad_scene_or_output(tmp_path, capsys, argv, message):
    assert view_main([a.replace("{d}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def test_paths_with_the_right_scene_hash_are_drawn(room_file, tmp_path):
    scene = load_scene(room_file)
    paths = trace(scene, np.array([[2.0, 2.0, 4.0]]), np.array([[18.0, 3.0, 1.0]]), 3.5e9)
    _save_with_hash(paths, tmp_path / "ok.npz", scene.content_hash())
    assert view_main([str(room_file), "--paths", str(tmp_path / "ok.npz"), "-q",
                      "-o", str(tmp_path / "v.html")]) == 0  # fmt: skip


# -- in a real browser -------------------------------------------------------------------------
def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


#: Appended to a copy of the page: collects uncaught errors and console.error calls, then after
#: the page settled writes what it rendered into <pre id="probe"> for --dump-dom.
PROBE = """<script>
window.__errors = [];
window.addEventListener('error', function (e) { window.__errors.push(String(e.message)); });
var __err = console.error;
console.error = function () { window.__errors.push(Array.from(arguments).join(' '));
                              __err.apply(console, arguments); };
setTimeout(function () {
  var gd = document.querySelector('.plotly-graph-div');
  var out = {errors: window.__errors,
             traces: gd && gd.data ? gd.data.map(function (t) { return t.name; }) : null,
             gl: document.querySelectorAll('.gl-container canvas').length,
             legend: Array.from(document.querySelectorAll('.legendtext'))
                          .map(function (e) { return e.textContent; }),
             resources: performance.getEntriesByType('resource').map(function (e) { return e.name; })};
  var pre = document.createElement('pre'); pre.id = 'probe';
  pre.textContent = JSON.stringify(out); document.body.appendChild(pre);
}, 3000);
</script>"""


def _browser(chromium: str, page, tmp_path, *args: str) -> subprocess.CompletedProcess:
    """Headless Chromium on a local page, no network (every host name unresolvable), software
    WebGL."""
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
           "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--host-resolver-rules=MAP * ~NOTFOUND", f"--user-data-dir={tmp_path / 'profile'}",
           "--window-size=1400,1000", "--hide-scrollbars", "--virtual-time-budget=10000",
           *args, page.as_uri()]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S)


def test_page_in_a_headless_browser(tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("Chromium is not installed (apt-get install chromium): this test opens the "
                    "view in a real headless browser; CI installs it")  # fmt: skip
    out = tmp_path / "view.html"
    argv = ["hall", "--link", "BS1,P07", "--link", "BS3,P23", "--link", "BS2,P06", "-q",
            "-o", str(out)]  # fmt: skip
    assert view_main(argv) == 0
    probe = tmp_path / "probe.html"
    probe.write_text(out.read_text().replace("</body>", PROBE + "</body>"))
    shot = tmp_path / "shot.png"
    run = _browser(chromium, probe, tmp_path, "--dump-dom", f"--screenshot={shot}")
    assert run.returncode == 0 and shot.is_file(), run.stderr[-2000:]
    text = run.stdout.split('<pre id="probe">')[1].split("</pre>")[0]
    found = json.loads(text.replace("&quot;", '"').replace("&amp;", "&"))
    assert found["errors"] == []
    assert found["resources"] == []  # nothing fetched: the page works offline
    assert found["gl"] >= 1  # the WebGL scene was created
    for name in ("concrete", "metal", "plastic", "base stations", "points",
                 "line of sight (first arrival)", "reflection", "diffraction (first arrival)"):  # fmt: skip
        assert name in found["traces"] and name in found["legend"], name
    from PIL import Image

    with Image.open(shot) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=float)
    assert rgb.std(axis=(0, 1)).mean() >= MIN_PIXEL_STD
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) >= MIN_COLOURS
    # the hall's concrete grey and the base stations' gold are on the picture
    for colour in ((158, 158, 153), (255, 215, 0)):
        near = np.abs(rgb - np.array(colour)).max(axis=2) <= 40
        assert near.sum() >= 50, colour
