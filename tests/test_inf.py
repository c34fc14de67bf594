"""Synthetic InF halls: TR 38.901 parameters, geometry invariants, reproducibility, the hall
schema round trip, the LoS check against an independent segment-box test, and the CLIs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from raytrace.cli.build_hall import build_hall_main
from raytrace.cli.make_hall import hall_los_check_main, make_hall_main
from raytrace.core.errors import HallrayError
from raytrace.halls.inf import (
    BS_CLEARANCE_M,
    DEFAULT_MATERIALS,
    DENSITY_TOL,
    POINT_BS_CLEARANCE_M,
    POINT_CLUTTER_CLEARANCE_M,
    POINT_WALL_CLEARANCE_M,
    WALL_AISLE_M,
    LosSample,
    fit_decay_distance_m,
    generate_hall,
    hall_yaml,
    los_check,
    los_decay_distance_m,
    los_probability_3gpp,
    los_sample,
    parse_size,
    resolve_params,
    scene_from_spec,
    split_spec,
    wilson_interval,
)
from raytrace.halls.spec import load_hall_spec, parse_hall_spec, parse_los_note
from raytrace.scene.io import load_scene

SMALL = "30x24x8"
#: closed-form 3GPP decay distances are computed to this relative precision
K_REL_TOL = 1e-12
#: coordinates in the YAML are rounded to 1 mm
ROUND_TOL_M = 1e-9
#: float32 GLB vertices vs float64 in-memory scene
GLB_TOL_M = 1e-5


def _boxes(spec: dict) -> np.ndarray:
    """``(K, 6)`` x0, y0, z0, x1, y1, z1 of the clutter boxes of a generated spec."""
    rows = [
        [*o["min"], *(np.add(o["min"], o["size"]))] for o in spec["objects"] if o["type"] == "box"
    ]
    return np.array(rows, dtype=float).reshape(-1, 6)


def _segment_hits_boxes(
    o: np.ndarray, e: np.ndarray, boxes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Independent LoS: slab test of segments ``o -> e`` (n, 3) against axis-aligned boxes.

    Returns ``(blocked (n,), depth (n,))``: whether any box overlaps the open segment and the
    largest overlap length (m), to tell grazing cases apart."""
    d = e - o
    lo = boxes[None, :, :3]
    hi = boxes[None, :, 3:]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o[:, None, :]) / d[:, None, :]
        t2 = (hi - o[:, None, :]) / d[:, None, :]
    tmin = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    tmax = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2))
    # a zero direction component: inside the slab or never
    zero = d[:, None, :] == 0
    inside = (o[:, None, :] > lo) & (o[:, None, :] < hi)
    tmin = np.where(zero, np.where(inside, -np.inf, np.inf), tmin)
    tmax = np.where(zero, np.where(inside, np.inf, -np.inf), tmax)
    enter = np.maximum(tmin.max(axis=2), 0.0)
    leave = np.minimum(tmax.min(axis=2), 1.0)
    overlap = np.clip(leave - enter, 0.0, None) * np.linalg.norm(d, axis=1)[:, None]
    return (overlap > 0).any(axis=1), overlap.max(axis=1, initial=0.0)


# --------------------------------------------------------------------------------------------
# 3GPP formulas
# --------------------------------------------------------------------------------------------


def test_decay_distance_closed_forms():
    # TR 38.901 Table 7.4.2-1 with the evaluation values of Table 7.8-7
    k_sl = los_decay_distance_m(0.2, 10.0)
    assert k_sl == pytest.approx(-10.0 / math.log(0.8), rel=K_REL_TOL)
    assert k_sl == pytest.approx(44.8142, abs=1e-4)
    k_dl = los_decay_distance_m(0.6, 2.0)
    assert k_dl == pytest.approx(2.0 / math.log(1 / 0.4), rel=K_REL_TOL)
    k_sh = los_decay_distance_m(
        0.2, 10.0, high=True, bs_height_m=8.0, ut_height_m=1.5, clutter_height_m=2.0
    )
    assert k_sh == pytest.approx(k_sl * 6.5 / 0.5, rel=K_REL_TOL)
    k_dh = los_decay_distance_m(
        0.6, 2.0, high=True, bs_height_m=8.0, ut_height_m=1.5, clutter_height_m=6.0
    )
    assert k_dh == pytest.approx(k_dl * 6.5 / 4.5, rel=K_REL_TOL)
    assert los_decay_distance_m(0.0, 10.0) == math.inf
    p = los_probability_3gpp(np.array([0.0, k_sl, 2 * k_sl]), k_sl)
    np.testing.assert_allclose(p, [1.0, math.exp(-1), math.exp(-2)], rtol=1e-14)
    np.testing.assert_array_equal(los_probability_3gpp(np.array([5.0, 50.0]), math.inf), [1, 1])


