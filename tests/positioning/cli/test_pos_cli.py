"""estimate-positions and accuracy-report on small synthetic datasets in the contract format."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from pos_synth import write_dataset

from positioning import METHODS, error_2d, method_names, summarize
from positioning.cli.accuracy import accuracy_report_main
from positioning.cli.estimate import estimate_positions_main
from positioning.report.fixes_file import FIXES_COLUMNS

#: Coordinates are written with 6 decimals (micrometres).
CSV_TOL_M = 2e-6

POINTS = np.array([[5.0, 6.0, 1.0], [14.0, 12.0, 1.0], [22.0, 19.0, 1.0], [25.0, 4.0, 1.5]])


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    a = write_dataset(root / "static_c", points=POINTS, n_epochs=4, nlos={(1, 0): 5.0}, seed=1)
    b = write_dataset(
        root / "semi_mm",
        points=POINTS,
        n_epochs=4,
        sigma_m=0.02,
        nlos={(0, 2): 3.0, (2, 1): 4.0},
        missing=[(0, 3, 0)],
        scenario="semi-dynamic",
        band="mmwave",
        seed=2,
    )
    return a, b


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def run_error(main, argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_estimate_positions_writes_fixes(datasets, tmp_path, capsys):
    out = tmp_path / "fixes.csv"
    assert estimate_positions_main([str(datasets[1]), "--method", "ls", "-o", str(out)]) == 0
    assert "ls: 16 fixes, availability 100.0 % (0 unsolved)" in capsys.readouterr().out
    rows = read_csv(out)
    assert tuple(rows[0]) == FIXES_COLUMNS
    assert len(rows) == 16
    est = np.array([[float(r[c]) for c in "xyz"] for r in rows])
    true = np.array([[float(r[c]) for c in ("x_true", "y_true", "z_true")] for r in rows])
    err = np.array([float(r["error_m"]) for r in rows])
    np.testing.assert_allclose(err, error_2d(est, true), atol=CSV_TOL_M)
    np.testing.assert_allclose(est[:, 2], true[:, 2])  # 2D solve at the true height
    assert {r["method"] for r in rows} == {"ls"}
    assert [int(r["n_bs"]) for r in rows][:4] == [4, 4, 4, 3]  # epoch 0, P04 lost BS1
    assert all(r["status"] for r in rows)
    assert not list(tmp_path.glob(".*.tmp"))


def test_estimate_positions_params_height_and_3d(datasets, tmp_path, capsys):
    out = tmp_path / "f.csv"
    argv = [str(datasets[0]), "--method", "irls", "--param", "u_max=2.5", "--height", "1.0"]
    assert estimate_positions_main([*argv, "-o", str(out)]) == 0
    rows = read_csv(out)
    assert {float(r["z"]) for r in rows} == {1.0}
    ref = [str(datasets[0]), "--method", "ls", "--param", "reference=BS2", "-o", str(out)]
    assert estimate_positions_main(ref) == 0
    d5 = write_dataset(
        tmp_path / "five",
        points=POINTS,
        bs=np.array(
            [[0.0, 0.0, 2.0], [29.0, 0.0, 5.0], [29.0, 25.0, 7.0], [0.0, 25.0, 3.0], [14, -4, 8]]
        ),
        n_epochs=1,
        sigma_m=0.0,
    )
    assert estimate_positions_main([str(d5), "--method", "ls", "--3d", "-o", str(out)]) == 0
    rows = read_csv(out)
    est = np.array([[float(r[c]) for c in "xyz"] for r in rows])
    np.testing.assert_allclose(est, POINTS, atol=1e-5)


def test_list_methods(capsys):
    assert estimate_positions_main(["--list-methods"]) == 0
    out = capsys.readouterr().out
    for m in METHODS:
        assert m in out
    assert "u_max=3.0" in out


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--method", "magic"], "unknown method 'magic'"),
        (["--param", "u_max=-1"], "u_max"),
        (["--param", "u_max=abc"], "u_max"),
        (["--param", "bogus=1"], "bogus"),
        (["--param", "u_max"], "NAME=VALUE"),
        (["--method", "ls", "--param", "reference=BS9"], "reference"),
        (["--method", "ls", "--param", "reference=nearest"], "first, random, strongest, fixed:N"),
        (["--method", "ls", "--param", "reference=fixed:7"], "4 base stations"),
        (["--height", "nan"], "height"),
    ],
)
def test_estimate_positions_bad_arguments(datasets, tmp_path, capsys, extra, needle):
    out = tmp_path / "fixes.csv"
    line = run_error(estimate_positions_main, [str(datasets[0]), *extra, "-o", str(out)], capsys)
    assert needle in line
    assert not out.exists() and not list(tmp_path.iterdir())


def break_dataset(src: Path, dst: Path, how: str) -> Path:
    dst.mkdir()
    meta = json.loads((src / "meta.json").read_text())
    text = (src / "toa.csv").read_text()
    if how == "no_csv":
        text = None
    elif how == "columns":
        text = text.replace("x_true", "x_truth", 1)
    elif how == "number":
        lines = text.splitlines()
        f = lines[3].split(",")
        f[4] = "soon"
        lines[3] = ",".join(f)
        text = "\n".join(lines) + "\n"
    elif how == "bs_name":
        text = text.replace(",BS2,", ",BS7,", 1)
    elif how == "json":
        meta = None
    elif how == "two_bs":
        meta["base_stations"] = meta["base_stations"][:2]
        lines = text.splitlines()
        text = "\n".join([lines[0]] + [ln for ln in lines[1:] if ",BS1," in ln or ",BS2," in ln])
    elif how == "duplicate":
        lines = text.splitlines()
        text = "\n".join([*lines, lines[1]]) + "\n"
    if text is not None:
        (dst / "toa.csv").write_text(text)
    (dst / "meta.json").write_text("{not json" if meta is None else json.dumps(meta))
    return dst


@pytest.mark.parametrize(
    ("how", "needle"),
    [
        ("missing_dir", "not found"),
        ("no_csv", "toa.csv"),
        ("columns", "missing columns: x_true"),
        ("number", "bad number in toa_s"),
        ("bs_name", "'BS7'"),
        ("json", "meta.json"),
        ("two_bs", "no fix could be solved"),
        ("duplicate", "duplicate row"),
    ],
)
def test_bad_datasets_give_one_line_error_and_no_file(datasets, tmp_path, capsys, how, needle):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    src = tmp_path / "nothing" if how == "missing_dir" else None
    if src is None:
        src = break_dataset(datasets[0], tmp_path / "bad", how)
    out = out_dir / "fixes.csv"
    line = run_error(estimate_positions_main, [str(src), "-o", str(out)], capsys)
    assert needle in line
    assert not list(out_dir.iterdir())
    rep = tmp_path / "report"
    line = run_error(accuracy_report_main, [str(datasets[1]), str(src), "-o", str(rep)], capsys)
    assert needle in line
    assert not rep.exists()


def test_accuracy_report(datasets, tmp_path, capsys):
    out = tmp_path / "report"
    assert accuracy_report_main([*map(str, datasets), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    md = (out / "table.md").read_text()
    assert md in printed
    # one summary line per dataset and method, with availability and the doubtful-fix counts
    assert "static_c irls: 16 fixes, availability 100.0 % (0 unsolved)" in printed
    assert printed.count("; ill-conditioned ") == 2 * len(method_names(include_map=False))
    assert "| setup | band | method | avail. % |" in (out / "integrity.md").read_text()
    assert "| mean [m] | static | C-band | static_c |" in md
    assert "| 90th pct [m] | semi-dynamic | mmWave | semi_mm |" in md
    rows = read_csv(out / "table.csv")
    assert [r["metric"] for r in rows] == ["mean", "mean", "p90", "p90"] + ["availability"] * 2
    assert [r["dataset"] for r in rows] == ["static_c", "semi_mm"] * 3
    assert all(float(r[m]) == 100.0 for r in rows[4:] for m in method_names(include_map=False))
    assert float(rows[0]["paper_irls"]) == 0.24 and float(rows[3]["paper_ls"]) == 0.62
    for name in (
        "cdf_by_method",
        "cdf_static_c",
        "cdf_semi_mm",
        "topview_static_c",
        "topview_semi_mm",
    ):
        png = (out / f"{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    assert not list(out.glob(".*.tmp"))
    # the table agrees with estimate-positions for each (map-free, default) method on the data
    for m in method_names(include_map=False):
        fx = tmp_path / f"{m}.csv"
        assert estimate_positions_main([str(datasets[0]), "--method", m, "-o", str(fx)]) == 0
        s = summarize(np.array([float(r["error_m"]) for r in read_csv(fx)]))
        assert float(rows[0][m]) == pytest.approx(s["mean_m"], abs=1e-5)
        assert float(rows[2][m]) == pytest.approx(s["p90_m"], abs=1e-5)


def test_accuracy_report_bad_options(datasets, tmp_path, capsys):
    out = tmp_path / "r"
    line = run_error(
        accuracy_report_main, [str(datasets[0]), "--methods", "ls,nope", "-o", str(out)], capsys
    )
    assert "nope" in line
    line = run_error(accuracy_report_main, [str(datasets[0])], capsys)
    assert "-o" in line
    line = run_error(
        accuracy_report_main,
        [str(datasets[0]), "--param", "irls:u_max=0", "-o", str(out)],
        capsys,
    )
    assert "u_max" in line
    assert not out.exists()


#: Three points for the service area's and the alert limit's checks.
THREE_POINTS = np.array([[5.0, 6.0, 1.0], [14.0, 12.0, 1.0], [22.0, 19.0, 1.0]])


def test_cli_area_counts_columns_and_untrustworthy_run(tmp_path, capsys):
    # a service area that leaves P01 outside: its fixes are bounded, then rejected
    area = {"polygon": [[10, 2], [28, 2], [28, 24], [10, 24]], "source": "test"}
    ds = write_dataset(
        tmp_path / "d", points=THREE_POINTS, n_epochs=3, extra_meta={"service_area": area}
    )
    out = tmp_path / "f.csv"
    assert estimate_positions_main([str(ds), "--method", "irls", "-o", str(out)]) == 0
    line = capsys.readouterr().out
    assert "availability 100.0 % (0 unsolved)" in line and "out of area 3" in line
    assert "ill-conditioned 0, not converged 0" in line
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == FIXES_COLUMNS and FIXES_COLUMNS[-3:] == ("hpl_m", "chi2n", "flagged")
    p1 = [r for r in rows if r["point"] == "P01"]
    assert all("area_bound" in r["status"] and float(r["x"]) >= 10.0 - 1e-6 for r in p1)
    assert estimate_positions_main([str(ds), "--outside", "reject", "-o", str(out)]) == 0
    assert "availability 66.7 % (3 unsolved)" in capsys.readouterr().out
    # nothing inside: no trustworthy fix -> one-line error, exit 2, no file
    far = {"polygon": [[100, 100], [110, 100], [110, 110]], "source": "test"}
    ds2 = write_dataset(
        tmp_path / "e", points=THREE_POINTS, n_epochs=2, extra_meta={"service_area": far}
    )
    out2 = tmp_path / "g.csv"
    for extra in ([], ["--outside", "reject"]):
        assert estimate_positions_main([str(ds2), *extra, "-o", str(out2)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no trustworthy fix" in err[0], err
        assert not out2.exists()


@pytest.mark.parametrize("bad", ["0", "-1", "nan"])
def test_cli_bad_alert_limit(tmp_path, capsys, bad):
    ds = write_dataset(tmp_path / "d", points=THREE_POINTS, n_epochs=1)
    assert estimate_positions_main([str(ds), "--alert-limit", bad, "-o", str(tmp_path / "x")]) == 2
    assert "alert-limit" in capsys.readouterr().err


def test_accuracy_report_workers_bit_identical(datasets, tmp_path, capsys):
    """The datasets solved on two spawned worker processes give the report of one process, byte
    for byte (tables, integrity, the fixes in the figures), and the same printed lines."""
    outs = {}
    printed = {}
    for n in (1, 2):
        outs[n] = tmp_path / f"w{n}"
        argv = [*map(str, datasets), "-o", str(outs[n]), "--workers", str(n)]
        assert accuracy_report_main(argv) == 0
        printed[n] = capsys.readouterr().out.replace(str(outs[n]), "OUT")
    names = sorted(p.name for p in outs[1].iterdir())
    assert names == sorted(p.name for p in outs[2].iterdir())
    assert "table.csv" in names and "integrity.md" in names
    for name in names:
        assert (outs[1] / name).read_bytes() == (outs[2] / name).read_bytes(), name
    assert printed[1] == printed[2]


def test_accuracy_reports_side_by_side_are_the_reports_of_one_process(datasets, tmp_path,
                                                                       capsys):  # fmt: skip
    """Two reports on spawned processes at once (reproduce-paper's receivers): each writes the
    files the report written in this process writes, byte for byte, and returns what it
    printed; a report's error is raised in the caller."""
    from positioning.cli.accuracy import accuracy_reports
    from positioning.errors import PositioningError

    argvs = {n: [[str(datasets[0]), "-o", str(tmp_path / f"{n}{i}"), "--methods", m]
                 for i, m in enumerate(("ls,irls", "nlos-map"))]
             for n in ("alone", "side")}  # fmt: skip
    printed = []
    for argv in argvs["alone"]:
        assert accuracy_report_main(argv) == 0
        printed.append(capsys.readouterr().out.replace(argv[2], "OUT"))
    got = accuracy_reports(argvs["side"], 2)
    for i, (code, text, _) in enumerate(got):
        assert code == 0
        assert text.replace(argvs["side"][i][2], "OUT") == printed[i]
        alone, side = tmp_path / f"alone{i}", tmp_path / f"side{i}"
        names = sorted(p.name for p in alone.iterdir())
        assert names == sorted(p.name for p in side.iterdir()) and "table.csv" in names
        for name in names:
            assert (alone / name).read_bytes() == (side / name).read_bytes(), name
    bad = [str(tmp_path / "missing"), "-o", str(tmp_path / "bad")]
    with pytest.raises(PositioningError):
        accuracy_reports([argvs["side"][0], bad], 2)


def test_accuracy_report_bad_workers(datasets, tmp_path, capsys):
    out = tmp_path / "r"
    line = run_error(accuracy_report_main, [str(datasets[0]), "-o", str(out), "--workers", "0"],
                     capsys)  # fmt: skip
    assert "--workers" in line
    assert not out.exists()
