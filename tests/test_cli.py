"""trace-scene: summary, tracing, path files, glTF export, one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from conftest import box, quad

from raytrace.cli.trace_scene import trace_scene_main
from raytrace.solver.paths import Paths


@pytest.fixture
def scene_file(tmp_path):
    s = trimesh.Scene()
    s.add_geometry(quad((-10, -10, 0), (20, 0, 0), (0, 20, 0)), node_name="floor_itu_concrete")
    s.add_geometry(box((2, -1, 0), (3, 1, 2)), node_name="machine_itu_metal")
    s.add_geometry(box((9.0, -10, 0), (9.3, 10, 5)), node_name="wall_itu_concrete")
    s.metadata["hallray"] = {
        "base_stations": [{"name": "BS1", "xyz": [-5.0, 0.0, 3.0]}],
        "points": [{"name": "P1", "xyz": [6.0, 0.5, 1.0]}, {"name": "P2", "xyz": [-2.0, 5.0, 1.0]}],
    }
    p = tmp_path / "scene.glb"
    p.write_bytes(s.export(file_type="glb"))
    return p


def test_summary_only_json(scene_file, capsys):
    assert trace_scene_main([str(scene_file), "--summary-only", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["objects"] == 3 and out["materials"] == {"concrete": 2, "metal": 1}


def test_traces_stored_positions_and_writes_all_formats(scene_file, tmp_path, capsys):
    for suffix in (".npz", ".json", ".csv"):
        out = tmp_path / f"paths{suffix}"
        assert trace_scene_main([str(scene_file), "-q", "-o", str(out)]) == 0
        assert out.exists()
    text = capsys.readouterr().out
    assert "BS1    P1" in text and "BS1    P2" in text
    p = Paths.load(tmp_path / "paths.npz")
    assert p.n_links == 2
    doc = json.loads((tmp_path / "paths.json").read_text())
    assert len(doc["paths"]) == p.n_paths
    rows = (tmp_path / "paths.csv").read_text().splitlines()
    assert len(rows) == p.n_paths + 1 and rows[0].startswith("link,tx_index,rx_index,kind,delay_s")
    # P1 is behind the metal machine: no LoS; P2 sees BS1
    first = p.first_arrival()
    assert p.kind_label[first[0]] != "LoS" and p.kind_label[first[1]] == "LoS"


def test_json_output_and_explicit_positions(scene_file, capsys):
    code = trace_scene_main(
        [str(scene_file), "--tx", "0,0,2", "--rx", "5,5,1", "--json", "--max-diffractions", "0"]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    link = out["links"][0]
    assert link["los"] is True
    assert link["first_delay_ns"] == pytest.approx(
        np.linalg.norm([5, 5, -1]) / 0.299792458, abs=1e-3
    )


def test_export_glb(scene_file, tmp_path):
    out = tmp_path / "paths.glb"
    assert (
        trace_scene_main([str(scene_file), "-q", "--export-glb", str(out), "--link", "BS1,P1"]) == 0
    )
    loaded = trimesh.load(out, force="scene")
    names = list(loaded.geometry)
    assert any(n.startswith("path_link0_") for n in names)
    assert "machine_itu_metal" in names


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.glb"], "scene file not found"),
        (["{scene}", "--tx", "0,0,2", "--rx", "500000,0,1"], "outside the scene"),
        (["{scene}", "--tx", "2.5,0,1", "--rx", "5,5,1"], "inside the solid 'machine_itu_metal'"),
        (["{scene}", "--band", "x-band"], "unknown band"),
        (["{scene}", "--frequency-hz", "150e9"], "concrete"),
        (["{scene}", "-o", "{tmp}/nodir/p.npz"], "output directory does not exist"),
        (["{scene}", "-o", "{tmp}/p.txt"], "unknown paths format"),
        (["{scene}", "--export-glb", "{tmp}/x.glb", "--link", "BS9,P1"], "not a known name"),
    ],
)
def test_bad_input_one_line_error(scene_file, tmp_path, capsys, args, message):
    argv = [a.format(scene=scene_file, tmp=tmp_path) for a in args]
    assert trace_scene_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err
    assert err.count("\n") == 1
    assert not list(tmp_path.glob("*.tmp")) and not (tmp_path / "p.txt").exists()


def test_unwritable_output_is_one_line_error(scene_file, capsys):
    # /proc refuses new files even to root
    assert trace_scene_main([str(scene_file), "-q", "-o", "/proc/hallray-paths.npz"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_bad_coordinates_are_rejected_by_argparse(scene_file, capsys):
    # like every tool, trace-scene returns its exit status rather than raising SystemExit
    assert trace_scene_main([str(scene_file), "--tx", "0,0", "--rx", "1,1,1"]) == 2
    err = capsys.readouterr().err
    assert "expected X,Y,Z" in err and err.startswith("error: ") and err.count("\n") == 1
