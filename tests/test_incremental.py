"""Incremental retrace: static paths re-evaluated plus paths involving new objects = full retrace."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box, make_scene, quad, shoebox_sheets

from raytrace.solver.config import TraceConfig
from raytrace.solver.paths import Paths
from raytrace.solver.tracer import reevaluate, trace

F_C = 3.775e9


def _key(p: Paths):
    kinds = p.kind_label
    order = np.lexsort((p.gain.imag, p.gain.real, kinds, p.delay_s, p.link))
    return p.link[order], p.delay_s[order], kinds[order], p.gain[order]


@pytest.mark.parametrize("forklift_x", [3.0, 5.5, 8.0])
def test_incremental_equals_full_retrace(forklift_x):
    static = shoebox_sheets((12.0, 10.0, 4.0)) + [
        ("machine", box((6.0, 6.0, 0.0), (8.0, 8.0, 2.0)), "metal")
    ]
    forklift = ("forklift", box((forklift_x, 3.0, 0.0), (forklift_x + 2.0, 4.2, 2.2)), "metal")
    tx = np.array([[1.0, 1.0, 3.0], [11.0, 9.0, 3.0]])
    rx = np.array([[11.0, 4.0, 1.0], [4.0, 8.5, 1.0], [6.0, 2.0, 1.0]])
    cfg = TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=2)
    s0 = make_scene(static)
    s1 = make_scene(static + [forklift])
    base = trace(s0, tx, rx, F_C, cfg)
    full = trace(s1, tx, rx, F_C, cfg)
    new = trace(s1, tx, rx, F_C, cfg, involving=[len(static)])
    inc = Paths.concatenate([reevaluate(s1, base, TraceConfig(max_penetrations=2)), new]).sorted()
    assert inc.n_paths == full.n_paths
    a, b = _key(inc), _key(full)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_allclose(a[3], b[3], rtol=1e-12, atol=1e-300)
    # the forklift changes something in every placement
    assert new.n_paths > 0


def test_reevaluate_in_the_same_scene_is_identity(shoebox):
    tx = np.array([[2.0, 3.0, 1.5]])
    rx = np.array([[7.0, 5.0, 1.2], [5.0, 5.0, 2.0]])
    p = trace(shoebox, tx, rx, F_C)
    q = reevaluate(shoebox, p)
    np.testing.assert_array_equal(p.delay_s, q.delay_s)
    np.testing.assert_allclose(p.gain, q.gain, rtol=1e-12)


def test_involving_only_returns_paths_on_those_objects():
    sc = make_scene(
        [
            ("floor", quad((-20, -20, 0), (40, 0, 0), (0, 40, 0)), "concrete"),
            ("b", box((4, -1, 0), (5, 1, 2)), "metal"),
        ]
    )
    p = trace(sc, [[0, 0, 1.5]], [[1.0, 3.0, 1.0]], F_C, involving=[1])
    assert p.n_paths > 0
    assert not p.los.any()
    rd = (p.interaction == 1) | (p.interaction == 3)
    assert (np.where(rd, p.objects, -1) == 1).any(axis=1).all()