def test_params_defaults_follow_tr38901():
    sl = resolve_params("InF-SL")
    assert (sl.density, sl.clutter_size, sl.clutter_height) == (0.2, 10.0, 2.0)
    assert sl.bs_height == 1.5 and sl.ut_height == 1.5
    assert sl.size == (120.0, 60.0, 10.0)
    assert sl.bs_grid == (6, 3)  # 18 BSs on a 20 m grid
    dh = resolve_params("inf-dh")  # case-insensitive
    assert dh.profile == "InF-DH"
    assert (dh.density, dh.clutter_size, dh.clutter_height, dh.bs_height) == (0.6, 2.0, 6.0, 8.0)
    # a high BS is clamped 0.5 m below a low ceiling
    assert resolve_params("InF-DH", "30x30x8").bs_height == 7.5
    assert resolve_params("InF-SL", "42x46x8.8").bs_grid == (2, 2)
    assert resolve_params("InF-SL", [42, 46, 8.8], bs_grid=[3, 1]).bs_grid == (3, 1)
    assert sum(resolve_params("InF-SL").materials.values()) == pytest.approx(1.0)


def test_parse_size():
    assert parse_size("42x46x8.8") == (42.0, 46.0, 8.8)
    assert parse_size("42X46X8.8") == (42.0, 46.0, 8.8)
    assert parse_size([10, 20, 3]) == (10.0, 20.0, 3.0)
    for bad in ("42x46", "42x46x", "axbxc", "42x46x-1", "42x46x0", "42x46xnan", "42x46x8x1", ""):
        with pytest.raises(HallrayError, match="bad size") as exc:
            parse_size(bad)
        assert "\n" not in str(exc.value)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"profile": "InF-HH"}, "unknown profile"),
        ({"profile": "UMa"}, "unknown profile"),
        ({"profile": "InF-SL", "size": "42x46"}, "bad size"),
        ({"profile": "InF-SL", "density": 0.4}, "out of range for sparse"),
        ({"profile": "InF-SH", "density": -0.1}, "out of range for sparse"),
        ({"profile": "InF-DL", "density": 0.39}, "out of range for dense"),
        ({"profile": "InF-DH", "density": 1.0}, "out of range for dense"),
        ({"profile": "InF-DL", "density": float("nan")}, "must be finite"),
        ({"profile": "InF-SL", "clutter_size": 0.0}, "clutter size"),
        ({"profile": "InF-SL", "clutter_height": 1.0}, "above the UT height"),
        ({"profile": "InF-DL", "size": "40x40x5"}, "below the ceiling"),
        ({"profile": "InF-SL", "bs_height": 3.0}, "below the clutter"),
        ({"profile": "InF-SH", "bs_height": 1.5}, "above the clutter"),
        ({"profile": "InF-SH", "bs_height": 9.8}, "below the ceiling"),
        ({"profile": "InF-DH", "height_spread": 0.5}, "tallest clutter"),
        ({"profile": "InF-SL", "bs_grid": [0, 2]}, "bs_grid"),
        ({"profile": "InF-SL", "n_points": -1}, "number of points"),
        ({"profile": "InF-SL", "materials": {"unobtainium": 1.0}}, "unknown clutter material"),
        ({"profile": "InF-SL", "seed": -3}, "seed"),
        # clutter that cannot be placed
        ({"profile": "InF-DL", "size": "20x20x8", "density": 0.95}, "cannot place clutter"),
        # points that cannot be placed
        ({"profile": "InF-SL", "size": "2x2x3", "density": 0.0}, "cannot place 50 test points"),
    ],
)
def test_bad_input_one_line_errors(kwargs, match):
    kwargs = dict(kwargs)
    profile = kwargs.pop("profile")
    size = kwargs.pop("size", SMALL)
    with pytest.raises(HallrayError, match=match) as exc:
        generate_hall(profile, size, kwargs.pop("seed", 0), los_notes=False, **kwargs)
    assert "\n" not in str(exc.value)


