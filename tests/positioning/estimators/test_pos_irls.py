"""The paper's LS (eq. 7) and IRLS (Algorithm 1, eqs. 8-12), with the guards the paper omits."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import C0, Status, andrews_weight, error_2d, locate, make_problem
from positioning.estimators.irls import IrlsConfig, irls, uncertainties

#: Absolute tolerance of hand-computed weights.
WEIGHT_TOL = 1e-12
#: Tolerance of positions that must coincide exactly (same arithmetic), metres.
SAME_TOL_M = 1e-9
#: Range noise of the NLoS scenarios, metres (1 sigma).
SIGMA_M = 0.02
#: The NLoS excess delay of one base station, metres.
NLOS_BIAS_M = 5.0

SQUARE = np.array([[0.0, 0.0, 4.0], [29.0, 0.0, 4.0], [29.0, 25.0, 4.0], [0.0, 25.0, 4.0]])


def ring(n: int) -> np.ndarray:
    """n base stations on a 15 m circle around the centre of the paper's area, at 4 m."""
    a = np.arange(n) * 2 * np.pi / n + 0.3
    return np.column_stack([14.5 + 15 * np.cos(a), 12.5 + 15 * np.sin(a), np.full(n, 4.0)])


def devices(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(7, 22, n), rng.uniform(5, 20, n), np.ones(n)])


def measure(bs, dev, sigma, seed, bias=None):
    rng = np.random.default_rng(seed)
    d = np.linalg.norm(dev[:, None, :] - bs[None, :, :], axis=2)
    d = d + rng.normal(0.0, sigma, d.shape)
    if bias is not None:
        d = d + bias
    return d / C0 + rng.uniform(-1e-3, 1e-3, (len(dev), 1))


@pytest.mark.parametrize(
    ("u", "expect"),
    [
        (0.0, 1.0),  # the limit of sin(x)/x
        (1.0, (np.sqrt(3) / 2) / (np.pi / 3)),  # sin(pi/3)/(pi/3) = 0.826993...
        (1.5, 2.0 / np.pi),  # sin(pi/2)/(pi/2) = 0.636620...
        (2.25, (np.sqrt(2) / 2) / (3 * np.pi / 4)),  # 0.300105...
        (3.0, 0.0),  # sin(pi)/pi: continuous at the cut-off
        (3.0001, 0.0),
        (50.0, 0.0),
        (np.nan, 0.0),
    ],
)
def test_andrews_weight_hand_values(u, expect):
    assert andrews_weight(u, 3.0) == pytest.approx(expect, abs=WEIGHT_TOL)


def test_andrews_weight_literals():
    """The same against decimal numbers typed in from a calculator."""
    w = andrews_weight(np.array([1.0, 1.5, 2.25]), 3.0)
    np.testing.assert_allclose(w, [0.8269933431, 0.6366197724, 0.3001054387], atol=1e-10)


def test_uncertainty_eq10_against_a_loop():
    bs = ring(5)
    dev = devices(3, 1)
    t = measure(bs, dev, 0.3, 2)
    t[1, 3] = np.nan
    prob = make_problem(t, bs, height_m=1.0)
    q = dev + np.array([0.4, -0.3, 0.0])
    u = uncertainties(prob, q)
    for i in range(3):
        ok = np.flatnonzero(np.isfinite(t[i]))
        for e in ok:
            terms = []
            for n in ok:
                if n == e:
                    continue
                dd = C0 * (t[i, n] - t[i, e])
                model = np.linalg.norm(q[i] - bs[n]) - np.linalg.norm(q[i] - bs[e])
                terms.append(abs(dd - model))
            assert u[i, e] == pytest.approx(np.mean(terms), abs=1e-6)
    assert np.isnan(u[1, 3])


def test_ls_biased_reference_and_irls_rejects_it():
    """BS0 has +5 m NLoS excess and is LS's reference (the default: first base station). With
    6 base stations IRLS gives the estimate referenced to BS0 a weight near zero and its error
    is well below LS's at every point."""
    bs = ring(6)
    dev = devices(60, 3)
    bias = np.zeros(6)
    bias[0] = NLOS_BIAS_M
    t = measure(bs, dev, SIGMA_M, 4, bias)
    ls = locate(t, bs, "ls", height_m=1.0)
    f = locate(t, bs, "irls", height_m=1.0, return_info=True)
    e_ls, e_irls = error_2d(ls, dev), error_2d(f.xyz, dev)
    assert np.all(f.weights[:, 0] < 0.1)
    assert np.median(f.weights[:, 0]) < 1e-3
    assert np.all(e_irls < 0.7 * e_ls)
    assert e_irls.mean() < 0.45 * e_ls.mean()
    # ... but every per-reference estimate still uses BS0's biased ToA, so IRLS does not reach
    # the clean accuracy (the estimators in positioning.robust do).
    assert e_irls.mean() > 10 * SIGMA_M


