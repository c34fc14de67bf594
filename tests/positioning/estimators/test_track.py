"""Tests of ``positioning.track``: the robust constant-velocity Kalman filter (METHOD+track)."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import Status, locate
from positioning.errors import PositioningError
from positioning.estimators.track import (
    DEFAULT_DT_S,
    RESTART_AFTER,
    check_params,
    kalman_track,
    split_method,
    step_response,
    track_fixes,
)

#: Stated latency of a step beyond the gate: the restart at the RESTART_AFTER-th fix.
STEP_LATENCY_S = RESTART_AFTER * DEFAULT_DT_S
#: Steady-state error ratio (tracked / raw, mean 2D error) of a static point for the defaults;
#: the exact CV-filter value at sigma 0.3 m, q 0.2 m^2/s^3, 10 Hz is about 0.45.
STATIC_RATIO_MAX = 0.6


def test_split_method():
    assert split_method("irls+track") == ("irls", True)
    assert split_method("twin") == ("twin", False)


def test_static_point_converges():
    rng = np.random.default_rng(1)
    n = 600
    truth = np.array([12.0, 7.0])
    xy = truth + rng.normal(0.0, 0.3, (n, 2))
    out, _ = kalman_track(xy, np.zeros(n), np.arange(n) * DEFAULT_DT_S)
    raw = np.hypot(*(xy[100:] - truth).T).mean()
    tracked = np.hypot(*(out[100:] - truth).T).mean()
    assert tracked < STATIC_RATIO_MAX * raw
    # the mean of the last 200 tracked fixes is within 3 standard errors of the truth
    assert np.hypot(*(out[-200:].mean(axis=0) - truth)) < 3 * 0.3 / np.sqrt(200 / 10)


@pytest.mark.parametrize("step_m", [1.5, 3.0, 10.0])
def test_step_is_followed_within_the_stated_latency(step_m):
    assert step_response(step_m) <= STEP_LATENCY_S + 1e-9


def test_small_step_is_followed_by_the_filter():
    # a step inside the gate is followed by the filter dynamics (bounded, documented: < 2 s)
    assert 0.0 < step_response(0.7) < 2.0


def test_gate_rejects_an_outlier_epoch():
    rng = np.random.default_rng(2)
    n = 200
    xy = np.array([5.0, 5.0]) + rng.normal(0.0, 0.05, (n, 2))
    xy[120] += [4.0, 0.0]  # one NLoS epoch: the fix jumps 4 m
    out, st = kalman_track(xy, np.zeros(n), np.arange(n) * DEFAULT_DT_S)
    assert st[120] & Status.TRACK_GATED
    assert not st[121] & Status.TRACK_RESTART
    assert np.hypot(*(out[120] - [5.0, 5.0])) < 0.1


def test_devices_are_independent_and_order_is_by_time():
    rng = np.random.default_rng(3)
    n = 100
    a = np.array([1.0, 2.0]) + rng.normal(0, 0.1, (n, 2))
    b = np.array([20.0, 3.0]) + rng.normal(0, 0.1, (n, 2))
    t = np.arange(n) * 0.1
    xy = np.vstack([a, b])
    dev = np.array(["A"] * n + ["B"] * n)
    tt = np.concatenate([t, t])
    perm = rng.permutation(2 * n)  # shuffled rows give the same per-row result
    out, _ = kalman_track(xy, dev, tt)
    out_p, _ = kalman_track(xy[perm], dev[perm], tt[perm])
    np.testing.assert_allclose(out_p, out[perm])
    alone, _ = kalman_track(a, np.zeros(n), t)
    np.testing.assert_allclose(out[:n], alone)


def test_unsolved_fixes_are_predicted_through():
    n = 50
    xy = np.tile([3.0, 4.0], (n, 1))
    xy[:5] = np.nan
    xy[20:25] = np.nan
    out, _ = kalman_track(xy, np.zeros(n))
    assert np.isnan(out[:5]).all()
    np.testing.assert_allclose(out[20:25], np.tile([3.0, 4.0], (5, 1)), atol=1e-9)


def test_track_fixes_names_and_flags():
    bs = np.array([[0.0, 0, 4], [29, 0, 4], [29, 25, 4], [0, 25, 4]])
    p = np.array([10.0, 8.0, 1.0])
    d = np.linalg.norm(p - bs, axis=1)
    rng = np.random.default_rng(4)
    toa = (d + rng.normal(0, 0.1, (40, 4))) / 299_792_458.0
    f = locate(toa, bs, "irls", height_m=1.0, return_info=True)
    t = track_fixes(f, np.zeros(40), np.arange(40) * 0.1)
    assert t.method == "irls+track" and t.n_unsolved == 0
    np.testing.assert_allclose(t.xyz[:, 2], 1.0)
    with pytest.raises(PositioningError, match="track has no parameter"):
        check_params({"nope": 1})
    with pytest.raises(PositioningError, match="positive"):
        check_params({"sigma_m": -1})
