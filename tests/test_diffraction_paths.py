"""Diffraction in the tracer: pure and mixed paths against independent geometry and knife edges."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import admit_every_beam, box, make_scene, quad
from scipy.optimize import minimize_scalar

from raytrace.constants import C0
from raytrace.diffraction import fresnel_kirchhoff_v, knife_edge_loss_db
from raytrace.tracer import trace

F_C = 3.775e9
DELAY_TOL_S = 1e-12
#: UTD (hard polarisation, vertical field on a horizontal edge) vs the P.526 knife-edge
#: approximation in the shadow region, v in [0.5, 3]: the J(v) formula itself is ~1 dB from the
#: Fresnel integral, and UTD's hard coefficient differs from scalar Kirchhoff by a few tenths.
KNIFE_EDGE_TOL_DB = 1.5


def _shortest_over_edge(src, dst, a, b):
    """Length of the shortest path src -> edge -> dst, by numerical minimisation."""
    res = minimize_scalar(
        lambda u: np.linalg.norm(a + u * (b - a) - src) + np.linalg.norm(dst - a - u * (b - a)),
        bounds=(0.0, 1.0),
        method="bounded",
        options={"xatol": 1e-12},
    )
    return res.fun


def _metal_box_scene():
    return make_scene(
        [
            ("floor", box((-30, -30, -0.3), (30, 30, 0.0)), "concrete"),
            ("block", box((4.0, -1.0, 0.0), (5.0, 1.0, 3.0)), "metal"),
        ]
    )


def test_metal_box_first_arrival_is_the_shortest_edge_diffraction():
    sc = _metal_box_scene()
    tx = np.array([[0.0, 0.0, 4.0]])
    rx = np.array([[10.0, 0.5, 1.0]])
    p = trace(sc, tx, rx, F_C, max_reflections=2, max_penetrations=2, max_diffractions=1)
    assert not p.los.any()
    first = p.first_arrival()[0]
    assert p.kind_label[first] == "D"
    # the top edge on the far side (x = 5, z = 3) is the one a single diffraction can use
    expected = _shortest_over_edge(tx[0], rx[0], np.array([5.0, -1, 3]), np.array([5.0, 1, 3]))
    assert abs(p.delay_s[first] - expected / C0) < DELAY_TOL_S
    np.testing.assert_allclose(p.points[first, 0, [0, 2]], [5.0, 3.0], atol=1e-9)


def test_reflection_into_edge_and_edge_into_reflection():
    """RD: floor reflection then a screen's top edge; DR: the edge then a wall reflection."""
    screen = quad((5.0, -15.0, 0.0), (0.0, 30.0, 0.0), (0.0, 0.0, 3.0))  # x = 5, top edge z = 3
    floor = box((-30, -30, -0.3), (30, 30, 0.0))
    wall = box((-30, 16.0, 0.0), (30, 16.3, 8.0))
    sc = make_scene(
        [("floor", floor, "concrete"), ("screen", screen, "metal"), ("wall", wall, "concrete")]
    )
    tx = np.array([[0.0, 0.0, 2.0]])
    rx = np.array([[9.0, 8.0, 1.0]])
    p = trace(
        sc,
        tx,
        rx,
        F_C,
        max_reflections=1,
        max_penetrations=0,
        max_diffractions=1,
        max_interactions=2,
    )
    a, b = np.array([5.0, -15.0, 3.0]), np.array([5.0, 15.0, 3.0])
    kinds = p.kind_label
    # RD via the floor: image of tx in z = 0
    on_top = np.isclose(p.points[:, :, 2], 3.0, atol=1e-9)
    rd = np.flatnonzero((kinds == "RD") & (p.objects[:, 0] == 0) & on_top[:, 1])
    assert len(rd) == 1
    img_tx = tx[0] * [1, 1, -1]
    assert abs(p.delay_s[rd[0]] - _shortest_over_edge(img_tx, rx[0], a, b) / C0) < DELAY_TOL_S
    assert p.points[rd[0], 0, 2] == pytest.approx(0.0, abs=1e-9)
    # DR via the wall's face y = 16: image of rx in that plane
    dr = np.flatnonzero((kinds == "DR") & (p.objects[:, 1] == 2) & on_top[:, 0])
    assert len(dr) == 1
    img_rx = rx[0].copy()
    img_rx[1] = 32.0 - rx[0, 1]
    assert abs(p.delay_s[dr[0]] - _shortest_over_edge(tx[0], img_rx, a, b) / C0) < DELAY_TOL_S
    assert p.points[dr[0], 1, 1] == pytest.approx(16.0, abs=1e-9)


