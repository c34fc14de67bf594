"""The optional extras of a dataset: the receiver's reports per link, the link budget and the
service area (positioning.io.dataset)."""

from __future__ import annotations

import numpy as np
import pytest
from pos_synth import write_dataset

POINTS = np.array([[5.0, 6.0, 1.0], [14.0, 12.0, 1.0], [22.0, 19.0, 1.0]])


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
