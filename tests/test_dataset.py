"""ToA datasets: time model, LoS flags under moving forklifts, reproducibility, CLI, atomic output."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import box, make_scene, quad

from hallray.safe_output import MARKER
from raytrace.cli.make_dataset import make_dataset_main
from raytrace.core.constants import K_BOLTZMANN
from raytrace.core.errors import HallrayError, SceneError
from raytrace.emulation.bands import get_band
from raytrace.emulation.channel import LinkBudget, detection_snr_db
from raytrace.emulation.dataset import COLUMNS, make_dataset, make_datasets
from raytrace.emulation.measurement import (
    CLOCK_OFFSET_MAX_S,
    DELTA_S,
    Measurements,
    ToaModel,
    emulate_toa,
    epoch_rngs,
    link_los,
)
from raytrace.emulation.receivers import Receiver
from raytrace.solver.tracer import trace

#: ToAs are sums of a schedule (<= 0.03 s), a clock offset (< 1 ms) and a delay: float64 keeps
#: them to ~1e-17 s; the CSV stores repr() (round trip).
TOA_TOL_S = 1e-15
#: Positions and distances, m.
POS_TOL_M = 1e-12

BS = [("BS1", (10.0, 2.0, 1.0)), ("BS2", (2.0, 18.0, 3.0)), ("BS3", (18.0, 18.0, 3.0))]
POINTS = [("P1", (10.0, 18.0, 1.0)), ("P2", (15.0, 6.0, 1.0))]
ROUTE = {
    "name": "forklift_1",
    "size": [2.0, 1.0, 2.0],
    "material": "metal",
    "waypoints": [[2.05, 10.0], [17.95, 10.0]],
    "speed": 2.0,
    "mode": "back_and_forth",
}


def _metadata(routes=True, bs=True, points=True):
    meta = {
        "hall": {"size": [20.0, 20.0, 5.0]},
        "obstacles_2d": [{"name": "crate", "xy": [[4, 4], [5, 4], [5, 5], [4, 5]], "z": [0, 1]}],
    }
    if bs:
        meta["base_stations"] = [{"name": n, "xyz": list(p)} for n, p in BS]
    if points:
        meta["points"] = [{"name": n, "xyz": list(p)} for n, p in POINTS]
    if routes:
        meta["routes"] = [ROUTE]
    return {"hallray": meta}


def _scene(**kw):
    objects = [
        ("floor", quad((0, 0, 0), (20, 0, 0), (0, 20, 0)), "concrete"),
        ("crate", box((4.0, 4.0, 0.0), (5.0, 5.0, 1.0)), "wood"),
    ]
    sc = make_scene(objects)
    sc.metadata = _metadata(**kw)
    return sc


def _read(d: Path) -> tuple[list[dict[str, str]], dict]:
    with (d / "toa.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return rows, json.loads((d / "meta.json").read_text())


def _first_detectable_delay(paths, band, noise_figure_db=9.0):
    """Independent detection rule: per-path SNR P_tx |g|^2 / (k T B F) times the processing
    gain B / spacing must reach the Marcum-Q SNR of (P_fa, P_d)."""
    assert LinkBudget().noise_figure_db == noise_figure_db
    noise_w = K_BOLTZMANN * 290.0 * band.bandwidth_hz * 10 ** (noise_figure_db / 10)
    snr = 0.1 * np.abs(paths.gain) ** 2 / noise_w  # 20 dBm
    post_db = 10 * np.log10(snr * band.bandwidth_hz / band.subcarrier_spacing_hz)
    ok = post_db >= detection_snr_db(1e-6, 0.9)
    out = np.full(paths.n_links, np.nan)
    for link in range(paths.n_links):
        sel = ok & (paths.link == link)
        if sel.any():
            out[link] = paths.delay_s[sel].min()
    return out


# -- emulate_toa ------------------------------------------------------------------------------
def test_emulate_toa_without_noise_is_the_first_detectable_delay():
    sc = _scene()
    tx = np.array([p for _, p in BS])
    rx = np.array([p for _, p in POINTS])
    band = get_band("mmwave")
    paths = trace(sc, tx, rx, band.center_frequency_hz)
    est = emulate_toa(paths, band, method="first-path", noise=False)
    want = _first_detectable_delay(paths, band)
    np.testing.assert_array_equal(np.isnan(est.toa_s), np.isnan(want))
    np.testing.assert_allclose(est.toa_s, want, rtol=0, atol=0)
    # kinds and LoS flags of the first paths
    assert set(est.first_kind) <= set(paths.kind_label)
    los = np.array([paths.los[paths.link == k].any() for k in range(paths.n_links)])
    np.testing.assert_array_equal(est.los, los)


# -- the measurement model --------------------------------------------------------------------
def _small_paths(band):
    tx = np.array([p for _, p in BS])
    rx = np.array([p for _, p in POINTS])
    return trace(_scene(), tx, rx, get_band(band).center_frequency_hz)


def test_los_flags_given_once_are_those_each_epoch_computes():
    """The datasets compute the links' LoS flags once per band and snapshot for all its models:
    the same flags (an independent per-link test) and the same measurements as without."""
    paths = _small_paths("c-band")
    los = link_los(paths)
    want = np.array([paths.los[paths.link == k].any() for k in range(paths.n_links)])
    assert los.dtype == bool and los.tolist() == want.tolist()
    model = ToaModel(Receiver("first-path", "c-band"), seed=3)
    a, b = model.measure(paths, [0, 4]), model.measure(paths, [0, 4], None, los)
    for name in Measurements.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_measurement_model_is_schedule_plus_clock_plus_first_detectable_delay():
    """Noise-free first-path ToAs: delay = the independent first detectable delay, schedule
    b * delta, one clock offset per (epoch, point) drawn from the epoch's first stream."""
    paths = _small_paths("c-band")
    model = ToaModel(Receiver("first-path", "c-band"), seed=7, noise=False)
    m = model.measure(paths, [0, 1, 2, 5])
    n_p, n_b = len(POINTS), len(BS)
    assert m.toa_s.shape == (4, n_p, n_b) and m.clock_offset_s.shape == (4, n_p)
    want = _first_detectable_delay(paths, get_band("c-band")).reshape(n_b, n_p).T  # (N, B)
    for i, e in enumerate([0, 1, 2, 5]):
        np.testing.assert_array_equal(m.delay_s[i], want)
        clock = epoch_rngs(7, e)[0].uniform(0.0, CLOCK_OFFSET_MAX_S, n_p)
        np.testing.assert_array_equal(m.clock_offset_s[i], clock)
    np.testing.assert_array_equal(m.tx_offset_s, DELTA_S * np.arange(n_b))
    rebuilt = m.tx_offset_s[None, None, :] + m.clock_offset_s[:, :, None] + want[None]
    np.testing.assert_allclose(m.toa_s, rebuilt, rtol=0, atol=TOA_TOL_S)
    np.testing.assert_array_equal(np.isnan(m.toa_s), ~m.detected)


