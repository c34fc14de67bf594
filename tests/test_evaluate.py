"""The candidates' back end: which candidates an opaque object blocks."""

from __future__ import annotations

import numpy as np
import pytest
from test_diffraction_paths import _cluttered_scene

from raytrace import TraceConfig
from raytrace.core.jit import carray
from raytrace.solver import evaluate, kernels
from raytrace.solver.context import TraceContext
from raytrace.solver.penetration import (
    CONTACT_TOL_MARGINS,
    convex_plane_arrays,
    flat_sheet_arrays,
)


def _rays_counted(sc, monkeypatch) -> list[int]:
    """The number of rays of each opaque query on ``sc``'s class, from now on."""
    rays: list[int] = []
    real = type(sc).first_hit_among
    monkeypatch.setattr(type(sc), "first_hit_among",
                        lambda self, *a: rays.append(len(a[1])) or real(self, *a))  # fmt: skip
    return rays


@pytest.mark.parametrize("m", [150, 1500], ids=["all at once", "sampled order"])
def test_the_opaque_test_is_the_rule_on_every_segment(m, monkeypatch):
    """A candidate is blocked when any of its segments is (kernels.opaque_blocks on that
    segment's first opaque hit): the same verdicts as querying every segment of every candidate,
    whatever the order the segments are queried in (past ORDER_SAMPLE candidates, the order of
    how often each segment blocked a sample, whose verdicts are kept)."""
    sc, tx, rx = _cluttered_scene(5)
    ctx = TraceContext(sc, tx, rx, 3.775e9, TraceConfig())
    assert ctx.opaque.any() and not ctx.opaque.all()
    rng = np.random.default_rng(3)
    t_idx, r_idx = rng.integers(0, len(tx), m), rng.integers(0, len(rx), m)
    facet = rng.integers(0, len(sc.facets), (m, 2))
    verts = rng.uniform((0.5, 0.5, 0.2), (19.5, 19.5, 3.0), (m, 2, 3))
    # the second vertex near the receiver mostly: that short segment is blocked least often
    verts[:, 1] = rx[r_idx] + rng.normal(0, 0.3, (m, 3))
    cand = evaluate.candidates(ctx, t_idx, r_idx, verts, facet)
    real = type(sc).first_hit_among
    rays = _rays_counted(sc, monkeypatch)
    got = evaluate.blocked_by_opaque(ctx, cand)
    assert sum(rays) < 3 * m
    chain, vobj = carray(cand.chain), carray(cand.vobj, np.int64)
    want = np.zeros(m, dtype=bool)
    everything = np.arange(m)
    for j in range(chain.shape[1] - 1):
        a, d, length, org, d32, reach = kernels.segment_rays(chain, everything, j, sc.margin)
        hit = real(sc, ctx.opaque, org, d32, reach)
        want |= kernels.opaque_blocks(hit, everything, j, vobj, a, d, length,
                                      *convex_plane_arrays(sc), *flat_sheet_arrays(sc),
                                      CONTACT_TOL_MARGINS * sc.margin)  # fmt: skip
    np.testing.assert_array_equal(got, want)
    assert 0.2 < want.mean() < 0.9  # the test has its power: both verdicts, often


def test_the_segment_that_blocks_most_is_queried_first(monkeypatch):
    """Candidates whose short first segment runs through a metal box half the time and whose
    long segments are never blocked: queried longest first that is three rays per candidate,
    the likeliest to block first about two."""
    from conftest import box, make_scene

    sc = make_scene([("floor", box((-1, -1, -0.3), (21, 21, 0)), "concrete"),
                     ("cabinet", box((2, 2, 0), (4, 4, 3)), "metal")])  # fmt: skip
    tx, rx = np.array([[1.0, 3.0, 1.5]]), np.array([[18.0, 2.0, 5.0]])
    ctx = TraceContext(sc, tx, rx, 3.775e9, TraceConfig())
    rng = np.random.default_rng(4)
    m = 2000
    behind = rng.random(m) < 0.5
    v1 = np.column_stack([np.where(behind, 5.0, 1.0),
                          np.where(behind, rng.uniform(2.5, 3.5, m), rng.uniform(5, 7, m)),
                          np.full(m, 1.5)])  # fmt: skip
    v2 = np.column_stack([rng.uniform(14, 16, m), rng.uniform(14, 16, m), np.full(m, 5.0)])
    floor = int(np.flatnonzero(sc.facets.object == 0)[0])  # the vertices' element: not the box
    cand = evaluate.candidates(ctx, np.zeros(m, int), np.zeros(m, int), np.stack([v1, v2], 1),
                               np.full((m, 2), floor))  # fmt: skip
    rays = _rays_counted(sc, monkeypatch)
    got = evaluate.blocked_by_opaque(ctx, cand)
    np.testing.assert_array_equal(got, behind)
    # a sample of ~256 candidates queried on every segment, then two segments per candidate
    # (the box's, then for the half it does not block, the others): 2 m + 256-ish, not 3 m
    assert sum(rays) <= 2 * m + 2 * evaluate.ORDER_SAMPLE
