"""Issue 18, reliability: every case of the issue through the command line (exit status, message,
the files on disk afterwards), the fault-injection runs (SIGTERM / SIGKILL at random points) and
the memory bound of a large receiver grid. The case table is docs/reliability.md."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh
from pos_synth import write_dataset

from hallray.safe_output import MARKER, output_dir, output_lock, write_file
from positioning.cli.accuracy import accuracy_report_main
from positioning.cli.estimate import estimate_positions_main
from raytrace.cli.make_dataset import make_dataset_main
from raytrace.cli.make_hall import format_los_report, hall_los_check_main, make_hall_main
from raytrace.cli.render_scene import render_scene_main
from raytrace.cli.trace_scene import trace_scene_main

ROOT = Path(__file__).resolve().parents[1]
CANON = ROOT / "scenes" / "canonical"
POINTS = np.array([[5.0, 5.0, 1.5], [20.0, 8.0, 1.5], [12.0, 18.0, 1.5]])


@pytest.fixture()
def ds(tmp_path):
    return write_dataset(tmp_path / "ds", points=POINTS, n_epochs=3)


def _err(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def _only_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, err
    return lines[0]


def _leftovers(folder: Path) -> list[str]:
    """Hidden temporary files and locks the output layer might leave."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# -- the output layer -----------------------------------------------------------------------------
def test_special_file_output_is_refused_and_left_alone(ds, tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert estimate_positions_main([str(ds), "-o", str(fifo)]) == 2
    assert "is a FIFO: refusing" in _only_line(_err(capsys))
    assert fifo.is_fifo()
    assert estimate_positions_main([str(ds), "-o", "/dev/null"]) == 2
    assert "character device" in _err(capsys)


def test_symlink_output_is_followed(ds, tmp_path, capsys):
    target, link = tmp_path / "real.csv", tmp_path / "link.csv"
    target.write_text("old")
    link.symlink_to(target.name)
    assert estimate_positions_main([str(ds), "-o", str(link)]) == 0
    assert link.is_symlink() and target.read_text().startswith("epoch,time_s,point")
    assert _leftovers(tmp_path) == []


def test_output_that_is_an_input_is_refused(ds, capsys):
    before = (ds / "toa.csv").read_bytes()
    assert estimate_positions_main([str(ds), "-o", str(ds / "toa.csv")]) == 2
    assert "is an input of this command" in _only_line(_err(capsys))
    assert (ds / "toa.csv").read_bytes() == before
    assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(ds.parent)]) == 2
    assert "contains an input of this command" in _err(capsys)


def test_export_glb_onto_its_own_scene_is_refused(tmp_path, capsys):
    scene = tmp_path / "X.glb"
    scene.write_bytes((CANON / "one_wall.glb").read_bytes())
    before = scene.read_bytes()
    argv = [str(scene), "--tx", "0,-3,1.5", "--rx", "1,-4,1.5", "-q", "--export-glb", str(scene)]
    assert trace_scene_main(argv) == 2
    assert "--export-glb" in _only_line(_err(capsys))
    assert scene.read_bytes() == before


def test_dash_is_stdout(ds, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert estimate_positions_main([str(ds), "-o", "-"]) == 0
    out = capsys.readouterr()
    assert out.out.startswith("epoch,time_s,point") and len(out.out.splitlines()) == 1 + 9
    assert "irls: 9 fixes" in out.err  # the summary goes to stderr when stdout holds the CSV
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize(
    "mask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o027, 0o640, 0o750)]
)
def test_modes_follow_the_umask(ds, tmp_path, capsys, mask, file_mode, dir_mode):
    old = os.umask(mask)
    try:
        assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 0
        assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(tmp_path / "rep")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "f.csv").stat().st_mode & 0o777 == file_mode
    assert (tmp_path / "rep").stat().st_mode & 0o777 == dir_mode
    assert (tmp_path / "rep" / "table.md").stat().st_mode & 0o777 == file_mode


