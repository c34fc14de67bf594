"""accel.points_in_facets: the shortcut for axis-aligned rectangles gives the barycentric test's
answer, also within rounding of the rectangles' sides."""

from __future__ import annotations

import numpy as np

from raytrace import load_scene
from raytrace.scene import accel


def test_rectangle_shortcut_agrees_with_barycentric_test() -> None:
    fc = load_scene("hall").facets
    rect, _, _ = accel._rectangles(fc)
    assert rect.sum() > len(fc) // 2  # walls, floor, shelves: mostly rectangles
    rng = np.random.default_rng(14)
    n = 20000
    facet = rng.integers(0, len(fc), n)
    lo, hi = accel.facet_boxes(fc, 0.0)
    # points over each facet's box and a little beyond, some exactly on or next to its sides
    u = rng.uniform(-0.05, 1.05, (n, 3))
    u[rng.random((n, 3)) < 0.1] = 0.0
    u[rng.random((n, 3)) < 0.1] = 1.0
    p = lo[facet] + u * (hi[facet] - lo[facet])
    p += rng.choice([0.0, 1e-7, -1e-7, 1e-12, -1e-12], (n, 3)) * (rng.random((n, 3)) < 0.3)
    # on the facet's plane (the function's contract)
    nrm, off = fc.normal[facet], fc.offset[facet]
    p -= (np.einsum("ij,ij->i", p, nrm) - off)[:, None] * nrm
    got = accel.points_in_facets(p, facet, fc)
    box_lo, box_hi = accel.facet_boxes(fc)
    near = np.all((p >= box_lo[facet]) & (p <= box_hi[facet]), axis=1)
    ref = np.zeros(n, dtype=bool)
    ref[near] = accel._in_triangles(p[near], facet[near], fc)
    assert np.array_equal(got, ref)
    assert 0.2 < got.mean() < 0.95  # both answers exercised