# --------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def halls() -> dict[str, dict]:
    return {
        prof: generate_hall(prof, "42x46x8.8", 7, n_points=60)
        for prof in ("InF-SL", "InF-DL", "InF-SH", "InF-DH")
    }


@pytest.mark.parametrize("profile", ["InF-SL", "InF-DL", "InF-SH", "InF-DH"])
def test_geometry_invariants(halls, profile):
    spec = halls[profile]
    p = spec["_inf"]["params"]
    lx, ly, lz = p["size"]
    boxes = _boxes(spec)
    assert len(boxes) == spec["_inf"]["n_clutter"] > 0
    # inside the hall, off the wall aisle, on the floor, all of height h_c
    assert np.all(boxes[:, :2] >= WALL_AISLE_M - ROUND_TOL_M)
    assert np.all(boxes[:, 3] <= lx - WALL_AISLE_M + ROUND_TOL_M)
    assert np.all(boxes[:, 4] <= ly - WALL_AISLE_M + ROUND_TOL_M)
    np.testing.assert_array_equal(boxes[:, 2], 0.0)
    np.testing.assert_allclose(boxes[:, 5], p["clutter_height"], atol=ROUND_TOL_M)
    # no two boxes overlap (they may not even touch: a gap separates cells)
    ov_x = (boxes[:, None, 0] < boxes[None, :, 3]) & (boxes[None, :, 0] < boxes[:, None, 3])
    ov_y = (boxes[:, None, 1] < boxes[None, :, 4]) & (boxes[None, :, 1] < boxes[:, None, 4])
    overlap = ov_x & ov_y
    np.fill_diagonal(overlap, False)
    assert not overlap.any()
    # density: the covered floor fraction, recomputed from the YAML, is the closest the cells allow
    area = (boxes[:, 3] - boxes[:, 0]) * (boxes[:, 4] - boxes[:, 1])
    achieved = area.sum() / (lx * ly)
    assert achieved == pytest.approx(spec["_inf"]["achieved_density"], abs=1e-9)
    assert abs(achieved - p["density"]) <= max(area.max() / (lx * ly) / 2, DENSITY_TOL) + 1e-12
    # typical size: the mean box side is d_clutter minus the gaps (within 15 %)
    side = np.concatenate([boxes[:, 3] - boxes[:, 0], boxes[:, 4] - boxes[:, 1]])
    if len(boxes) > 50:
        assert np.mean(side) == pytest.approx(p["clutter_size"], rel=0.15)
    assert np.all(side <= 1.5 * p["clutter_size"] * 2 + ROUND_TOL_M)  # a merged last piece
    # base stations: a grid at h_BS, D/2 from the walls
    bs = np.array([b["xyz"] for b in spec["base_stations"]])
    np.testing.assert_allclose(sorted(set(bs[:, 0])), [lx / 4, 3 * lx / 4], atol=1e-3)
    np.testing.assert_allclose(sorted(set(bs[:, 1])), [ly / 4, 3 * ly / 4], atol=1e-3)
    np.testing.assert_array_equal(bs[:, 2], p["bs_height"])
    if profile.endswith("L"):
        assert p["bs_height"] < p["clutter_height"]
        # keep-out: no clutter within BS_CLEARANCE_M (Chebyshev) of a low BS
        dx = np.maximum(
            np.maximum(boxes[None, :, 0] - bs[:, None, 0], bs[:, None, 0] - boxes[None, :, 3]), 0
        )
        dy = np.maximum(
            np.maximum(boxes[None, :, 1] - bs[:, None, 1], bs[:, None, 1] - boxes[None, :, 4]), 0
        )
        assert np.all(np.maximum(dx, dy) >= BS_CLEARANCE_M - ROUND_TOL_M)
    else:
        assert p["clutter_height"] < p["bs_height"] <= lz - 0.5
    # points: n, at h_UT, on the free floor away from clutter, walls and base stations
    pts = np.array([q["xyz"] for q in spec["points"]])
    assert len(pts) == 60
    np.testing.assert_array_equal(pts[:, 2], 1.5)
    assert np.all(pts[:, 0] >= POINT_WALL_CLEARANCE_M) and np.all(
        pts[:, 0] <= lx - POINT_WALL_CLEARANCE_M
    )
    assert np.all(pts[:, 1] >= POINT_WALL_CLEARANCE_M) and np.all(
        pts[:, 1] <= ly - POINT_WALL_CLEARANCE_M
    )
    c = POINT_CLUTTER_CLEARANCE_M
    near = (
        (pts[:, None, 0] > boxes[None, :, 0] - c) & (pts[:, None, 0] < boxes[None, :, 3] + c)
        & (pts[:, None, 1] > boxes[None, :, 1] - c) & (pts[:, None, 1] < boxes[None, :, 4] + c)
    )  # fmt: skip
    assert not near.any()
    d_bs = np.hypot(pts[:, None, 0] - bs[None, :, 0], pts[:, None, 1] - bs[None, :, 1])
    assert d_bs.min() >= POINT_BS_CLEARANCE_M
    # every coordinate is on the 1 mm grid
    coords = np.concatenate([boxes.ravel(), bs.ravel(), pts.ravel()])
    np.testing.assert_allclose(coords * 1000, np.round(coords * 1000), atol=1e-6)