def test_second_writer_gets_a_clear_error(ds, tmp_path, capsys):
    out = tmp_path / "same"
    with output_lock(out):  # another process is writing it
        assert estimate_positions_main([str(ds), "-o", str(out)]) == 2
        assert "being written by another process" in _only_line(_err(capsys))
        argv = ["--scenario", "static", "--band", "c-band", "-q", "-o", str(out)]
        assert make_dataset_main(argv) == 2
        assert "being written by another process" in _err(capsys)
    assert not out.exists() and _leftovers(tmp_path) == []


def test_report_is_whole_or_nothing_and_replaces_only_a_report(ds, tmp_path, capsys):
    rep = tmp_path / "rep"
    assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(rep)]) == 0
    (rep / "table.md").write_text("edited")  # a previous report is replaced whole
    (rep / "table.csv").unlink()
    assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(rep)]) == 0
    assert (rep / "table.md").read_text().startswith("| metric") and (rep / "table.csv").is_file()
    # issue 40: a file the report did not write is someone else's: the report is not replaced
    (rep / "notes.txt").write_text("mine")
    assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(rep)]) == 2
    assert "holds files accuracy-report did not write (notes.txt)" in _only_line(_err(capsys))
    assert (rep / "notes.txt").read_text() == "mine" and (rep / "table.md").is_file()
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("keep")
    assert accuracy_report_main([str(ds), "--methods", "ls", "-o", str(mine)]) == 2
    assert "not empty" in _err(capsys)
    assert (mine / "thesis.tex").read_text() == "keep" and len(list(mine.iterdir())) == 1


def test_interrupted_directory_leaves_nothing_and_killed_leftovers_are_cleaned(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt), output_dir(out) as tmp:
        (tmp / "half.csv").write_text("1,2")
        raise KeyboardInterrupt  # what the harness makes of SIGTERM
    assert list(tmp_path.iterdir()) == []
    # what a SIGKILL leaves: the next run on the same output removes it
    (tmp_path / ".out.abcd1234.tmp").mkdir()
    (tmp_path / ".out.abcd1234.tmp" / "half.csv").write_text("1")
    with output_dir(out) as tmp:
        (tmp / "whole.csv").write_text("1,2\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    write_file(tmp_path / "f.txt", "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.txt", "out"]


# -- legitimate input ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "scene, tx, rx",
    [
        ("one_sheet.glb", "0,-5,1", "0,-2,1"),  # 5 m in front of a lone wall
        ("floor.glb", "0,0,2", "1,1,1.5"),  # 2 m above a floor
        ("floor.glb", "0,0,30", "1,1,1.5"),  # 30 m above it: a warning, not an error
    ],
)
def test_positions_outside_the_box_are_traced(scene, tx, rx, capsys):
    with warnings.catch_warnings(record=True) as rec:
        assert trace_scene_main([str(CANON / scene), "--tx", tx, "--rx", rx, "-q"]) == 0
    assert "error" not in _err(capsys)
    far = any("far outside the scene" in str(w.message) for w in rec)
    assert far == tx.endswith(",30")


def test_positions_beyond_the_scale_rule_are_refused(capsys):
    argv = [str(CANON / "floor.glb"), "--tx", "0,0,2", "--rx", "9000,0,1500", "-q"]
    assert trace_scene_main(argv) == 2
    assert "millimetres" in _only_line(_err(capsys))


def test_negative_coordinates(capsys):
    assert (
        trace_scene_main([str(CANON / "floor.glb"), "--tx", "-1,-2,2", "--rx", "-1,2,1.5", "-q"])
        == 0
    )


def test_tx_equal_rx_is_one_line(capsys):
    argv = [str(CANON / "floor.glb"), "--tx", "1,2,1.5", "--rx", "1,2,1.5", "-q"]
    assert trace_scene_main(argv) == 2
    assert "same position" in _only_line(_err(capsys))


@pytest.mark.parametrize("eta, ok", [("1.0e9", True), ("1.0", True), ("0.5", False)])
def test_eta_real_yaml(tmp_path, capsys, eta, ok):
    y = tmp_path / "m.yaml"
    y.write_text(f"materials:\n  mymat: {{eta_real: {eta}, sigma: 0.1}}\ndefault: mymat\n")
    code = trace_scene_main([str(CANON / "floor.glb"), "--materials", str(y), "--summary-only"])
    assert code == (0 if ok else 2)
    if not ok:
        line = _only_line(_err(capsys))
        assert "eta_real" in line and "eta_real >= 1" in line