def test_four_base_stations_irls_still_beats_a_biased_reference():
    """With 4 base stations in 2D the residuals cannot tell which base station is biased (one
    redundant measurement), so IRLS's uncertainties are similar for all references; it still
    beats LS referenced to the biased base station by averaging the N estimates."""
    dev = devices(60, 5)
    t = measure(SQUARE, dev, SIGMA_M, 6, np.array([NLOS_BIAS_M, 0, 0, 0]))
    e_ls = error_2d(locate(t, SQUARE, "ls", height_m=1.0), dev)
    e_irls = error_2d(locate(t, SQUARE, "irls", height_m=1.0), dev)
    assert np.all(e_irls < e_ls)
    assert e_irls.mean() < 0.8 * e_ls.mean()


def test_irls_matches_ls_without_outliers():
    for bs in (SQUARE, ring(6)):
        dev = devices(50, 7)
        t = measure(bs, dev, SIGMA_M, 8)
        ls = locate(t, bs, "ls", height_m=1.0)
        ir = locate(t, bs, "irls", height_m=1.0)
        assert np.max(np.linalg.norm(ls - ir, axis=1)) < 3 * SIGMA_M
        assert abs(error_2d(ls, dev).mean() - error_2d(ir, dev).mean()) < SIGMA_M


def test_ls_reference_choice_and_fallback():
    dev = devices(2, 9)
    t = measure(SQUARE, dev, 0.0, 9, np.array([0, 0, NLOS_BIAS_M, 0]))
    e0 = error_2d(locate(t, SQUARE, "ls", height_m=1.0), dev)
    e2 = error_2d(locate(t, SQUARE, "ls", height_m=1.0, reference=2), dev)
    assert np.all(e2 > e0)  # referencing the biased base station is worse
    t[1, 2] = np.nan
    f = locate(t, SQUARE, "ls", height_m=1.0, reference=2, return_info=True)
    assert f.status[1] & Status.REFERENCE_FALLBACK and not f.status[0] & Status.REFERENCE_FALLBACK
    np.testing.assert_allclose(f.xyz[1], dev[1], atol=1e-6)  # remaining 3 are LoS & noiseless


def test_all_weights_zero_keeps_equal_weight_average():
    """u_max far below the noise: every eq. 11 weight is 0 at the first reweighting. The epoch
    keeps the equal-weight average of the N estimates (eq. 8 at i = 0) and is flagged."""
    dev = devices(5, 10)
    t = measure(SQUARE, dev, 0.5, 11)
    prob = make_problem(t, SQUARE, height_m=1.0)
    res = irls(prob, IrlsConfig(u_max=1e-3))
    assert np.all(res.status & Status.ALL_WEIGHTS_ZERO)
    np.testing.assert_allclose(res.xyz, res.extra["estimates"].mean(axis=1), atol=SAME_TOL_M)
    assert np.all(res.weights == 0.0)
    assert np.all(res.iterations == 1)


def test_not_converged_returns_last_estimate():
    """max_iter = 1: the result is exactly one reweighting of Algorithm 1, computed here by hand
    from the per-reference estimates, and the epoch is flagged NOT_CONVERGED."""
    dev = devices(4, 12)
    t = measure(ring(5), dev, SIGMA_M, 13, np.array([0, 3.0, 0, 0, 0]))
    prob = make_problem(t, ring(5), height_m=1.0)
    res = irls(prob, IrlsConfig(max_iter=1, epsilon=1e-12))
    q = res.extra["estimates"]
    q0 = q.mean(axis=1)
    w = andrews_weight(uncertainties(prob, q0), 3.0)
    expect = np.sum((w / w.sum(axis=1, keepdims=True))[..., None] * q, axis=1)
    np.testing.assert_allclose(res.xyz, expect, atol=SAME_TOL_M)
    assert np.all(res.status & Status.NOT_CONVERGED)
    full = irls(prob)
    assert not np.any(full.status & Status.NOT_CONVERGED)
    assert np.all(full.iterations > 1)


