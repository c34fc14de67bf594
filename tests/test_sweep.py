"""Sweeps: config validation, cell keys, the end-to-end pipeline's invariants (ToA causality,
exact positions from exact ToAs, IRLS vs LS under injected NLoS, clutter vs LoS), resume after
an interruption, the local pool and a real Dask LocalCluster, and the command line."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
import yaml

from raytrace.cli.run_sweep import run_sweep_main
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.studies.sweep import (
    CELL_KEYS,
    cell_key,
    cell_path,
    load_sweep_config,
    parse_sweep_config,
    run_cell,
    run_sweep,
    simulate_cell,
)

SMALL = "30x24x8"
#: exact (noise-free) ToA of a LoS link vs distance / c, seconds (float64 over ~1e-7 s)
DELAY_TOL_S = 1e-15
#: eq. 3 noise: a first-path ToA is never earlier than d/c by more than this many sigma
NOISE_SIGMAS = 6.0
#: exact ToAs on all-LoS fixes give the position to this, m (Gauss-Newton tolerance)
EXACT_POS_TOL_M = 1e-6
#: fields of a cell result that depend on the machine, not on the parameters
VOLATILE = ("timing_s", "host")


def small_config(**over) -> dict:
    cfg = {
        "name": "test",
        "grid": {"profile": ["InF-SL", "InF-SH"], "seed": [0, 1]},
        "fixed": {
            "size": SMALL,
            "n_points": 8,
            "max_reflections": 1,
            "max_diffractions": 0,
            "max_interactions": 1,
            "duration_s": 1.0,
            "rate_hz": 3.0,
        },
        "methods": ["ls", "irls"],
    }
    cfg.update(over)
    return cfg


def _stable(result: dict) -> dict:
    return {k: v for k, v in result.items() if k not in VOLATILE}


# --------------------------------------------------------------------------------------------
# config
# --------------------------------------------------------------------------------------------


def test_cells_are_the_grid_product_with_defaults():
    cfg = parse_sweep_config(small_config())
    cells = cfg.cells()
    assert [(c.params["profile"], c.params["seed"]) for c in cells] == [
        ("InF-SL", 0),
        ("InF-SL", 1),
        ("InF-SH", 0),
        ("InF-SH", 1),
    ]
    assert set(cells[0].params) == set(CELL_KEYS)
    assert cells[0].params["band"] == "c-band" and cells[0].params["n_points"] == 8
    assert cells[0].methods["irls"]["u_max"] == 3.0  # positioning's default, filled in
    assert len({c.key for c in cells}) == 4
    assert cfg.varying == ["profile", "seed"]


def test_cell_key_depends_on_every_parameter_not_on_order():
    cfg = parse_sweep_config(small_config())
    cell = cfg.cells()[0]
    reordered = dict(reversed(list(cell.params.items())))
    assert cell_key(reordered, cell.methods) == cell.key
    for k, v in (("n_points", 9), ("band", "mmwave"), ("max_penetrations", 1), ("noise", False)):
        assert cell_key({**cell.params, k: v}, cell.methods) != cell.key
    other = {**cell.methods, "irls": {**cell.methods["irls"], "u_max": 1.0}}
    assert cell_key(cell.params, other) != cell.key
    # method parameters in the grid
    cfg2 = parse_sweep_config(small_config(grid={"profile": ["InF-SL"], "irls.u_max": [1.0, 2.0]}))
    assert [c.methods["irls"]["u_max"] for c in cfg2.cells()] == [1.0, 2.0]
    assert cfg2.varying == ["irls.u_max"]


@pytest.mark.parametrize(
    "over, match",
    [
        ({"grids": {}}, "unknown key 'grids'"),
        ({"grid": {"profile": ["InF-SL"], "colour": [1]}}, "unknown parameter"),
        ({"grid": {"profile": "InF-SL"}}, "non-empty list"),
        ({"grid": {"profile": ["InF-SL", "InF-SL"]}}, "listed twice"),
        ({"grid": {"profile": ["InF-XL"]}}, "unknown profile"),
        ({"grid": {"seed": [0]}}, "give the profile"),
        ({"grid": {"profile": ["InF-SL"], "size": ["30x24"]}}, "bad size"),
        ({"grid": {"profile": ["InF-SL"], "density": [0.1, 0.5]}}, "cell 1 .*out of range"),
        ({"grid": {"profile": ["InF-DL"], "size": ["12x12x8"], "density": [0.7]}}, "cannot place"),
        ({"grid": {"profile": ["InF-SL"], "band": ["x-band"]}}, "band"),
        ({"grid": {"profile": ["InF-SL"], "toa_method": ["magic"]}}, "toa_method"),
        ({"grid": {"profile": ["InF-SL"], "max_reflections": [3]}}, "max_reflections"),
        ({"grid": {"profile": ["InF-SL"], "rate_hz": [0]}}, "rate_hz"),
        ({"grid": {"profile": ["InF-SL"], "inject_nlos_fraction": [1.5]}}, "inject_nlos"),
        ({"grid": {"profile": ["InF-SL"], "height": ["maybe"]}}, "height"),
        ({"grid": {"profile": ["InF-SL"]}, "methods": ["ls", "magic"]}, "unknown method"),
        ({"grid": {"profile": ["InF-SL"]}, "method_params": {"irls": {"u_max": -1}}}, "u_max"),
        ({"grid": {"profile": ["InF-SL"]}, "method_params": {"irls": {"bogus": 1}}}, "bogus"),
        ({"grid": {"profile": ["InF-SL"], "subset.alpha": [0.1]}}, "not in methods"),
        (
            {"grid": {"profile": ["InF-SL"], "seed": [0]}, "fixed": {"seed": 1}},
            "both grid and fixed",
        ),
    ],
)
def test_bad_configs_one_line_errors(over, match):
    cfg = small_config(**{k: v for k, v in over.items() if k != "fixed"})
    cfg["fixed"] = {k: v for k, v in cfg["fixed"].items() if k not in cfg["grid"]}
    cfg["fixed"].update(over.get("fixed", {}))
    with pytest.raises(HallrayError, match=match) as exc:
        parse_sweep_config(cfg, source="s.yaml")
    assert "\n" not in str(exc.value)
    assert str(exc.value).startswith("s.yaml: ")


def test_load_config_file_errors(tmp_path):
    with pytest.raises(HallrayError, match="cannot read"):
        load_sweep_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("grid: [unclosed\n")
    with pytest.raises(HallrayError, match="invalid YAML"):
        load_sweep_config(bad)


# --------------------------------------------------------------------------------------------
# the pipeline of one cell
# --------------------------------------------------------------------------------------------


def _cell(**over):
    fixed = {**small_config()["fixed"], "profile": "InF-SL", **over}
    cfg = parse_sweep_config(small_config(grid={}, fixed=fixed))
    return cfg.cells()[0]


@pytest.mark.parametrize("profile", ["InF-SL", "InF-DL", "InF-SH", "InF-DH"])
def test_toa_never_before_line_of_sight(profile):
    """Causality: a first-arrival ToA is at or after d/c, up to eq. 3 noise; noise-free LoS links
    give exactly d/c; the measured ToA is schedule + clock + delay (+ injected NLoS)."""
    n = 10 if profile[-2] == "S" else 5
    # the ideal receiver: its error is eq. 3 noise alone (band-limited receivers can be early)
    cell = _cell(
        profile=profile, seed=3, n_points=n, max_diffractions=1, max_interactions=1,
        toa_method="first-path",
    )  # fmt: skip
    data = simulate_cell(cell.params, cell.methods)
    los_delay = (data.distance_m / C0).T  # (N, B)
    prop = data.propagation_toa_s  # (E, N, B)
    ok = np.isfinite(prop)
    sigma = np.broadcast_to(data.sigma_s.T, prop.shape)
    assert ok.any()
    assert np.all(prop[ok] >= np.broadcast_to(los_delay, prop.shape)[ok] - NOISE_SIGMAS * sigma[ok])
    rebuilt = data.tx_offset_s[None, None, :] + data.clock_offset_s[:, :, None] + prop
    np.testing.assert_array_equal(np.isfinite(data.toa_s), ok)
    np.testing.assert_allclose(data.toa_s[ok], rebuilt[ok], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(data.tx_offset_s, 0.01 * np.arange(len(data.bs_xyz)))
    exact_cell = _cell(profile=profile, seed=3, n_points=n, noise=False, toa_method="first-path")
    exact = simulate_cell(exact_cell.params, exact_cell.methods)
    e_prop = exact.propagation_toa_s[0]  # (N, B)
    e_ok = np.isfinite(e_prop)
    assert np.all(e_prop[e_ok] >= los_delay[e_ok] - DELAY_TOL_S)
    los = exact.los.T & e_ok
    np.testing.assert_allclose(e_prop[los], los_delay[los], rtol=0, atol=DELAY_TOL_S)


def test_exact_toas_give_exact_positions():
    """Noise-free ToAs in a hall where some devices see every BS on line of sight: their fixes
    are exact (whatever the schedule and clock offsets), for LS and IRLS."""
    cell = _cell(profile="InF-SH", seed=2, n_points=12, noise=False, toa_method="first-path")
    data = simulate_cell(cell.params, cell.methods)
    all_los = data.los.all(axis=0)  # (N,)
    assert all_los.sum() >= 3
    fix_all_los = np.tile(all_los, data.toa_s.shape[0])
    for m in ("ls", "irls"):
        err = data.errors_2d(m)
        assert np.all(err[fix_all_los] < EXACT_POS_TOL_M)


def test_injected_nlos_irls_beats_ls_on_average():
    """Injected positive biases (1-3 m extra path) on 20 % of the ToAs in mostly-LoS halls with
    9 base stations: the paper's IRLS beats LS on the mean 2D error averaged over seeds, and LS
    is worse than without injection."""
    cfg = parse_sweep_config(
        small_config(
            grid={"seed": [0, 1, 2, 3]},
            fixed={
                **small_config()["fixed"],
                "profile": "InF-SH",
                "bs_grid": [3, 3],
                "n_points": 10,
                "noise": True,
                "inject_nlos_fraction": 0.2,
                "inject_nlos_bias_m": 2.0,
            },
        )
    )
    means = {"ls": [], "irls": []}
    for cell in cfg.cells():
        res = run_cell(cell.task())
        assert 0.1 < res["stats"]["injected_fraction"] < 0.3
        for m in means:
            means[m].append(res["errors"][m]["mean_m"])
    assert np.mean(means["irls"]) < np.mean(means["ls"])
    clean = parse_sweep_config(
        small_config(grid={"seed": [0]}, fixed={**cfg.fixed, "inject_nlos_fraction": 0.0})
    ).cells()[0]
    res = run_cell(clean.task())
    assert res["errors"]["ls"]["mean_m"] < means["ls"][0]


def test_more_clutter_fewer_los_links_through_the_pipeline():
    cfg = parse_sweep_config(
        small_config(grid={"profile": ["InF-SL", "InF-DL"], "seed": [0, 1, 2]})
    )
    los = {"InF-SL": [], "InF-DL": []}
    for cell in cfg.cells():
        res = run_cell(cell.task())
        los[cell.params["profile"]].append(res["stats"]["los_fraction"])
        assert 0.0 <= res["stats"]["detected_fraction"] <= 1.0
    assert np.mean(los["InF-DL"]) < np.mean(los["InF-SL"])


# --------------------------------------------------------------------------------------------
# running, resuming, clusters
# --------------------------------------------------------------------------------------------


def test_resume_recomputes_only_missing_cells(tmp_path):
    cfg = parse_sweep_config(small_config())
    out = tmp_path / "out"
    first = run_sweep(cfg, out, workers=1, limit=2)  # "interrupted" after 2 cells
    assert len(first.computed) == 2 and not first.skipped
    assert "2 of 4 cells" in (out / "results.md").read_text()
    second = run_sweep(cfg, out, workers=1)
    assert sorted(second.skipped) == sorted(first.computed)
    assert len(second.computed) == 2 and set(second.computed).isdisjoint(first.computed)
    files = {c.key: cell_path(out, c.key) for c in cfg.cells()}
    stamp = {k: (p.stat().st_mtime_ns, p.read_bytes()) for k, p in files.items()}
    victim = cfg.cells()[2].key
    os.unlink(files[victim])
    third = run_sweep(cfg, out, workers=1)
    assert third.computed == [victim] and len(third.skipped) == 3
    for k, p in files.items():
        if k != victim:
            assert (p.stat().st_mtime_ns, p.read_bytes()) == stamp[k]
    assert _stable(json.loads(files[victim].read_text())) == _stable(json.loads(stamp[victim][1]))
    # a corrupt (e.g. truncated by hand) cell file is recomputed, not trusted
    files[victim].write_text("{")
    assert run_sweep(cfg, out, workers=1).computed == [victim]
    # no temporary files left behind; the tables have every cell
    assert sorted(p.name for p in (out / "cells").iterdir()) == sorted(f"{k}.json" for k in files)
    rows = (out / "results.csv").read_text().splitlines()
    assert len(rows) == 5 and rows[0].startswith("cell,profile,seed,los_fraction")
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["n_finished"] == 4 and summary["last_run"]["computed"] == 1


def test_datasets_are_the_dataset_writers_and_give_the_same_fixes(tmp_path):
    """``datasets: true``: every cell's ToA dataset is written by the dataset writer
    (raytrace.emulation.dataset.write_dataset) from the cell's measurements; its ToAs equal the
    sweep's in-memory ones exactly, and positioning the dataset file gives the cell's errors. A
    missing dataset makes its cell count as not done."""
    from positioning import error_2d, locate, summarize
    from positioning.io.dataset import load_dataset
    from raytrace.studies.sweep import dataset_dir

    cfg = parse_sweep_config(small_config(grid={"profile": ["InF-SL", "InF-SH"]}, datasets=True))
    out = tmp_path / "out"
    rep = run_sweep(cfg, out, workers=1)
    assert len(rep.computed) == 2
    for cell in cfg.cells():
        res = json.loads(cell_path(out, cell.key).read_text())
        assert res["stats"]["dataset_max_diff_s"] == 0.0
        assert "_files" not in res
        ds = load_dataset(dataset_dir(out, cell.key))
        assert ds.n_fixes == res["stats"]["n_fixes"]
        for m, p in cell.methods.items():
            xyz = locate(
                ds.toa_s,
                ds.bs_xyz,
                m,
                tx_offsets_s=ds.tx_offset_s[0],
                height_m=ds.true_xyz[:, 2],
                **p,
            )
            got = summarize(error_2d(xyz, ds.true_xyz))
            for k in ("n", "n_unsolved"):
                assert got[k] == res["errors"][m][k]
            for k in ("mean_m", "median_m", "p90_m"):
                assert got[k] == pytest.approx(res["errors"][m][k], rel=1e-9, abs=1e-12)
    victim = cfg.cells()[1].key
    (dataset_dir(out, victim) / "toa.csv").unlink()
    again = run_sweep(cfg, out, workers=1)
    assert again.computed == [victim] and len(again.skipped) == 1
    assert (dataset_dir(out, victim) / "toa.csv").is_file()
    with pytest.raises(HallrayError, match="datasets"):
        parse_sweep_config(small_config(datasets="yes"))


def test_sweep_dataset_is_byte_for_byte_what_make_dataset_writes(tmp_path):
    """The sweep writes a cell's dataset from the ToAs it positions (no second trace): the files
    are byte for byte those make_dataset writes for the cell's hall and settings, so the two
    writers cannot drift apart (the realistic receiver with noise; a rate that is not 10 Hz)."""
    from raytrace.emulation.dataset import make_dataset
    from raytrace.halls.inf import generate_hall, scene_from_spec
    from raytrace.solver.config import TraceConfig
    from raytrace.studies.sweep import HALL_KEYS, dataset_dir

    cfg = parse_sweep_config(
        small_config(grid={"profile": ["InF-DH"]}, fixed={**small_config()["fixed"], "seed": 5},
                     datasets=True)
    )  # fmt: skip
    (cell,) = cfg.cells()
    assert cell.params["toa_method"] == "search-back" and cell.params["noise"] is True
    run_sweep(cfg, tmp_path / "sweep", workers=1)
    p = cell.params
    spec = generate_hall(
        p["profile"], p["size"], p["seed"], los_notes=False,
        **{k: p[k] for k in HALL_KEYS if k not in ("profile", "size", "seed")},
    )  # fmt: skip
    make_dataset(
        tmp_path / "made", "static", p["band"], scene=scene_from_spec(spec),
        duration_s=p["duration_s"], rate_hz=p["rate_hz"], seed=p["seed"],
        toa_method=p["toa_method"], noise=p["noise"], trace_settings=TraceConfig.from_mapping(p),
    )  # fmt: skip
    swept = dataset_dir(tmp_path / "sweep", cell.key)
    assert sorted(f.name for f in swept.iterdir()) == ["meta.json", "toa.csv"]
    for name in ("toa.csv", "meta.json"):
        assert (swept / name).read_bytes() == (tmp_path / "made" / name).read_bytes(), name


def test_local_pool_matches_in_process(tmp_path):
    cfg = parse_sweep_config(small_config())
    a = run_sweep(cfg, tmp_path / "a", workers=1)
    b = run_sweep(cfg, tmp_path / "b", workers=2)
    assert b.mode == "pool:2" and not b.failed
    for key in a.results:
        assert _stable(a.results[key]) == _stable(b.results[key])


def test_dask_local_cluster_in_process(tmp_path):
    """The Dask path for real: a LocalCluster in this process (inproc transport, no sockets)."""
    distributed = pytest.importorskip("distributed")
    cfg = parse_sweep_config(small_config())
    ref = run_sweep(cfg, tmp_path / "ref", workers=1)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        res = run_sweep(cfg, tmp_path / "dask", scheduler=cluster.scheduler_address)
        again = run_sweep(cfg, tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert res.mode == "dask" and not res.failed and len(res.computed) == 4
    assert len(again.skipped) == 4 and not again.computed
    for key in ref.results:
        assert _stable(ref.results[key]) == _stable(res.results[key])


@pytest.mark.skipif(not os.uname().sysname == "Linux", reason="glibc mallopt")
def test_tune_malloc_applies_on_glibc():
    from raytrace.studies.cluster import tune_malloc

    assert tune_malloc() is True


@pytest.mark.slow
def test_dask_local_cluster_two_worker_processes(tmp_path):
    """Two worker processes on 127.0.0.1 (tcp), as on a real cluster: same results."""
    distributed = pytest.importorskip("distributed")
    cfg = parse_sweep_config(small_config())
    ref = run_sweep(cfg, tmp_path / "ref", workers=1)
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert (
            run_sweep_main(
                [
                    str(_write(tmp_path, cfg_dict=small_config())),
                    "-o",
                    str(tmp_path / "cli"),
                    "--scheduler",
                    cluster.scheduler_address,
                    "-q",
                ]
            )
            == 0
        )
    for key in ref.results:
        got = json.loads(cell_path(tmp_path / "cli", key).read_text())
        assert _stable(got) == _stable(ref.results[key])


def test_unreachable_scheduler_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    pytest.importorskip("distributed")
    import raytrace.studies.cluster as cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 0.5)
    path = _write(tmp_path, small_config())
    code = run_sweep_main(
        [str(path), "-o", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: cannot connect") and err.count("\n") == 1
    assert not (tmp_path / "o").exists()  # nothing written


# --------------------------------------------------------------------------------------------
# command line
# --------------------------------------------------------------------------------------------


def _write(tmp_path, cfg_dict, name: str = "sweep.yaml") -> os.PathLike:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(cfg_dict, sort_keys=False))
    return path


def test_cli_runs_lists_and_resumes(tmp_path, capsys):
    path = _write(tmp_path, small_config(grid={"profile": ["InF-SL"], "seed": [0, 1]}))
    assert run_sweep_main([str(path), "--workers", "1", "--limit", "1", "-q"]) == 0
    out = capsys.readouterr().out
    assert "1 computed, 0 already done" in out
    default_out = tmp_path / "sweep-sweep"
    assert (default_out / "results.md").is_file()
    assert run_sweep_main([str(path), "--list"]) == 0
    listing = capsys.readouterr().out.splitlines()
    assert [line.split()[2] for line in listing] == ["done", "todo"]
    assert run_sweep_main([str(path), "--workers", "1", "-q"]) == 0
    assert "1 computed, 1 already done" in capsys.readouterr().out
    md = (default_out / "results.md").read_text()
    assert "\n| cell | seed | los_fraction |" in md  # only the seed varies
    assert md.count("\n| ") == 1 + 2  # header and two cells


def test_cli_bad_input(tmp_path, capsys):
    for argv in (
        [str(tmp_path / "missing.yaml")],
        [str(_write(tmp_path, {"grid": {"profile": ["InF-ZZ"]}}, "bad.yaml"))],
        [str(_write(tmp_path, small_config())), "--workers", "0"],
        [str(_write(tmp_path, small_config())), "--limit", "-1"],
        [str(_write(tmp_path, small_config())), "-o", str(tmp_path / "no" / "such" / "dir")],
    ):
        assert run_sweep_main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1


def test_failed_cell_is_reported_and_retried(tmp_path, monkeypatch, capsys):
    import raytrace.studies.sweep.run as sweep

    real = sweep.run_cell

    def flaky(task):
        if task["params"]["seed"] == 1:
            raise HallrayError("simulated failure")
        return real(task)

    monkeypatch.setattr(sweep, "run_cell", flaky)
    path = _write(tmp_path, small_config(grid={"profile": ["InF-SL"], "seed": [0, 1]}))
    assert run_sweep_main([str(path), "--workers", "1", "-q", "-o", str(tmp_path / "o")]) == 1
    captured = capsys.readouterr()
    assert "1 failed" in captured.out and "simulated failure" in captured.err
    monkeypatch.setattr(sweep, "run_cell", real)
    assert run_sweep_main([str(path), "--workers", "1", "-q", "-o", str(tmp_path / "o")]) == 0
    assert "1 computed, 1 already done" in capsys.readouterr().out


def test_example_config_is_valid():
    from pathlib import Path

    example = Path(__file__).resolve().parent.parent / "docs" / "sweep_example.yaml"
    cfg = load_sweep_config(example)
    assert len(cfg.cells()) == 20
    assert cfg.varying == ["profile", "seed"]
    assert math.isfinite(cfg.cells()[0].params["duration_s"])
