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


def test_shared_hypotheses_give_the_same_figures_bit_for_bit():
    """The fault hypotheses fitted once (HypothesisCache) and shared by two methods' fixes give
    every method the HPL and chi2n it gets with its own fits (exactly)."""
    import pytest

    from positioning.evaluation.integrity import HypothesisCache, integrity
    from positioning.model.problem import make_problem

    dev, toa, links = nlos_scene(5, 120, PAPER_BS, 1)
    prob = make_problem(toa, PAPER_BS, height_m=1.0, area=HALL, links=links)
    cache = HypothesisCache(prob)
    for method in ("ls", "nlos-map"):
        f = locate(toa, PAPER_BS, method, height_m=1.0, links=links, area=HALL,
                   return_info=True)  # fmt: skip
        alone = integrity(prob, f.xyz, f.status)
        shared = integrity(prob, f.xyz, f.status, cache)
        for a, b in zip(alone, shared):
            np.testing.assert_array_equal(a, b)
    assert len(cache) == 1  # all solved: one set of epochs, fitted once
    with pytest.raises(ValueError, match="another problem"):
        integrity(prob.take(np.arange(3)), f.xyz[:3], f.status[:3], cache)