def test_measurements_do_not_depend_on_how_epochs_are_grouped():
    """Each epoch draws from its own streams: measuring epochs together, in chunks or one by one
    gives the same numbers, with the realistic receiver and its noise."""
    paths = _small_paths("mmwave")
    model = ToaModel(Receiver("first-lobe", "mmwave"), seed=2)
    whole = model.measure(paths, range(6))
    prep = model.prepare(paths)
    parts = Measurements.concatenate(
        [
            model.measure(paths, [0, 1], prep),
            model.measure(paths, [2]),
            model.measure(paths, [3, 4, 5]),
        ]
    )
    names = ("epochs", "toa_s", "delay_s", "clock_offset_s", "snr_db", "first_kind", "detected")
    for name in names:
        np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name), err_msg=name)
    assert np.isfinite(whole.toa_s).any()
    assert not np.array_equal(whole.toa_s[0], whole.toa_s[1])  # other epoch, other draws


# -- the time model ---------------------------------------------------------------------------
def test_static_toa_is_delay_plus_schedule_plus_clock_offset(tmp_path):
    sc = _scene()
    out = tmp_path / "ds"
    summary = make_dataset(
        out, "static", "c-band", scene=sc, duration_s=1.0, rate_hz=5.0, seed=3, noise=False,
        toa_method="first-path",
    )  # fmt: skip
    rows, meta = _read(out)
    assert summary["epochs"] == 5 and len(rows) == 5 * len(POINTS) * len(BS)
    assert list(rows[0]) == list(COLUMNS)
    band = get_band("c-band")
    tx = np.array([p for _, p in BS])
    rx = np.array([p for _, p in POINTS])
    paths = trace(sc, tx, rx, band.center_frequency_hz)
    first = _first_detectable_delay(paths, band)
    bs_index = {n: k for k, (n, _) in enumerate(BS)}
    pt_index = {n: k for k, (n, _) in enumerate(POINTS)}
    clocks: dict[tuple[int, str], float] = {}
    for r in rows:
        b, p, e = bs_index[r["bs"]], pt_index[r["point"]], int(r["epoch"])
        assert float(r["time_s"]) == e / 5.0
        assert float(r["tx_offset_s"]) == b * DELTA_S == meta["schedule_s"][r["bs"]]
        clock = float(r["clock_offset_s"])
        assert 0.0 <= clock < CLOCK_OFFSET_MAX_S
        # one clock offset per fix (epoch, point), the same for every base station
        assert clocks.setdefault((e, r["point"]), clock) == clock
        want = b * DELTA_S + clock + first[b * len(POINTS) + p]
        assert float(r["toa_s"]) == pytest.approx(want, abs=TOA_TOL_S)
        xyz = np.array([float(r[c]) for c in ("x_true", "y_true", "z_true")])
        np.testing.assert_allclose(xyz, POINTS[p][1], atol=POS_TOL_M)
        dist = np.linalg.norm(np.subtract(POINTS[p][1], BS[b][1]))
        assert float(r["distance_m"]) == pytest.approx(dist, abs=POS_TOL_M)
    # the offsets differ between fixes
    assert len(set(clocks.values())) == len(clocks)


