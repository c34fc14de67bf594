"""Tests of the ``twin`` estimator: fingerprint-map matching with the map's NLoS bias."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from pos_synth import PAPER_BS, nlos_bias, synth_map, synth_toa, write_dataset

from positioning import METHODS, Status, error_2d, locate
from positioning.cli.accuracy import accuracy_report_main
from positioning.cli.estimate import estimate_positions_main
from positioning.errors import PositioningError
from positioning.twin.estimator import clamp_to_polygon
from positioning.twin.fingerprint import write_map
from positioning.twin.lattice import interp_bias

#: Range noise of the synthetic data (m) and what the twin must reach: with the bias known,
#: the error is the noise's (p90 about 2.5 sigma times the geometry's dilution, ~1.5 here).
SIGMA_M = 0.05
TWIN_P90_MAX_M = 0.2
#: IRLS keeps most of the bias of one NLoS base station with 4 in 2D (p90 ~ 1.6 m here).
IRLS_P90_MIN_M = 1.0


@pytest.fixture(scope="module")
def fmap():
    return synth_map()


def test_bilinear_bias_is_exact_for_a_linear_field(fmap):
    from positioning.twin.lattice import load

    _, lat = load(fmap)
    xy = np.array([[3.3, 4.1], [17.77, 20.02], [10.0, 10.0]])
    np.testing.assert_allclose(interp_bias(lat, xy), nlos_bias(xy), atol=1e-9)


def test_twin_removes_the_bias_irls_keeps(fmap):
    toa, p = synth_toa(2000, sigma_m=SIGMA_M)
    e_irls = error_2d(locate(toa, PAPER_BS, "irls", height_m=1.0), p)
    f = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, return_info=True)
    e_twin = error_2d(f.xyz, p)
    assert np.percentile(e_irls, 90) > IRLS_P90_MIN_M
    assert np.percentile(e_twin, 90) < TWIN_P90_MAX_M
    assert f.count(Status.MAP_MISMATCH) == 0
    # it judges the NLoS base station (index 2) NLoS and the others not
    assert f.extra["nlos"][:, 2].all() and not f.extra["nlos"][:, [0, 1, 3]].any()
    assert np.nanmax(f.extra["match_m"]) < 4 * SIGMA_M
    # the interpolated-bias refinement is exact for this linear bias field too, and differs
    g = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias="interp")
    assert np.percentile(error_2d(g, p), 90) < TWIN_P90_MAX_M
    assert not np.allclose(g, f.xyz)


def test_stale_map_falls_back_and_flags(fmap):
    # a forklift adds 4 m on base station 0 that the map does not know: the fix does not
    # match and falls back to the default map-free method, flagged; the others keep the twin
    n = 400
    extra = np.zeros((n, 4))
    extra[: n // 2, 0] = 4.0
    toa, p = synth_toa(n, sigma_m=SIGMA_M, extra_m=extra, seed=5)
    f = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, return_info=True)
    flagged = (f.status & Status.MAP_MISMATCH) != 0
    assert flagged[: n // 2].mean() > 0.9 and flagged[n // 2 :].mean() < 0.05
    fb = METHODS["twin"].params["fallback"][0]
    ref = locate(toa, PAPER_BS, fb, height_m=1.0)  # the twin runs it on the same batch
    ref[:, :2], _ = clamp_to_polygon(ref[:, :2], np.array([[0, 0], [29, 0], [29, 25], [0, 25.0]]))
    np.testing.assert_allclose(f.xyz[flagged], ref[flagged], atol=1e-9)
    assert f.extra["stale"][flagged].any(axis=1).all()


def test_no_fix_outside_the_service_area(fmap):
    toa, p = synth_toa(300, sigma_m=2.0, seed=6)  # very noisy: raw fixes leave the area
    xyz = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, fallback_m=0.01)
    assert (xyz[:, 0] >= 0).all() and (xyz[:, 0] <= 29).all()
    assert (xyz[:, 1] >= 0).all() and (xyz[:, 1] <= 25).all()
    poly = np.array([[0.0, 0], [10, 0], [10, 10], [0, 10]])
    q, moved = clamp_to_polygon(np.array([[12.0, 5.0], [5.0, 5.0], [-1.0, -2.0]]), poly)
    np.testing.assert_allclose(q, [[10.0, 5.0], [5.0, 5.0], [0.0, 0.0]], atol=1e-5)
    assert moved.tolist() == [True, False, True]


def test_map_of_another_site_is_refused(fmap):
    toa, _ = synth_toa(5)
    other = PAPER_BS + [0.5, 0.0, 0.0]
    with pytest.raises(PositioningError, match="not this site's map"):
        locate(toa, other, "twin", height_m=1.0, map=fmap)
    with pytest.raises(PositioningError, match="needs a fingerprint map"):
        locate(toa, PAPER_BS, "twin", height_m=1.0)
    with pytest.raises(PositioningError, match="2D only"):
        locate(toa, PAPER_BS, "twin", map=fmap)


def test_cli_twin_and_tracked_rows(fmap, tmp_path, capsys):
    pts = np.array([[8.3, 6.1, 1.0], [20.2, 17.9, 1.0]])
    nlos = {(i, 2): float(nlos_bias(pts[i : i + 1, :2])[0, 2]) for i in range(len(pts))}
    ds = write_dataset(tmp_path / "ds", points=pts, n_epochs=20, sigma_m=SIGMA_M, nlos=nlos)
    mp = write_map(tmp_path / "hall.npz", fmap)
    out = tmp_path / "fx.csv"
    argv = [str(ds), "--method", "twin", "--map", str(mp), "-o", str(out)]
    assert estimate_positions_main(argv) == 0
    lines = out.read_text().splitlines()
    assert lines[0].endswith(",nlos_bs,match_m") and lines[1].split(",")[-2] == "BS3"
    rep = tmp_path / "rep"
    argv = [str(ds), "--methods", "irls,twin,twin+track", "--map", str(mp), "-o", str(rep)]
    assert accuracy_report_main(argv) == 0
    head = (rep / "table.csv").read_text().splitlines()[0].split(",")
    assert "twin" in head and "twin+track" not in head
    tracked = (rep / "table_tracked.csv").read_text().splitlines()
    assert "twin+track" in tracked[0].split(",") and "twin" not in tracked[0].split(",")


@pytest.mark.parametrize("damage", ["truncate", "schema", "missing", "band", "names"])
def test_corrupt_map_is_refused_in_one_line(fmap, tmp_path, capsys, damage):
    ds = write_dataset(tmp_path / "ds", points=np.array([[8.3, 6.1, 1.0]]), n_epochs=2)
    if damage == "band":  # the dataset is c-band
        fmap = replace(fmap, meta={**fmap.meta, "band": "mmwave"})
    elif damage == "names":
        fmap = replace(fmap, bs_names=np.array(["A", "B", "C", "D"]))
    mp = write_map(tmp_path / "m.npz", fmap)
    if damage == "truncate":
        mp.write_bytes(mp.read_bytes()[:300])
    elif damage == "schema":
        with np.load(mp) as z:
            data = dict(z)
        data["schema_version"] = np.array(99)
        np.savez(mp, **data)
    else:
        mp = tmp_path / "nope.npz"
    out = tmp_path / "fx.csv"
    code = estimate_positions_main([str(ds), "--method", "twin", "--map", str(mp), "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ")
    assert not out.exists()


def test_report_picks_the_map_of_each_dataset_band(fmap, tmp_path, capsys):
    pts = np.array([[8.3, 6.1, 1.0]])
    c = write_dataset(tmp_path / "c", points=pts, n_epochs=4, band="c-band")
    mm = write_dataset(tmp_path / "mm", points=pts, n_epochs=4, band="mmwave")
    mp_c = write_map(tmp_path / "c.npz", replace(fmap, meta={**fmap.meta, "band": "c-band"}))
    mp_mm = write_map(tmp_path / "mm.npz", replace(fmap, meta={**fmap.meta, "band": "mmwave"}))
    argv = [str(c), str(mm), "--methods", "twin", "--map", str(mp_mm), "--map", str(mp_c)]
    assert accuracy_report_main([*argv, "-o", str(tmp_path / "rep")]) == 0
    # a band without a map: one line naming the bands the maps are for
    argv = [str(c), str(mm), "--methods", "twin", "--map", str(mp_c), "--map", str(mp_c)]
    assert accuracy_report_main([*argv, "-o", str(tmp_path / "rep2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none of the maps is for band 'mmwave'" in err[0]
    assert not (tmp_path / "rep2").exists()
