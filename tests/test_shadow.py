"""solver.shadow: facets and edges an end point sees only through an opaque convex solid."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box, make_scene
from conftest import box as box_mesh

from raytrace import TraceConfig, trace
from raytrace.solver.context import opaque_objects
from raytrace.solver.shadow import SHADOW_DEPTH_M, shadowed

F_C = 3.775e9
#: The box that casts the shadow, and the walls behind it.
BOX = ((2.0, 3.0, 0.0), (3.0, 7.0, 3.0))


def _scene(box_material: str = "metal"):
    """A floor, a box (``box_material``) at x 2..3, y 3..7, z 0..3, and behind it (seen from x < 2)
    a small wall ``hidden`` (y 4.5..5.5, z 1..2) and a wide wall ``wide`` (y -10..20)."""
    return make_scene(
        [
            ("floor", box((-2.0, -2.0, -0.3), (12.0, 12.0, 0.0)), "concrete"),
            ("box", box(*BOX), box_material),
            ("hidden", box((6.0, 4.5, 1.0), (6.2, 5.5, 2.0)), "concrete"),
            ("wide", box((9.0, -10.0, 0.0), (9.2, 20.0, 6.0)), "concrete"),
        ]
    )


def _facet(sc, name: str, normal) -> int:
    """The facet of object ``name`` with outward normal ``normal``."""
    o = [ob.name for ob in sc.objects].index(name)
    k = np.flatnonzero((sc.facets.object == o) & (sc.facets.normal @ np.asarray(normal, float) > 0.99))
    assert len(k) == 1
    return int(k[0])


def _edges_of(sc, name: str) -> np.ndarray:
    o = [ob.name for ob in sc.objects].index(name)
    return np.flatnonzero(sc.wedges.object == o)


def test_a_metal_box_hides_the_wall_behind_it_and_only_that():
    sc = _scene()
    ends = np.array([[0.0, 5.0, 1.5],  # hidden wall fully behind the box
                     [0.0, 0.5, 1.5],  # seen past the box's side
                     [0.0, 5.0, 5.5]])  # seen over the box's top  # fmt: skip
    facets, wedges = shadowed(sc, opaque_objects(sc, F_C), ends)
    front = _facet(sc, "hidden", (-1, 0, 0))
    assert facets[:, front].tolist() == [True, False, False]
    # every edge of the hidden wall is behind the box from the first end (the far face's too)
    assert wedges[0, _edges_of(sc, "hidden")].all()
    assert not wedges[1:, _edges_of(sc, "hidden")].any()
    # the wide wall is only partly hidden; the box's own faces and edges never are
    assert not facets[:, _facet(sc, "wide", (-1, 0, 0))].any()
    own = sc.facets.object == [ob.name for ob in sc.objects].index("box")
    assert not facets[:, own].any() and not wedges[:, _edges_of(sc, "box")].any()


def test_a_facet_in_shadow_reflects_nothing_of_that_end():
    """reflecting_sides: the facets' reflecting sides of a trace's ends, 0 where the end sees the
    facet only through the metal box, as reflecting_side elsewhere."""
    from raytrace.solver.context import TraceContext
    from raytrace.solver.reflection import reflecting_side
    from raytrace.solver.shadow import reflecting_sides

    sc = _scene()
    tx = np.array([[0.0, 5.0, 1.5], [0.0, 0.5, 1.5]])
    rx = np.array([[1.0, 5.0, 1.5]])
    ctx = TraceContext(sc, tx, rx, F_C, TraceConfig())
    got, plain = reflecting_sides(ctx, ctx.tx), reflecting_side(sc.facets, tx)
    front = _facet(sc, "hidden", (-1, 0, 0))
    assert plain[:, front].tolist() == [1, 1] and got[:, front].tolist() == [0, 1]
    rest = ~shadowed(sc, ctx.opaque, tx)[0]
    np.testing.assert_array_equal(got[rest], plain[rest])
    assert (got[~rest] == 0).all() and (plain[~rest] != 0).any()


def test_only_opaque_solids_cast_shadows():
    sc = _scene("concrete")
    facets, wedges = shadowed(sc, opaque_objects(sc, F_C), np.array([[0.0, 5.0, 1.5]]))
    assert not facets.any() and not wedges.any()
    facets, _ = shadowed(sc, np.zeros(len(sc.objects), bool), np.array([[0.0, 5.0, 1.5]]))
    assert not facets.any()


@pytest.mark.parametrize("inside_mm, hidden", [(0.5, False), (2.0, True)])
def test_a_corner_must_be_behind_the_solid_by_the_depth(inside_mm, hidden):
    """An end level with the hidden wall's top (z 2) and the box's top lowered to just above the
    line to it: the wall is in shadow only when that line runs at least SHADOW_DEPTH_M (1 mm)
    inside the box."""
    assert SHADOW_DEPTH_M == pytest.approx(1e-3)
    top = 2.0 + inside_mm * 1e-3
    sc = make_scene([("box", box((2.0, 3.0, 0.0), (3.0, 7.0, top)), "metal"),
                     ("hidden", box((6.0, 4.5, 1.0), (6.2, 5.5, 2.0)), "concrete")])  # fmt: skip
    facets, _ = shadowed(sc, opaque_objects(sc, F_C), np.array([[0.0, 5.0, 2.0]]))
    assert facets[0, _facet(sc, "hidden", (-1, 0, 0))] == hidden


def test_every_point_of_a_shadowed_facet_is_behind_the_box_by_the_depth():
    """Random ends; for each facet or edge in shadow, random points on it (and 1 um off it): the
    segment from the end passes through the box shrunk by the depth (slab method, closed form)."""
    sc = _scene()
    rng = np.random.default_rng(3)
    ends = np.column_stack([rng.uniform(-1.5, 1.8, 40), rng.uniform(0, 10, 40),
                            rng.uniform(0.2, 3.5, 40)])  # fmt: skip
    facets, wedges = shadowed(sc, opaque_objects(sc, F_C), ends)
    assert facets.sum() > 20 and wedges.sum() > 20
    lo, hi = np.array(BOX[0]) + SHADOW_DEPTH_M, np.array(BOX[1]) - SHADOW_DEPTH_M
    fc, w = sc.facets, sc.wedges
    for e, k in zip(*np.nonzero(facets)):
        tri = fc.triangles[fc.tri_start[k] + rng.integers(0, fc.tri_count[k], 50)]
        bary = rng.dirichlet(np.ones(3), 50)
        p = np.einsum("nc,ncd->nd", bary, tri) + rng.normal(size=(50, 3)) * 1e-6
        _assert_through(ends[e], p, lo, hi)
    for e, j in zip(*np.nonzero(wedges)):
        t = rng.uniform(-1e-6, 1 + 1e-6, 50)[:, None]
        _assert_through(ends[e], w.start[j] + t * (w.end[j] - w.start[j]), lo, hi)


def _assert_through(end, p, lo, hi):
    """Each segment end -> p meets the box [lo, hi] (slab method)."""
    d = p - end
    with np.errstate(divide="ignore"):
        t1, t2 = (lo - end) / d, (hi - end) / d
    t_in = np.max(np.minimum(t1, t2), axis=1)
    t_out = np.min(np.maximum(t1, t2), axis=1)
    assert np.all(np.maximum(t_in, 0) < np.minimum(t_out, 1)), (end, p[t_in >= t_out])


def _trace_without_shadows(monkeypatch, sc, tx, rx, cfg):
    """The trace with every shadow pruning off (and the scene's kept triples dropped), and its
    counters."""
    import raytrace.solver.shadow as shadow_mod

    def nothing(ctx, ends):
        return (np.zeros((len(ends), len(ctx.scene.facets)), bool),
                np.zeros((len(ends), len(ctx.scene.wedges)), bool))  # fmt: skip

    # the stages ask the shadow module for every shadow (shadow.shadows_of, reflecting_sides,
    # triples_in_shadow): its two entry points off switch them all off
    monkeypatch.setattr(shadow_mod, "shadows_of", nothing)
    monkeypatch.setattr(shadow_mod, "triples_in_shadow",
                        lambda sc, o, e, f, *a: np.zeros(len(f), dtype=bool))  # fmt: skip
    sc.wedges.cache.clear()  # the transmitters' kept triples
    stats: dict = {}
    return trace(sc, tx, rx, F_C, cfg, threads=1, stats=stats), stats


@pytest.mark.parametrize("seed", [5, 11])
def test_shadows_lose_no_path(monkeypatch, seed):
    """Tracing with the shadows' pruning and without it gives the same paths, on boxes of mixed
    materials (metal among them), while the pruning removes candidates."""
    from test_diffraction_paths import _cluttered_scene, _same_paths

    sc, tx, rx = _cluttered_scene(seed)
    cfg = TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=3)
    with_shadows = trace(sc, tx, rx, F_C, cfg, threads=1, stats=(on := {}))
    without, off = _trace_without_shadows(monkeypatch, sc, tx, rx, cfg)
    _same_paths(with_shadows, without)
    for kind in ("candidates_rd", "candidates_dr", "candidates_r1"):
        assert on[kind] < off[kind], kind


def test_the_transmitters_shadows_are_kept_per_position_and_opaque_set(monkeypatch):
    """A grid is traced in chunks against the same transmitters: their shadows are computed once
    per scene, position and opaque set; the receivers' every trace."""
    import raytrace.solver.shadow as shadow_mod

    sc = _scene()
    calls = []
    real = shadow_mod.shadowed
    monkeypatch.setattr(shadow_mod, "shadowed", lambda s, o, e: calls.append(len(e)) or real(s, o, e))
    tx = np.array([[0.0, 5.0, 1.5], [0.0, 0.5, 1.5]])
    rx = np.array([[7.0, 5.0, 1.5], [8.0, 2.0, 1.0]])
    cfg = TraceConfig()
    first = trace(sc, tx, rx, F_C, cfg, threads=1)
    assert sorted(calls) == [2, 2]  # transmitters and receivers
    calls.clear()
    again = trace(sc, tx, rx[::-1], F_C, cfg, threads=1)
    assert calls == [2]  # the receivers only
    assert again.n_paths == first.n_paths
    calls.clear()
    none = np.zeros(len(sc.objects), dtype=bool)
    trace(sc, tx, rx, F_C, cfg, threads=1, opaque=none)
    assert sorted(calls) == [2, 2]  # another opaque set: computed anew


def test_ends_in_blocks_give_the_same_shadows(monkeypatch):
    import raytrace.solver.shadow as shadow_mod

    sc = _scene()
    rng = np.random.default_rng(8)
    ends = np.column_stack([rng.uniform(-1.5, 1.8, 30), rng.uniform(0, 10, 30),
                            rng.uniform(0.2, 3.5, 30)])  # fmt: skip
    whole = shadowed(sc, opaque_objects(sc, F_C), ends)
    monkeypatch.setattr(shadow_mod, "ENDS_PER_QUERY", 4)
    blocks = shadowed(sc, opaque_objects(sc, F_C), ends)
    assert whole[0].any() and all(np.array_equal(a, b) for a, b in zip(whole, blocks))


def test_shadows_lose_no_path_in_a_dense_metal_factory(monkeypatch):
    """A synthetic 3GPP InF-DH hall with metal clutter (many shadows): the same paths with the
    shadows' pruning and without it, and far fewer mixed candidates with it."""
    from test_diffraction_paths import _same_paths

    from raytrace.halls.inf import generate_hall, scene_from_spec, split_spec
    from raytrace.scene.metadata import SceneMetadata

    spec, _ = split_spec(generate_hall("InF-DH", size=(40, 30, 8), seed=3, los_notes=False,
                                       materials={"metal": 0.7, "concrete": 0.3}))  # fmt: skip
    sc = scene_from_spec(spec)
    inp = SceneMetadata.from_scene(sc, require=True)
    tx, rx = inp.bs_xyz, inp.point_xyz[:12]
    with_shadows = trace(sc, tx, rx, F_C, TraceConfig(), threads=1, stats=(on := {}))
    without, off = _trace_without_shadows(monkeypatch, sc, tx, rx, TraceConfig())
    _same_paths(with_shadows, without)
    assert on["candidates_rd"] < 0.5 * off["candidates_rd"]


def _rd_scene(box, material="metal"):
    """A wall (facet at x = 10 facing -x), a pillar whose vertical edge stands at (5, 5) and a box
    ``(lo, hi)`` of ``material`` between them."""
    return make_scene([
        ("floor", box_mesh((-1.0, -1.0, -0.3), (12.0, 12.0, 0.0)), "concrete"),
        ("wall", box_mesh((10.0, 0.0, 0.0), (10.2, 10.0, 5.0)), "concrete"),
        ("pillar", box_mesh((4.6, 4.6, 0.0), (5.0, 5.0, 5.0)), "concrete"),
        ("box", box_mesh(*box), material),
    ])  # fmt: skip


def _rd_triple(sc, tx):
    """The triple (wall facet, the pillar's edge at (5, 5)) of transmitter ``tx``: facet, edge,
    the image, and the whole edge as the span."""
    f = _facet(sc, "wall", (-1, 0, 0))
    w = sc.wedges
    mid = 0.5 * (w.start + w.end)
    j = int(np.flatnonzero((np.abs(mid[:, 0] - 5) < 1e-9) & (np.abs(mid[:, 1] - 5) < 1e-9)
                           & (np.abs(w.direction[:, 2]) > 0.99))[0])  # fmt: skip
    img = tx - 2 * (tx @ sc.facets.normal[f] - sc.facets.offset[f]) * sc.facets.normal[f]
    length = np.linalg.norm(w.end[j] - w.start[j])
    return np.array([f]), np.array([j]), img[None, :], np.array([0.0]), np.array([length])


@pytest.mark.parametrize("box, material, blocked", [
    (((7.0, 5.3, -0.2), (8.0, 6.2, 6.0)), "metal", True),      # every reflection -> edge leg
    (((7.0, 5.3, -0.2), (8.0, 6.2, 6.0)), "concrete", False),  # not opaque
    (((7.0, 5.3, -0.2), (8.0, 6.2, 2.0)), "metal", False),     # the upper legs pass over it
    (((5.5, 7.6, -0.2), (6.5, 8.8, 6.0)), "metal", True),      # every transmitter -> wall leg
    (((12.0, 6.5, -0.2), (14.0, 8.5, 6.0)), "metal", False),   # behind the wall: only images
])  # fmt: skip
def test_a_triple_is_blocked_only_when_every_path_of_it_is(box, material, blocked):
    """Transmitter (2, 9, 2): its image in the wall is (18, 9, 2); a diffraction point (5, 5, z)
    on the edge has its reflection point at (10, 6.54, 2 + 8 (z - 2) / 13). A metal box across
    every reflection-to-edge leg (y 5.6-5.9 at x 7-8) blocks the triple; concrete, or a box too
    low for the legs to the top of the edge, does not; one across every transmitter-to-wall leg
    does too; one behind the wall, across the lines from the image only, does not. Sampled
    candidates of a blocked triple cross the box shrunk by the depth on one of the two legs
    (slab method)."""
    from raytrace.solver.shadow import triples_in_shadow

    sc = _rd_scene(box, material)
    tx = np.array([2.0, 9.0, 2.0])
    f, j, img, lo, hi = _rd_triple(sc, tx)
    got = triples_in_shadow(sc, opaque_objects(sc, F_C), tx, f, j, img, lo, hi)
    assert got.tolist() == [blocked]
    if blocked:
        w = sc.wedges
        rng = np.random.default_rng(1)
        d = w.start[j] + rng.uniform(0, 1, (200, 1)) * (w.end[j] - w.start[j])
        u = (img[0, 0] - 10.0) / (img[0, 0] - d[:, 0])
        r = img + u[:, None] * (d - img)
        b_lo, b_hi = np.array(box[0]) + SHADOW_DEPTH_M, np.array(box[1]) - SHADOW_DEPTH_M
        for rr, dd in zip(r, d):
            assert _meets(tx, rr, b_lo, b_hi) or _meets(rr, dd, b_lo, b_hi)


def _meets(a, b, lo, hi) -> bool:
    d = b - a
    with np.errstate(divide="ignore"):
        t1, t2 = (lo - a) / d, (hi - a) / d
    return bool(max(np.max(np.minimum(t1, t2)), 0) < min(np.min(np.maximum(t1, t2)), 1))


def test_a_blocked_triple_is_sound_for_random_boxes_and_an_edge_through_the_plane():
    """Random metal boxes; the triples (wall facet, pillar edge) and (wall facet, the floor's
    edge along x, which runs through the wall's plane: its span's far part lies behind it, where
    no diffraction point of the triple can be), boxes in front of the wall and behind it.
    Whenever a triple is found blocked, every sampled
    candidate (a diffraction point on the end's side of the plane, its reflection point on the
    plane) crosses the box shrunk by the depth on one of its two legs."""
    from raytrace.solver.shadow import triples_in_shadow

    rng = np.random.default_rng(12)
    tx = np.array([2.0, 9.0, 2.0])
    found = 0
    for i in range(160):
        lo = rng.uniform((3.0, -3.0, -0.2), (9.0, 9.0, 1.0))
        hi = lo + rng.uniform((0.3, 0.3, 0.5), (2.5, 4.0, 6.0))
        hi[0] = min(hi[0], 9.9)
        if i % 2:  # behind the wall, where the floor edge's span runs on (x 10.3 - 12)
            lo[0], hi[0] = rng.uniform(10.3, 11.5), 12.5
        if (lo[:2] < 5.1).all() and (hi[:2] > 4.5).all():
            continue  # across the pillar (its edge would be covered)
        sc = _rd_scene((tuple(lo), tuple(hi)))
        if sc.inside_solid(tx[None])[0] >= 0:
            continue
        f = _facet(sc, "wall", (-1, 0, 0))
        fn, fo = sc.facets.normal[f], sc.facets.offset[f]
        w = sc.wedges
        along_x = np.flatnonzero((np.abs(w.direction[:, 0]) > 0.99) & (np.abs(w.start[:, 2]) < 1e-9)
                                 & (np.abs(w.start[:, 1] + 1.0) < 1e-9))  # fmt: skip
        edges = [int(_rd_triple(sc, tx)[1][0]), int(along_x[0])]
        img = tx - 2 * (tx @ fn - fo) * fn
        length = np.linalg.norm(w.end[edges] - w.start[edges], axis=1)
        got = triples_in_shadow(sc, opaque_objects(sc, F_C), tx, np.array([f, f]),
                                np.array(edges), np.stack([img, img]), np.zeros(2), length)  # fmt: skip
        b_lo, b_hi = lo + SHADOW_DEPTH_M, hi - SHADOW_DEPTH_M
        for k in np.flatnonzero(got):
            found += 1
            j = edges[k]
            d = w.start[j] + rng.uniform(0, 1, (300, 1)) * (w.end[j] - w.start[j])
            d = d[(d @ fn - fo) * (tx @ fn - fo) > 1e-12]  # on the transmitter's side
            u = (img @ fn - fo) / ((img @ fn - fo) - (d @ fn - fo))
            r = img + u[:, None] * (d - img)
            for rr, dd in zip(r, d):
                assert _meets(tx, rr, b_lo, b_hi) or _meets(rr, dd, b_lo, b_hi), (lo, hi, j)
    assert found >= 5