def test_noise_follows_eq3_scale(tmp_path):
    """With noise on, the ToA error of each row is within a few eq. 3 sigmas of zero."""
    sc = _scene()
    kw = {"scene": sc, "duration_s": 2.0, "rate_hz": 10.0, "toa_method": "first-path"}
    make_dataset(tmp_path / "n", "static", "mmwave", **kw)
    make_dataset(tmp_path / "q", "static", "mmwave", noise=False, **kw)
    rows_n, _ = _read(tmp_path / "n")
    rows_q, _ = _read(tmp_path / "q")
    err = np.array([float(a["toa_s"]) - float(b["toa_s"]) for a, b in zip(rows_n, rows_q)])
    # same seed -> same clock offsets; the difference is the estimation noise alone
    assert np.all(np.abs(err) > 0)
    snr = 10 ** (np.array([float(a["snr_db"]) for a in rows_n]) / 10)
    band = get_band("mmwave")
    t_s = 1 / band.subcarrier_spacing_hz
    sigma = 1 / np.sqrt((2 * math.pi * band.bandwidth_hz) ** 2 * t_s * band.bandwidth_hz * snr)
    z = err / sigma
    assert np.all(np.abs(z) < 6)
    assert 0.6 < np.std(z) < 1.4


SEMI = dict(duration_s=6.0, rate_hz=5.0, seed=11, toa_method="first-path")


@pytest.fixture(scope="module")
def semi_w1(tmp_path_factory) -> Path:
    """A semi-dynamic dataset of the small scene, one worker."""
    out = tmp_path_factory.mktemp("semi") / "w1"
    make_datasets(out, [("semi-dynamic", "c-band")], scene=_scene(), workers=1, **SEMI)
    return out / "semi-dynamic-c-band"


def test_semi_dynamic_los_flag_follows_the_forklift(semi_w1):
    """BS1 (10, 2, 1) -> P1 (10, 18, 1) is blocked while the box (x(t) +- 1, 10 +- 0.5) covers
    x = 10: x(t) = 2.05 + 2 t, so for 3.475 < t < 4.475 s (and on the way back)."""
    rows, meta = _read(semi_w1)
    link = [r for r in rows if r["bs"] == "BS1" and r["point"] == "P1"]
    t = np.array([float(r["time_s"]) for r in link])
    blocked = np.abs(2.05 + 2 * t - 10.0) < 1.0
    assert blocked.sum() == 5
    los = np.array([r["los"] == "1" for r in link])
    np.testing.assert_array_equal(los, ~blocked)
    d_los = 16.0 / 299_792_458.0
    # eq. 3 noise at these SNRs is ~1e-12 s; detours around the box are > 4e-10 s longer
    for r, b in zip(link, blocked):
        toa = float(r["toa_s"]) - float(r["clock_offset_s"]) if r["toa_s"] else math.inf
        if b:
            assert r["first_kind"] != "LoS" and toa > d_los + 1e-10
        else:
            assert r["first_kind"] == "LoS" and toa == pytest.approx(d_los, abs=1e-10)
    assert meta["forklifts"]["routes"][0]["name"] == "forklift_1"
    poses = (semi_w1 / "forklifts.csv").read_text().splitlines()
    assert len(poses) == 1 + 30 and poses[0].startswith("epoch,time_s,forklift,x,y")