def test_materials_mostly_metal():
    spec = generate_hall("InF-DL", "60x40x8", 3, n_points=1, los_notes=False)
    mats = [o["material"] for o in spec["objects"]]
    n = len(mats)
    assert n > 300
    for m, prob in DEFAULT_MATERIALS.items():
        frac = mats.count(m) / n
        # binomial: within 5 standard deviations
        assert abs(frac - prob) <= 5 * math.sqrt(prob * (1 - prob) / n)
    only = generate_hall(
        "InF-DL", "30x24x8", 3, n_points=1, los_notes=False, materials={"glass": 1}
    )
    assert {o["material"] for o in only["objects"]} == {"glass"}


def test_height_spread():
    spec = generate_hall("InF-DL", SMALL, 2, height_spread=0.25, los_notes=False)
    h = _boxes(spec)[:, 5]
    assert h.min() >= 6.0 * 0.75 - ROUND_TOL_M and h.max() <= 6.0 * 1.25 + ROUND_TOL_M
    assert h.std() > 0.3  # uniform on a 3 m range: std 0.87 m


def test_seed_reproducible_and_streams_independent():
    a = hall_yaml(generate_hall("InF-DL", SMALL, 11))
    b = hall_yaml(generate_hall("InF-DL", SMALL, 11))
    assert a == b
    assert a != hall_yaml(generate_hall("InF-DL", SMALL, 12))
    # more points: same clutter and base stations, the first points unchanged
    few = generate_hall("InF-DL", SMALL, 11, n_points=10, los_notes=False)
    many = generate_hall("InF-DL", SMALL, 11, n_points=200, los_notes=False)
    assert few["objects"] == many["objects"]
    assert few["base_stations"] == many["base_stations"]
    assert [p["xyz"] for p in few["points"]] == [p["xyz"] for p in many["points"][:10]]


def test_spec_passes_the_hall_schema_and_yaml_round_trip(halls):
    spec = halls["InF-DL"]
    text = hall_yaml(spec)
    assert text.startswith("# synthetic indoor-factory hall")
    data = yaml.safe_load(text)
    assert data == split_spec(spec)[0]
    hall = parse_hall_spec(data)
    assert len(hall.objects) == spec["_inf"]["n_clutter"]
    assert {o.material for o in hall.objects} <= set(DEFAULT_MATERIALS)


