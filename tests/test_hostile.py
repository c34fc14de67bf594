"""Issue 40, the hostile-input audit: inputs are never destroyed, absurd sizes are refused before
any work, YAML and JSON are read strictly, and the Python API keeps the commands' promises. Each
test runs a case of the issue (docs/reliability.md, the second case table) and fails without its
fix: through the command line (exit status, one-line message, the files afterwards) or through
the library call the issue names."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from pos_synth import PAPER_BS, write_dataset

from positioning.cli.accuracy import accuracy_report_main
from positioning.cli.estimate import estimate_positions_main
from raytrace.cli.accuracy_map import accuracy_map_main
from raytrace.cli.make_dataset import make_dataset_main
from raytrace.cli.make_hall import hall_los_check_main, make_hall_main
from raytrace.cli.trace_scene import trace_scene_main

ROOT = Path(__file__).resolve().parents[1]
POINTS = np.array([[5.0, 5.0, 1.5], [20.0, 8.0, 1.5], [12.0, 18.0, 1.5]])


@pytest.fixture()
def ds(tmp_path):
    return write_dataset(tmp_path / "ds", points=POINTS, n_epochs=3)


def _line(capsys) -> str:
    """The one ``error:`` line of a refused command (and no traceback)."""
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, err
    return lines[0]


# -- inputs are sacred ----------------------------------------------------------------------------
def test_estimate_never_writes_over_its_map(ds, tmp_path, capsys):
    m = tmp_path / "m.npz"
    m.write_bytes(b"the user's map")
    argv = [str(ds), "--method", "twin", "--map", str(m), "-o", str(m)]
    assert estimate_positions_main(argv) == 2
    assert "is an input of this command" in _line(capsys)
    assert m.read_bytes() == b"the user's map"
    # a map given as a method parameter is an input too
    argv = [str(ds), "--method", "twin", "--param", f"twin:map={m}", "-o", str(m)]
    assert estimate_positions_main(argv) == 2
    assert m.read_bytes() == b"the user's map"


def test_report_never_replaces_the_directory_of_its_map(ds, tmp_path, capsys):
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "map.npz").write_bytes(b"map")
    argv = [str(ds), "--methods", "ls", "--map", str(rep / "map.npz"), "-o", str(rep)]
    assert accuracy_report_main(argv) == 2
    assert "contains an input of this command" in _line(capsys)
    assert (rep / "map.npz").read_bytes() == b"map"


def test_accuracy_map_force_never_deletes_its_scene_or_materials(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    scene = out / "hall.yaml"
    scene.write_bytes((ROOT / "scenes" / "hall.yaml").read_bytes())
    assert accuracy_map_main([str(scene), "--force", "-q", "-o", str(out)]) == 2
    assert "contains an input of this command" in _line(capsys)
    assert scene.read_bytes() == (ROOT / "scenes" / "hall.yaml").read_bytes()
    mats = out / "mats.yaml"
    mats.write_text("materials: {}\n")
    argv = ["hall", "--materials", str(mats), "--force", "-q", "-o", str(out)]
    assert accuracy_map_main(argv) == 2
    assert "contains an input" in _line(capsys)
    assert mats.read_text() == "materials: {}\n"


def test_force_never_replaces_the_working_directory_or_its_ancestors(tmp_path, capsys, monkeypatch):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    (work / "thesis.tex").write_text("keep")
    monkeypatch.chdir(work)
    base = ["--scenario", "static", "--band", "c-band", "--duration", "0.1", "--force", "-q"]
    for out in (work, tmp_path / "a", tmp_path):
        assert make_dataset_main([*base, "-o", str(out)]) == 2
        assert "the working directory" in _line(capsys)
    assert (work / "thesis.tex").read_text() == "keep"


def test_force_never_touches_the_installed_package():
    """Checked on the rule itself, never through a command: a regression must not wipe the
    package it tests (a run of this case through make-dataset on the tree before issue 40 did)."""
    import raytrace
    from hallray.safe_output import OutputError, check_output, check_output_dir

    pkg = Path(raytrace.__file__).resolve().parent
    for out in (pkg, pkg / "scratch", pkg.parent / "scenes"):
        with pytest.raises(OutputError, match="installed package"):
            check_output_dir(out, command="make-dataset", force=True)
    with pytest.raises(OutputError, match="installed package"):
        check_output(pkg / "cli" / "fixes.csv")
    assert (pkg / "__init__.py").is_file() and not (pkg / "scratch").exists()


def test_force_replaces_only_an_earlier_output_of_the_same_command(tmp_path, capsys):
    from hallray.safe_output import MARKER

    out = tmp_path / "out"
    assert make_hall_main(["--profile", "InF-SL", "--size", "20x20x6", "--points", "3",
                           "-o", str(out)]) == 0  # fmt: skip
    assert (out / MARKER).is_file()
    base = ["--scenario", "static", "--band", "c-band", "--duration", "0.1", "--force", "-q"]
    assert make_dataset_main([*base, "-o", str(out)]) == 2
    assert "was written by make-hall, not make-dataset" in _line(capsys)
    assert (out / "hall.yaml").is_file()


def test_make_hall_never_deletes_a_users_file(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert make_hall_main(["--profile", "InF-SL", "--size", "20x20x6", "-o", str(out)]) == 2
    line = _line(capsys)
    assert "not empty" in line and "--force" not in line  # make-hall has no --force
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    # its own earlier output is replaced, but not once the user put a file into it
    out2 = tmp_path / "out2"
    argv = ["--profile", "InF-SL", "--size", "20x20x6", "--points", "3", "-o", str(out2)]
    assert make_hall_main(argv) == 0
    assert make_hall_main(argv) == 0
    capsys.readouterr()
    (out2 / "notes.txt").write_text("mine")
    assert make_hall_main(argv) == 2
    assert "holds files make-hall did not write (notes.txt)" in _line(capsys)
    assert (out2 / "notes.txt").read_text() == "mine"


def test_symlink_loop_is_not_replaced(ds, tmp_path, capsys):
    loop = tmp_path / "loop.csv"
    loop.symlink_to(loop.name)
    assert estimate_positions_main([str(ds), "-o", str(loop)]) == 2
    assert "symlink loop" in _line(capsys)
    assert loop.is_symlink()


def test_export_glb_must_be_glb(tmp_path, capsys):
    out = tmp_path / "x.obj"
    argv = ["hall", "--tx", "10,10,3", "--rx", "20,20,1.5", "--export-glb", str(out)]
    assert trace_scene_main(argv) == 2
    assert "name it .glb" in _line(capsys)
    assert not out.exists()


def test_sweep_never_writes_into_a_dataset(ds, tmp_path, capsys):
    from raytrace.cli.run_sweep import run_sweep_main

    cfg = tmp_path / "s.yaml"
    cfg.write_text(
        "grid: {seed: [0]}\nfixed: {profile: InF-SL, size: 20x20x6, n_points: 3, "
        "duration_s: 0.2}\nmethods: [ls]\n"
    )
    before = sorted(p.name for p in ds.iterdir())
    assert run_sweep_main([str(cfg), "-o", str(ds)]) == 2
    assert "choose another -o" in _line(capsys)
    assert sorted(p.name for p in ds.iterdir()) == before


# -- sizes are checked before any work --------------------------------------------------------------
@pytest.mark.parametrize(
    "argv, what",
    [
        (["--duration", "1e9"], "epochs"),
        (["--duration", "1e6", "--rate", "1000"], "epochs"),
    ],
)
def test_absurd_epochs_are_refused_up_front(tmp_path, capsys, argv, what):
    t0 = time.perf_counter()
    base = ["--scenario", "static", "--band", "c-band", "-q", "-o", str(tmp_path / "o")]
    assert make_dataset_main([*base, *argv]) == 2
    line = _line(capsys)
    assert what in line and "above the limit" in line and "HALLRAY_NO_LIMITS=1" in line
    assert "days" in line or "years" in line or "h" in line  # the estimate
    assert time.perf_counter() - t0 < 20 and not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "argv, what",
    [
        (["--draws", "1000000000"], "draws per cell"),
        # paths are stored for the receiver the twin re-synthesises (not the default's)
        (["--paths", "1000000", "--receiver", "first-lobe"], "paths per link"),
    ],
)
def test_absurd_map_counts_are_refused_up_front(tmp_path, capsys, argv, what):
    assert accuracy_map_main(["hall", *argv, "-q", "-o", str(tmp_path / "m")]) == 2
    assert what in _line(capsys)
    assert not (tmp_path / "m").exists()


def test_make_hall_points_and_bs_grid_are_bounded(tmp_path, capsys):
    base = ["--profile", "InF-SL", "--size", "100x100x8", "-o", str(tmp_path / "h")]
    assert make_hall_main([*base, "--points", "100000000"]) == 2
    assert "points" in _line(capsys)
    assert make_hall_main([*base, "--bs-grid", "2000x2000"]) == 2
    assert "base stations" in _line(capsys)
    assert not (tmp_path / "h").exists()


def test_los_check_seeds_are_bounded(capsys):
    t0 = time.perf_counter()
    assert hall_los_check_main(["InF-SL", "--seeds", "100000000"]) == 2
    assert "halls" in _line(capsys) and time.perf_counter() - t0 < 20


def test_hall_yaml_repeat_is_bounded_before_expansion(capsys):
    from hallray.errors import InputError
    from raytrace.halls.spec import load_hall_spec

    spec = {
        "schema_version": 1,
        "hall": {"size": [100.0, 100.0, 8.0]},
        "objects": [{"name": "rack_{i}", "type": "box", "min": [1.0, 1.0, 0.0],
                     "size": [0.1, 0.1, 1.0],
                     "repeat": {"count": [100000, 100000], "step": [[0.0, 0.0], [0.0, 0.0]]}}],
    }  # fmt: skip
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="above the limit"):
        load_hall_spec(spec)
    assert time.perf_counter() - t0 < 5
    spec["objects"] = [{"name": "pillar", "type": "cylinder", "material": "metal",
                        "base": [50.0, 50.0, 0.0], "radius": 1.0, "height": 8.0,
                        "sections": 10**9}]  # fmt: skip
    with pytest.raises(InputError, match="sides|above the limit"):
        load_hall_spec(spec)


def test_sweep_grid_is_bounded(tmp_path):
    from hallray.errors import InputError
    from raytrace.studies.sweep.config import parse_sweep_config

    data = {"grid": {"seed": list(range(1000)), "n_points": list(range(1, 1001))},
            "fixed": {"profile": "InF-SL"}, "methods": ["ls"]}  # fmt: skip
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="cells"):
        parse_sweep_config(data)
    assert time.perf_counter() - t0 < 5
    data = {"grid": {"seed": [0]}, "fixed": {"profile": "InF-SL", "n_points": 10**9},
            "methods": ["ls"]}  # fmt: skip
    with pytest.raises(InputError, match="points"):
        parse_sweep_config(data)


def test_limits_can_be_overridden(monkeypatch):
    from hallray.limits import OVERRIDE_ENV, SizeError, check_size

    with pytest.raises(SizeError, match="epochs"):
        check_size("epochs", 10**7, "--duration")
    monkeypatch.setenv(OVERRIDE_ENV, "1")
    check_size("epochs", 10**7, "--duration")


def test_service_area_grid_is_bounded_by_memory():
    from positioning.model.area import MAX_GRID_POINTS, ServiceArea
    from positioning.model.scale import ScaleError

    big = ServiceArea(np.array([[0.0, 0.0], [4200.0, 0.0], [4200.0, 4200.0], [0.0, 4200.0]]))
    g = big.grid(1.0)
    assert 0.5 * MAX_GRID_POINTS <= len(g) <= MAX_GRID_POINTS
    assert len(big.outline(0.01)) <= MAX_GRID_POINTS + 4
    small = ServiceArea(np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0]]))
    assert len(small.grid(1.0)) == 40 * 30  # a hall's grid is untouched
    with pytest.raises(ScaleError, match="millimetres"):
        ServiceArea(np.array([[0.0, 0.0], [40000.0, 0.0], [40000.0, 30000.0], [0.0, 30000.0]]))


# -- YAML and JSON are read strictly --------------------------------------------------------------
def test_yaml_alias_chain_is_refused_without_expanding_it(tmp_path, capsys):
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, "
              f"*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]" for i in range(1, 10)]  # fmt: skip
    lines += ["materials: *a9"]
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(lines) + "\n")
    t0 = time.perf_counter()
    argv = ["hall", "--materials", str(bomb), "--tx", "10,10,3", "--rx", "20,20,1.5"]
    assert trace_scene_main(argv) == 2
    line = _line(capsys)
    assert "aliases expand to more than" in line and len(line) < 400
    assert time.perf_counter() - t0 < 20


def test_yaml_duplicate_keys_are_refused(tmp_path):
    from raytrace.core.errors import HallrayError
    from raytrace.core.fileio import read_yaml

    f = tmp_path / "d.yaml"
    f.write_text("materials:\n  mine: {eta_real: 3}\nmaterials:\n  mine: {eta_real: 5}\n")
    with pytest.raises(HallrayError, match="given twice"):
        read_yaml(f, "materials")
    f.write_text("base: &b {x: 1}\nother:\n  <<: *b\n  x: 2\n")  # a merge key may be overridden
    assert read_yaml(f, "x")["other"]["x"] == 2


def test_case_duplicate_material_names_are_refused():
    from raytrace.core.errors import MaterialError
    from raytrace.physics.materials import MaterialLibrary

    entry = {"eta_real": 5.0, "sigma": 0.1}
    with pytest.raises(MaterialError, match="are one material"):
        MaterialLibrary.itu().with_yaml({"materials": {"Foo": entry, "foo": entry}})


def test_messages_never_print_an_unbounded_value():
    from hallray.errors import brief
    from hallray.harness import MAX_MESSAGE_CHARS, one_line

    assert len(brief(list(range(10**6)))) < 80
    assert len(brief("x" * 10**6)) < 100
    assert len(one_line(ValueError("y" * 10**6))) < MAX_MESSAGE_CHARS + 60


def test_json_duplicate_keys_are_refused(ds, capsys):
    meta = (ds / "meta.json").read_text()
    (ds / "meta.json").write_text(meta.replace('{\n', '{\n "scenario": "x",\n', 1))
    assert estimate_positions_main([str(ds), "-o", "-"]) == 2
    assert "given twice" in _line(capsys)


# -- the Python API keeps the commands' promises ----------------------------------------------------
def _toas(points: np.ndarray, bs: np.ndarray = PAPER_BS) -> np.ndarray:
    return np.linalg.norm(points[:, None, :] - bs[None, :, :], axis=2) / 299_792_458.0


def test_locate_refuses_unit_mistakes():
    from positioning import locate
    from positioning.model.scale import ScaleError

    toa = _toas(POINTS)
    assert np.allclose(locate(toa, PAPER_BS, "ls", height_m=1.5), POINTS, atol=1e-6)
    with pytest.raises(ScaleError, match="nanoseconds"):
        locate(toa * 1e9, PAPER_BS, "ls", height_m=1.5)
    with pytest.raises(ScaleError, match="microseconds"):
        locate(toa * 1e6, PAPER_BS, "ls", height_m=1.5)
    with pytest.raises(ScaleError, match="millimetres"):
        locate(toa, PAPER_BS * 1000.0, "ls", height_m=1.5)
    with pytest.raises(ScaleError, match="height_m 1000"):
        locate(toa, PAPER_BS, "ls", height_m=1000.0)
    # checks=False: the caller's own responsibility
    assert locate(toa, PAPER_BS, "ls", height_m=1000.0, checks=False).shape == (3, 3)


def test_locate_refuses_flat_stations_in_3d():
    from positioning import locate
    from positioning.errors import PositioningError

    with pytest.raises(PositioningError, match="give height_m"):
        locate(_toas(POINTS), PAPER_BS, "ls")


def test_near_collinear_stations_with_exact_toas_are_trusted(tmp_path, capsys):
    bs = np.array([[0.0, 0.0, 4.0], [20.0, 0.3, 4.0], [40.0, 0.0, 4.0], [60.0, 0.4, 4.0]])
    pts = np.array([[10.0, 15.0, 1.5], [30.0, 12.0, 1.5], [50.0, 20.0, 1.5]])
    d = write_dataset(tmp_path / "ds", points=pts, bs=bs, n_epochs=2, sigma_m=0.0)
    assert estimate_positions_main([str(d), "--method", "ls", "-o", str(tmp_path / "f.csv")]) == 0
    capsys.readouterr()


def test_trace_involving_out_of_range_is_a_clear_value_error():
    from raytrace import trace
    from raytrace.core.errors import TraceInputError
    from raytrace.scene.io import load_scene

    scene = load_scene("hall")
    for bad in ([99999], [-1], ["a"]):
        with pytest.raises(TraceInputError, match="involving"):
            trace(scene, [10.0, 10.0, 3.0], [20.0, 20.0, 1.5], 3.7e9, involving=bad)
    with pytest.raises(TraceInputError, match="GHz"):
        trace(scene, [10.0, 10.0, 3.0], [20.0, 20.0, 1.5], 3.7)


# -- silent wrongs, over-strict cases, messages -----------------------------------------------------
def test_dataset_given_twice_is_refused(ds, tmp_path, capsys):
    assert accuracy_report_main([str(ds), str(ds), "--methods", "ls", "-o", str(tmp_path / "r")]) == 2
    assert "given twice" in _line(capsys)


def test_truth_in_millimetres_is_refused(tmp_path, capsys):
    """ToAs in seconds, base stations in metres, only the truth columns in mm."""
    import csv

    d = write_dataset(tmp_path / "ds", points=POINTS, n_epochs=2)
    rows = list(csv.DictReader((d / "toa.csv").open()))
    for r in rows:
        for k in ("x_true", "y_true", "z_true"):
            r[k] = repr(float(r[k]) * 1000.0)
    with (d / "toa.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    assert estimate_positions_main([str(d), "--height", "1.5", "-o", "-"]) == 2
    assert "millimetres" in _line(capsys)


def test_swapped_base_stations_contradict_distance(ds, capsys):
    import json

    meta = json.loads((ds / "meta.json").read_text())
    bss = meta["base_stations"]
    key = "xyz" if isinstance(bss, list) and "xyz" in bss[0] else None
    if key is None:  # a mapping name -> xyz
        names = list(bss)
        bss[names[0]], bss[names[2]] = bss[names[2]], bss[names[0]]
    else:
        bss[0]["xyz"], bss[2]["xyz"] = bss[2]["xyz"], bss[0]["xyz"]
    (ds / "meta.json").write_text(json.dumps(meta))
    assert estimate_positions_main([str(ds), "-o", "-"]) == 2
    assert "swapped or moved" in _line(capsys)


def test_param_of_a_method_not_run_is_refused(ds, capsys):
    assert estimate_positions_main([str(ds), "--method", "ls", "--param", "irls:u_max=-3",
                                    "-o", "-"]) == 2  # fmt: skip
    assert "irls" in _line(capsys)


def test_minus_infinity_needs_no_equals_sign(capsys):
    argv = ["hall", "--tx", "10,10,3", "--rx", "20,20,1.5", "--min-power-db", "-inf"]
    assert trace_scene_main(argv) == 0
    capsys.readouterr()


def test_extrapolation_message_names_the_option(capsys):
    from raytrace.core.errors import MaterialError
    from raytrace.physics.materials import MaterialLibrary

    with pytest.raises(MaterialError, match="--extrapolate"):
        MaterialLibrary.itu()["concrete"].permittivity(1.0)


def test_microseconds_are_not_called_nanoseconds():
    from positioning.model.scale import likely_time_factor

    assert likely_time_factor(1e6 * 0.5)[1] == "microseconds"
    assert likely_time_factor(1e9 * 0.5)[1] == "nanoseconds"
    assert likely_time_factor(1e3 * 0.5)[1] == "milliseconds"


def test_elev_nan_is_refused(tmp_path, capsys):
    from raytrace.cli.render_scene import render_scene_main

    out = tmp_path / "x.png"
    assert render_scene_main(["hall", "-o", str(out), "--elev", "nan"]) == 2
    assert "--elev" in _line(capsys) and not out.exists()


def test_overlapping_solids_are_refused():
    from raytrace.core.errors import HallrayError
    from raytrace.halls.spec import load_hall_spec

    def spec(x2: float) -> dict:
        return {
            "schema_version": 1,
            "hall": {"size": [20.0, 20.0, 6.0]},
            "objects": [
                {"name": "a", "type": "box", "material": "metal", "min": [2.0, 2.0, 0.0], "size": [2.0, 2.0, 2.0]},
                {"name": "b", "type": "box", "material": "metal", "min": [x2, 2.0, 0.0], "size": [2.0, 2.0, 2.0]},
            ],
        }

    load_hall_spec(spec(4.0))  # touching is fine
    with pytest.raises(HallrayError, match="overlaps object"):
        load_hall_spec(spec(3.0))


def test_base_station_at_exactly_the_clearance_is_accepted():
    from raytrace.halls.spec import load_hall_spec

    load_hall_spec({
        "schema_version": 1,
        "hall": {"size": [20.0, 20.0, 6.0]},
        "base_stations": [{"name": "BS1", "xyz": [0.01, 10.0, 3.0]}],
    })  # fmt: skip


def test_hall_in_kilometres_is_refused(tmp_path, capsys):
    from raytrace.core.errors import HallrayError
    from raytrace.halls.spec import load_hall_spec

    with pytest.raises(HallrayError, match="kilometres"):
        load_hall_spec({"schema_version": 1, "hall": {"size": [0.04, 0.03, 0.008]}})
    with pytest.raises(HallrayError, match="high"):
        load_hall_spec({"schema_version": 1, "hall": {"size": [40.0, 30.0, 800.0]}})


def test_paths_of_another_scene_are_refused(tmp_path, capsys):
    from raytrace.cli.render_scene import render_scene_main

    paths = tmp_path / "p.npz"
    argv = ["hall", "--tx", "10,10,3", "--rx", "20,20,1.5", "-o", str(paths)]
    assert trace_scene_main(argv) == 0
    capsys.readouterr()
    from raytrace.cli.build_hall import build_hall_main

    yaml = tmp_path / "other.yaml"
    text = (ROOT / "scenes" / "hall.yaml").read_text()
    yaml.write_text(text.replace("wall_thickness: 0.3", "wall_thickness: 0.31"))
    assert "wall_thickness: 0.31" in yaml.read_text()
    other = tmp_path / "other.glb"
    assert build_hall_main([str(yaml), "-o", str(other)]) == 0
    capsys.readouterr()
    assert render_scene_main([str(other), "--paths", str(paths), "-o", str(tmp_path / "x.png")]) == 2
    assert "another scene" in _line(capsys)


def test_map_step_is_checked_before_the_datasets(tmp_path, capsys):
    from raytrace.cli.reproduce_paper import reproduce_paper_main

    t0 = time.perf_counter()
    argv = ["-o", str(tmp_path / "p"), "--duration", "1", "--map-step", "0.001", "--quiet"]
    assert reproduce_paper_main(argv) == 2
    _line(capsys)
    assert time.perf_counter() - t0 < 60 and not (tmp_path / "p").exists()


def test_memory_error_is_one_line(monkeypatch, capsys, ds):
    import positioning.cli.estimate as est

    def boom(*a, **k):
        raise MemoryError

    monkeypatch.setattr(est, "load_dataset", boom)
    assert estimate_positions_main([str(ds), "-o", "-"]) == 2
    assert "out of memory" in _line(capsys)



# -- a long dataset's memory does not grow with its epochs ------------------------------------------
def test_dataset_epochs_are_streamed_not_gathered(tmp_path, monkeypatch):
    """make_datasets writes each chunk of epochs as it is measured: no Measurements of more than
    one chunk ever exists (before, every epoch's were concatenated, then written)."""
    from raytrace.emulation import measurement
    from raytrace.emulation.dataset.make import make_datasets

    largest = [0]
    real = measurement.Measurements.concatenate.__func__
    real_init = measurement.Measurements.__init__

    def spy(cls, parts):
        out = real(cls, parts)
        largest[0] = max(largest[0], len(out.epochs))
        return out

    def spy_init(self, *a, **k):
        real_init(self, *a, **k)
        largest[0] = max(largest[0], len(self.epochs))

    monkeypatch.setattr(measurement.Measurements, "concatenate", classmethod(spy))
    monkeypatch.setattr(measurement.Measurements, "__init__", spy_init)
    out = tmp_path / "ds"
    make_datasets(out, [("static", "c-band")], scene="hall", duration_s=6.0, rate_hz=10.0,
                  subdirectories=False)  # fmt: skip
    import json

    meta = json.loads((out / "meta.json").read_text())
    rows = (out / "toa.csv").read_text().count("\n") - 1
    assert meta["n_epochs"] == 60  # every epoch written
    assert rows == meta["summary"]["rows"] == 60 * len(meta["points"]) * len(meta["base_stations"])
    assert 0 < largest[0] <= 10  # one chunk (epochs.py measures 10 epochs at a time)


def test_twin_map_of_another_device_height_is_refused():
    from pos_synth import synth_map, synth_toa

    from positioning import locate
    from positioning.errors import PositioningError

    fmap = synth_map()
    toa, _ = synth_toa(20, sigma_m=0.05)
    h = float(np.median(fmap.cell_xyz[:, 2]))
    locate(toa, PAPER_BS, "twin", height_m=h, map=fmap)
    with pytest.raises(PositioningError, match="map is at device height"):
        locate(toa, PAPER_BS, "twin", height_m=h + 1.0, map=fmap)