def _box_mesh() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=[4, 0.3, 3])


@pytest.mark.parametrize("suffix", ["obj", "ply", "stl"])
def test_nan_vertices_are_refused_naming_the_file(tmp_path, capsys, suffix):
    m = _box_mesh()
    v = m.vertices.copy()
    v[0, 0] = np.nan
    bad = trimesh.Trimesh(v, m.faces, process=False)
    path = tmp_path / f"wall.{suffix}"
    path.write_bytes(
        bad.export(file_type=suffix) if suffix != "obj" else bad.export(file_type="obj").encode()
    )
    code = trace_scene_main([str(path), "--default-material", "concrete", "--summary-only"])
    assert code == 2
    line = _only_line(_err(capsys))
    assert f"wall.{suffix}" in line and "NaN or infinite" in line


def test_clean_mesh_still_loads_closed(tmp_path, capsys):
    path = tmp_path / "wall.ply"
    path.write_bytes(_box_mesh().export(file_type="ply"))
    assert trace_scene_main([str(path), "--default-material", "concrete", "--summary-only"]) == 0
    assert "1 closed solids" in capsys.readouterr().out


def test_truncated_binary_ply_is_refused(tmp_path, capsys):
    data = _box_mesh().export(file_type="ply", encoding="binary")
    path = tmp_path / "cut.ply"
    path.write_bytes(data[: len(data) - 100])
    assert trace_scene_main([str(path), "--default-material", "concrete", "--summary-only"]) == 2
    assert "cut.ply" in _only_line(_err(capsys))


def test_toa_csv_with_bom_is_read(ds, tmp_path, capsys):
    (ds / "toa.csv").write_bytes(b"\xef\xbb\xbf" + (ds / "toa.csv").read_bytes())
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 0


def _meta(ds: Path, **changes) -> None:
    meta = json.loads((ds / "meta.json").read_text())
    meta.update(changes)
    (ds / "meta.json").write_text(json.dumps(meta))


def test_truncated_toa_csv_against_meta_rows(ds, tmp_path, capsys):
    lines = (ds / "toa.csv").read_text().splitlines(True)
    _meta(ds, summary={"rows": len(lines) - 1})
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "a.csv")]) == 0
    (ds / "toa.csv").write_text("".join(lines[:20]))
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "b.csv")]) == 2
    assert "19 data rows, meta.json says 36" in _only_line(_err(capsys))
    assert not (tmp_path / "b.csv").exists()


def test_unknown_schema_version_is_refused(ds, tmp_path, capsys):
    _meta(ds, schema_version=99)
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 2
    assert "schema_version 99" in _only_line(_err(capsys))


def test_truth_differing_within_a_fix_is_refused(ds, tmp_path, capsys):
    lines = (ds / "toa.csv").read_text().splitlines(True)
    row = lines[2].split(",")
    row[5] = str(float(row[5]) + 3.0)
    lines[2] = ",".join(row)
    (ds / "toa.csv").write_text("".join(lines))
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 2
    assert "line 3: true position" in _only_line(_err(capsys))


def _paths_file(tmp_path: Path) -> Path:
    out = tmp_path / "p.npz"
    argv = [str(CANON / "floor.glb"), "--tx", "0,0,2", "--rx", "1,1,1.5", "-q", "-o", str(out)]
    assert trace_scene_main(argv) == 0
    return out


def test_render_refuses_truncated_and_nan_paths(tmp_path, capsys):
    good = _paths_file(tmp_path)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:300])
    png = tmp_path / "r.png"
    assert render_scene_main([str(CANON / "floor.glb"), "--paths", str(cut), "-o", str(png)]) == 2
    assert "cut.npz" in _only_line(_err(capsys))
    with np.load(good) as z:
        arrays = dict(z)
    arrays["delay_s"] = arrays["delay_s"].copy()
    arrays["delay_s"][0] = np.nan
    nan = tmp_path / "nan.npz"
    np.savez(nan, **arrays)
    assert render_scene_main([str(CANON / "floor.glb"), "--paths", str(nan), "-o", str(png)]) == 2
    assert "NaN or infinite" in _only_line(_err(capsys))
    assert not png.exists()


