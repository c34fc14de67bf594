"""The accuracy map: closed forms on canonical scenes, the clearance rule, the file schema and
the command's bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from positioning.twin.fingerprint import read_map
from raytrace import HallrayError, load_scene
from raytrace.cli.accuracy_map import accuracy_map_main
from raytrace.core.constants import C0
from raytrace.physics.materials import MaterialLibrary, slab_group_delay
from raytrace.studies.accuracy_map import (
    CSV_SCHEMA,
    CSV_VERSION,
    MapSettings,
    compute_map,
    gdop_2d,
    grid_offset,
    lattice_distance,
    make_grid,
    write_outputs,
)

#: Excess path length of a LoS first arrival, m (float64 delays of metre-scale paths).
EXCESS_TOL_M = 1e-9
#: Delay of a straight path against distance / c, s.
DELAY_TOL_S = 1e-15
#: GDOP closed forms, relative.
GDOP_RTOL = 1e-12
#: 2D error of the ideal receiver in LoS at high SNR (eq. 3 sigma of millimetres), m.
LOS_ERROR_M = 0.05
#: Concrete wall of the canonical one-wall scene, m.
WALL_THICKNESS_M = 0.2

SHOEBOX_BS = np.array([[1.0, 1.0, 2.5], [9.0, 1.0, 2.5], [9.0, 7.0, 2.5], [1.0, 7.0, 2.5]])


def _settings(**kw) -> MapSettings:
    base = dict(step_m=2.0, receiver="first-path", methods=("ls",), draws=4)
    base.update(kw)
    return MapSettings(**base)


@pytest.fixture(scope="module")
def shoebox_map():
    sc = load_scene("canonical/shoebox")
    return sc, compute_map(sc, _settings(), scene_name="canonical/shoebox", bs_xyz=SHOEBOX_BS,
                           workers=1)  # fmt: skip


def test_empty_room_every_cell_sees_every_base_station_first(shoebox_map):
    _, amap = shoebox_map
    f = amap.fmap
    assert f.n_cells == 20  # 10 x 8 m floor, 2 m cells centred in it
    np.testing.assert_array_equal(f.n_los(), 4)
    assert (f.first_kind == "LoS").all()
    np.testing.assert_allclose(f.excess_m, 0.0, atol=EXCESS_TOL_M)
    dist = np.linalg.norm(f.cell_xyz[:, None, :] - f.bs_xyz[None, :, :], axis=2)
    np.testing.assert_allclose(f.toa_s, dist / C0, atol=DELAY_TOL_S)  # first-path, no noise
    np.testing.assert_array_equal(f.detected_fraction, 1.0)
    assert (f.toa_std_s > 0).all()
    np.testing.assert_array_equal(f.availability, 1.0)
    assert (f.err_p90_m < LOS_ERROR_M).all()
    np.testing.assert_allclose(f.gdop, gdop_2d(f.cell_xyz, f.bs_xyz), rtol=GDOP_RTOL)
    np.testing.assert_allclose(f.cell_xyz[:, 2], 1.5)  # no test points: the fallback height


def test_one_wall_los_count_and_penetration_excess_delay():
    sc = load_scene("canonical/one_wall")
    bs = np.array([[0.0, -5.0, 1.5]])
    area = np.array([[-4.0, -4.0], [4.0, -4.0], [4.0, 4.0], [-4.0, 4.0]])
    amap = compute_map(sc, _settings(step_m=1.0, height_m=1.5), bs_xyz=bs, area_xy=area,
                       workers=1)  # fmt: skip
    f = amap.fmap
    y = f.cell_xyz[:, 1]
    assert (y < 0).any() and (y > 0).any()
    np.testing.assert_array_equal(f.los[:, 0], y < 0)  # the wall hides the far side
    np.testing.assert_array_equal(f.first_kind[:, 0], np.where(y < 0, "LoS", "T"))
    d = f.cell_xyz - bs
    cos_i = np.abs(d[:, 1]) / np.linalg.norm(d, axis=1)
    mat = MaterialLibrary.itu()["concrete"]
    f_c = f.meta["frequency_hz"]
    tau = slab_group_delay(mat.permittivity(f_c), cos_i, WALL_THICKNESS_M,
                           mat.permittivity_slope(f_c))  # fmt: skip
    want = np.where(y < 0, 0.0, C0 * tau)
    np.testing.assert_allclose(f.excess_m[:, 0], want, atol=1e-6)
    assert (want[y > 0] > 0.2).all()  # the wall adds over 20 cm: the test can see it
    assert np.isnan(f.gdop).all()  # one base station: no fix
    np.testing.assert_array_equal(f.availability, 0.0)


@pytest.mark.parametrize("n_bs", [3, 4, 7])
def test_gdop_of_base_stations_evenly_on_a_circle(n_bs):
    """N base stations at equal angles on a circle, elevation e seen from the centre:
    H^T H = diag(N cos^2 e / 2, N cos^2 e / 2, N), so GDOP = 2 / (sqrt(N) cos e)."""
    radius, dz = 10.0, 3.0
    a = 2 * np.pi * np.arange(n_bs) / n_bs + 0.3
    bs = np.column_stack([radius * np.cos(a), radius * np.sin(a), np.full(n_bs, 1.0 + dz)])
    cell = np.array([[0.0, 0.0, 1.0]])
    cos_e = radius / np.hypot(radius, dz)
    assert gdop_2d(cell, bs)[0] == pytest.approx(2 / (np.sqrt(n_bs) * cos_e), rel=GDOP_RTOL)


def test_gdop_needs_three_base_stations_off_a_line():
    bs = np.array([[0.0, 0, 3], [10, 0, 3], [20, 0, 3], [0, 10, 3]])
    cell = np.array([[5.0, 5.0, 1.0]])
    use = np.array([[True, True, False, False]])
    assert np.isnan(gdop_2d(cell, bs, use)[0])  # two base stations
    assert np.isfinite(gdop_2d(cell, bs)[0])
    on_line = np.array([[30.0, 0.0, 3.0]])  # cell on the line of three base stations
    assert np.isnan(gdop_2d(on_line, bs[:3])[0])


def test_grid_origin_keeps_cells_away_from_test_points():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 20, (30, 2))
    step, clearance = 2.0, 0.25
    off = grid_offset(np.zeros(2), step, pts, clearance)
    assert ((0 <= off) & (off < step)).all()
    nodes = np.stack(np.meshgrid(np.arange(-1, 12), np.arange(-1, 12), indexing="ij"), -1)
    nodes = off + step * nodes.reshape(-1, 2)  # an explicit lattice around the points
    brute = np.linalg.norm(pts[:, None, :] - nodes[None, :, :], axis=2).min(axis=1)
    assert brute.min() >= clearance
    np.testing.assert_allclose(lattice_distance(pts, off, step), brute, atol=1e-12)
    # a point on the centred lattice moves the grid; an impossible clearance is refused
    assert not np.allclose(grid_offset(np.zeros(2), step, np.array([[1.0, 1.0]]), 0.25), 1.0)
    with pytest.raises(HallrayError, match="clearance"):
        grid_offset(np.zeros(2), step, pts, 1.5)  # > step / sqrt(2): no lattice can


def test_hall_grid_records_the_test_points_distance():
    sc = load_scene("hall")
    inputs = sc.metadata["hallray"]["points"]
    xyz = np.array([p["xyz"] for p in inputs])
    grid = make_grid(sc, _settings(step_m=2.0, clearance_m=0.25), [p["name"] for p in inputs], xyz)
    brute = np.linalg.norm(xyz[:, None, :2] - grid.cell_xyz[None, :, :2], axis=2).min(axis=1)
    np.testing.assert_allclose(grid.test_distance_m, brute, atol=1e-12)
    assert grid.test_distance_m.min() >= 0.25
    assert (sc.inside_solid(grid.cell_xyz) < 0).all()
    np.testing.assert_allclose(grid.cell_xyz[:, 2], np.median(xyz[:, 2]))
    np.testing.assert_allclose(grid.cell_xyz[:, :2], grid.origin_xy + grid.ij * 2.0)


def test_files_round_trip_through_the_positioning_reader(shoebox_map, tmp_path):
    sc, amap = shoebox_map
    files = write_outputs(tmp_path / "map", sc, amap, pictures=False)  # pictures: slow test
    assert [p.name for p in files] == ["map.npz", "map.csv", "map.json"]
    back = read_map(tmp_path / "map" / "map.npz")
    for key, arr in amap.fmap.arrays().items():
        np.testing.assert_array_equal(getattr(back, key), arr, err_msg=key)
    for key in ("band", "frequency_hz", "bandwidth_hz", "receiver", "step_m", "height_m",
                "scene", "draws", "service_area", "test_points", "grid"):  # fmt: skip
        assert key in back.meta
    with open(tmp_path / "map" / "map.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))  # plain CSV: the header first
    schema = json.loads((tmp_path / "map" / "map.json").read_text())
    assert (schema["schema"], schema["schema_version"]) == (CSV_SCHEMA, CSV_VERSION) == (
        "hallray-accuracy-map-csv", 2)
    assert schema["columns"] == list(rows[0])
    assert schema["map"]["band"] == back.meta["band"]
    assert len(rows) == back.n_cells
    np.testing.assert_array_equal([int(r["n_los"]) for r in rows], back.n_los())
    np.testing.assert_allclose([float(r["BS2:toa_s"]) for r in rows], back.toa_s[:, 1], rtol=1e-11)
    np.testing.assert_allclose([float(r["ls:err_p90_m"]) for r in rows], back.err_p90_m[0],
                               rtol=1e-5)  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--step", "0"], "--step"),
        (["--step", "1000"], "no cell"),
        (["--step", "0.01"], "more than the limit"),
        (["--height", "20"], "outside the hall"),
        (["--height", "-1"], "outside the hall"),
        (["--band", "x-band"], "band"),
        (["--receiver", "psychic"], "unknown receiver"),
        (["--methods", "ls", "magic"], "unknown positioning method"),
        (["--clearance", "5"], "clearance"),
        (["--draws", "0"], "--draws"),
        (["--workers", "0"], "workers"),
        (["--receiver", "leading-edge", "--paths", "16"],
         "--paths-per-link 16 needs --receiver first-lobe"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, extra, message):
    out = tmp_path / "map"
    assert accuracy_map_main(["hall", "-q", "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err and message in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_command_on_the_hall_and_workers_do_not_change_the_map(tmp_path):
    args = ["hall", "--step", "12", "--draws", "3", "--methods", "ls", "-q"]
    assert accuracy_map_main([*args, "--workers", "1", "-o", str(tmp_path / "a")]) == 0
    assert accuracy_map_main([*args, "--workers", "2", "-o", str(tmp_path / "b")]) == 0
    pictures = {p.name for p in (tmp_path / "a").glob("*.png")}
    assert pictures >= {"n_los.png", "gdop.png", "err_p90_ls.png", "excess_worst_m.png"}
    a, b = read_map(tmp_path / "a" / "map.npz"), read_map(tmp_path / "b" / "map.npz")
    for key, arr in a.arrays().items():
        np.testing.assert_array_equal(getattr(b, key), arr, err_msg=key)
    assert all(t["nearest_cell_m"] >= 0.25 for t in a.meta["test_points"])


def test_dask_cluster_gives_the_same_map(shoebox_map):
    """The chunks on a Dask LocalCluster in this process: the same map as in this process."""
    distributed = pytest.importorskip("distributed")
    sc, ref = shoebox_map
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        amap = compute_map(sc, _settings(chunk_links=24), bs_xyz=SHOEBOX_BS,
                           scheduler=cluster.scheduler_address)  # fmt: skip
    local = compute_map(sc, _settings(chunk_links=24), bs_xyz=SHOEBOX_BS, workers=1)
    assert amap.fmap.meta["workers"] == "dask"
    for key, arr in local.fmap.arrays().items():
        np.testing.assert_array_equal(getattr(amap.fmap, key), arr, err_msg=key)
    assert ref.fmap.n_cells == amap.fmap.n_cells


def test_stored_paths_reproduce_the_maps_toa(tmp_path):
    """A first-lobe map with every path stored (schema v2): positioning's receiver model run on
    the stored paths of each cell gives the map's own toa_s (within 1e-4 T), the directions are
    unit vectors, and the file reads back as version 2."""
    from positioning.twin.fingerprint import write_map
    from positioning.twin.lobe import LobeReceiver

    sc = load_scene("canonical/shoebox")
    amap = compute_map(sc, _settings(receiver="first-lobe", paths=200), bs_xyz=SHOEBOX_BS,
                       workers=1)  # fmt: skip
    f = amap.fmap
    assert f.version == 2 and f.path_delay_s.shape[:2] == f.toa_s.shape
    assert np.isnan(f.path_delay_s).any()  # padded: every path of every link is stored
    model = LobeReceiver.from_meta(f.meta["receiver_model"])
    n, b, k = f.path_delay_s.shape
    toa = model.toa(f.path_delay_s.reshape(n * b, k), f.path_gain.reshape(n * b, k)).reshape(n, b)
    assert np.array_equal(np.isfinite(toa), np.isfinite(f.toa_s))
    assert np.nanmax(np.abs(toa - f.toa_s)) <= 1e-4 * model.period_s
    has = np.isfinite(f.path_delay_s)
    np.testing.assert_allclose(np.linalg.norm(f.path_dir[has], axis=1), 1.0, atol=1e-9)
    write_map(tmp_path / "m.npz", f)
    assert read_map(tmp_path / "m.npz").version == 2
