"""One result type for every estimator: each returns Fixes (positioning.estimators.fixes), named
after its method, with its config's fields as parameters; the old dict access still works for one
release."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pos_synth import PAPER_BS, synth_map

from positioning import Fixes, Status, make_problem
from positioning.estimators.fixes import config_params
from positioning.estimators.irls import IrlsConfig, LsConfig, irls, least_squares
from positioning.estimators.nlos import NlosMapConfig, nlos_map
from positioning.estimators.robust import (
    MEstimatorConfig,
    NlosAwareConfig,
    SubsetConfig,
    m_estimator,
    nlos_aware,
    subset,
)
from positioning.estimators.track import TrackConfig, check_params, track_fixes
from positioning.model.tdoa import C0
from positioning.twin.estimator import TwinConfig, twin

ESTIMATORS = [
    ("ls", least_squares, LsConfig()),
    ("irls", irls, IrlsConfig()),
    ("m-estimator", m_estimator, MEstimatorConfig()),
    ("subset", subset, SubsetConfig()),
    ("nlos-aware", nlos_aware, NlosAwareConfig()),
    ("nlos-map", nlos_map, NlosMapConfig()),
]


def _problem():
    """Five noiseless devices (2D, 1 m) and an epoch with two base stations only (unsolved)."""
    rng = np.random.default_rng(3)
    dev = np.column_stack([rng.uniform(3, 26, 5), rng.uniform(3, 22, 5), np.ones(5)])
    toa = np.linalg.norm(dev[:, None] - PAPER_BS[None], axis=2) / C0
    toa = np.vstack([toa, [toa[0, 0], np.nan, toa[0, 2], np.nan]])
    return make_problem(toa, PAPER_BS, height_m=1.0), dev


@pytest.mark.parametrize("name, estimator, config", ESTIMATORS, ids=[e[0] for e in ESTIMATORS])
def test_every_estimator_returns_fixes(name, estimator, config):
    prob, dev = _problem()
    f = estimator(prob, config)
    assert isinstance(f, Fixes) and f.method == name
    assert f.params == {k.name: getattr(config, k.name) for k in dataclasses.fields(config)}
    assert f.xyz.shape == (6, 3) and f.weights.shape == (6, 4) and f.iterations.shape == (6,)
    np.testing.assert_array_equal(f.n_used, [4, 4, 4, 4, 4, 2])
    np.testing.assert_allclose(f.xyz[:5], dev, atol=1e-6)  # noiseless: exact
    assert f.status[5] & Status.UNSOLVED and np.isnan(f.xyz[5]).all()
    assert estimator(prob).params == f.params  # the default config is the one given here


def test_twin_and_tracking_return_fixes():
    prob, dev = _problem()
    f = twin(prob, TwinConfig(fingerprint_map=synth_map(), bias="cell"))
    assert isinstance(f, Fixes) and f.method == "twin" and f.params["bias"] == "cell"
    assert set(f.extra) == {"nlos", "stale", "match_m", "fallback"}
    t = track_fixes(f, np.zeros(6), np.arange(6) * 0.1, check_params({"gate": "9"}))
    assert isinstance(t, Fixes) and t.method == "twin+track"
    assert t.params["gate"] == 9.0 and t.params["bias"] == "cell"
    assert check_params({}) == TrackConfig()


def test_configs_are_frozen_and_params_are_shallow():
    fmap = synth_map()
    cfg = TwinConfig(fingerprint_map=fmap)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.top = 5  # type: ignore[misc]
    assert config_params(cfg)["fingerprint_map"] is fmap  # the map, not a deep copy


def test_the_old_dict_access_warns_and_reads_the_same():
    prob, _ = _problem()
    f = irls(prob)
    with pytest.warns(DeprecationWarning, match=r"positioning\.Fixes\['xyz'\] moved to "
                                                r"positioning\.Fixes\.xyz"):  # fmt: skip
        assert f["xyz"] is f.xyz
    with pytest.warns(DeprecationWarning, match=r"Fixes\.extra\['estimates'\]"):
        assert f["estimates"] is f.extra["estimates"]
    with pytest.warns(DeprecationWarning):
        assert f["fit_weights"] is None
