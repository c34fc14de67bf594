"""nlos-map on injected NLoS, integrity figures (HPL, chi2n, INTEGRITY), and the CLI contract
of the service area and integrity (issue 13 items 4, 5, 8; issue 18's untrustworthy runs)."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from pos_synth import PAPER_BS, write_dataset  # noqa: E402

from positioning import Status, locate  # noqa: E402
from positioning.cli.estimate import estimate_positions_main  # noqa: E402
from positioning.model.area import ServiceArea  # noqa: E402
from positioning.model.noise import FLOOR_FIRST_LOBE  # noqa: E402
from positioning.model.problem import LinkInfo  # noqa: E402
from positioning.model.tdoa import C0  # noqa: E402
from positioning.report.fixes_file import FIXES_COLUMNS  # noqa: E402

#: mmWave-like band: 400 MHz, 28 GHz; link budget offset so that the free-space SNR at 20 m is
#: about 12 dB (as in the bundled hall).
BAND = {"bandwidth_hz": 400e6, "center_frequency_hz": 28e9, "subcarrier_spacing_hz": 120e3}
SNR_OFFSET_DB = 99.4
SIGMA_M = FLOOR_FIRST_LOBE * C0 / BAND["bandwidth_hz"]  # 0.045 m: the model's noise core
HALL = ServiceArea.box((-2.0, -2.0), (31.0, 27.0))
SIX_BS = np.vstack([PAPER_BS, [[14.5, -1.0, 5.0], [14.5, 26.0, 3.0]]])


def _scene(seed: int, n: int, bs: np.ndarray, n_nlos: int, excess=(5.0, 30.0)):
    """ToAs and receiver reports of n devices: range noise SIGMA_M, ``n_nlos`` base stations per
    epoch with a uniform excess and an SNR 15 dB under free space (a blocked link); LoS links
    at their free-space SNR."""
    rng = np.random.default_rng(seed)
    dev = np.column_stack([rng.uniform(2, 27, n), rng.uniform(2, 23, n), np.full(n, 1.0)])
    d = np.linalg.norm(dev[:, None] - bs[None], axis=2)
    lam = C0 / BAND["center_frequency_hz"]
    snr = SNR_OFFSET_DB + 20 * np.log10(lam / (4 * np.pi * d))
    bias = np.zeros_like(d)
    for i in range(n):
        j = rng.choice(len(bs), n_nlos, replace=False)
        bias[i, j] = rng.uniform(*excess, n_nlos)
        snr[i, j] -= 15.0
    toa = (d + bias + rng.normal(0, SIGMA_M, d.shape)) / C0 + rng.uniform(0, 1e-3, (n, 1))
    links = LinkInfo(
        snr_db=snr,
        peak_ratio_db=np.zeros_like(d),
        lobe_width=np.ones_like(d),
        receiver="first-lobe",
        snr_offset_db=SNR_OFFSET_DB,
        **BAND,
    )
    return dev, toa, links


def _err(f, dev):
    return np.hypot(*(f.xyz[:, :2] - dev[:, :2]).T)


def test_nlos_map_removes_one_nlos_base_station_of_six():
    dev, toa, links = _scene(1, 200, SIX_BS, 1)
    f = locate(toa, SIX_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    e = _err(f, dev)
    # with the biased one out, 5 LoS ranges of noise SIGMA_M: a few sigma at worst
    assert np.percentile(e, 90) < 3 * SIGMA_M, np.percentile(e, [50, 90, 100])
    assert np.max(e) < 10 * SIGMA_M


def test_nlos_map_with_four_base_stations_uses_snr_and_positivity():
    dev, toa, links = _scene(2, 300, PAPER_BS, 1)
    f = locate(toa, PAPER_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    g = locate(toa, PAPER_BS, "irls", height_m=1.0, area=HALL, return_info=True)
    e, ei = _err(f, dev), _err(g, dev)
    # redundancy 1: the exact leave-one-out fits all fit; the SNR deficit and the sign of the
    # excess pick the right one in most epochs
    assert np.median(e) < 2 * SIGMA_M, np.percentile(e, [50, 90])
    assert np.mean(e) < 0.3 * np.mean(ei)


def test_integrity_clean_data_rarely_flagged():
    dev, toa, links = _scene(3, 400, PAPER_BS, 0)
    for method in ("irls", "nlos-map"):
        f = locate(
            toa,
            PAPER_BS,
            method,
            height_m=1.0,
            links=links,
            area=HALL,
            alert_limit_m=1.0,
            return_info=True,
        )
        assert f.flagged.mean() <= 0.01, method
        e = _err(f, dev)
        assert np.all(e <= f.hpl_m), method
        # chi2n of consistent measurements at the model's sigma: about 1 (1 dof: mean 1)
        assert 0.5 < np.nanmean(f.chi2n) < 2.0


def test_integrity_one_nlos_base_station_every_epoch():
    dev, toa, links = _scene(4, 300, PAPER_BS, 1)
    for method in ("ls", "irls", "nlos-map"):
        f = locate(
            toa,
            PAPER_BS,
            method,
            height_m=1.0,
            links=links,
            area=HALL,
            alert_limit_m=2.0,
            return_info=True,
        )
        e = _err(f, dev)
        big = e > 2.0
        assert f.flagged[big].all(), (method, np.flatnonzero(big & ~f.flagged))
        # one fault: the protection level bounds the error in every epoch
        assert np.all(e <= f.hpl_m), (method, np.max(e - f.hpl_m))
        assert ((f.status & int(Status.INTEGRITY)) != 0).sum() == f.flagged.sum()


POINTS = np.array([[5.0, 6.0, 1.0], [14.0, 12.0, 1.0], [22.0, 19.0, 1.0]])


def test_cli_area_counts_columns_and_untrustworthy_run(tmp_path, capsys):
    # a service area that leaves P01 outside: its fixes are bounded, then rejected
    area = {"polygon": [[10, 2], [28, 2], [28, 24], [10, 24]], "source": "test"}
    ds = write_dataset(tmp_path / "d", points=POINTS, n_epochs=3, extra_meta={"service_area": area})
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
    ds2 = write_dataset(tmp_path / "e", points=POINTS, n_epochs=2, extra_meta={"service_area": far})
    out2 = tmp_path / "g.csv"
    for extra in ([], ["--outside", "reject"]):
        assert estimate_positions_main([str(ds2), *extra, "-o", str(out2)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no trustworthy fix" in err[0], err
        assert not out2.exists()


@pytest.mark.parametrize("bad", ["0", "-1", "nan"])
def test_cli_bad_alert_limit(tmp_path, capsys, bad):
    ds = write_dataset(tmp_path / "d", points=POINTS, n_epochs=1)
    assert estimate_positions_main([str(ds), "--alert-limit", bad, "-o", str(tmp_path / "x")]) == 2
    assert "alert-limit" in capsys.readouterr().err


def test_link_reports_and_area_from_a_dataset(tmp_path):
    from positioning.io.dataset import (
        dataset_area,
        link_budget_offset_db,
        link_reports,
        load_dataset,
    )

    meta = {
        "toa_method": "first-lobe",
        "band_parameters": {"bandwidth_hz": 1e8, "center_frequency_hz": 3.775e9},
        "link_budget": {"tx_power_dbm": 20.0, "noise_figure_db": 9.0, "temperature_k": 290.0},
    }
    ds = load_dataset(write_dataset(tmp_path / "d", points=POINTS, n_epochs=2, extra_meta=meta))
    links = link_reports(ds)
    assert links.snr_db.shape == ds.toa_s.shape and np.all(links.snr_db == 30.0)  # pos_synth
    assert np.isnan(links.lobe_width).all() and np.isnan(links.peak_ratio_db).all()  # absent
    assert links.receiver == "first-lobe" and links.bandwidth_hz == 1e8
    # P_tx - (-174 dBm/Hz + 80 dB + 9 dB) = 20 + 85 = 105 dB
    assert link_budget_offset_db(ds.meta) == pytest.approx(105.0, abs=1e-9)
    area = dataset_area(ds)  # no service_area: the hall_xy rectangle of pos_synth
    assert area is not None and area.source == "meta.json hall_xy"
    np.testing.assert_allclose(area.bounds[0], [-2.0, -2.0])
