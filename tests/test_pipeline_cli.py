"""reproduce-paper: bad input gives one line and exit 2, and writes nothing."""

from __future__ import annotations

import pytest

from raytrace.cli.reproduce_paper import reproduce_paper_main


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--scene", "no_such_scene.glb"], "scene file not found"),
        (["--duration", "-1"], "duration"),
        (["--workers", "0"], "workers"),
    ],
)
def test_bad_input(tmp_path, capsys, extra, message):
    out = tmp_path / "run"
    assert reproduce_paper_main(["-o", str(out), "-q", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
    assert not out.exists()


def test_refuses_a_non_empty_output_directory(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert reproduce_paper_main(["-o", str(out), "-q"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "mine"