# --------------------------------------------------------------------------------------------
# line of sight
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["InF-SL", "InF-DL", "InF-SH", "InF-DH"])
def test_embree_los_matches_independent_slab_test(halls, profile):
    """Scene.occluded on the built hall == a closed-form segment/box slab test (the shell
    never blocks an inside segment), apart from grazing contacts shallower than 1 mm."""
    spec = halls[profile]
    hall = parse_hall_spec(split_spec(spec)[0])
    sample = los_sample(scene_from_spec(hall), hall, spec["_inf"]["k_subsce_m"])
    bs, pts = hall.base_station_xyz, hall.point_xyz
    o, e = np.repeat(bs, len(pts), axis=0), np.tile(pts, (len(bs), 1))
    blocked, depth = _segment_hits_boxes(o, e, _boxes(spec))
    clear_cut = (depth == 0) | (depth > 1e-3)
    assert clear_cut.mean() > 0.99
    np.testing.assert_array_equal(sample.los[clear_cut], ~blocked[clear_cut])
    np.testing.assert_allclose(sample.d2d_m, np.hypot(*(e - o)[:, :2].T), rtol=1e-12)
    # and the notes written by the generator say the same
    k = 0
    for b in hall.base_stations:
        for p in hall.points:
            status = parse_los_note(p.note)
            assert (status[b.name] == ()) == bool(sample.los[k])
            k += 1


def test_hall_scene_inside_solid_is_exact(halls):
    """Scene.inside_solid of a hall (convex solids: the exact facet-plane test) agrees with the
    primitives' closed-form containment, also in the band below the wall tops where a ray-parity
    test miscounts (the exit from a wall slab hides behind the entry into the ceiling slab that
    shares its top face)."""
    hall = parse_hall_spec(split_spec(halls["InF-DL"])[0])
    scene = scene_from_spec(hall)
    rng = np.random.default_rng(0)
    lx, ly, lz = hall.size
    p = rng.uniform([-0.5, -0.5, -0.5], [lx + 0.5, ly + 0.5, lz + 0.5], (20000, 3))
    prims = {hall.node_name(q): q for q in hall.shell() + hall.objects}
    ref = np.full(len(p), -1)
    for i, name in enumerate(scene.object_names):
        ref = np.where((ref < 0) & prims[name].contains(p), i, ref)
    np.testing.assert_array_equal(scene.inside_solid(p), ref)
    empty = scene_from_spec(parse_hall_spec({"hall": {"size": [30.0, 24.0, 8.0]}}))
    band = np.column_stack([np.full(13, 10.0), np.linspace(19.0, 20.2, 13), np.full(13, 1.5)])
    np.testing.assert_array_equal(empty.inside_solid(band), -1)


def test_high_bs_blocked_only_near_the_ut(halls):
    """SH/DH: the BS is above the clutter, so a blocking box lies within the horizontal distance
    d (h_c - h_UT) / (h_BS - h_UT) of the device (the geometry behind the 3GPP k scaling)."""
    for profile in ("InF-SH", "InF-DH"):
        spec = halls[profile]
        p = spec["_inf"]["params"]
        hall = parse_hall_spec(split_spec(spec)[0])
        scene = scene_from_spec(hall)
        bs, pts = hall.base_station_xyz, hall.point_xyz
        o, e = np.repeat(pts, len(bs), axis=0), np.tile(bs, (len(pts), 1))  # from the UT up
        blocked = scene.occluded(o, e)
        assert blocked.any()
        d = e[blocked] - o[blocked]
        length = np.linalg.norm(d, axis=1)
        t, _, _ = scene.intersect(o[blocked], d / length[:, None], length)
        frac = (p["clutter_height"] - p["ut_height"]) / (p["bs_height"] - p["ut_height"])
        horizontal = t / length * np.hypot(d[:, 0], d[:, 1])
        assert np.all(horizontal <= frac * np.hypot(d[:, 0], d[:, 1]) + GLB_TOL_M)


def test_more_clutter_fewer_los_links():
    """Averaged over the same seeds: dense clutter blocks more links than sparse (low and high
    base stations), and high base stations see more devices than low ones in sparse clutter."""
    seeds = range(3)
    frac = {
        prof: los_check(prof, seeds, SMALL, n_points=60).los_fraction
        for prof in ("InF-SL", "InF-DL", "InF-SH", "InF-DH")
    }
    assert frac["InF-DL"] < frac["InF-SL"]
    assert frac["InF-DH"] < frac["InF-SH"]
    assert frac["InF-SH"] > frac["InF-SL"]


def test_fit_decay_distance_recovers_k():
    rng = np.random.default_rng(5)
    k_true = 12.0
    d = rng.uniform(0, 60, 20000)
    los = rng.random(d.size) < np.exp(-d / k_true)
    # max-likelihood on 20000 Bernoulli samples: standard error about 1.5 %
    assert fit_decay_distance_m(d, los) == pytest.approx(k_true, rel=0.06)
    assert fit_decay_distance_m(d, np.ones(d.size, bool)) == math.inf
    assert fit_decay_distance_m(d, np.zeros(d.size, bool)) == 0.0