def test_same_seed_gives_identical_files_whatever_the_workers(tmp_path, semi_w1):
    make_datasets(tmp_path / "w2", [("semi-dynamic", "c-band")], scene=_scene(), workers=2, **SEMI)
    for name in ("toa.csv", "meta.json", "forklifts.csv"):
        a = (semi_w1 / name).read_bytes()
        assert a == (tmp_path / "w2" / "semi-dynamic-c-band" / name).read_bytes(), name
    # another seed draws other offsets and noise
    kw = dict(scene=_scene(), duration_s=0.5)
    make_dataset(tmp_path / "s1", "static", "c-band", seed=1, **kw)
    make_dataset(tmp_path / "s2", "static", "c-band", seed=2, **kw)
    make_dataset(tmp_path / "s1b", "static", "c-band", seed=1, **kw)
    one = (tmp_path / "s1" / "toa.csv").read_bytes()
    assert one == (tmp_path / "s1b" / "toa.csv").read_bytes()
    assert one != (tmp_path / "s2" / "toa.csv").read_bytes()


def test_first_lobe_datasets_identical_whatever_the_workers(tmp_path):
    """The default receiver draws its noise from the epoch's own stream: worker count and chunking
    do not change a byte."""
    kw = dict(scene=_scene(), duration_s=3.0, rate_hz=5.0, seed=4)
    pairs = [("static", "c-band"), ("semi-dynamic", "mmwave")]
    make_datasets(tmp_path / "w1", pairs, workers=1, **kw)
    make_datasets(tmp_path / "w2", pairs, workers=2, **kw)
    for sub in ("static-c-band", "semi-dynamic-mmwave"):
        a = (tmp_path / "w1" / sub / "toa.csv").read_bytes()
        assert a == (tmp_path / "w2" / sub / "toa.csv").read_bytes(), sub
        assert b",LoS," in a  # the small scene has line-of-sight links


def test_static_epochs_on_workers_equal_this_process(tmp_path, monkeypatch):
    """A static group with a costly receiver (search-back) is measured on worker processes from
    STATIC_POOL_EPOCHS epochs on, each worker preparing the paths itself: the files are those of
    the epochs measured in this process, byte for byte."""
    from raytrace.emulation.dataset import epochs

    kw = dict(scene=_scene(), duration_s=2.0, rate_hz=5.0, seed=5,
              toa_method=["search-back", "paper"])  # fmt: skip
    pairs = [("static", "c-band"), ("static", "mmwave")]
    make_datasets(tmp_path / "here", pairs, workers=1, **kw)
    monkeypatch.setattr(epochs, "STATIC_POOL_EPOCHS", 2)
    pooled = []
    real = epochs.ProcessPoolExecutor

    def spy(*args, **kwargs):
        pooled.append(kwargs["max_workers"])
        return real(*args, **kwargs)

    monkeypatch.setattr(epochs, "ProcessPoolExecutor", spy)
    make_datasets(tmp_path / "pool", pairs, workers=2, **kw)
    assert pooled == [2]  # the static group went to two workers
    subs = ["static-c-band", "static-c-band-paper", "static-mmwave", "static-mmwave-paper"]
    for sub in subs:
        for name in ("toa.csv", "meta.json"):
            a = (tmp_path / "here" / sub / name).read_bytes()
            assert a == (tmp_path / "pool" / sub / name).read_bytes(), (sub, name)


