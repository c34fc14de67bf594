"""Eq. 7 against one reference: the reference choices and the lowest minimum in the service area
(positioning.estimators.eq7), and IRLS as written (irls-paper) beside the guarded one."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import C0, PositioningError, Status, locate, make_problem
from positioning.estimators.eq7 import (
    REFERENCE_CHOICES,
    choose_reference,
    eq7_cost,
    parse_reference,
    reference_by_name,
    solve_eq7,
)
from positioning.estimators.irls import IrlsConfig, irls
from positioning.methods.registry import METHODS, resolve_params
from positioning.model.area import ServiceArea
from positioning.model.problem import LinkInfo

SQUARE = np.array([[0.0, 0.0, 4.0], [29.0, 0.0, 4.0], [29.0, 25.0, 4.0], [0.0, 25.0, 4.0]])
AREA = ServiceArea.box([-6.0, -6.0], [35.0, 31.0])
#: The two-minimum case: a device near BS3 whose reference BS1 is 6.13 m late.
DEVICE = np.array([25.43, 19.84, 1.0])
BIAS = np.array([6.13, 0.0, 0.0, 0.0])
#: Pitch of the brute-force grid of the eq. 7 cost, m, and how far its best cell may be from a
#: minimum found by Gauss-Newton (half a diagonal).
BRUTE_M = 0.05
BRUTE_SLACK_M = 0.05
#: Costs that must agree (same minimum), m^2.
COST_TOL = 1e-9


def two_minimum_problem(area=AREA):
    d = np.linalg.norm(DEVICE[None] - SQUARE, axis=1) + BIAS
    return make_problem((d / C0)[None], SQUARE, height_m=1.0, area=area)


def brute_force_minima(prob, lo, hi):
    """Local minima of the eq. 7 cost (reference 0) on a BRUTE_M grid over [lo, hi]^2: cells
    lower than their 8 neighbours, as (k, 2) points and (k,) costs, deepest first."""
    xs = np.arange(lo[0], hi[0], BRUTE_M)
    ys = np.arange(lo[1], hi[1], BRUTE_M)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    rho = prob.rho[0]
    R = np.sqrt((X[..., None] - SQUARE[:, 0]) ** 2 + (Y[..., None] - SQUARE[:, 1]) ** 2 + 9.0)
    c = np.sum(((rho[1:] - rho[0]) - (R[..., 1:] - R[..., :1])) ** 2, axis=2)
    inner = c[1:-1, 1:-1]
    is_min = np.ones_like(inner, dtype=bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                is_min &= inner < c[1 + dx : c.shape[0] - 1 + dx, 1 + dy : c.shape[1] - 1 + dy]
    i, j = np.nonzero(is_min)
    pts = np.column_stack([xs[i + 1], ys[j + 1]])
    order = np.argsort(inner[i, j])
    return pts[order], inner[i, j][order]


def test_the_closed_form_start_stops_in_the_worse_minimum_and_the_search_does_not():
    prob = two_minimum_problem()
    ref, rows = np.zeros(1, np.int64), np.ones(1, bool)
    local = solve_eq7(prob, ref, rows, tol=1e-9, max_iter=50, grid_m=0.0)
    best = solve_eq7(prob, ref, rows, tol=1e-9, max_iter=50)
    assert best.converged[0]  # (the closed-form one crawls along a flat valley: 50 iterations)
    c_local = eq7_cost(prob, ref, local.xyz)[0]
    c_best = eq7_cost(prob, ref, best.xyz)[0]
    # the brute-force cost map has exactly these two minima near the hall, and the search's is
    # the deepest, inside the area; the closed-form start's lies outside and costs more
    pts, costs = brute_force_minima(prob, (-20.0, -20.0), (60.0, 60.0))
    assert len(pts) == 2
    np.testing.assert_allclose(best.xyz[0, :2], pts[0], atol=BRUTE_SLACK_M)
    np.testing.assert_allclose(local.xyz[0, :2], pts[1], atol=BRUTE_SLACK_M)
    assert c_best < c_local - 1.0 and c_best <= costs[0] + COST_TOL
    assert AREA.contains(best.xyz[:, :2])[0] and not AREA.contains(local.xyz[:, :2])[0]
    # through the registered method: ls finds it whatever the reference choice gives (ref 0)
    fix = locate(prob_toa(), SQUARE, "ls", height_m=1.0, area=AREA, return_info=True)
    np.testing.assert_allclose(fix.xyz, best.xyz, atol=1e-9)
    assert fix.count(Status.AREA_BOUND) == 0
    old = locate(prob_toa(), SQUARE, "ls", height_m=1.0, area=AREA, grid_m=0, return_info=True)
    assert old.count(Status.AREA_BOUND) == 1  # it left the area: bounded back into it


def prob_toa():
    d = np.linalg.norm(DEVICE[None] - SQUARE, axis=1) + BIAS
    return (d / C0)[None]


def test_without_an_area_the_search_covers_the_base_stations_box():
    prob = two_minimum_problem(area=None)
    best = solve_eq7(prob, np.zeros(1, np.int64), np.ones(1, bool), tol=1e-9, max_iter=50)
    pts, _ = brute_force_minima(prob, (-20.0, -20.0), (60.0, 60.0))
    # the box grown by half its diagonal (19 m) holds both minima: the lower one is kept
    np.testing.assert_allclose(best.xyz[0, :2], pts[0], atol=BRUTE_SLACK_M)


def test_a_single_minimum_is_found_with_or_without_the_search():
    rng = np.random.default_rng(4)
    dev = np.column_stack([rng.uniform(3, 26, 50), rng.uniform(3, 22, 50), np.ones(50)])
    d = np.linalg.norm(dev[:, None] - SQUARE[None], axis=2) + rng.normal(0, 0.05, (50, 4))
    prob = make_problem(d / C0, SQUARE, height_m=1.0, area=AREA)
    ref, rows = np.zeros(50, np.int64), np.ones(50, bool)
    a = solve_eq7(prob, ref, rows, tol=1e-9, max_iter=50, grid_m=0.0)
    b = solve_eq7(prob, ref, rows, tol=1e-9, max_iter=50)
    # the closed-form start's descent reaches the only minimum: its result is kept, bit for bit
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.iterations, b.iterations)


# --------------------------------------------------------------------------------------------
# Reference choices
# --------------------------------------------------------------------------------------------


def test_reference_choices_parse_and_unknown_ones_list_the_known():
    assert parse_reference(None) == "first" and parse_reference("random") == "random"
    assert parse_reference(2) == parse_reference("2") == parse_reference("fixed:2") == "fixed:2"
    assert parse_reference("Strongest") == "strongest"
    with pytest.raises(PositioningError, match="first, random, strongest, fixed:N, got 'best'"):
        parse_reference("best")
    with pytest.raises(PositioningError, match="4 base stations"):
        parse_reference("fixed:4", 4)
    assert REFERENCE_CHOICES == ("first", "random", "strongest", "fixed:N")
    assert reference_by_name("fixed:BS3", ["BS1", "BS2", "BS3"]) == "fixed:2"
    assert reference_by_name("BS1", ["BS1", "BS2"]) == "fixed:0"
    assert reference_by_name("random", ["BS1"]) == "random"
    with pytest.raises(PositioningError, match="parameter 'reference'.*known|first, random"):
        resolve_params("ls", {"reference": "nearest"}, 4)
    assert resolve_params("ls", {"reference": "random", "seed": "3"}, 4)["seed"] == 3


def test_random_reference_is_seeded_uniform_over_the_received_ones():
    n = 8000
    t = np.full((n, 4), 1e-7)
    t[::2, 1] = np.nan  # BS2 missing in every other epoch
    prob = make_problem(t, SQUARE, height_m=1.0)
    ref, fallback = choose_reference(prob, "random", seed=5)
    again, _ = choose_reference(prob, "random", seed=5)
    other, _ = choose_reference(prob, "random", seed=6)
    np.testing.assert_array_equal(ref, again)
    assert (ref != other).mean() > 0.5 and not fallback.any()
    assert prob.valid[np.arange(n), ref].all()  # never a missing one
    full = np.bincount(ref[1::2], minlength=4) / (n / 2)
    part = np.bincount(ref[::2], minlength=4) / (n / 2)
    # uniform: 1/4 each with all four, 1/3 each of the three received (sampling std < 0.01)
    np.testing.assert_allclose(full, 0.25, atol=0.03)
    np.testing.assert_allclose(part[[0, 2, 3]], 1 / 3, atol=0.03)
    assert part[1] == 0.0


def test_fixed_and_strongest_references():
    t = np.full((3, 4), 1e-7)
    t[1, 2] = np.nan
    snr = np.array([[10.0, 20.0, 30.0, 5.0]] * 3)
    width = np.array([[1.0, 1.0, 1.3, 1.0], [1.0, 1.0, 1.0, 1.0], [np.nan] * 4])
    ratio = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, -6.0, 0.0, 0.0], [np.nan] * 4])
    links = LinkInfo(snr, ratio, width)
    prob = make_problem(t, SQUARE, height_m=1.0, links=links)
    ref, fallback = choose_reference(prob, "fixed:2")
    assert ref.tolist() == [2, 0, 2] and fallback.tolist() == [False, True, False]
    # epoch 0: BS3 is the strongest but its lobe is broadened; epoch 1: BS3 is missing and BS2's
    # lobe is 6 dB under the strongest peak; epoch 2: no lobe shape reported
    ref, _ = choose_reference(prob, "strongest")
    assert ref.tolist() == [1, 0, 2]
    no_links = make_problem(t, SQUARE, height_m=1.0)
    assert choose_reference(no_links, "strongest")[0].tolist() == [0, 0, 0]
    f = locate(t, SQUARE, "ls", height_m=1.0, reference="fixed:2", return_info=True)
    assert f.status[1] & Status.REFERENCE_FALLBACK and not f.status[0] & Status.REFERENCE_FALLBACK


# --------------------------------------------------------------------------------------------
# IRLS as written and as guarded
# --------------------------------------------------------------------------------------------


def algorithm_1(prob, q, use, u_max=3.0, epsilon=1e-4, max_iter=100):
    """Algorithm 1 of the paper written out for one epoch: equal weights, then eqs. 10, 11, 9,
    8 until the average moves by at most epsilon (the estimates q (N, 3) where ``use``)."""
    Q = q[use].mean(axis=0)
    for _ in range(max_iter):
        R = np.linalg.norm(Q - prob.bs, axis=1)
        s = prob.rho[0] - R
        u = np.array([np.mean(np.abs(np.delete(s, e) - s[e])) for e in range(len(s))])
        w = np.where(use & (u <= u_max), np.sinc(u / u_max), 0.0)
        if w.sum() == 0:  # eq. 9 undefined: the previous average stays
            break
        new = (w / w.sum()) @ np.where(use[:, None], q, 0.0)
        moved = np.linalg.norm(new - Q)
        Q = new
        if moved <= epsilon:
            break
    return Q


def test_irls_paper_averages_every_estimate_and_irls_only_the_converged(monkeypatch):
    """One per-reference solve did not converge (stopped 6 m off): the guarded IRLS leaves it
    out; Algorithm 1 as written (irls-paper) averages it in."""
    import positioning.estimators.irls as irls_module

    dev = np.array([12.0, 9.0, 1.0])
    d = np.linalg.norm(dev[None] - SQUARE, axis=1) + np.array([0.0, 0.0, 0.0, 2.0])
    prob = make_problem((d / C0)[None], SQUARE, height_m=1.0)
    q = np.array([[[12.3, 9.2, 1.0], [11.8, 9.4, 1.0], [12.1, 8.7, 1.0], [17.0, 13.0, 1.0]]])
    conv = np.array([[True, True, True, False]])

    def fake(prob, rows, config):
        return q.copy(), conv.copy(), np.zeros(1, bool)

    monkeypatch.setattr(irls_module, "reference_estimates", fake)
    guarded = irls(prob)
    plain = METHODS["irls-paper"].run(prob, resolve_params("irls-paper", {}, 4))
    every = np.ones(4, bool)
    np.testing.assert_allclose(plain.xyz[0], algorithm_1(prob, q[0], every), atol=1e-6)
    np.testing.assert_allclose(guarded.xyz[0], algorithm_1(prob, q[0], conv[0]), atol=1e-6)
    assert guarded.weights[0, 3] == 0.0 and plain.weights[0, 3] > 0.0
    assert np.linalg.norm(plain.xyz[0, :2] - dev[:2]) > 3 * np.linalg.norm(
        guarded.xyz[0, :2] - dev[:2]
    )
    assert guarded.status[0] & Status.NOT_CONVERGED and plain.status[0] & Status.NOT_CONVERGED
    # with every solve converged the two are the same algorithm
    monkeypatch.undo()
    rng = np.random.default_rng(8)
    devs = np.column_stack([rng.uniform(5, 24, 20), rng.uniform(5, 20, 20), np.ones(20)])
    dd = np.linalg.norm(devs[:, None] - SQUARE[None], axis=2) + rng.normal(0, 0.3, (20, 4))
    many = make_problem(dd / C0, SQUARE, height_m=1.0)
    a = irls(many)
    b = METHODS["irls-paper"].run(many, resolve_params("irls-paper", {}, 4))
    np.testing.assert_array_equal(a.xyz, b.xyz)
    assert irls(many, IrlsConfig(guard=False)).method == "irls"
