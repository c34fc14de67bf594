"""The mixed stages' wedge-interior pruning never drops a diffraction that wedge_geometry would
accept, wherever on the edge the diffraction point is."""

from __future__ import annotations

import numpy as np

from raytrace import TraceConfig, load_scene
from raytrace.physics.utd import wedge_geometry
from raytrace.solver import diffraction
from raytrace.solver.context import TraceContext


def test_surely_inside_implies_invalid_anywhere_on_the_edge() -> None:
    scene = load_scene("hall")
    w = scene.wedges
    ctx = TraceContext(scene, np.zeros((1, 3)), np.ones((1, 3)), 3.775e9, TraceConfig(), None, None)
    frame = diffraction._wedge_frame(ctx)
    rng = np.random.default_rng(14)
    n = 20000
    wi = rng.integers(0, len(w), n)
    # points around the edges: mostly near (where the interior is), some at the edge line
    t = rng.uniform(0, 1, n)[:, None]
    on_edge = w.start[wi] + t * (w.end[wi] - w.start[wi])
    scale = rng.choice([1e-4, 1e-2, 1.0, 10.0], n)[:, None]
    p = on_edge + rng.normal(size=(n, 3)) * scale
    inside = diffraction._surely_inside(frame, wi, p[:, 0], p[:, 1], p[:, 2])
    assert 0.05 < inside.mean() < 0.9  # both outcomes exercised
    # the diffraction point anywhere on the edge, the other end anywhere
    q = w.start[wi] + rng.uniform(0, 1, n)[:, None] * (w.end[wi] - w.start[wi])
    other = rng.uniform(-50, 50, (n, 3))
    args = (w.direction[wi], w.normal0[wi], w.normal1[wi], w.face0_dir[wi])
    assert not wedge_geometry(p, other, q, *args).valid[inside].any()
    assert not wedge_geometry(other, p, q, *args).valid[inside].any()
