"""The bounded re-solve inside the service area and the no-runaway guarantee (issue 13 item 4;
positioning.estimators.bounded, applied by positioning.methods.run)."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import PositioningError, Status, locate, method_names
from positioning.estimators.bounded import bounded_refit, concentrated_cost
from positioning.model.area import ServiceArea
from positioning.model.problem import make_problem
from positioning.model.tdoa import C0

BOX = ServiceArea.box((0.0, 0.0), (30.0, 26.0))
#: An L-shaped hall: the square (12, 12)-(30, 26) is not floor.
L_SHAPE = ServiceArea(
    np.array([[0, 0], [30, 0], [30, 12], [12, 12], [12, 26], [0, 26]], dtype=float), "L"
)
BS = np.array([[1.0, 1.0, 4.0], [29.0, 1.0, 6.0], [29.0, 11.0, 4.5], [1.0, 25.0, 5.0]])
#: Grid pitch of the brute-force reference, and the cost it may beat the bounded fit by: the cost
#: grows at most by |grad| * pitch / sqrt(2) between grid points and the fit (|grad| ~ 2 r).
GRID_PITCH_M = 0.05






def _junk(seed: int, n: int, area: ServiceArea, three_d: bool):
    """ToAs of devices inside ``area``: half with 5-30 m excess on 1-2 base stations, a quarter
    pure junk (uniform within 100 m), a quarter consistent plus noise."""
    rng = np.random.default_rng(seed)
    g = area.grid(0.5)
    dev = g[rng.integers(0, g.shape[0], n)]
    z = rng.uniform(0.5, 2.0, n)
    xyz = np.column_stack([dev, z])
    d = np.linalg.norm(xyz[:, None, :] - BS[None], axis=2) + rng.normal(0, 0.1, (n, 4))
    kind = rng.integers(0, 4, n)
    for i in np.flatnonzero(kind < 2):
        nb = rng.integers(1, 3)
        d[i, rng.choice(4, nb, replace=False)] += rng.uniform(5, 30, nb)
    junk = kind == 2
    d[junk] = rng.uniform(0, 100, (junk.sum(), 4))
    toa = d / C0 + rng.uniform(0, 1e-3, (n, 1))
    return toa, (None if three_d else z)


# the L-shaped 2D case runs in the fast suite; the box and 3D cases with -m slow
@pytest.mark.parametrize("three_d", [False, pytest.param(True, marks=pytest.mark.slow)])
@pytest.mark.parametrize(
    "area", [pytest.param(BOX, marks=pytest.mark.slow, id="box"), pytest.param(L_SHAPE, id="L")]
)
@pytest.mark.parametrize("method", method_names(include_map=False))  # twin: test_twin.py
def test_no_solved_fix_outside_the_area(method, area, three_d):
    bs = BS if not three_d else np.vstack([BS, [[15.0, 6.0, 8.0]]])
    toa_all, h_all = [], []
    for seed in range(20):
        toa, h = _junk(seed, 30, area, three_d)
        if three_d:  # a fifth base station for the 3D solve: ranges to it from the same rule
            toa = np.column_stack(
                [toa, toa[:, 0] + np.random.default_rng(seed).uniform(0, 6e-8, 30)]
            )
        toa_all.append(toa)
        h_all.append(h)
    toa = np.vstack(toa_all)
    h = None if three_d else np.concatenate(h_all)
    for outside in ("constrain", "reject"):
        f = locate(toa, bs, method, height_m=h, area=area, outside=outside, return_info=True)
        assert area.contains(f.xyz[f.solved, :2]).all()
        bound = (f.status & int(Status.AREA_BOUND)) != 0
        if outside == "reject":
            assert not f.solved[bound].any() and np.isnan(f.xyz[bound]).all()
        else:
            assert f.solved.all()
        if method != "nlos-map":  # nlos-map searches inside the area from the start
            assert bound.any()  # the junk did push fixes out


def test_bounded_fit_matches_brute_force_grid():
    rng = np.random.default_rng(7)
    n = 40
    toa, h = _junk(3, n, L_SHAPE, False)
    toa[:, 1] += rng.uniform(20, 40, n) / C0  # a large excess on BS2: many optima outside
    prob = make_problem(toa, BS, None, h, area=L_SHAPE)
    idx = np.arange(n)
    W = np.ones((n, 4))
    xyz, cost = bounded_refit(prob, idx, np.full((n, 3), np.nan), W)
    assert L_SHAPE.contains(xyz[:, :2]).all()
    np.testing.assert_allclose(cost, concentrated_cost(prob, xyz, idx, W), rtol=1e-9)
    g = L_SHAPE.grid(GRID_PITCH_M)
    for i in range(n):
        pts = np.column_stack([g, np.full(len(g), h[i])])
        c = concentrated_cost(prob, pts, np.full(len(g), i), np.ones((len(g), 4)))
        j = np.argmin(c)
        # the bounded fit is at least as good as the grid's best, up to the grid's resolution
        slack = 2.0 * np.sqrt(c[j]) * GRID_PITCH_M + 1e-6
        assert cost[i] <= c[j] + slack, (i, cost[i], c[j], xyz[i], pts[j])


def test_inside_fixes_are_untouched():
    dev = np.array([[10.0, 5.0, 1.0], [5.0, 20.0, 1.5]])
    d = np.linalg.norm(dev[:, None] - BS[None], axis=2)
    toa = d / C0
    a = locate(toa, BS, "irls", height_m=dev[:, 2], return_info=True)
    b = locate(toa, BS, "irls", height_m=dev[:, 2], area=L_SHAPE, return_info=True)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    assert b.count(Status.AREA_BOUND) == 0 and b.availability == 1.0
    with pytest.raises(PositioningError, match="outside"):
        locate(toa, BS, "irls", height_m=1.0, area=L_SHAPE, outside="clip")
