"""nlos-map on injected NLoS (issue 13 item 5; positioning.estimators.nlos)."""

from __future__ import annotations

import numpy as np
from pos_synth import PAPER_BS, SIGMA_M, nlos_scene

from positioning import locate
from positioning.model.area import ServiceArea

HALL = ServiceArea.box((-2.0, -2.0), (31.0, 27.0))


SIX_BS = np.vstack([PAPER_BS, [[14.5, -1.0, 5.0], [14.5, 26.0, 3.0]]])


def _err(f, dev):
    return np.hypot(*(f.xyz[:, :2] - dev[:, :2]).T)


def test_nlos_map_removes_one_nlos_base_station_of_six():
    dev, toa, links = nlos_scene(1, 200, SIX_BS, 1)
    f = locate(toa, SIX_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    e = _err(f, dev)
    # with the biased one out, 5 LoS ranges of noise SIGMA_M: a few sigma at worst
    assert np.percentile(e, 90) < 3 * SIGMA_M, np.percentile(e, [50, 90, 100])
    assert np.max(e) < 10 * SIGMA_M


def test_nlos_map_with_four_base_stations_uses_snr_and_positivity():
    dev, toa, links = nlos_scene(2, 300, PAPER_BS, 1)
    f = locate(toa, PAPER_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    g = locate(toa, PAPER_BS, "irls", height_m=1.0, area=HALL, return_info=True)
    e, ei = _err(f, dev), _err(g, dev)
    # redundancy 1: the exact leave-one-out fits all fit; the SNR deficit and the sign of the
    # excess pick the right one in most epochs
    assert np.median(e) < 2 * SIGMA_M, np.percentile(e, [50, 90])
    assert np.mean(e) < 0.3 * np.mean(ei)