@pytest.mark.parametrize("rx_z", [-0.5, -1.0, -2.0, -3.0])
def test_half_plane_shadow_matches_knife_edge(rx_z):
    """A vertical metal screen with a horizontal top edge; tx and rx far from it."""
    screen = quad(
        (0.0, -60.0, -60.0), (0.0, 120.0, 0.0), (0.0, 0.0, 60.0)
    )  # plane x = 0, edge z = 0
    sc = make_scene([("screen", screen, "metal")])
    d1, d2 = 30.0, 30.0
    tx = np.array([[-d1, 0.0, -0.2]])
    rx = np.array([[d2, 0.0, rx_z]])
    p = trace(sc, tx, rx, F_C, max_reflections=0, max_penetrations=0, max_diffractions=1)
    assert not p.los.any()
    # the top edge (z = 0); the finite screen's side edges diffract too, much weaker
    d = p.select((p.kind_label == "D") & np.isclose(p.points[:, 0, 2], 0.0, atol=1e-9))
    assert d.n_paths == 1
    lam = C0 / F_C
    # height of the edge above the tx-rx line at the screen
    h = 0.0 - (tx[0, 2] + (rx[0, 2] - tx[0, 2]) * d1 / (d1 + d2))
    v = fresnel_kirchhoff_v(h, d1, d2, lam)
    dist = np.linalg.norm(rx[0] - tx[0])
    free = 20 * np.log10(lam / (4 * np.pi * dist))
    expected_db = free - knife_edge_loss_db(v)
    assert abs(d.power_db[0] - expected_db) < KNIFE_EDGE_TOL_DB


def _cluttered_scene(seed: int):
    """Floor, a two-sided screen and boxes of mixed materials at random places (no two touch)."""
    rng = np.random.default_rng(seed)
    objs = [
        ("floor", box((-1, -1, -0.3), (21, 21, 0.0)), "concrete"),
        ("screen", quad((10.0, 2.0, 0.0), (0.0, 6.0, 0.0), (0.0, 0.0, 2.5)), "glass"),
    ]
    materials = ["metal", "wood", "concrete", "metal", "glass", "metal"]
    placed = []
    while len(placed) < 9:
        lo = np.append(rng.uniform(1, 17, 2), 0.0)
        hi = lo + np.append(rng.uniform(0.6, 2.5, 2), rng.uniform(0.5, 4))
        # keep boxes apart (and off the screen): touching faces are a separate matter
        if any((lo[:2] < h[:2] + 0.2).all() and (l[:2] < hi[:2] + 0.2).all() for l, h in placed):
            continue
        if lo[0] < 10.2 and hi[0] > 9.8 and lo[1] < 8.2 and hi[1] > 1.8:
            continue
        placed.append((lo, hi))
        objs.append((f"b{len(placed)}", box(lo, hi), materials[len(placed) % len(materials)]))
    sc = make_scene(objs)
    tx = np.array([[0.5, 0.5, 4.5], [19.5, 19.5, 3.5], [0.5, 19.0, 2.0]])
    rx = rng.uniform((0.5, 0.5, 0.5), (19.5, 19.5, 2.0), size=(12, 3))
    rx = rx[sc.inside_solid(rx) < 0]
    return sc, tx, rx


def _same_paths(a, b):
    assert a.n_paths == b.n_paths > 0
    np.testing.assert_array_equal(a.link, b.link)
    np.testing.assert_array_equal(a.interaction, b.interaction)
    np.testing.assert_array_equal(a.elements, b.elements)
    np.testing.assert_array_equal(a.delay_s, b.delay_s)
    np.testing.assert_array_equal(a.gain, b.gain)


@pytest.mark.parametrize("seed", [5, 11])
def test_mixed_path_pruning_loses_no_path(monkeypatch, seed):
    """The candidate pruning of RD, DR and RDR paths (object and edge beams, the visible part of
    each edge) only drops candidates that fail later anyway: switching it off changes nothing."""
    import raytrace.diffraction_paths as dp

    sc, tx, rx = _cluttered_scene(seed)
    kw = dict(max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=3)
    pruned = trace(sc, tx, rx, F_C, **kw)
    assert {"RD", "DR", "RDR"} <= set(pruned.kind_label)

    def whole_edge(a, b, lo, hi):
        return np.zeros(len(a)), np.ones(len(a))

    admit_every_beam(monkeypatch)
    monkeypatch.setattr(dp, "_segment_box_span", whole_edge)
    monkeypatch.setattr(dp, "SPAN_PAD_M", np.inf)
    _same_paths(pruned, trace(sc, tx, rx, F_C, **kw))


def test_segment_box_span_against_sampling():
    rng = np.random.default_rng(2)
    n = 400
    a = rng.uniform(-2, 2, (n, 3))
    b = rng.uniform(-2, 2, (n, 3))
    b[:40, 1] = a[:40, 1]  # segments parallel to a slab
    lo = rng.uniform(-1.5, 0.0, (n, 3))
    hi = lo + rng.uniform(0.2, 1.5, (n, 3))
    from raytrace.diffraction_paths import _segment_box_span

    s_in, s_out = _segment_box_span(a, b, lo, hi)
    s = np.linspace(0, 1, 4001)
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]
    inside = ((pts >= lo[:, None]) & (pts <= hi[:, None])).all(axis=2)
    step = s[1] - s[0]
    for i in range(n):
        if inside[i].any():
            assert s_in[i] <= s_out[i]
            assert s_in[i] <= s[inside[i]].min() + 1e-12
            assert s_out[i] >= s[inside[i]].max() - 1e-12
            # and not much larger than the sampled span
            assert s_in[i] >= s[inside[i]].min() - step and s_out[i] <= s[inside[i]].max() + step
        else:
            assert s_in[i] > s_out[i] or s_out[i] - s_in[i] < step
