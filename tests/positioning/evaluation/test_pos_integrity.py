"""Integrity figures: HPL, chi2n and the INTEGRITY flag (issue 13 item 8;
positioning.evaluation.integrity)."""

from __future__ import annotations

import numpy as np
from pos_synth import PAPER_BS, nlos_scene

from positioning import Status, locate
from positioning.model.area import ServiceArea

HALL = ServiceArea.box((-2.0, -2.0), (31.0, 27.0))


def _err(f, dev):
    return np.hypot(*(f.xyz[:, :2] - dev[:, :2]).T)


def test_integrity_clean_data_rarely_flagged():
    dev, toa, links = nlos_scene(3, 400, PAPER_BS, 0)
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
    dev, toa, links = nlos_scene(4, 300, PAPER_BS, 1)
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


def test_shared_hypotheses_give_the_same_figures_bit_for_bit(monkeypatch):
    """With a memo (Problem.with_memo) the fault hypotheses are fitted once and shared by every
    method's fixes: each method gets the HPL and chi2n of its own fits, exactly."""
    from positioning.evaluation import integrity as integrity_module
    from positioning.model.problem import make_problem

    dev, toa, links = nlos_scene(5, 120, PAPER_BS, 1)
    prob = make_problem(toa, PAPER_BS, height_m=1.0, area=HALL, links=links)
    kept = prob.with_memo()
    fitted = []
    real = integrity_module.hypotheses
    monkeypatch.setattr(integrity_module, "hypotheses",
                        lambda *a: fitted.append(1) or real(*a))  # fmt: skip
    for method in ("ls", "nlos-map"):
        f = locate(toa, PAPER_BS, method, height_m=1.0, links=links, area=HALL,
                   return_info=True)  # fmt: skip
        alone = integrity_module.integrity(prob, f.xyz, f.status)
        shared = integrity_module.integrity(kept, f.xyz, f.status)
        for a, b in zip(alone, shared, strict=True):
            np.testing.assert_array_equal(a, b)
    assert len(fitted) == 2 + 1  # without the memo once per method; with it once