def test_several_receivers_from_one_trace_equal_separate_runs(tmp_path):
    """Receivers written together share the traces; each dataset is byte-identical to the one a
    run with that receiver alone writes."""
    kw = dict(scene=_scene(), duration_s=1.0, rate_hz=5.0, seed=3)
    pairs = [("static", "mmwave"), ("semi-dynamic", "c-band")]
    both = make_datasets(tmp_path / "both", pairs, toa_method=["first-lobe", "first-path"], **kw)
    assert [Path(s["directory"]).name for s in both] == [
        "static-mmwave", "static-mmwave-first-path", "semi-dynamic-c-band",
        "semi-dynamic-c-band-first-path",
    ]  # fmt: skip
    make_datasets(tmp_path / "lobe", pairs, toa_method="first-lobe", **kw)
    make_datasets(tmp_path / "ideal", pairs, toa_method="first-path", **kw)
    for sub in ("static-mmwave", "semi-dynamic-c-band"):
        a = (tmp_path / "both" / sub / "toa.csv").read_bytes()
        assert a == (tmp_path / "lobe" / sub / "toa.csv").read_bytes()
        b = (tmp_path / "both" / f"{sub}-first-path" / "toa.csv").read_bytes()
        assert b == (tmp_path / "ideal" / sub / "toa.csv").read_bytes()
        assert a != b


def test_paper_receiver_and_first_path_without_threshold_datasets(tmp_path):
    """Datasets of the paper receiver and of first-path without its threshold: their meta.json
    says so; both take the same first path as each other, noiselessly the paper's ToA is the
    lobe top and first-path's the exact delay; first-path with its threshold writes no extra
    key (its files are unchanged)."""
    kw = dict(scene=_scene(), duration_s=0.4, rate_hz=5.0, seed=3, noise=False)
    pairs = [("static", "c-band")]
    make_datasets(tmp_path / "p", pairs, toa_method=["paper", "first-path"], **kw)
    make_datasets(tmp_path / "n", pairs, toa_method="first-path", first_path_threshold=False, **kw)
    paper_rows, paper_meta = _read(tmp_path / "p" / "static-c-band")
    thr_rows, thr_meta = _read(tmp_path / "p" / "static-c-band-first-path")
    free_rows, free_meta = _read(tmp_path / "n" / "static-c-band")
    assert paper_meta["toa_method"] == "paper" and paper_meta["paper"]["power_floor_db"] == -250.0
    assert free_meta["first_path"] == {"detection_threshold": False}
    assert "first_path" not in thr_meta and "paper" not in thr_meta
    assert [r["first_kind"] for r in paper_rows] == [r["first_kind"] for r in free_rows]
    # same clock offsets and schedule: the difference is the pull of the later paths on the
    # first path's lobe (floor and wall reflections here), within half a pulse period
    T = 1.25 / 100e6
    diff = np.array([float(p["toa_s"]) - float(f["toa_s"]) for p, f in zip(paper_rows, free_rows)])
    assert np.all(np.abs(diff) < 0.5 * T) and np.any(np.abs(diff) > 1e-4 * T)


def test_meta_json_carries_the_parameters(tmp_path):
    sc = _scene()
    make_dataset(tmp_path / "m", "static", "mmwave", scene=sc, duration_s=0.5, seed=5)
    _, meta = _read(tmp_path / "m")
    from raytrace import __version__

    assert meta["schema_version"] == 2
    assert (meta["scenario"], meta["band"], meta["seed"]) == ("static", "mmwave", 5)
    assert meta["scene_sha256"] == sc.content_hash()
    assert meta["version"] == __version__
    assert meta["n_epochs"] == 5 and meta["rate_hz"] == 10.0 and meta["duration_s"] == 0.5
    assert [b["name"] for b in meta["base_stations"]] == [n for n, _ in BS]
    assert [p["xyz"] for p in meta["points"]] == [list(p) for _, p in POINTS]
    assert meta["schedule_s"] == {"BS1": 0.0, "BS2": 0.01, "BS3": 0.02}
    assert meta["hall_xy"] == [[0.0, 0.0], [20.0, 20.0]]
    assert meta["obstacles_2d"][0]["polygon"] == [[4, 4], [5, 4], [5, 5], [4, 5]]
    assert meta["band_parameters"]["center_frequency_hz"] == 26.85e9
    assert meta["link_budget"]["tx_power_dbm"] == 20.0
    assert meta["toa_method"] == "search-back"  # the default (docs/channel.md, receiver study)
    assert meta["receiver_settings"]["search_back"]["two_pulse"] is True
    assert meta["first_lobe"] == {"relative_threshold_db": -12.0, "cfar_cells": 64}
    assert set(meta["summary"]) >= {"rows", "detected_fraction", "los_fraction"}