def test_hall_los_check_never_prints_nan(capsys):
    assert (
        hall_los_check_main(["InF-SL", "--seeds", "1", "--size", "20x20x5", "--points", "0"]) == 2
    )
    assert "--points" in _only_line(_err(capsys))
    summary = {
        "params": {"profile": "InF-SL", "size": [20, 20, 5], "bs_grid": [1, 1], "n_points": 1,
                   "density": 0.2, "clutter_size": 10, "clutter_height": 2, "bs_height": 1.5,
                   "ut_height": 1.5},
        "n_halls": 1, "n_links": 1, "k_3gpp_m": 44.8, "k_fit_m": float("inf"),
        "los_fraction": 1.0, "los_fraction_3gpp": 0.9, "bins": [],
    }  # fmt: skip
    text = format_los_report(summary)
    assert "nan" not in text and "not defined: every link is LoS" in text


# -- the scale rule -------------------------------------------------------------------------------
def test_scene_in_millimetres_is_refused_before_tracing(tmp_path, capsys):
    m = trimesh.creation.box(extents=[42.0, 46.0, 8.8])  # the paper's hall, in millimetres
    m.apply_scale(1000.0)
    path = tmp_path / "mm.ply"
    path.write_bytes(m.export(file_type="ply"))
    t0 = time.perf_counter()
    assert (
        trace_scene_main(
            [str(path), "--default-material", "concrete", "--tx", "1,1,1", "--rx", "2,2,1"]
        )
        == 2
    )
    assert time.perf_counter() - t0 < 5.0
    assert "millimetres (x1000)" in _only_line(_err(capsys))


def test_make_hall_in_millimetres_fails_fast(tmp_path, capsys):
    t0 = time.perf_counter()
    argv = ["--profile", "InF-SL", "--size", "120000x60000x10000", "-o", str(tmp_path / "h")]
    assert make_hall_main(argv) == 2
    assert time.perf_counter() - t0 < 2.0
    assert "millimetres" in _only_line(_err(capsys))
    assert not (tmp_path / "h").exists()


def test_toas_in_milliseconds_are_refused(ds, tmp_path, capsys):
    text = (ds / "toa.csv").read_text().splitlines()
    head = text[0].split(",")
    i, j = head.index("toa_s"), head.index("tx_offset_s")
    rows = [text[0]]
    for line in text[1:]:
        r = line.split(",")
        r[i], r[j] = repr(float(r[i]) * 1e3), repr(float(r[j]) * 1e3)
        rows.append(",".join(r))
    (ds / "toa.csv").write_text("\n".join(rows) + "\n")
    _meta(ds, schedule_s={})
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 2
    assert "milliseconds (x1000)" in _only_line(_err(capsys))


def test_station_in_millimetres_is_refused(ds, tmp_path, capsys):
    meta = json.loads((ds / "meta.json").read_text())
    meta["base_stations"][1]["xyz"] = [v * 1000 for v in meta["base_stations"][1]["xyz"]]
    (ds / "meta.json").write_text(json.dumps(meta))
    assert estimate_positions_main([str(ds), "-o", str(tmp_path / "f.csv")]) == 2
    assert "millimetres" in _only_line(_err(capsys))


def test_height_in_millimetres_is_refused(ds, tmp_path, capsys):
    assert (
        estimate_positions_main([str(ds), "--height", "1500", "-o", str(tmp_path / "f.csv")]) == 2
    )
    assert "--height 1500" in _only_line(_err(capsys))
    assert estimate_positions_main([str(ds), "--height", "1.5", "-o", str(tmp_path / "f.csv")]) == 0


