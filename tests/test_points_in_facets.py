"""accel.points_in_facets: the shortcut for axis-aligned rectangles gives the barycentric test's
answer, also within rounding of the rectangles' sides."""

from __future__ import annotations

import numpy as np

from raytrace import load_scene
from raytrace.scene import accel
from raytrace.scene.elements import Facets


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
    ref[near] = _barycentric(p[near], facet[near], fc)
    assert np.array_equal(got, ref)
    assert 0.2 < got.mean() < 0.95  # both answers exercised


def _barycentric(p: np.ndarray, facet: np.ndarray, fc: Facets) -> np.ndarray:
    """The point is in one of its facet's triangles (barycentric coordinates >= -BARY_TOL),
    written out in numpy as the reference."""
    out = np.zeros(len(p), dtype=bool)
    for i in range(int(fc.tri_count.max())):
        has = fc.tri_count[facet] > i
        tri = fc.triangles[fc.tri_start[facet[has]] + i]
        v0, v1, v2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p[has] - tri[:, 0]
        d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
        d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
        den = d00 * d11 - d01 * d01
        v, w = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
        tol = accel.BARY_TOL
        out[has] |= (v >= -tol) & (w >= -tol) & (v + w <= 1 + tol)
    return out


def _facets(tris: list[np.ndarray]) -> Facets:
    """Facets of two triangles each, in the plane z = 0 (normal +z)."""
    k = len(tris)
    return Facets(
        normal=np.tile([0.0, 0.0, 1.0], (k, 1)),
        offset=np.zeros(k),
        object=np.arange(k),
        material=np.zeros(k, np.int64),
        two_sided=np.ones(k, bool),
        area=np.ones(k),
        tri_start=2 * np.arange(k),
        tri_count=np.full(k, 2),
        triangles=np.concatenate(tris).astype(float),
    )


def test_only_true_rectangles_take_the_shortcut() -> None:
    a, b, c, d = [0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]  # corners of a 2 x 1 rectangle
    e = [1, 1, 0]  # midpoint of a side
    fc = _facets(
        [
            np.array([[a, b, c], [a, c, d]]),  # split along a diagonal: a rectangle
            np.array([[b, d, a], [d, b, c]]),  # the other diagonal: a rectangle
            np.array([[a, b, c], [a, b, d]]),  # overlapping halves: not the rectangle
            np.array([[a, b, e], [a, e, d]]),  # a vertex off the corners
        ]
    )
    rect, lo, hi = accel._rectangles(fc)
    assert rect.tolist() == [True, True, False, False]
    assert np.array_equal(lo[0], [0, 0, -np.inf]) and np.array_equal(hi[0], [2, 1, np.inf])
    # the overlapping halves leave the top middle uncovered: the barycentric test decides
    p = np.array([[1.0, 0.9, 0.0]] * 4)
    assert accel.points_in_facets(p, np.arange(4), fc).tolist() == [True, True, False, True]
