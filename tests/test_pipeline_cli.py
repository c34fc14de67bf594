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
        (["--map-step", "-1"], "--map-step"),
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


def test_unknown_receiver_lists_the_known_ones(tmp_path, capsys):
    out = tmp_path / "run"
    assert reproduce_paper_main(["-o", str(out), "-q", "--receiver", "oracle"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "first-lobe, first-path, peak, leading-edge, paper" in err
    assert not out.exists()


@pytest.mark.slow
def test_reproduce_paper_writes_both_receivers_and_the_comparison(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["-o", str(out), "-q", "--duration", "0.3", "--workers", "1", "--map-step", "4"]
    assert reproduce_paper_main(argv) == 0
    assert (out / "report" / "table.csv").is_file()
    assert (out / "report-first-path" / "table.csv").is_file()
    assert (out / "report-paper" / "table.csv").is_file()
    text = (out / "paper.md").read_text()
    for needle in ("IRLS <= LS", "IRLS as written <= LS", "mmWave <= C-band",
                   "static <= semi-dynamic", "first-lobe LS", "paper IRLS as written"):  # fmt: skip
        assert needle in text
    # the paper's model first in Table II
    assert "| published LS | published IRLS | paper LS |" in text
    assert text.index("| paper LS |") < text.index("| first-lobe LS |")
    assert "| first-path | static | C-band | LoS |" in text
    assert "| paper | static | C-band | LoS |" in text
    assert "random reference" in text
    assert "## Tracked rows" in text and "| twin |" in text and "| c-band |" in text
    assert (out / "maps" / "mmwave" / "map.npz").is_file()


@pytest.mark.parametrize("workers", ["1", "2"])
def test_reproduce_paper_interrupted_in_the_report_says_so_once(tmp_path, capsys, monkeypatch,
                                                                workers):  # fmt: skip
    """Ctrl-C or SIGTERM while the accuracy report runs (in this process with one worker, the
    reports side by side on spawned processes with two): the report does not turn it into an
    exit status of its own; reproduce-paper reports the interruption once, exits 130 and
    leaves no output."""
    import positioning.cli.accuracy
    from raytrace.emulation.dataset import make as dataset

    def datasets(folder, pairs, **kw):
        return [{"directory": str(folder / "static-c-band"), "epochs": 1, "toa_method": r}
                for r in kw["toa_method"]]  # fmt: skip

    def report(args):
        raise KeyboardInterrupt

    def reports(argvs, processes):
        assert processes == 3 and len(argvs) == 3  # one process per report on two cores
        assert all(a[a.index("--workers") + 1] == "1" for a in argvs)  # the reports: the lanes
        raise KeyboardInterrupt

    monkeypatch.setattr(dataset, "make_datasets", datasets)
    monkeypatch.setattr(positioning.cli.accuracy, "_report", report)
    monkeypatch.setattr(positioning.cli.accuracy, "accuracy_reports", reports)
    out = tmp_path / "run"
    argv = ["-o", str(out), "-q", "--map-step", "0", "--workers", workers]
    assert reproduce_paper_main(argv) == 130
    err = capsys.readouterr().err
    assert err.count("interrupted") == 1, err
    assert not out.exists() and not list(tmp_path.iterdir())