def test_collinear_stations_and_flat_3d_are_not_trusted(tmp_path, capsys):
    line = np.array([[0.0, 0.0, 4.0], [10.0, 0.0, 4.0], [20.0, 0.0, 4.0], [30.0, 0.0, 4.0]])
    d = write_dataset(tmp_path / "col", points=POINTS, bs=line)
    assert estimate_positions_main([str(d), "-o", str(tmp_path / "c.csv")]) == 2
    assert "collinear" in _only_line(_err(capsys))
    d2 = write_dataset(tmp_path / "flat", points=POINTS)  # the paper's stations, all at 4 m
    assert estimate_positions_main([str(d2), "--3d", "-o", str(tmp_path / "f.csv")]) == 2
    assert "one plane" in _only_line(_err(capsys))
    assert not (tmp_path / "c.csv").exists() and not (tmp_path / "f.csv").exists()
    assert estimate_positions_main([str(d2), "-o", str(tmp_path / "ok.csv")]) == 0
    assert "ill-conditioned 0," in capsys.readouterr().out


# -- resources ------------------------------------------------------------------------------------
def test_csv_is_streamed_in_blocks_with_the_same_bytes(monkeypatch):
    import raytrace.emulation.dataset.files as dsm
    from raytrace.emulation.measurement import Measurements  # noqa: F401  (type of the fields)

    class Inputs:
        point_names, bs_names = ["P1", "P2"], ["B1", "B2", "B3"]
        point_xyz = np.array([[1.0, 2.0, 1.5], [3.0, 4.0, 1.5]])
        bs_xyz = np.array([[0.0, 0.0, 4.0], [9.0, 0.0, 4.0], [0.0, 9.0, 4.0]])

    class M:
        shape = (7, 2, 3)
        epochs = np.arange(7)
        toa_s = np.random.default_rng(1).uniform(0, 1e-6, shape)
        detected = toa_s > 2e-7
        los = detected
        snr_db = peak_ratio_db = lobe_width = toa_s * 1e7
        first_kind = lobe_kind = np.full(shape, "LoS", dtype=object)
        tx_offset_s = np.array([0.0, 0.01, 0.02])
        clock_offset_s = np.zeros((7, 2))

    times = np.arange(7) / 10.0
    whole = dsm._toa_csv(Inputs, times, M)
    monkeypatch.setattr(dsm, "CSV_BLOCK_EPOCHS", 2)
    blocks = list(dsm._toa_csv_blocks(Inputs, times, M))
    assert len(blocks) == 1 + 4 and "".join(blocks) == whole
    assert whole.count("\n") == 1 + 7 * 2 * 3


def test_stop_pool_is_prompt():
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from raytrace.studies.sweep.run import _stop_pool

    pool = ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn"))
    futures = [pool.submit(time.sleep, 30) for _ in range(4)]
    while not any(f.running() for f in futures):
        time.sleep(0.05)
    t0 = time.perf_counter()
    _stop_pool(pool)
    assert time.perf_counter() - t0 < 5.0


# -- fault injection ------------------------------------------------------------------------------
def _cli(module: str, func: str, args: list[str]) -> subprocess.Popen:
    code = f"import sys; from {module} import {func} as m; sys.exit(m())"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-c", code, *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip


def _whole_dataset(out: Path) -> bool:
    """A ToA dataset directory with its two files and every row its ``meta.json`` announces."""
    if sorted(p.name for p in out.iterdir()) != [MARKER, "meta.json", "toa.csv"]:
        return False
    meta = json.loads((out / "meta.json").read_text())
    rows = meta["n_epochs"] * len(meta["base_stations"]) * len(meta["points"])
    with open(out / "toa.csv") as fh:
        return sum(1 for _ in fh) == 1 + rows


def _whole_report(out: Path) -> bool:
    """An accuracy report directory with its tables, CDFs and top views."""
    names = {p.name for p in out.iterdir()}
    return {"table.md", "table.csv", "cdf_by_method.png", "integrity.md"} <= names and any(
        n.startswith("topview_") for n in names
    )


