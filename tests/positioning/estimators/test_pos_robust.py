"""Estimators beyond the paper: they must remove a single NLoS base station's influence."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import C0, Status, error_2d, locate, make_problem
from positioning.estimators.robust import (
    HUBER_C,
    TUKEY_C,
    m_estimator,
    nlos_aware,
    nlos_loss,
    nlos_weights,
    robust_weights,
    subset,
)

#: Range noise, metres (1 sigma).
SIGMA_M = 0.02
#: NLoS excess range of the biased base station, metres.
NLOS_BIAS_M = 5.0
#: A robust fix with one NLoS base station must stay this close to the clean fix, metres.
CLEAN_MATCH_M = 5 * SIGMA_M
#: Noiseless nlos-aware fix with the right hypothesis (residual influence of the outlier), m.
HYP_TOL_M = 0.03
#: Ratio of parity-vector components beyond which the first-order hypothesis prediction holds.
DECISIVE = 1.2
#: Tolerance of hand-computed loss / weight values.
VALUE_TOL = 1e-12

ROBUST = ("m-estimator", "subset", "nlos-aware")
SQUARE = np.array([[0.0, 0.0, 4.0], [29.0, 0.0, 4.0], [29.0, 25.0, 4.0], [0.0, 25.0, 4.0]])


def ring(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = np.arange(n) * 2 * np.pi / n + rng.uniform(0, 0.5)
    r = rng.uniform(13, 17, n)
    return np.column_stack([14.5 + r * np.cos(a), 12.5 + r * np.sin(a), rng.uniform(3, 6, n)])


def devices(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(6, 23, n), rng.uniform(4, 21, n), np.ones(n)])


def measure(bs, dev, sigma, seed, bias=None):
    rng = np.random.default_rng(seed)
    d = np.linalg.norm(dev[:, None, :] - bs[None, :, :], axis=2)
    d = d + rng.normal(0.0, sigma, d.shape) + (0.0 if bias is None else bias)
    return d / C0 + rng.uniform(-1e-3, 1e-3, (len(dev), 1))


@pytest.mark.parametrize("n_bs", [5, 6])
@pytest.mark.parametrize("method", ROBUST)
def test_single_nlos_base_station_any_one_is_removed(method, n_bs):
    """Same noise, +5 m on base station j (every j in turn): the robust fix stays within
    5 sigma of the fix from clean data, while LS and IRLS are off by metres."""
    bs = ring(n_bs, seed=n_bs)
    dev = devices(40, 1)
    rng = np.random.default_rng(2)
    noise = rng.normal(0.0, SIGMA_M, (40, n_bs))
    clean = measure(bs, dev, 0.0, 3, noise)
    ref = locate(clean, bs, method, height_m=1.0)
    assert error_2d(ref, dev).max() < 5 * SIGMA_M
    for j in range(n_bs):
        bias = noise.copy()
        bias[:, j] += NLOS_BIAS_M
        t = measure(bs, dev, 0.0, 3, bias)
        f = locate(t, bs, method, height_m=1.0, return_info=True)
        shift = np.linalg.norm(f.xyz - ref, axis=1)
        assert shift.max() < CLEAN_MATCH_M, (j, shift.max())
        assert np.all(f.status & Status.OUTLIER_REJECTED)
        assert np.all(f.weights[:, j] < 0.01)
        e_ls = error_2d(locate(t, bs, "ls", height_m=1.0), dev)
        e_irls = error_2d(locate(t, bs, "irls", height_m=1.0), dev)
        assert e_irls.mean() > 10 * error_2d(f.xyz, dev).mean()
        assert e_ls.mean() > 10 * error_2d(f.xyz, dev).mean()


def test_two_nlos_base_stations_with_six():
    """subset drops as many as identifiable; nlos-aware with max_drop=2 hypotheses too."""
    bs = ring(6, seed=6)
    dev = devices(30, 4)
    bias = np.zeros(6)
    bias[[1, 4]] = [NLOS_BIAS_M, 3.0]
    t = measure(bs, dev, SIGMA_M, 5, bias)
    clean = locate(measure(bs, dev, SIGMA_M, 5), bs, "subset", height_m=1.0)
    for method, kw in (("subset", {}), ("nlos-aware", {"max_drop": 2})):
        f = locate(t, bs, method, height_m=1.0, return_info=True, **kw)
        assert np.linalg.norm(f.xyz - clean, axis=1).max() < 10 * SIGMA_M, method
        assert np.all(f.weights[:, [1, 4]] < 0.01)


def test_four_base_stations_2d_residuals_cannot_identify():
    """N = 4 in 2D: a leave-one-out subset has 3 base stations = 3 unknowns (x, y, clock), an
    exact fit. subset detects the inconsistency but cannot attribute it and returns the full fit,
    m-estimator returns least squares; both flag NO_REDUNDANCY. nlos-aware uses that NLoS only
    delays: most fixes are back to the clean accuracy, and it clearly beats LS."""
    dev = devices(200, 6)
    rng = np.random.default_rng(7)
    bias = np.zeros((200, 4))
    bias[np.arange(200), rng.integers(0, 4, 200)] = NLOS_BIAS_M
    t = measure(SQUARE, dev, SIGMA_M, 8, bias)
    prob = make_problem(t, SQUARE, height_m=1.0)
    s = subset(prob)
    assert np.all(s.status & Status.NO_REDUNDANCY)
    assert np.all(s.status & Status.INCONSISTENT)
    assert np.all(s.weights == 1.0)
    m = m_estimator(prob)
    assert np.all(m.status & Status.NO_REDUNDANCY)
    e_ls = error_2d(locate(t, SQUARE, "ls", height_m=1.0), dev)
    e_na = error_2d(nlos_aware(prob).xyz, dev)
    assert np.median(e_na) < 5 * SIGMA_M < np.median(e_ls)
    assert np.mean(e_na < 5 * SIGMA_M) > 0.55
    assert e_na.mean() < 0.75 * e_ls.mean()


def parity_vector(bs: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """Left null vector of the pseudo-range Jacobian [d|p-b_n|/d(x, y), 1] (4 x 3) at ``dev``."""
    diff = dev[None, :] - bs
    J = np.column_stack([diff[:, :2] / np.linalg.norm(diff, axis=1)[:, None], np.ones(len(bs))])
    return np.linalg.svd(J.T)[2][-1]


@pytest.mark.parametrize("dev_xy", [(6.0, 5.0), (20.0, 8.0), (11.0, 17.0)])
def test_positivity_decides_between_hypotheses(dev_xy):
    """4 base stations, 2D, noiseless, +5 m on base station k. To first order, the fit without
    base station j predicts an excess ``b v_k / v_j`` for j (v: parity vector). Hypotheses with
    ``sign(v_j) != sign(v_k)`` need an *early* arrival and are rejected; of the others nlos-aware
    takes the smallest excess, i.e. the right one iff ``|v_k|`` is the largest of its sign
    group. Checked for every k where the prediction is decisive (|v| of the two candidates
    differ by more than ``DECISIVE``; closer, the second-order terms decide). (The log loss leaves the
    rejected measurement an influence ``k^2 sigma / z``: about 1 cm here, hence ``HYP_TOL_M``.)"""
    dev = np.array([dev_xy[0], dev_xy[1], 1.0])
    v = parity_vector(SQUARE, dev)
    n_decided = 0
    for k in range(4):
        bias = np.zeros((1, 4))
        bias[0, k] = NLOS_BIAS_M
        t = measure(SQUARE, dev[None], 0.0, 0, bias)
        f = locate(t, SQUARE, "nlos-aware", height_m=1.0, return_info=True)
        others = [j for j in range(4) if j != k and np.sign(v[j]) == np.sign(v[k])]
        j = max(others, key=lambda i: abs(v[i]))
        ratio = abs(v[k]) / abs(v[j])
        if ratio > DECISIVE:  # first-order prediction: k is blamed, the fix is right
            np.testing.assert_allclose(f.xyz[0], dev, atol=HYP_TOL_M)
            assert f.weights[0, k] < 0.01
            n_decided += 1
        elif ratio < 1 / DECISIVE:  # j needs the smaller excess: a wrong, consistent hypothesis
            assert f.weights[0, j] < 0.05 and error_2d(f.xyz, dev[None])[0] > 1.0
            n_decided += 1
    assert n_decided >= 2


def test_clean_data_keeps_every_base_station():
    """alpha = 1 %: the chi-square test rarely drops a LoS base station; robust fixes stay close
    to least squares on clean data."""
    bs = ring(6, seed=1)
    dev = devices(300, 9)
    t = measure(bs, dev, 0.1, 10)
    f = locate(t, bs, "subset", height_m=1.0, sigma_m=0.1, return_info=True)
    assert f.count(Status.OUTLIER_REJECTED) < 0.05 * 300
    ls = locate(t, bs, "irls", height_m=1.0)
    for m in ROBUST:
        e = error_2d(
            locate(t, bs, m, height_m=1.0, sigma_m=0.1)
            if m != "m-estimator"
            else locate(t, bs, m, height_m=1.0),
            dev,
        )
        assert e.mean() < 1.25 * error_2d(ls, dev).mean(), m


def test_robust_weight_functions_hand_values():
    z = np.array([0.0, 2.0, -3.0, TUKEY_C, 10.0])
    tukey = robust_weights(z, "tukey", TUKEY_C)
    np.testing.assert_allclose(
        tukey,
        [1.0, (1 - (2 / TUKEY_C) ** 2) ** 2, (1 - (3 / TUKEY_C) ** 2) ** 2, 0.0, 0.0],
        atol=VALUE_TOL,
    )
    np.testing.assert_allclose(tukey[1], 0.6687334119, atol=1e-9)  # (1 - 4/21.949225)^2
    huber = robust_weights(z, "huber", HUBER_C)
    np.testing.assert_allclose(huber, [1.0, 0.6725, 1.345 / 3, 1.345 / TUKEY_C, 0.1345])


def test_nlos_loss_is_one_sided_and_smooth():
    k = 2.0
    z = np.array([-10.0, -1.0, 0.0, 1.0, 2.0, 4.0, 20.0])
    np.testing.assert_allclose(
        nlos_loss(z, k),
        [50.0, 0.5, 0.0, 0.5, 2.0, 2.0 + 4.0 * np.log(2.0), 2.0 + 4.0 * np.log(10.0)],
        atol=VALUE_TOL,
    )
    np.testing.assert_allclose(nlos_weights(z, k), [1, 1, 1, 1, 1, 0.25, 0.01], atol=VALUE_TOL)
    h = 1e-6  # derivative continuous at k: psi(k-) = k = psi(k+)
    left = (nlos_loss(np.array([k]), k) - nlos_loss(np.array([k - h]), k)) / h
    right = (nlos_loss(np.array([k + h]), k) - nlos_loss(np.array([k]), k)) / h
    np.testing.assert_allclose([left[0], right[0]], [k, k], atol=1e-5)
    # a 5 m late arrival costs far less than a 5 m early one (sigma 0.1 m)
    assert nlos_loss(np.array([50.0]), k)[0] < 0.015 * nlos_loss(np.array([-50.0]), k)[0]


def test_candidates_are_fitted_once_per_problem_with_a_memo_and_are_the_same():
    """With a memo, the robust estimators' hypothesis fits are made at the first method that
    asks and handed to the others: the same fits, and every method's fixes bit for bit; a
    sub-problem (another set of arrays) does not take them."""
    from pos_synth import PAPER_BS, nlos_scene

    from positioning.estimators import robust
    from positioning.estimators.nlos import nlos_map
    from positioning.model.problem import make_problem

    _, toa, links = nlos_scene(11, 80, PAPER_BS, 1)
    plain = make_problem(toa, PAPER_BS, height_m=1.0, links=links)
    kept = plain.with_memo()
    calls = []
    real = robust._candidates

    def counted(*a):
        calls.append(1)
        return real(*a)

    mp = pytest.MonkeyPatch()
    mp.setattr(robust, "_candidates", counted)
    try:
        for est in (robust.m_estimator, robust.nlos_aware, nlos_map):
            a, b = est(plain), est(kept)
            for name in ("xyz", "status", "weights", "iterations"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert len(calls) == 3 + 1  # plain: once per method; with the memo: once
        sub = kept.take(np.arange(10))
        assert sub.memo is None
        from dataclasses import replace

        other = replace(kept, rho=kept.rho + 1.0)  # carries the memo, not its arrays
        list(robust.candidates(other, other.solvable, 1, 1.0))
        assert len(calls) == 5
    finally:
        mp.undo()
