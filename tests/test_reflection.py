"""Image-method geometry of raytrace.solver.reflection against closed forms and brute force."""

from __future__ import annotations

import numpy as np
from conftest import box, make_scene, quad

from raytrace.scene import accel
from raytrace.scene.dynamic import extend_scene
from raytrace.scene.elements import Facets
from raytrace.solver import reflection as refl

GEOM_TOL_M = 1e-12


def test_image_point_of_a_plane():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = rng.uniform(-3, 3, 50)
    p = rng.uniform(-5, 5, (50, 3))
    img = refl.mirror(p, n, off)
    # the midpoint lies on the plane and the displacement is along the normal
    np.testing.assert_allclose(refl.signed_distance(0.5 * (p + img), n, off), 0.0, atol=GEOM_TOL_M)
    np.testing.assert_allclose(np.cross(img - p, n), 0.0, atol=GEOM_TOL_M)
    np.testing.assert_allclose(refl.mirror(img, n, off), p, atol=GEOM_TOL_M)


def test_cone_reaches_is_conservative():
    """Every sampled ray from the apex through the facet's sphere that meets the target sphere
    is admitted by the cone test."""
    rng = np.random.default_rng(1)
    rejected = 0
    for _ in range(200):
        apex = rng.uniform(-4, 4, 3)
        centre = rng.uniform(-4, 4, 3)
        radius = rng.uniform(0.1, 1.5)
        target = rng.uniform(-6, 6, 3)
        t_radius = rng.uniform(0.0, 1.0)
        pts = centre + radius * rng.uniform(-1, 1, (400, 3)) / np.sqrt(3)
        d = pts - apex
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        v = target - apex
        along = d @ v
        miss = np.linalg.norm(v[None] - along[:, None] * d, axis=1)
        hits = ((along > 0) & (miss <= t_radius)).any()
        admitted = refl.cone_reaches(apex, centre, radius, target, t_radius)
        if hits:
            assert admitted
        rejected += not admitted
    # and it does prune
    assert rejected > 50


def test_scalar_beam_sphere_test_equals_beam_reaches():
    """The compiled form of :func:`beam_reaches` (multiplied out by the distance) that
    ``facet_wedge_pairs`` applies to groups and edges and ``second_order_receivers`` to each
    second image (the receivers' bounding sphere) decides as numpy does, apex inside and target
    around the apex included."""
    from raytrace.solver.kernels.prune import beam_reaches1

    rng = np.random.default_rng(5)
    n = 3000
    apex = rng.uniform(-4, 4, (n, 3))
    centre = rng.uniform(-4, 4, (n, 3))
    radius = rng.uniform(0.05, 2.0, n)
    target = rng.uniform(-6, 6, (n, 3))
    t_radius = rng.uniform(0.0, 3.0, n)
    b = refl.beam(apex, centre, radius)
    want = refl.beam_reaches(b, target, t_radius)
    got = np.array([
        beam_reaches1(*b.apex[i], *b.axis[i], b.cos_a[i], b.sin_a[i], b.apex_inside[i],
                      *target[i], t_radius[i])
        for i in range(n)
    ])  # fmt: skip
    assert 0.1 < want.mean() < 0.9 and b.apex_inside.any()
    assert np.array_equal(got, want)


def _fresh(facets: Facets) -> Facets:
    return Facets(**facets.arrays())  # the same arrays, an empty cache


def test_facing_pairs_extended_equals_recomputed():
    """A scene with moving objects joined to a static one: its facets' trees are the static
    scene's and one over the added facets (no tree of the whole scene per snapshot), and beam
    queries on them find what a tree over all of the joined facets finds. The pairwise facing
    test is the (facets x facets) table's, pair by pair."""
    base = make_scene(
        [
            ("floor", quad((0, 0, 0), (10, 0, 0), (0, 10, 0)), "concrete"),
            ("wall", box((0, 9.5, 0), (10, 10, 3)), "concrete"),
            ("crate", box((2, 2, 0), (3, 3, 1)), "wood"),
            ("screen", quad((6, 1, 0), (0, 3, 0), (0, 0, 2)), "glass"),
        ]
    )
    extra = make_scene(
        [
            ("cart", box((4, 5, 0.05), (6, 6, 1.5)), "metal"),
            ("board", quad((8, 2, 0.5), (1, 0, 0), (0, 0, 1)), "wood"),
        ]
    )
    joined = extend_scene(base, extra)
    forest = accel.facet_forest(joined.facets)
    assert len(forest) == 2 and forest[0][0] is accel.facet_tree(base.facets)
    fresh = _fresh(joined.facets)
    rng = np.random.default_rng(7)
    k = len(fresh)
    centre, radius = accel.facet_spheres(fresh)
    apex = rng.uniform(-2, 12, (300, 3))
    through = rng.integers(0, k, 300)
    b = refl.beam(apex, centre[through], radius[through])
    side = rng.integers(-1, 2, 300).astype(np.int8)
    args = (b, fresh.normal[through], fresh.offset[through], side)
    got = accel.beam_facets(joined.facets, *args)
    want = accel.beam_facets(fresh, *args)
    assert len(got[0]) > 300 and (got[1] >= len(base.facets)).any()
    order_g, order_w = np.lexsort(got[::-1]), np.lexsort(want[::-1])
    np.testing.assert_array_equal(got[0][order_g], want[0][order_w])
    np.testing.assert_array_equal(got[1][order_g], want[1][order_w])
    # the pairwise test against the table; the joined scene's table extends the base's
    table = accel.facing_pairs(fresh)
    np.testing.assert_array_equal(accel.facing_pairs(joined.facets), table)
    assert "facing" in base.facets.cache
    i, j = np.divmod(np.arange(k * k), k)
    np.testing.assert_array_equal(accel.facing(fresh, i, j), table[i, j])
    assert table[: len(base.facets), len(base.facets) :].any()
    np.testing.assert_array_equal(table, table.T)
    assert not table.diagonal().any()
