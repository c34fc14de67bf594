"""Diffraction in the tracer: pure and mixed paths against independent geometry and knife edges."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import admit_every_beam, assert_same_both_ways, box, make_scene, quad
from scipy.optimize import minimize_scalar

from raytrace.core.constants import C0
from raytrace.physics.utd import fresnel_kirchhoff_v, knife_edge_loss_db
from raytrace.solver.config import TraceConfig
from raytrace.solver.paths import DIFFRACTION
from raytrace.solver.tracer import trace

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
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1)
    )
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
        TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=1, max_interactions=2),
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
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=0, max_penetrations=0, max_diffractions=1)
    )
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
    sc, tx, rx = _cluttered_scene(seed)
    cfg = TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=3)
    pruned = trace(sc, tx, rx, F_C, cfg)
    assert {"RD", "DR", "RDR"} <= set(pruned.kind_label)

    admit_every_beam(monkeypatch)
    unpruned = trace(sc, tx, rx, F_C, cfg, stats=(stats := {}))
    # the pruning was off: far more candidates
    assert stats["candidates_rd"] > 5 * sum(pruned.kind_label == "RD")
    _same_paths(pruned, unpruned)


# -- lossy wedges in the tracer: labels, winding, mirror symmetry; junctions ------------------
MIRROR_TOL_DB = 0.05  # issue 17: mirrored tx and rx about a wedge's bisector, same gain
RELABEL_RTOL = 1e-9  # relabelling the faces of every wedge: the same paths, the same gains


def _relabelled(sc):
    """The scene with face 0 and face n of every wedge swapped (what another mesher may do)."""
    import dataclasses

    w = sc.wedges
    tn = np.cross(w.direction, w.normal1)
    tn /= np.linalg.norm(tn, axis=1)[:, None]
    # a convex wedge's face n lies behind face 0's outward normal; a sheet's two faces are the
    # same half-plane, so its face0_dir stays
    tn *= np.where(np.einsum("ij,ij->i", tn, w.normal0) > 0, -1.0, 1.0)[:, None]
    half = np.einsum("ij,ij->i", w.normal0, w.normal1) < -1 + 1e-9
    tn = np.where(half[:, None], w.face0_dir, tn)
    swapped = dataclasses.replace(w, normal0=w.normal1, normal1=w.normal0, face0_dir=tn)
    out = dataclasses.replace(sc, wedges=swapped)
    out.build_embree()
    return out


def _concrete_pillar_scene():
    return make_scene(
        [
            ("floor", box((-20, -20, -0.3), (20, 20, 0.0)), "concrete"),
            ("pillar", box((-0.3, -0.3, 0.0), (0.3, 0.3, 8.0)), "concrete"),
            ("screen", quad((3.0, -4.0, 0.0), (0.0, 8.0, 0.0), (0.0, 0.0, 2.5)), "glass"),
        ]
    )


def test_relabelled_faces_give_the_same_diffraction():
    sc = _concrete_pillar_scene()
    rng = np.random.default_rng(17)
    tx = rng.uniform([-8, -8, 0.5], [8, 8, 4], (3, 3))
    rx = rng.uniform([-8, -8, 0.5], [8, 8, 4], (6, 3))
    cfg = TraceConfig(max_reflections=1, max_penetrations=1, max_diffractions=1, max_interactions=2)
    a = trace(sc, tx, rx, F_C, cfg)
    b = trace(_relabelled(sc), tx, rx, F_C, cfg)
    d = a.n_diffractions > 0
    assert d.sum() > 50
    ka = np.lexsort((a.delay_s, a.link))
    kb = np.lexsort((b.delay_s, b.link))
    np.testing.assert_array_equal(a.link[ka], b.link[kb])
    np.testing.assert_allclose(b.gain[kb], a.gain[ka], rtol=RELABEL_RTOL, atol=0)


def test_mirrored_links_about_a_concrete_pillar_edge_have_the_same_diffracted_gain():
    """A vertical pillar edge, symmetric about its bisector plane: tx and rx mirrored through it
    (vertical polarisation is mirrored onto itself) must see the same edge-diffracted gain."""
    sc = make_scene(
        [
            ("floor", box((-15, -15, -0.3), (15, 15, 0.0)), "concrete"),  # sets the bounds
            ("pillar", box((-0.3, -0.3, 0.0), (0.3, 0.3, 8.0)), "concrete"),
        ]
    )
    edge = np.array([0.3, 0.3])  # the edge x = y = 0.3; bisector plane x - y = 0
    rng = np.random.default_rng(3)
    ang = rng.uniform(-0.7, 0.7, (2, 40)) * np.pi + 0.25 * np.pi  # around the bisector
    r = rng.uniform(2, 9, (2, 40))
    tx = np.stack(
        [edge[0] + r[0] * np.cos(ang[0]), edge[1] + r[0] * np.sin(ang[0]), rng.uniform(0.5, 7, 40)],
        1,
    )
    rx = np.stack(
        [edge[0] + r[1] * np.cos(ang[1]), edge[1] + r[1] * np.sin(ang[1]), rng.uniform(0.5, 7, 40)],
        1,
    )
    swap = np.array([1, 0, 2])
    gains = []
    for t, q in ((tx, rx), (tx[:, swap], rx[:, swap])):
        p = trace(
            sc, t, q, F_C, TraceConfig(max_reflections=0, max_penetrations=0, max_diffractions=1)
        )
        on_edge = (p.n_diffractions == 1) & np.all(np.isclose(p.points[:, 0, :2], edge), axis=1)
        g = np.full(len(t) * len(q), np.nan)
        g[p.link[on_edge]] = 20 * np.log10(np.abs(p.gain[on_edge]))
        gains.append(g)
    both = np.isfinite(gains[0]) & np.isfinite(gains[1])
    assert both.sum() > 100 and np.array_equal(np.isfinite(gains[0]), np.isfinite(gains[1]))
    assert np.max(np.abs(gains[0][both] - gains[1][both])) < MIRROR_TOL_DB


@pytest.mark.parametrize("name", ["canonical/shoebox", "canonical/box_on_floor_concrete"])
def test_no_diffraction_at_room_corners_or_where_a_box_stands(name):
    from raytrace.scene.io import load_scene

    sc = load_scene(name)
    if name.endswith("shoebox"):
        tx, rx = (
            np.array([[2.0, 3.0, 1.5], [8.0, 1.0, 2.5]]),
            np.array([[7.0, 5.0, 1.2], [1.0, 7.0, 0.5]]),
        )
    else:
        tx, rx = (
            np.array([[-5.0, 0.0, 1.5]]),
            np.array([[5.0, 0.0, 1.5], [0.0, 5.0, 1.0], [2.0, 3.0, 0.3]]),
        )
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1)
    )
    d = p.n_diffractions > 0
    if name.endswith("shoebox"):
        assert not d.any()  # the room's edges are concave inside; their outside is out of reach
        assert p.n_paths >= len(tx) * len(rx) * (1 + 6 + 18)  # LoS + 6 + 18 image paths survive
    else:
        # no diffraction point on the box's bottom edges (z = 0 on the box's footprint); the
        # floor sheet's own free edges (|x| or |y| = 10) are real edges
        pts = p.points[d][p.interaction[d] == DIFFRACTION]
        on_bottom = (np.abs(pts[:, 2]) < 1e-6) & np.all(np.abs(pts[:, :2]) <= 1 + 1e-6, axis=1)
        assert d.any() and not on_bottom.any()


def test_diffracted_paths_are_reciprocal():
    """Swapping transmitter and receiver gives the same D, RD and DR paths with the same delays
    and gains on lossy wedges (a concrete pillar, a wooden crate, a glass pane: solids and a
    sheet), with one antenna at both ends. Luebbers' original face rule (the incident ray's angle
    on a face the source lights, the diffracted ray's on the other) changed these gains by up to
    60 dB on the hall (``tools/check_reciprocity.py``)."""
    sc = make_scene(
        [
            ("floor", box((-8, -8, -0.3), (8, 8, 0.0)), "concrete"),
            ("pillar", box((-0.4, -0.4, 0.0), (0.4, 0.4, 3.5)), "concrete"),
            ("crate", box((2.0, 1.0, 0.0), (3.0, 2.5, 1.4)), "wood"),
            ("pane", quad((-3, 2, 0), (0, 3.5, 0), (0, 0, 2.5)), "glass"),
        ]
    )
    cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=1,
                      min_power_db=-np.inf)  # fmt: skip
    rng = np.random.default_rng(8)
    ends_a = np.array([[-5.0, -4.2, 2.7], [5.5, -3.1, 3.1]])
    ends_b = rng.uniform([-6.0, -1.0, 0.5], [6.0, 6.0, 2.0], (6, 3))
    ends_b = ends_b[sc.inside_solid(ends_b) < 0]
    fwd = trace(sc, ends_a, ends_b, F_C, cfg, threads=1)
    rev = trace(sc, ends_b, ends_a, F_C, cfg, threads=1)
    has_d = (fwd.interaction == DIFFRACTION).any(axis=1)
    assert has_d.sum() > 40
    assert_same_both_ways(fwd, rev, len(ends_a), len(ends_b))


def test_segment_touching_an_opaque_box_is_not_blocked_one_way_only():
    """Two metal machines side by side on the hall's grid line y = 12 and a point on that line:
    the diffraction at the far machine's corner reaches the point along the near machine's face.
    Embree reported that face from the point's end and not from the corner's, so the path was
    blocked by the opaque box in one direction only. A touch is not a block: both directions
    find the path, with the same gain."""
    sc = make_scene(
        [
            ("floor", box((0.0, 0.0, -0.3), (42.0, 46.0, 0.0)), "concrete"),
            ("st_01", box((27.5, 12.0, 0.0), (29.7, 14.0, 2.2)), "metal"),
            ("st_02", box((29.9, 12.0, 0.0), (32.1, 14.0, 2.2)), "metal"),
        ]
    )
    cfg = TraceConfig(max_reflections=0, max_penetrations=0, max_diffractions=1)
    point, bs = np.array([[23.0, 12.0, 1.0]]), np.array([[6.5, 10.5, 4.0]])
    fwd = trace(sc, bs, point, F_C, cfg, threads=1)
    rev = trace(sc, point, bs, F_C, cfg, threads=1)
    corner = [32.1, 12.0]

    def at_corner(p):
        on = (p.interaction[:, 0] == DIFFRACTION) & np.all(
            np.abs(p.points[:, 0, :2] - corner) < 1e-5, axis=1)
        return np.flatnonzero(on)

    i, j = at_corner(fwd), at_corner(rev)
    assert len(i) == len(j) == 1
    np.testing.assert_allclose(rev.gain[j], fwd.gain[i], rtol=1e-9)


@pytest.mark.parametrize("boundary", ["shadow", "reflection"])
def test_the_total_field_exactly_on_a_boundary_is_its_limit_from_either_side(boundary):
    """A metal sheet 100 m wide and a receiver whose line of sight passes exactly over its top
    edge (shadow boundary), or whose reflection point lies exactly on that edge (reflection
    boundary), then 1 mm either side. The tracer counts the geometrical-optics field exactly on
    the boundary (a grazing ray only touches the edge; a point on a facet's edge is in it), so
    the diffracted term must take the lit side's value there: the total field is the mean of
    the two sides' within 0.2 % (about half the GO field). It was the whole GO field: 6 dB
    above both."""
    sc = make_scene([("sheet", quad((0, -50, -50), (0, 100, 0), (0, 0, 52)), "metal")])
    cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=1,
                      max_interactions=1)  # fmt: skip
    tx = np.array([[-5.0, 0.3, 4.0]])
    total = []
    for dz in (0.0, 1e-3, -1e-3):
        q = tx + 2.5 * (np.array([0.0, 1.0, 2.0 + dz]) - tx)  # through the edge point (0, 1, 2)
        rx = q if boundary == "shadow" else q * [-1, 1, 1]  # its mirror: reflected at the edge
        p = trace(sc, tx, rx, F_C, cfg, threads=1)
        gain = p.gain[p.kind_label != "LoS"] if boundary == "reflection" else p.gain
        total.append(abs(gain.sum()))
    on, side = total[0], 0.5 * (total[1] + total[2])
    assert abs(on - side) < 2e-3 * side
    free = C0 / F_C / (4 * np.pi * np.linalg.norm(q - tx))
    assert 0.4 < side / free < 0.6