def test_positioning_reads_the_dataset(tmp_path):
    from positioning.io.dataset import load_dataset

    sc = _scene()
    make_dataset(
        tmp_path / "p", "static", "c-band", scene=sc, duration_s=0.3, noise=False,
        toa_method="first-path",
    )  # fmt: skip
    ds = load_dataset(tmp_path / "p")
    assert ds.n_fixes == 3 * len(POINTS)
    assert ds.bs_names == [n for n, _ in BS]
    # the schedule removed, every row of a fix keeps the same clock offset: TDoAs are delays
    rows, _ = _read(tmp_path / "p")
    r0 = [r for r in rows if r["epoch"] == "0" and r["point"] == "P2"]
    unsched = np.array([float(r["toa_s"]) - float(r["tx_offset_s"]) for r in r0])
    dist = np.array([float(r["distance_m"]) for r in r0])
    los = np.array([r["los"] == "1" for r in r0])
    tdoa_m = (unsched - unsched[0]) * 299_792_458.0
    np.testing.assert_allclose(tdoa_m[los], (dist - dist[0])[los], atol=1e-6)


# -- errors and atomic output ------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(scenario="dynamic"), "unknown scenario"),
        (dict(band="x-band"), "unknown band"),
        (dict(duration_s=0.0), "duration"),
        (dict(rate_hz=-1.0), "rate"),
        (dict(toa_method="median"), "ToA method"),
        (dict(seed=-1), "seed"),
        (dict(workers=0), "workers"),
    ],
)
def test_library_rejects_bad_settings(tmp_path, kwargs, message):
    args = {"scenario": "static", "band": "c-band", **kwargs}
    with pytest.raises(HallrayError, match=message):
        make_dataset(tmp_path / "x", args.pop("scenario"), args.pop("band"), scene=_scene(), **args)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(routes=False), "routes"),
        (dict(bs=False), "base_stations"),
        (dict(points=False), "points"),
    ],
)
def test_scene_without_positions_or_routes(tmp_path, kw, message):
    with pytest.raises(SceneError, match=message):
        make_dataset(tmp_path / "x", "semi-dynamic", "c-band", scene=_scene(**kw), duration_s=1)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def tiny_glb(tmp_path_factory) -> Path:
    """A small hall with base stations, points and a route, built like the reference hall."""
    from raytrace.halls import spec as hallspec

    spec = hallspec.load_hall_spec(
        {
            "schema_version": 1,
            "name": "tiny",
            "hall": {"size": [12.0, 20.0, 4.0], "material": "concrete", "wall_thickness": 0.2},
            "objects": [
                {"name": "machine", "type": "box", "material": "metal", "min": [7.0, 14.0, 0.0],
                 "size": [2.0, 2.0, 1.5]}
            ],
            "base_stations": [
                {"name": "BS1", "xyz": [1.0, 1.0, 3.0]},
                {"name": "BS2", "xyz": [11.0, 1.0, 3.0]},
                {"name": "BS3", "xyz": [6.0, 19.0, 3.0]},
            ],
            "points": [{"name": "P1", "xyz": [3.0, 16.0, 1.0]}, {"name": "P2", "xyz": [9.0, 5.0, 1.0]}],
            "routes": [
                {"name": "forklift_1", "size": [2.0, 1.0, 2.0], "material": "metal",
                 "waypoints": [[2.05, 10.0], [10.0, 10.0]], "speed": 2.0, "mode": "back_and_forth"}
            ],
        }
    )  # fmt: skip
    path = tmp_path_factory.mktemp("scene") / "tiny.glb"
    hallspec.write_glb(spec, path)
    return path


