"""The compiled pruning loops (raytrace.solver.kernels) against independent computations: closed
forms, the dense numpy expressions they replace, and brute-force sampling of the edges."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box, make_scene, quad

from raytrace.core.jit import carray
from raytrace.physics import utd
from raytrace.scene import accel
from raytrace.solver import diffraction, kernels, shadow
from raytrace.solver import reflection as refl
from raytrace.solver.config import TraceConfig
from raytrace.solver.context import TraceContext


def _ctx(scene, tx, rx):
    return TraceContext(scene, np.atleast_2d(tx), np.atleast_2d(rx), 3.775e9, TraceConfig(),
                        None, None)  # fmt: skip


def test_surely_inside_a_box_corner_closed_form():
    """A unit cube's vertical edge at (1, 1): its interior is the quadrant x < 1, y < 1. Points
    in it by more than the margin are inside, points outside it or near the edge line are not."""
    sc = make_scene([("cube", box((0, 0, 0), (1, 1, 1)), "concrete")])
    w = sc.wedges
    edge = np.flatnonzero(
        (np.abs(w.direction[:, 2]) > 0.99) & np.all(np.abs(w.start[:, :2] - 1.0) < 1e-12, axis=1)
    )
    assert len(edge) == 1
    frame = diffraction._wedge_frame(_ctx(sc, [5, 5, 5], [6, 6, 6]))
    ang = np.radians([-89.0, -60.0, -10.0, 0.5, 45.0, 95.0, 135.0, 185.0, 269.0, 300.0])
    r = np.array([0.3] * len(ang))
    # azimuth about the edge from the +x direction: the interior is 180..270 degrees
    p = np.stack([1 + r * np.cos(ang), 1 + r * np.sin(ang), np.full(len(ang), 0.5)], axis=1)
    got = diffraction._surely_inside(frame, np.full(len(p), edge[0]), *p.T)
    expect = (np.degrees(ang) % 360 > 180) & (np.degrees(ang) % 360 < 270)
    np.testing.assert_array_equal(got, expect)
    # on the edge line (r below INSIDE_MIN_RHO_M): never
    q = np.array([[1 - 1e-4, 1 - 1e-4, 0.5]])
    assert not diffraction._surely_inside(frame, edge, *q.T).any()


def test_expand_over_others_equals_the_dense_numpy_expression():
    """The kernel keeps exactly the (triple, other end) pairs of the dense formula, in order."""
    rng = np.random.default_rng(4)
    n_w, n_o, n_q = 30, 17, 400
    w_idx = rng.integers(0, n_w, n_q)
    ts, rho_s = rng.uniform(-3, 8, n_q), rng.uniform(0, 5, n_q)
    rho_s[:10] = 0.0  # the image on the edge line
    t_lo = rng.uniform(-1, 4, n_q)
    t_hi = t_lo + rng.uniform(0, 3, n_q)
    td_w, rho_w = rng.uniform(-3, 8, (n_w, n_o)), rng.uniform(0, 5, (n_w, n_o))
    rho_w[0, :3] = 0.0
    open_w = rng.random((n_w, n_o)) > 0.2
    with np.errstate(divide="ignore", invalid="ignore"):
        td, rd = td_w[w_idx], rho_w[w_idx]
        t = ts[:, None] + (td - ts[:, None]) * rho_s[:, None] / (rho_s[:, None] + rd)
    q_ref, o_ref = np.nonzero((t >= t_lo[:, None]) & (t <= t_hi[:, None]) & open_w[w_idx])
    assert 0 < len(q_ref) < n_q * n_o
    q, o = kernels.expand_over_others(ts, rho_s, t_lo, t_hi, w_idx, td_w, rho_w, open_w, 0, n_q,
                                      True)  # fmt: skip
    np.testing.assert_array_equal(q, q_ref)
    np.testing.assert_array_equal(o, o_ref)
    # a sub-range gives absolute indices
    q2, _ = kernels.expand_over_others(ts, rho_s, t_lo, t_hi, w_idx, td_w, rho_w, open_w, 100,
                                       200, True)  # fmt: skip
    np.testing.assert_array_equal(q2, q_ref[(q_ref >= 100) & (q_ref < 200)])
    # no pruning: every pair
    q3, _ = kernels.expand_over_others(ts, rho_s, t_lo, t_hi, w_idx, td_w, rho_w, open_w, 0, n_q,
                                       False)  # fmt: skip
    assert len(q3) == n_q * n_o


def _floor_pane_boxes(rng):
    """A floor slab, a glass pane and three metal boxes at random places on the floor."""
    objs = [("floor", box((-1, -1, -0.3), (9, 9, 0.0)), "concrete"),
            ("pane", quad((4.0, 1.0, 0.0), (0.0, 3.0, 0.0), (0.0, 0.0, 2.0)), "glass")]  # fmt: skip
    for i in range(3):
        lo = np.append(rng.uniform(0.5, 6.5, 2), 0.0)
        objs.append((f"b{i}", box(lo, lo + np.append(rng.uniform(0.4, 1.5, 2), 1.5)), "metal"))
    return make_scene(objs)


@pytest.mark.parametrize("seed", [1, 2])
def test_facet_wedge_spans_hold_every_reachable_point_of_the_edge(seed):
    """Brute force: sample every edge densely; wherever the segment from an end's image in a
    facet to the edge point crosses the facet (the point on the end's side), the triple is
    returned and the point lies in its span."""
    rng = np.random.default_rng(seed)
    sc = _floor_pane_boxes(rng)
    ends = np.array([[0.3, 0.4, 2.5], [8.5, 7.7, 1.2]])
    ends = ends[sc.inside_solid(ends) < 0]
    ctx = _ctx(sc, ends, ends)
    e_idx, f_idx, w_idx, _, t_lo, t_hi = diffraction._facet_wedge_pairs(ctx, ends)
    spans = {(e, f, w): (lo, hi) for e, f, w, lo, hi in zip(e_idx, f_idx, w_idx, t_lo, t_hi)}
    fc, w = sc.facets, sc.wedges
    side = refl.reflecting_side(fc, ends)
    s = np.linspace(0.0, 1.0, 201)
    checked = 0
    for e in range(len(ends)):
        for f in np.flatnonzero(side[e] != 0):
            img = refl.mirror(ends[e][None], fc.normal[f][None], fc.offset[f][None])[0]
            pts = w.start[:, None] + s[None, :, None] * (w.end - w.start)[:, None]  # (W, S, 3)
            flat = pts.reshape(-1, 3)
            dist = refl.signed_distance(flat, np.broadcast_to(fc.normal[f], flat.shape),
                                        np.full(len(flat), fc.offset[f]))  # fmt: skip
            front = np.sign(dist) * side[e, f] > 0
            front &= np.abs(dist) > 1e-6
            u, p = refl.segment_plane_point(np.broadcast_to(img, flat.shape), flat,
                                            np.broadcast_to(fc.normal[f], flat.shape),
                                            np.full(len(flat), fc.offset[f]))  # fmt: skip
            ok = front & (u > 0) & (u < 1)
            ok[ok] = accel.points_in_facets(p[ok], np.full(int(ok.sum()), f), fc)
            frame = diffraction._wedge_frame(ctx)
            for k in np.flatnonzero(ok):
                wi, si = divmod(k, len(s))
                key = (e, f, wi)
                if diffraction._surely_inside(frame, np.array([wi]), *img[:, None]).any():
                    continue  # no valid diffraction from there (tested above)
                assert key in spans, key
                lo, hi = spans[key]
                t = s[si] * w.length[wi]
                assert lo <= t <= hi, (key, t, lo, hi)
                checked += 1
    assert checked > 500
    # the pruning prunes: far fewer triples than (end, facet, wedge) combinations on the side
    assert len(e_idx) < 0.5 * (side != 0).sum() * len(w)


def test_pair_buffers_grow_and_keep_every_end_in_order(monkeypatch):
    """Several ends' triples gathered in one set of buffers: with buffers of one row that double
    again and again, the triples are those of each end alone, in end order, and the kept ends
    (transmitters) give the same triples as the gathered ones."""
    rng = np.random.default_rng(5)
    sc = _floor_pane_boxes(rng)
    ends = np.column_stack([rng.uniform(0.0, 8.0, (12, 2)), rng.uniform(0.3, 3.0, 12)])
    ends = ends[sc.inside_solid(ends) < 0]
    ctx = _ctx(sc, ends, ends)
    whole = diffraction._facet_wedge_pairs(ctx, ends)
    assert len(whole[0]) > 200 and np.all(np.diff(whole[0]) >= 0)
    monkeypatch.setattr(diffraction, "PAIRS_PER_END", 1)
    grown = diffraction._facet_wedge_pairs(ctx, ends)
    for a, b in zip(whole, grown):
        np.testing.assert_array_equal(a, b)
    for e in range(len(ends)):
        alone = diffraction._facet_wedge_pairs(ctx, ends[e : e + 1])
        mine = whole[0] == e
        for a, b in zip(whole[1:], alone[1:]):
            np.testing.assert_array_equal(a[mine], b)
    sc.wedges.cache.pop("end_pairs", None)
    # (the kept ends' triples also lose those blocked whole: test_shadow.py; not here)
    monkeypatch.setattr(shadow, "triples_in_shadow",
                        lambda sc, o, e, f, *a: np.zeros(len(f), dtype=bool))  # fmt: skip
    kept = diffraction._facet_wedge_pairs(ctx, ends, keep=True)  # one end at a time, grown too
    for a, b in zip(whole, kept):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", [3, 4])
def test_reflection_edge_points_equal_the_numpy_tests_of_every_pair(seed):
    """RD candidates: the kernel's pairs, diffraction points and reflection points are those of
    the exact tests written out in numpy over every (triple, other end) pair (Keller's point by
    its closed form, the point on the end's side, the crossing on the segment and in the
    facet, a valid diffraction from the image to the receiver), in order; its pruning drops none
    of them."""
    rng = np.random.default_rng(seed)
    sc = _floor_pane_boxes(rng)
    tx = np.array([[0.3, 0.4, 2.5], [8.5, 7.7, 1.2]])
    rx = np.column_stack([rng.uniform(-0.5, 8.5, (40, 2)), rng.uniform(0.2, 3.0, 40)])
    tx, rx = tx[sc.inside_solid(tx) < 0], rx[sc.inside_solid(rx) < 0]
    ctx = _ctx(sc, tx, rx)
    fc, w = sc.facets, sc.wedges
    e_idx, f_idx, w_idx, img, t_lo, t_hi = diffraction._facet_wedge_pairs(ctx, tx)
    side = refl.reflecting_side(fc, tx)
    # the numpy reference over every pair
    q, o = np.divmod(np.arange(len(e_idx) * len(rx)), len(rx))
    src, dst, f, ww = img[q], rx[o], f_idx[q], w_idx[q]
    e = (w.end - w.start)[ww] / w.length[ww, None]
    a = w.start[ww]
    ts, td = np.einsum("ij,ij->i", src - a, e), np.einsum("ij,ij->i", dst - a, e)
    rho_s = np.linalg.norm(src - a - ts[:, None] * e, axis=1)
    rho_d = np.linalg.norm(dst - a - td[:, None] * e, axis=1)
    t = ts + (td - ts) * rho_s / (rho_s + rho_d)
    ok = (rho_s > 1e-9) & (rho_d > 1e-9) & (t >= -1e-9) & (t <= w.length[ww] + 1e-9)
    dpt = a + t[:, None] * e
    ok &= np.sign(refl.signed_distance(dpt, fc.normal[f], fc.offset[f])) == side[e_idx[q], f]
    u, p = refl.segment_plane_point(src, dpt, fc.normal[f], fc.offset[f])
    ok &= (u > 0) & (u < 1)
    ok[ok] = accel.points_in_facets(p[ok], f[ok], fc)
    wo = ww[ok]
    ok[ok] = utd.wedge_geometry(src[ok], dst[ok], dpt[ok], w.direction[wo], w.normal0[wo],
                                w.normal1[wo], w.face0_dir[wo]).valid  # fmt: skip
    frame = diffraction._wedge_frame(ctx).utd
    assert ok.sum() > 20

    td_w, rho_w = diffraction._along_and_off(rx.T[:, None, :], w.start.T[..., None],
                                             w.direction.T[..., None])  # fmt: skip
    open_w = ~diffraction._surely_inside(diffraction._wedge_frame(ctx),
                                         np.arange(len(w))[:, None], *rx.T[:, None, :])  # fmt: skip
    c = carray
    args = (c(e_idx, np.int64), c(f_idx, np.int64), c(w_idx, np.int64), c(img), c(t_lo),
            c(t_hi), c(rx), c(td_w), c(rho_w), c(open_w, bool), c(w.start), c(w.direction),
            c(w.end), c(fc.normal), c(fc.offset), c(side, np.int8),
            *accel.facet_test_arrays(fc), accel.BARY_TOL, accel.RECT_INSIDE_M, 1e-9,
            c(frame.edge_dir), c(frame.face0_tangent), c(frame.normal_0), c(frame.n), True)  # fmt: skip
    for prune in (False, True):
        kq, ko, pts, n_pairs = kernels.reflection_edge_points(0, len(e_idx), *args, prune)
        if prune:
            # the pruning drops pairs whose other end is surely inside the wedge (never a valid
            # diffraction, tested above) and pairs that fail the exact tests, no others
            assert n_pairs < len(q) / 3
            ok &= open_w[ww, o]
        else:
            assert n_pairs == len(q)
        np.testing.assert_array_equal(kq * len(rx) + ko, np.flatnonzero(ok))
        np.testing.assert_allclose(pts[:, :3], dpt[ok], rtol=0, atol=1e-12)
        np.testing.assert_allclose(pts[:, 3:], p[ok], rtol=0, atol=1e-12)
    # a sub-range of triples gives absolute indices
    kq2, _, _, _ = kernels.reflection_edge_points(5, 40, *args, True)
    np.testing.assert_array_equal(kq2, kq[(kq >= 5) & (kq < 40)])


def test_line_span_through_a_cube_closed_form():
    """Lines along x through the unit cube: the part at least ``inset`` inside is
    ``inset <= x <= 1 - inset``; a line beside it, parallel to its faces, has no span."""
    from raytrace.solver import penetration

    sc = make_scene([("cube", box((0, 0, 0), (1, 1, 1)), "concrete"),
                     ("sheet", quad((3, 0, 0), (1, 0, 0), (0, 1, 0)), "glass")])  # fmt: skip
    a = np.array([[-1.0, 0.5, 0.5], [-1.0, 0.5, 0.5], [-1.0, 2.0, 0.5], [2.0, 0.5, 0.5],
                  [0.0, 0.0, 0.0]])  # fmt: skip
    d = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0], [1.0, 0, 0]])
    o = np.array([0, 0, 0, 0, 1])
    for inset in (0.1, -0.05):
        convex, t_in, t_out, par = penetration._line_span(sc, o, a, d, inset)
        np.testing.assert_array_equal(convex, [True, True, True, True, False])
        np.testing.assert_allclose(t_in[:2], 1 + inset, rtol=0, atol=1e-12)
        np.testing.assert_allclose(t_out[:2], 2 - inset, rtol=0, atol=1e-12)
        assert par[2] and not par[:2].any()
        # reversed direction from the other side: the same stretch
        assert abs(t_in[3] - (1 + inset)) < 1e-12 and abs(t_out[3] - (2 - inset)) < 1e-12
    # a touch: the line along the cube's face (y = 1) never gets 1 mm inside
    assert penetration.touches(sc, np.array([0]), np.array([[-1.0, 1.0, 0.5]]),
                               np.array([[1.0, 0, 0]]), 1e-3)[0]  # fmt: skip


def test_opaque_blocks_drop_own_objects_and_touches_only():
    """A ray's opaque hit blocks unless it is the object under either end of the segment or a
    solid the segment only touches: segments past a cube's face plane, along it and through it,
    from and to vertices on it, against the rule written out here (line spans in numpy)."""
    from raytrace.solver import penetration

    sc = make_scene([("cube", box((0, 0, 0), (1, 1, 1)), "metal"),
                     ("slab", box((3, 0, 0), (4, 1, 1)), "metal")])  # fmt: skip
    rng = np.random.default_rng(11)
    m, k = 400, 1
    chain = rng.uniform(-1, 5, (m, k + 2, 3))
    chain[: m // 4, :, 1] = 1.0  # in the plane of the cubes' faces y = 1: touches
    chain[m // 4 : m // 2, 1] = [0.5, 1.0, 0.5]  # a vertex on the cube's top face
    vobj = np.where(rng.random((m, k)) < 0.5, 0, -1)
    tol = 1e-4
    for j in range(k + 1):
        live = np.flatnonzero(rng.random(m) < 0.9)
        a, d, length, org, d32, reach = kernels.segment_rays(chain, live, j, 1e-6)
        hit = sc.first_hit_among(np.ones(2, bool), org, d32, reach)
        got = kernels.opaque_blocks(hit, live, j, vobj, a, d, length,
                                    *penetration.convex_plane_arrays(sc),
                                    *penetration.flat_sheet_arrays(sc), tol)  # fmt: skip
        own = np.zeros(len(live), bool)
        if j > 0:
            own |= hit == vobj[live, j - 1]
        if j < k:
            own |= hit == vobj[live, j]
        convex, t_in, t_out, par = penetration._line_span(sc, np.maximum(hit, 0), a, d, tol)
        touch = convex & (par | (np.minimum(t_out, length) <= np.maximum(t_in, 0.0)))
        want = (hit >= 0) & ~own & ~touch
        np.testing.assert_array_equal(got, want)
        assert want.any() and (own & (hit >= 0)).any() and (touch & (hit >= 0)).any()


def test_edge_distance_against_the_triangle_closed_form():
    """The distance outside a right triangle's edges, and minus the distance to the nearest
    edge inside it; broadcasting over faces and points."""
    from raytrace.solver import penetration

    sc = make_scene([("sheet", quad((0, 0, 0), (2, 0, 0), (0, 2, 0)), "glass")])
    tri = sc.vertices[sc.faces[0]]
    rng = np.random.default_rng(7)
    p = np.column_stack([rng.uniform(-1, 3, (500, 2)), np.zeros(500)])
    got = penetration._edge_distance(sc, np.zeros(500, np.int64), p)
    # independent: signed distance to each edge line from the corners, outward normal in-plane
    ref = np.full(500, -np.inf)
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    for i in range(3):
        e = tri[(i + 1) % 3] - tri[i]
        out = np.cross(e, n)
        out /= np.linalg.norm(out)
        ref = np.maximum(ref, (p - tri[i]) @ out)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    both = penetration._edge_distance(sc, np.array([[0], [1]]), p[None, :3])  # (2, 3)
    assert both.shape == (2, 3)
    np.testing.assert_allclose(both[0], got[:3], rtol=0, atol=0)


def test_transmitter_side_work_kept_between_traces_changes_nothing():
    """The transmitters' second images and (facet, wedge) triples are kept on the scene for the
    next trace (a grid traced in chunks of receivers): traces after the first, with other
    receivers, other transmitters or a restriction to some objects, give exactly the paths of
    a fresh copy of the scene."""
    import pickle

    from test_diffraction_paths import _cluttered_scene

    from raytrace.solver.tracer import trace

    sc, tx, rx = _cluttered_scene(5)
    cfg = TraceConfig(max_reflections=2, max_penetrations=1, max_diffractions=1,
                      max_interactions=3)  # fmt: skip
    fresh = lambda: pickle.loads(pickle.dumps(sc))  # noqa: E731  (a scene pickles without caches)
    calls = [dict(tx=tx, rx=rx[:4]), dict(tx=tx, rx=rx[4:]), dict(tx=tx[::-1], rx=rx),
             dict(tx=tx[1:], rx=rx, involving=[2, 5]), dict(tx=tx, rx=rx[::2])]  # fmt: skip
    for kw in calls:
        # one thread: the stages in a fixed order (RD before RDR, which share transmitters)
        kept = trace(sc, frequency_hz=3.775e9, config=cfg, threads=1, **kw)
        again = trace(fresh(), frequency_hz=3.775e9, config=cfg, threads=1, **kw)
        assert kept.n_paths == again.n_paths > 0
        for name in ("link", "interaction", "elements", "delay_s", "gain", "points"):
            np.testing.assert_array_equal(getattr(kept, name), getattr(again, name))
    assert sc.wedges.cache.get("end_pairs") and sc.facets.cache.get("second_images")
    assert not fresh().wedges.cache.get("end_pairs")


def test_read_only_positions_are_traced():
    """The kernels take writable C arrays; positions a caller made read-only reach them through
    copies (core.jit.carray), not as a signature error."""
    from test_diffraction_paths import _cluttered_scene

    from raytrace.solver.tracer import trace

    sc, tx, rx = _cluttered_scene(11)
    cfg = TraceConfig(max_reflections=2, max_penetrations=1, max_diffractions=1)
    ref = trace(sc, tx, rx, 3.775e9, cfg, threads=1)
    tx_ro, rx_ro = tx.copy(), rx.copy()
    tx_ro.setflags(write=False)
    rx_ro.setflags(write=False)
    got = trace(sc, tx_ro, rx_ro, 3.775e9, cfg, threads=1)
    np.testing.assert_array_equal(got.gain, ref.gain)
    frame = diffraction._wedge_frame(_ctx(sc, tx, rx))
    w = np.zeros(len(rx), np.int64)
    w.setflags(write=False)
    assert diffraction._surely_inside(frame, w, *rx_ro.T).shape == (len(rx),)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _te_tm(e, k_in, k_out, normal, c_te, c_tm):
    """Reference: the field after an interaction with TE/TM coefficients, in the basis ``s = k_in
    x n`` (TE) and ``p = s x k`` on either side (TM): ``c_te (e . s) s + c_tm (e . p_in) p_out``
    (rays not at normal incidence)."""
    s = _unit(np.cross(k_in, normal))
    p_in, p_out = np.cross(s, k_in), np.cross(s, k_out)
    es, ep = (e * s).sum(axis=1), (e * p_in).sum(axis=1)
    return (c_te * es)[:, None] * s + (c_tm * ep)[:, None] * p_out


def vertical_pol(direction):
    """Reference: a vertical antenna's field for rays along ``direction`` (n, 3), z made
    perpendicular to the ray (x for a vertical ray), unit."""
    v = np.array([0.0, 0.0, 1.0]) - direction[:, 2:3] * direction
    vertical = np.linalg.norm(v, axis=1) < 1e-9
    v[vertical] = np.array([1.0, 0.0, 0.0]) - direction[vertical, 0:1] * direction[vertical]
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_path_gains_apply_the_numpy_interactions_in_order():
    """Two segments with a penetration each and a reflection (off a solid's face or an open
    sheet) or a diffraction between them: the compiled loop gives what the ITU-R P.2040
    coefficients of ``materials``, the TE/TM basis (written out here) and
    ``utd.diffracted_field`` give applied one after the other, to rounding; the delay is the
    unfolded length over c plus the slabs' group delays."""
    from raytrace.core.constants import C0
    from raytrace.physics import materials, utd
    from raytrace.solver.paths import DIFFRACTION, REFLECTION

    rng = np.random.default_rng(3)
    m, f = 400, 3.775e9
    k0, wavelength = 2 * np.pi * f / C0, C0 / f
    pts = rng.uniform(-5, 5, (m, 3, 3))
    dirs = _unit(pts[:, 1:] - pts[:, :-1])  # (m, 2, 3)
    seg_len = np.linalg.norm(pts[:, 1:] - pts[:, :-1], axis=2)
    total = seg_len.sum(axis=1)
    # three materials: a lossy dielectric, a low-loss one and a metal-like one
    eta = np.array([5.3 - 0.3j, 2.5 - 0.01j, 1.0 - 1e6j])
    slope = np.array([0.1 - 0.05j, 0.0j, -0.2 + 0.4j])
    thickness = np.array([0.2, 0.03, 0.002])
    obj_material = np.array([0, 1, 2, 0, 1])
    pen_obj = rng.integers(0, 2, (m, 2, 1)) * 3 + rng.integers(0, 2, (m, 2, 1))  # objects 0, 1, 3, 4
    pen_th = rng.uniform(0.01, 0.3, (m, 2, 1))
    pen_n = _unit(rng.normal(size=(m, 2, 1, 3)))
    # one facet per path: its normal, material, and whether it is an open sheet
    f_normal = _unit(rng.normal(size=(m, 3)))
    f_material = rng.integers(0, 3, m)
    f_sheet = rng.uniform(size=m) < 0.5
    # a wedge per path: edge through the middle vertex, normals perpendicular to it
    edge = _unit(rng.normal(size=(m, 3)))
    n0 = _unit(np.cross(edge, rng.normal(size=(m, 3))))
    nn = _unit(np.cross(edge, rng.normal(size=(m, 3))))
    geo = utd.wedge_geometry(pts[:, 0], pts[:, 2], pts[:, 1], edge, n0, nn)
    d_mat_all, spread_all = utd.diffraction_matrix(geo, f)
    e_start, e_rx = vertical_pol(dirs[:, 0]), vertical_pol(dirs[:, 1])
    assert 0.2 < geo.valid.mean() < 1.0  # some diffractions are not valid (ends in the wedge)

    def pen(e, j):
        mat = obj_material[pen_obj[:, j, 0]]
        cos = np.abs((pen_n[:, j, 0] * dirs[:, j]).sum(axis=1))
        _, _, t_te, t_tm = materials.slab(eta[mat], cos, pen_th[:, j, 0], f)
        delay = materials.slab_group_delay(eta[mat], cos, pen_th[:, j, 0], slope[mat])
        return _te_tm(e, dirs[:, j], dirs[:, j], pen_n[:, j, 0], t_te, t_tm), delay

    amp_scale = np.exp(1j * rng.uniform(0, 2 * np.pi, m)) * rng.uniform(0.5, 2, m)
    basis = np.stack([geo.beta_hat_in, geo.phi_hat_in, geo.beta_hat_out, geo.phi_hat_out], 1)
    for kind in (REFLECTION, DIFFRACTION):
        kinds = np.full((m, 1), kind, np.int8)
        # each diffraction's row in the operator arrays: reversed, so that a wrong row shows
        slot = np.full((m, 1), -1) if kind == REFLECTION else np.arange(m - 1, -1, -1).reshape(m, 1)
        d_rows = np.arange(m)[::-1]
        d_mat, basis_d = np.ascontiguousarray(d_mat_all[d_rows]), np.ascontiguousarray(basis[d_rows])
        spreading, valid = np.ascontiguousarray(spread_all[d_rows]), geo.valid[d_rows].copy()
        args = (np.ascontiguousarray(pts), kinds, np.arange(m).reshape(m, 1),
                np.ones((m, 2), np.int64), pen_n, pen_obj, pen_th, obj_material, eta, slope,
                thickness, f_normal, f_material, f_sheet, slot, d_mat, basis_d, spreading, valid,
                amp_scale, f, k0, wavelength)  # fmt: skip
        codes = (int(REFLECTION), int(DIFFRACTION))
        gain, delay = kernels.path_gains(*args, True, *codes)  # slab_delay on
        e, tau0 = pen(e_start.astype(complex), 0)
        if kind == REFLECTION:
            cos = np.abs((f_normal * dirs[:, 0]).sum(axis=1))
            r_te, r_tm, _, _ = materials.fresnel(eta[f_material], cos)
            s_te, s_tm, _, _ = materials.slab(eta[f_material], cos, thickness[f_material], f)
            r_te, r_tm = np.where(f_sheet, s_te, r_te), np.where(f_sheet, s_tm, r_tm)
            e = _te_tm(e, dirs[:, 0], dirs[:, 1], f_normal, r_te, r_tm)
            spread = wavelength / (4 * np.pi * total)
        else:
            e = utd.diffracted_field(geo, e, f, phase=False).field
            spread = 1.0
        e, tau1 = pen(e, 1)
        want = spread * amp_scale * np.exp(-1j * k0 * total) * np.einsum("ij,ij->i", e, e_rx)
        np.testing.assert_allclose(gain, want, rtol=1e-12, atol=1e-14 * np.abs(want).max())
        np.testing.assert_allclose(delay, total / C0 + tau0 + tau1, rtol=1e-15, atol=0)
        assert np.all(delay > total / C0)  # the slabs delay the path
        if kind == DIFFRACTION:
            assert np.all(gain[~geo.valid] == 0) and np.all(gain[geo.valid] != 0)
        else:
            assert 0.3 < f_sheet.mean() < 0.7 and np.all(gain != 0)
        # without slab_delay: free-space delays
        np.testing.assert_array_equal(kernels.path_gains(*args, False, *codes)[1], total / C0)


def test_interaction_sequences_put_each_segments_penetrations_before_its_vertex():
    """Random counts of penetrations per segment: the sequences of the kept paths are, per path,
    the penetrations of segment 0, vertex 0, the penetrations of segment 1, ..., padded (written
    out in Python)."""
    rng = np.random.default_rng(7)
    m, k, n_pen, depth = 50, 2, 2, 4
    count = rng.integers(0, n_pen + 1, (m, k + 1))
    count[count.sum(axis=1) > depth - k] = 0
    pen_obj = rng.integers(0, 99, (m, k + 1, n_pen))
    pen_pts = rng.normal(size=(m, k + 1, n_pen, 3))
    kinds = rng.choice(np.array([1, 3], np.int8), (m, k))
    verts = rng.normal(size=(m, k, 3))
    vobj, elem = rng.integers(0, 99, (m, k)), rng.integers(0, 99, (m, k))
    rows = np.flatnonzero(rng.random(m) < 0.8)  # the kept paths
    inter, pts, objs, elems = kernels.interaction_sequences(count, pen_obj, pen_pts, kinds, verts,
                                                            vobj, elem, depth, 2, rows)  # fmt: skip
    assert len(inter) == len(rows) < m
    for i, r in enumerate(rows):
        seq = []
        for j in range(k + 1):
            seq += [(2, tuple(pen_pts[r, j, s]), pen_obj[r, j, s], -1) for s in range(count[r, j])]
            if j < k:
                seq.append((kinds[r, j], tuple(verts[r, j]), vobj[r, j], elem[r, j]))
        n = len(seq)
        assert inter[i, :n].tolist() == [x[0] for x in seq] and not inter[i, n:].any()
        np.testing.assert_array_equal(pts[i, :n], [x[1] for x in seq])
        assert np.isnan(pts[i, n:]).all()
        assert objs[i, :n].tolist() == [x[2] for x in seq] and (objs[i, n:] == -1).all()
        assert elems[i, :n].tolist() == [x[3] for x in seq] and (elems[i, n:] == -1).all()


def test_entry_points_are_a_plus_t_d_and_nan_in_empty_slots():
    """The crossings' entry points: ``a + t d`` to the bit of the numpy expression, NaN where a
    slot has no penetration (``t`` infinite)."""
    rng = np.random.default_rng(2)
    n = 500
    a, d = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    dist = rng.uniform(0, 9, (n, 2))
    dist[rng.random((n, 2)) < 0.3] = np.inf
    want = a[:, None, :] + np.where(np.isfinite(dist), dist, np.nan)[:, :, None] * d[:, None, :]
    got = kernels.entry_points(a, d, dist)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(got[np.isinf(dist)]).all() and np.isfinite(got[np.isfinite(dist)]).all()


def test_mixed_candidates_are_the_stage_arrays_built_in_numpy():
    """RD and DR candidates from reflection_edge_points' output: the compiled pass gives the
    arrays ``evaluate.candidates`` builds from the stacked vertices (written out here), to the
    bit."""
    from types import SimpleNamespace

    from raytrace.solver.evaluate import candidates
    from raytrace.solver.paths import DIFFRACTION, REFLECTION

    rng = np.random.default_rng(11)
    n_t, n_r, n_f, n_w, n_q, m = 3, 7, 40, 30, 50, 300
    tx, rx = rng.normal(size=(n_t, 3)), rng.normal(size=(n_r, 3))
    f_obj, w_obj = rng.integers(0, 9, n_f), rng.integers(0, 9, n_w)
    f_idx, w_idx = rng.integers(0, n_f, n_q), rng.integers(0, n_w, n_q)
    q = np.sort(rng.integers(0, n_q, m))
    pts = rng.normal(size=(m, 6))
    ctx = SimpleNamespace(tx=tx, rx=rx, scene=SimpleNamespace(facets=SimpleNamespace(object=f_obj)),
                          wedge_object=lambda i: w_obj[np.clip(i, 0, n_w - 1)])  # fmt: skip
    for before in (True, False):
        e_idx = rng.integers(0, n_t if before else n_r, n_q)
        o_idx = rng.integers(0, n_r if before else n_t, m)
        got = kernels.mixed_candidates(q, o_idx, pts, e_idx, f_idx, w_idx, tx, rx, f_obj, w_obj,
                                       before, REFLECTION, DIFFRACTION)  # fmt: skip
        if before:  # tx -> reflection -> diffraction -> rx
            t_idx, r_idx = e_idx[q], o_idx
            verts = np.stack([pts[:, 3:], pts[:, :3]], axis=1)
            elem = np.stack([f_idx[q], w_idx[q]], axis=1)
            kinds = np.array([[REFLECTION, DIFFRACTION]], np.int8)
        else:  # tx -> diffraction -> reflection -> rx
            t_idx, r_idx = o_idx, e_idx[q]
            verts = pts.reshape(-1, 2, 3)
            elem = np.stack([w_idx[q], f_idx[q]], axis=1)
            kinds = np.array([[DIFFRACTION, REFLECTION]], np.int8)
        want = candidates(ctx, t_idx, r_idx, verts, elem, np.repeat(kinds, m, axis=0))
        for name, g in zip(("t_idx", "r_idx", "verts", "elem", "kinds", "chain", "vobj"), got):
            w = getattr(want, name)
            assert g.shape == w.shape and np.array_equal(g, w), (before, name)


def test_second_order_candidates_exact_tests_are_the_numpy_ones():
    """Double reflections in the hall from one transmitter to its points: the pairs the compiled
    exact tests keep, and their reflection points, are those of the numpy tests (written out
    here: the segment receiver -> second image through the second facet, from there to the first
    image through the first facet, the second point on the transmitter's side of the first
    facet) applied to the pairs that pass the receiver tests, to the bit."""
    from raytrace import load_scene
    from raytrace.scene.metadata import SceneMetadata
    from raytrace.solver import specular
    from raytrace.solver.context import TraceContext

    scene = load_scene("hall")
    inp = SceneMetadata.from_scene(scene, require=True)
    ctx = TraceContext(scene, inp.bs_xyz, inp.point_xyz, 3.775e9, TraceConfig())
    fc = scene.facets
    side_t, img1, i1, f1, f2, img2, _, receiver_args, exact_args = specular._second_images(
        ctx, 1, np.zeros(len(fc), dtype=bool)
    )
    side_rx = carray(refl.reflecting_side(fc, ctx.rx), np.int8)
    centre = 0.5 * (ctx.rx.min(axis=0) + ctx.rx.max(axis=0))
    radius = float(np.linalg.norm(ctx.rx - centre, axis=1).max()) * 1.01
    tests = (*accel.facet_test_arrays(fc), accel.BARY_TOL, accel.RECT_INSIDE_M)

    def run(exact):
        return kernels.second_order_candidates(
            0, len(f1), *receiver_args[:2], side_rx, *receiver_args[2:], carray(ctx.rx),
            *centre, radius, True, *exact_args[:4], carray(fc.normal), carray(fc.offset),
            exact_args[4], *tests, exact,
        )  # fmt: skip

    q, r, _, n_pairs = run(False)
    assert n_pairs == len(q) > 1000
    u2, p2 = refl.segment_plane_point(ctx.rx[r], img2[q], fc.normal[f2[q]], fc.offset[f2[q]])
    ok = (u2 > 0) & (u2 < 1)
    ok[ok] = accel.points_in_facets(p2[ok], f2[q][ok], fc)
    u1, p1 = refl.segment_plane_point(p2, img1[i1[q]], fc.normal[f1[q]], fc.offset[f1[q]])
    ok &= (u1 > 0) & (u1 < 1)
    ok[ok] = accel.points_in_facets(p1[ok], f1[q][ok], fc)
    s2 = refl.signed_distance(p2, fc.normal[f1[q]], fc.offset[f1[q]])
    ok &= np.sign(s2) == side_t[f1[q]]
    got_q, got_r, pts, got_pairs = run(True)
    assert got_pairs == n_pairs and 0 < len(got_q) < 0.5 * len(q)  # the tests do reject
    np.testing.assert_array_equal(got_q, q[ok])
    np.testing.assert_array_equal(got_r, r[ok])
    np.testing.assert_array_equal(pts, np.concatenate([p1[ok], p2[ok]], axis=1))


def test_second_pairs_too_many_to_keep_are_made_for_the_receivers_only(monkeypatch):
    """A transmitter's double-reflection pairs too many to keep (a million-triangle hall's) are
    made for the trace's receivers only: the pairs that reach none of them are dropped before
    they are sorted, mirrored and given beams. The paths are those of the pairs made for any
    receivers, bit for bit, with the same candidate count; nothing receiver-specific is kept;
    and the filter does drop pairs (on the hall with its trees, and a room with boxes and a
    noisy metal sphere)."""
    import pickle

    from conftest import shoebox_sheets
    from test_candidates_oracle import _noisy_sphere

    from raytrace import load_scene
    from raytrace.core.kept import nbytes
    from raytrace.scene.metadata import SceneMetadata
    from raytrace.solver import specular
    from raytrace.solver.paths import Paths
    from raytrace.solver.tracer import trace

    hall = load_scene("hall")
    inp = SceneMetadata.from_scene(hall, require=True)
    room = make_scene([*shoebox_sheets((14.0, 12.0, 5.0)),
                       ("crate", box((2.0, 2.0, 0.0), (3.5, 4.0, 2.0)), "metal"),
                       ("shelf", box((9.0, 7.0, 0.0), (12.0, 7.6, 3.0)), "wood"),
                       ("blob", _noisy_sphere((6.0, 8.0, 1.4), 0.6, 2, 0.02, 3), "metal")])  # fmt: skip
    room_tx = np.array([[1.0, 1.0, 4.0], [13.0, 11.0, 3.0]])
    room_rx = np.random.default_rng(3).uniform((0.5, 0.5, 0.5), (13.5, 11.5, 2.5), (10, 3))
    room_rx = room_rx[room.inside_solid(room_rx) < 0]
    monkeypatch.setattr(kernels, "TREES", True)
    cfg = TraceConfig(max_reflections=2, max_penetrations=1, max_diffractions=0)
    for scene, t, r in ((hall, inp.bs_xyz, inp.point_xyz[::3]), (room, room_tx, room_rx)):
        fresh = lambda scene=scene: pickle.loads(pickle.dumps(scene))  # noqa: E731  (no caches)
        monkeypatch.setattr(specular, "SECOND_IMAGES_KEPT_BYTES", 1 << 30)
        ctx = TraceContext(fresh(), t, r, 3.775e9, cfg)
        in_shadow = shadow.shadows_of(ctx, ctx.tx)[0][0]
        side_rx = carray(shadow.reflecting_sides(ctx, ctx.rx), np.int8)
        every = specular._second_images(ctx, 0, in_shadow)
        assert nbytes(every) == specular._kept_bytes(len(every[2]), len(every[1]),
                                                     len(ctx.scene.facets))  # fmt: skip
        big_st, small_st = {}, {}
        big = trace(fresh(), t, r, 3.775e9, cfg, threads=1, stats=big_st)
        monkeypatch.setattr(specular, "SECOND_IMAGES_KEPT_BYTES", 0)
        ctx.scene.facets.cache.clear()
        own = specular._second_images(ctx, 0, in_shadow, (side_rx, carray(ctx.rx)))
        assert 0 < len(own[4]) < len(every[4]) // 2
        assert not ctx.scene.facets.cache.get("second_images")
        small = trace(fresh(), t, r, 3.775e9, cfg, threads=1, stats=small_st)
        assert small.n_paths == big.n_paths > 0 and (small.n_reflections == 2).any()
        for name in Paths.PER_PATH:
            np.testing.assert_array_equal(getattr(small, name), getattr(big, name))
        assert small_st["candidates_r2"] == big_st["candidates_r2"] > 0
