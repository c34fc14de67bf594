"""The scene's bounding-volume hierarchy (raytrace.scene.spatial) against scans of every element."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.scene.spatial import build_tree, query_beams, query_boxes
from raytrace.solver.reflection import beam, beam_reaches


def _elements(rng, n, spread=20.0, size=0.5):
    lo = rng.uniform(-spread, spread, (n, 3))
    hi = lo + rng.uniform(0, size, (n, 3)) ** 2 / size
    centre = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo, axis=1)
    return lo, hi, centre, radius


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 100, 3000])
def test_every_element_is_in_exactly_one_leaf(n):
    tree = build_tree(*_elements(np.random.default_rng(n), n))
    leaves = tree.left < 0
    got = np.concatenate([tree.order[s : s + c] for s, c in zip(tree.start[leaves], tree.count[leaves])])
    assert np.array_equal(np.sort(got), np.arange(n))
    assert (tree.count[leaves] <= 8).all()


def test_nodes_bound_their_elements():
    rng = np.random.default_rng(1)
    lo, hi, centre, radius = _elements(rng, 2000)
    tree = build_tree(lo, hi, centre, radius, leaf_size=4)

    def elements(node):
        if tree.left[node] < 0:
            return tree.order[tree.start[node] : tree.start[node] + tree.count[node]]
        return np.concatenate([elements(tree.left[node]), elements(tree.right[node])])

    for node in rng.choice(len(tree.left), 200, replace=False):
        e = elements(node)
        assert (tree.node_lo[node] <= lo[e]).all() and (tree.node_hi[node] >= hi[e]).all()
        d = np.linalg.norm(centre[e] - tree.node_centre[node], axis=1) + radius[e]
        assert (d <= tree.node_radius[node]).all()


def test_box_queries_are_a_scan_of_every_box():
    rng = np.random.default_rng(2)
    lo, hi, centre, radius = _elements(rng, 5000)
    tree = build_tree(lo, hi, centre, radius)
    q_lo = rng.uniform(-22, 22, (300, 3))
    q_hi = q_lo + rng.uniform(0, 6, (300, 3))
    q_hi[:5] = q_lo[:5]  # degenerate query boxes (points)
    q_lo[5], q_hi[5] = lo[17], lo[17]  # a box touching an element at a corner
    off, hits = query_boxes(tree, q_lo, q_hi)
    for q in range(len(q_lo)):
        want = np.flatnonzero((lo <= q_hi[q]).all(axis=1) & (hi >= q_lo[q]).all(axis=1))
        assert np.array_equal(np.sort(hits[off[q] : off[q + 1]]), want)
    assert 17 in hits[off[5] : off[6]]


def test_beam_queries_are_a_scan_with_the_same_test():
    """Cones from apexes through spheres, with and without a plane: the elements found are those
    a scan of every element finds with reflection.beam_reaches (the same necessary condition)."""
    rng = np.random.default_rng(3)
    lo, hi, centre, radius = _elements(rng, 4000)
    tree = build_tree(lo, hi, centre, radius)
    nq = 200
    apex = rng.uniform(-25, 25, (nq, 3))
    through_c = rng.uniform(-20, 20, (nq, 3))
    through_r = rng.uniform(0.01, 8.0, nq) ** 1.5
    through_c[:3] = apex[:3]  # apex inside the sphere: every direction
    b = beam(apex, through_c, through_r)
    normal = rng.normal(size=(nq, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    offset = np.einsum("ij,ij->i", normal, through_c)
    side = rng.integers(-1, 2, nq).astype(np.int8)
    off, hits = query_beams(tree, b.apex, b.axis, b.cos_a, b.sin_a, b.apex_inside, normal, offset, side)
    n_found = 0
    for q in range(nq):
        reach = beam_reaches(b.take(np.full(len(centre), q)), centre, radius)
        s = centre @ normal[q] - offset[q]
        ahead = (s > -radius) if side[q] > 0 else (s < radius) if side[q] < 0 else np.ones(len(s), bool)
        want = np.flatnonzero(reach & ahead)
        got = np.sort(hits[off[q] : off[q + 1]])
        assert np.array_equal(got, want), q
        n_found += len(got)
    assert 0 < n_found < nq * len(centre) / 2  # the queries neither miss nor take everything


def test_queries_with_more_hits_than_their_first_buffer():
    """One query that meets every element (more than the first buffer holds), then many that
    fill several buffers: the answers are those of the scan, in query order."""
    rng = np.random.default_rng(4)
    lo, hi, centre, radius = _elements(rng, 6000)
    tree = build_tree(lo, hi, centre, radius)
    off, hits = query_boxes(tree, np.full((1, 3), -100.0), np.full((1, 3), 100.0))
    assert off.tolist() == [0, 6000] and np.array_equal(np.sort(hits), np.arange(6000))
    q_lo = np.repeat(np.array([[-100.0, -100.0, -100.0], [0.0, 0.0, 0.0]]), 3, axis=0)
    q_hi = np.repeat(np.array([[100.0, 100.0, 100.0], [1.0, 1.0, 1.0]]), 3, axis=0)
    off, hits = query_boxes(tree, q_lo, q_hi)
    for q in range(6):
        want = np.flatnonzero((lo <= q_hi[q]).all(axis=1) & (hi >= q_lo[q]).all(axis=1))
        assert np.array_equal(np.sort(hits[off[q] : off[q + 1]]), want)