def _kill_and_rerun(module: str, func: str, args: list[str], out: Path, rng: random.Random,
                    delays: tuple[float, float], kills: int = 4,
                    whole: Callable[[Path], bool] | None = None) -> None:  # fmt: skip
    """Kill a command at random points (SIGTERM and SIGKILL): the output is whole or absent,
    and a rerun succeeds and leaves no temporary file.

    A kill that lands after the output was renamed into place (the process still exiting) leaves
    it whole: with ``whole`` given, such an output is accepted when ``whole(out)`` holds."""
    for k in range(kills):
        if out.exists():
            import shutil

            shutil.rmtree(out)
        before = set(_leftovers(out.parent))  # a SIGKILL's leftovers, for the next run to clean
        proc = _cli(module, func, args)
        time.sleep(rng.uniform(*delays))  # mostly mid-run, after the imports
        sig = signal.SIGTERM if k % 2 == 0 else signal.SIGKILL
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        print(f"kill {k}: {sig.name} -> exit {proc.returncode}")
        if proc.returncode == 0:
            assert out.is_dir()  # finished before the signal: whole
        elif out.exists() and whole is not None:  # killed while exiting, after the rename
            assert whole(out), f"partial output after {sig.name}"
        else:
            assert not out.exists(), f"partial output after {sig.name}"
            if sig == signal.SIGTERM:  # -15: it came before the harness was up (importing)
                assert proc.returncode in (130, -signal.SIGTERM), err
                new = set(_leftovers(out.parent)) - before
                assert not new, f"SIGTERM left temporary files {new} ({proc.returncode}, {err!r})"
    proc = _cli(module, func, args)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert _leftovers(out.parent) == []


@pytest.mark.slow
def test_fault_injection_make_dataset(tmp_path):
    out = tmp_path / "ds"
    args = ["--scenario", "static", "--band", "c-band", "--duration", "20", "--rate", "10", "-q",
            "--force", "-o", str(out)]  # fmt: skip
    _kill_and_rerun(
        "raytrace.cli.make_dataset", "make_dataset_main", args, out, random.Random(18), (1.0, 4.0),
        whole=_whole_dataset,
    )
    assert (out / "toa.csv").is_file() and (out / "meta.json").is_file()


@pytest.mark.slow
def test_fault_injection_accuracy_report(tmp_path):
    d = write_dataset(tmp_path / "in" / "ds", points=POINTS, n_epochs=20)
    out = tmp_path / "out" / "rep"
    out.parent.mkdir()
    args = [str(d), "-o", str(out)]
    _kill_and_rerun(
        "positioning.cli.accuracy", "accuracy_report_main", args, out, random.Random(7), (1.0, 5.0),
        whole=_whole_report,
    )
    assert (out / "table.md").is_file()


# -- memory -------------------------------------------------------------------------------------
#: Peak RSS allowed for tracing a 20 000-receiver grid in a fresh process, MB (measured ~420 MB
#: with one worker; an unbatched trace of 100 000 receivers went past 9 GB).
RSS_LIMIT_MB = 900


@pytest.mark.slow
def test_trace_of_a_20k_receiver_grid_stays_under_the_rss_limit():
    code = (
        "import resource, numpy as np\n"
        "from raytrace.scene.io import load_scene\n"
        "from raytrace.solver.tracer import trace\n"
        "sc = load_scene('scenes/canonical/shoebox.glb')\n"
        "lo, hi = sc.bounds\n"
        "xs = np.linspace(lo[0] + 0.3, hi[0] - 0.3, 200); ys = np.linspace(lo[1] + 0.3, hi[1] - 0.3, 100)\n"
        "g = np.array(np.meshgrid(xs, ys, [1.5])).reshape(3, -1).T\n"
        "p = trace(sc, [[1.0, 1.0, 2.5]], g, 3.5e9, workers=1)\n"
        "assert p.n_links == 20000\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert int(res.stdout.split()[-1]) < RSS_LIMIT_MB


@pytest.mark.slow
def test_fault_injection_reproduce_paper(tmp_path):
    out = tmp_path / "rp"
    args = ["-o", str(out), "--duration", "0.5", "--rate", "2", "--workers", "1", "-q", "--force",
            "--map-step", "4"]  # fmt: skip
    _kill_and_rerun("raytrace.cli.reproduce_paper", "reproduce_paper_main", args, out,
                    random.Random(3), (3.0, 12.0), kills=2)  # fmt: skip
    assert (out / "report" / "table.md").is_file()
    # the four setups under the realistic and the ideal receiver
    assert len([p for p in (out / "datasets").iterdir() if p.name != MARKER]) == 8
    assert (out / "paper.md").is_file() and (out / "maps" / "c-band" / "map.npz").is_file()