def test_wilson_interval_closed_form():
    z = 1.959964
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(z * z / (10 + z * z), rel=1e-12)
    lo, hi = wilson_interval(10, 10)
    assert hi == pytest.approx(1.0, abs=1e-12) and lo == pytest.approx(10 / (10 + z * z), rel=1e-12)
    lo, hi = wilson_interval(50, 100)
    assert 0.5 - lo == pytest.approx(hi - 0.5, rel=1e-12)


def test_los_sample_bins():
    s = LosSample(np.array([1.0, 2.0, 6.0, 7.0, 8.0]), np.array([1, 1, 1, 0, 0], bool), 10.0)
    rows = s.bins(5.0)
    assert [(r["n"], r["n_los"]) for r in rows] == [(2, 2), (3, 1)]
    assert rows[1]["p_los_3gpp"] == pytest.approx(np.mean(np.exp(-np.array([6, 7, 8]) / 10)))
    assert s.los_fraction == pytest.approx(0.6)


# --------------------------------------------------------------------------------------------
# files and command lines
# --------------------------------------------------------------------------------------------


def test_make_hall_writes_reproducible_files(tmp_path, capsys):
    args = ["--profile", "InF-DL", "--size", SMALL, "--seed", "4", "--points", "20"]
    assert make_hall_main([*args, "-o", str(tmp_path / "a")]) == 0
    assert make_hall_main([*args, "-o", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "InF-DL" in out and "20 points" in out
    for name in ("hall.yaml", "hall.glb", "inf.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    # build-hall on the YAML gives the same GLB bytes; load_scene reads it
    assert build_hall_main([str(tmp_path / "a" / "hall.yaml"), "-o", str(tmp_path / "c.glb")]) == 0
    assert (tmp_path / "c.glb").read_bytes() == (tmp_path / "a" / "hall.glb").read_bytes()
    info = json.loads((tmp_path / "a" / "inf.json").read_text())
    scene = load_scene(tmp_path / "a" / "hall.glb")
    assert len(scene.objects) == info["n_clutter"] + 6
    hall = load_hall_spec(tmp_path / "a" / "hall.yaml")
    mem = scene_from_spec(hall)
    assert np.abs(mem.bounds - scene.bounds).max() < GLB_TOL_M
    assert mem.object_names == scene.object_names


def test_make_hall_errors_write_nothing(tmp_path, capsys):
    cases = [
        ["--profile", "InF-XY"],
        ["--profile", "InF-SL", "--size", "42by46"],
        ["--profile", "InF-SL", "--density", "0.7"],
        ["--profile", "InF-DL", "--size", "20x20x8", "--density", "0.9"],
        ["--profile", "InF-SL", "--bs-grid", "2"],
    ]
    for args in cases:
        assert make_hall_main([*args, "-o", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1
        assert not (tmp_path / "x").exists()
    assert make_hall_main(["--profile", "InF-SL", "-o", str(tmp_path / "no" / "dir")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_hall_los_check_cli(tmp_path, capsys):
    d = tmp_path / "h"
    assert (
        make_hall_main(["--profile", "InF-DH", "--size", SMALL, "--seed", "1", "-o", str(d)]) == 0
    )
    capsys.readouterr()
    assert hall_los_check_main([str(d), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["n_links"] == 4 * 50 and res["params"]["profile"] == "InF-DH"
    assert sum(b["n"] for b in res["bins"]) == res["n_links"]
    png = tmp_path / "los.png"
    assert hall_los_check_main(["InF-SL", "--seeds", "2", "--size", SMALL, "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "k = 44.81 m" in out and "2 hall(s)" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for args in (
        [str(d), "--seeds", "3"],
        ["InF-QQ"],
        [str(tmp_path / "missing")],
        [str(tmp_path)],  # a directory without inf.json
        ["InF-SL", "--seeds", "0"],
        ["InF-SL", "--size", SMALL, "--plot", str(tmp_path / "x.jpg")],
    ):
        assert hall_los_check_main(args) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1
    assert not (tmp_path / "x.jpg").exists()