def test_irls_with_missing_toas():
    """A missing ToA removes that base station as a reference (weight 0, estimate NaN)."""
    dev = devices(3, 14)
    t = measure(ring(5), dev, 0.0, 15)
    t[0, 1] = np.nan
    prob = make_problem(t, ring(5), height_m=1.0)
    res = irls(prob)
    assert np.isnan(res.extra["estimates"][0, 1]).all() and res.weights[0, 1] == 0.0
    np.testing.assert_allclose(res.weights.sum(axis=1), 1.0, atol=WEIGHT_TOL)
    np.testing.assert_allclose(res.xyz, dev, atol=1e-6)


def test_ls_not_converged_flag_and_iteration_count():
    """Noisy data: the closed-form start is not the least-squares optimum, so one LM iteration
    cannot meet the tolerance; with the default limit it converges in a few."""
    dev = devices(6, 16)
    t = measure(SQUARE, dev, 0.3, 17)
    f1 = locate(t, SQUARE, "ls", height_m=1.0, return_info=True, max_iter=1)
    assert np.all(f1.status & Status.NOT_CONVERGED) and np.all(f1.iterations == 1)
    f = locate(t, SQUARE, "ls", height_m=1.0, return_info=True)
    assert f.count(Status.NOT_CONVERGED) == 0 and np.all(f.iterations <= 10)


def test_fixes_container_and_status_labels():
    from positioning import status_label

    dev = devices(3, 18)
    t = measure(SQUARE, dev, 0.0, 19)
    t[2, :2] = np.nan
    f = locate(t, SQUARE, "irls", height_m=1.0, return_info=True)
    assert f.n_epochs == 3 and f.n_unsolved == 1 and f.solved.tolist() == [True, True, False]
    assert f.method == "irls" and f.params["u_max"] == 3.0
    assert f.labels() == ["ok", "ok", "unsolved"]
    assert status_label(Status.NOT_CONVERGED | Status.ALL_WEIGHTS_ZERO) == (
        "not_converged|all_weights_zero"
    )
    xyz = locate(t, SQUARE, "irls", height_m=1.0)
    np.testing.assert_array_equal(xyz, f.xyz)


def test_irls_ignores_a_per_reference_solve_that_converged_far_away():
    """An epoch of the hall's mmWave dataset where one reference's least squares converged on an
    asymptote millions of metres away: the average must stay inside the deployment."""
    import positioning

    toa = np.array(
        [6.6787641987511e-4, 0.01066783353996238, 0.02066794502550181, 0.03066791389432037]
    )
    bs = np.array([[6.5, 10.5, 4.0], [35.5, 10.5, 4.0], [35.5, 35.5, 4.0], [6.5, 35.5, 4.0]])
    true_xy = np.array([27.6, 10.9])
    fixes = positioning.locate(
        toa[None], bs, "irls", tx_offsets_s=[0.0, 0.01, 0.02, 0.03], height_m=1.0, return_info=True
    )
    err = np.linalg.norm(fixes.xyz[0, :2] - true_xy)
    # the deployment spans 29 m x 25 m: a bounded, flagged estimate, not 10^6 m
    assert err < 15.0
    assert "not_converged" in fixes.labels()[0]


def test_irls_stays_in_the_region_when_every_reference_diverges():
    """A 6 m NLoS excess on one of 4 base stations: every per-reference least squares runs off
    hundreds of km; IRLS must return a bounded, flagged estimate."""
    import positioning
    from positioning.model.tdoa import C0 as C

    bs = np.array([[7.5, 6.0, 7.5], [22.5, 6.0, 7.5], [7.5, 18.0, 7.5], [22.5, 18.0, 7.5]])
    ranges = np.array([27.7857, 15.5070, 16.6372, 6.4333])
    fixes = positioning.locate((ranges / C)[None], bs, "irls", height_m=1.5, return_info=True)
    xy = fixes.xyz[0, :2]
    diag = np.hypot(15.0, 12.0)
    assert np.all(xy >= bs[:, :2].min(axis=0) - diag) and np.all(xy <= bs[:, :2].max(axis=0) + diag)
    assert "not_converged" in fixes.labels()[0]