def _cli(args, capsys):
    code = make_dataset_main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_all_writes_four_datasets(tmp_path, tiny_glb, capsys):
    out = tmp_path / "all"
    code, stdout, err = _cli(
        ["--all", "--scene", tiny_glb, "--duration", "0.5", "--workers", "1", "-o", out], capsys
    )
    assert code == 0, err
    subdirs = sorted(p.name for p in out.iterdir() if p.name != MARKER)  # the output's marker
    assert (out / MARKER).is_file()
    assert subdirs == [
        "semi-dynamic-c-band",
        "semi-dynamic-mmwave",
        "static-c-band",
        "static-mmwave",
    ]
    for d in subdirs:
        rows, meta = _read(out / d)
        assert len(rows) == 5 * 2 * 3
        assert f"{meta['scenario']}-{meta['band']}" == d
    assert "semi-dynamic-mmwave" in stdout
    assert [p.name for p in tmp_path.iterdir()] == ["all"]  # no temporary left


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scenario", "dynamic", "--band", "c-band"], "unknown scenario"),
        (["--scenario", "static", "--band", "ka-band"], "unknown band"),
        (["--scenario", "static", "--band", "c-band", "--duration", "0"], "duration"),
        (["--scenario", "static", "--band", "c-band", "--duration", "nan"], "duration"),
        (["--scenario", "static", "--band", "c-band", "--rate", "-10"], "rate"),
        (["--scenario", "static", "--band", "c-band", "--duration", "abc"], "invalid float"),
        (["--scenario", "static", "--band", "c-band", "--toa-method", "x"], "ToA method"),
        (["--scenario", "static", "--band", "c-band", "--workers", "0"], "workers"),
        (["--scenario", "static"], "--band"),
        (["--all", "--scenario", "static"], "--all"),
        (["--scenario", "static", "--band", "c-band", "--scene", "nope.glb"], "not found"),
        (["--scenario", "semi-dynamic", "--band", "c-band", "--scene", "canonical/shoebox"],
         "base_stations"),
    ],
)  # fmt: skip
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    out = tmp_path / "ds"
    code, stdout, err = _cli([*args, "-o", out], capsys)
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_cli_scene_without_routes_for_semi_dynamic(tmp_path, capsys):
    sc = _scene(routes=False)
    with pytest.raises(SceneError, match="routes"):
        make_dataset(tmp_path / "x", "semi-dynamic", "mmwave", scene=sc)


def test_cli_refuses_a_non_empty_directory_unless_forced(tmp_path, tiny_glb, capsys):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "old.txt").write_text("keep me")
    base = ["--scenario", "static", "--band", "c-band", "--scene", tiny_glb, "--duration", "0.2"]
    code, _, err = _cli([*base, "-o", out], capsys)
    assert code == 2 and "not empty" in err and err.count("\n") == 1
    assert (out / "old.txt").read_text() == "keep me"
    # issue 40: --force replaces only an earlier make-dataset output, never someone's files
    code, _, err = _cli([*base, "--force", "-q", "-o", out], capsys)
    assert code == 2 and "was not written by make-dataset" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    out = tmp_path / "ds2"
    assert _cli([*base, "-q", "-o", out], capsys)[0] == 0
    code, _, err = _cli([*base, "-q", "-o", out], capsys)
    assert code == 2 and "earlier make-dataset output (use --force" in err
    code, _, err = _cli([*base, "--force", "-q", "-o", out], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "meta.json", "toa.csv"]
    # an existing empty directory is fine without --force
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _cli([*base, "-q", "-o", empty], capsys)[0] == 0
    assert (empty / "toa.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "ds2", "empty"]


def test_failure_midway_leaves_no_output(tmp_path, monkeypatch):
    from raytrace.emulation.measurement import ToaModel

    real = ToaModel.measure

    def failing(self, paths, epochs, prepared=None, los=None):
        if 3 in epochs:
            raise HallrayError("simulated failure in epoch 3")
        return real(self, paths, epochs, prepared, los)

    monkeypatch.setattr(ToaModel, "measure", failing)
    sc = _scene()
    with pytest.raises(HallrayError, match="simulated"):
        make_dataset(tmp_path / "ds", "semi-dynamic", "c-band", scene=sc, duration_s=1.0)
    assert list(tmp_path.iterdir()) == []
    # with --force, the previous dataset survives a failed run untouched
    make_dataset(tmp_path / "ds", "static", "c-band", scene=sc, duration_s=0.2)
    previous = (tmp_path / "ds" / "toa.csv").read_bytes()
    with pytest.raises(HallrayError, match="simulated"):
        make_dataset(tmp_path / "ds", "static", "c-band", scene=sc, duration_s=1.0, force=True)
    assert (tmp_path / "ds" / "toa.csv").read_bytes() == previous
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]
