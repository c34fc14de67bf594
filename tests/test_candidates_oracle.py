"""The tracer's candidates from the scene's trees (the default above
:data:`raytrace.solver.kernels.TABLE_MAX_PAIRS`, forced here with ``TREES``) against the
exhaustive tables
(:data:`raytrace.solver.kernels.EXHAUSTIVE`, today's all-pairs path, kept as the oracle): the
same paths on canonical scenes, the bundled hall and random cluttered scenes (issue 36).

"The same" is: the same links, the same interaction sequences (kinds, objects and elements), and
delays equal to 1 ps. Both tracers run the same exact image-method validation, so any difference
is a candidate the trees lost (a false negative of a conservative query) or invented."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, shoebox_sheets
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import raytrace
import raytrace.solver.kernels as kernels
from raytrace import TraceConfig

#: Delays of the same path from both candidate sources agree to this, seconds.
DELAY_TOL_S = 1e-12


def _signature(p) -> list[tuple]:
    """One sortable key per path: link, interaction kinds, objects, elements."""
    keys = []
    for i in range(p.n_paths):
        keys.append((int(p.tx_index[i]), int(p.rx_index[i]), tuple(np.asarray(p.interaction[i]).tolist()),
                     tuple(np.asarray(p.objects[i]).tolist()), tuple(np.asarray(p.elements[i]).tolist())))  # fmt: skip
    return keys


def assert_same_paths(a, b) -> None:
    ka, kb = _signature(a), _signature(b)
    sa, sb = sorted(range(len(ka)), key=ka.__getitem__), sorted(range(len(kb)), key=kb.__getitem__)
    lost = sorted(set(ka) - set(kb))
    extra = sorted(set(kb) - set(ka))
    assert not lost and not extra, f"{len(lost)} lost, {len(extra)} extra: {(lost + extra)[:3]}"
    np.testing.assert_allclose(a.delay_s[sa], b.delay_s[sb], rtol=0, atol=DELAY_TOL_S)


def _both(monkeypatch, scene, tx, rx, f=3.775e9, config=None, **kw):
    config = config or TraceConfig()
    monkeypatch.setattr(kernels, "TREES", True)  # the trees, also on these small scenes
    fast = raytrace.trace(scene, tx, rx, f, config, threads=1, **kw)
    monkeypatch.setattr(kernels, "TREES", False)
    monkeypatch.setattr(kernels, "EXHAUSTIVE", True)
    oracle = raytrace.trace(scene, tx, rx, f, config, threads=1, **kw)
    monkeypatch.setattr(kernels, "EXHAUSTIVE", False)
    return fast, oracle


def _noisy_sphere(centre, radius, subdivisions, noise, seed):
    s = trimesh.creation.icosphere(subdivisions, radius)
    s.vertices += np.random.default_rng(seed).normal(0.0, noise, s.vertices.shape)
    s.apply_translation(centre)
    return s


@pytest.mark.parametrize("name", ["shoebox", "box_on_floor", "half_plane", "two_boxes", "one_wall"])
def test_canonical_scenes(monkeypatch, name):
    scene = raytrace.load_scene(f"canonical/{name}")
    lo, hi = scene.bounds
    rng = np.random.default_rng(3)
    pts = rng.uniform(lo - 1.0, hi + 1.0, (16, 3))
    pts = pts[scene.inside_solid(pts) < 0]
    fast, oracle = _both(monkeypatch, scene, pts[:3], pts[3:])
    assert oracle.n_paths > 0
    assert_same_paths(fast, oracle)


def test_shoebox_with_machines(monkeypatch):
    objects = shoebox_sheets((12.0, 9.0, 4.0))
    objects += [("machine_a", box((3, 2, 0), (4.5, 3.2, 2.0)), "metal"),
                ("machine_b", box((7, 5, 0), (8.0, 7.5, 3.1)), "metal"),
                ("sphere", _noisy_sphere((6.0, 3.5, 1.4), 0.7, 2, 0.01, 1), "metal")]  # fmt: skip
    scene = make_scene(objects)
    rng = np.random.default_rng(7)
    tx = np.array([[1.0, 1.0, 3.0], [11.0, 8.0, 3.0]])
    rx = np.column_stack([rng.uniform(0.5, 11.5, 14), rng.uniform(0.5, 8.5, 14), rng.uniform(0.5, 1.6, 14)])
    rx = rx[scene.inside_solid(rx) < 0]
    fast, oracle = _both(monkeypatch, scene, tx, rx)
    assert oracle.n_paths > 200  # reflections, penetrations and diffractions all occur
    assert (oracle.n_diffractions > 0).any() and (oracle.n_reflections == 2).any()
    assert_same_paths(fast, oracle)


def test_bundled_hall(monkeypatch):
    from raytrace.scene.metadata import SceneMetadata

    scene = raytrace.load_scene("hall")
    inp = SceneMetadata.from_scene(scene, require=True)
    fast, oracle = _both(monkeypatch, scene, inp.bs_xyz, inp.point_xyz[::6], 26.85e9)
    assert oracle.n_paths > 500
    assert_same_paths(fast, oracle)
    # a restricted trace takes its candidates from a subset of the trees
    some = np.arange(0, len(scene.objects), 5)
    fast, oracle = _both(monkeypatch, scene, inp.bs_xyz[:1], inp.point_xyz[::5], involving=some)
    assert_same_paths(fast, oracle)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), n_boxes=st.integers(1, 6), subdiv=st.integers(0, 2))
def test_random_cluttered_scenes(monkeypatch, seed, n_boxes, subdiv):
    rng = np.random.default_rng(seed)
    size = np.array([rng.uniform(8, 16), rng.uniform(8, 16), rng.uniform(3, 6)])
    objects = shoebox_sheets(tuple(size))
    for k in range(n_boxes):
        lo = rng.uniform([0.5, 0.5, 0.0], size * [0.7, 0.7, 0.0] + [0.5, 0.5, 0.0])
        hi = lo + rng.uniform([0.3, 0.3, 0.5], [2.5, 2.5, size[2] * 0.8])
        objects.append((f"box{k}", box(lo, hi), ["metal", "concrete", "wood"][k % 3]))
    c = rng.uniform([1, 1, 0.8], size - [1, 1, 2.0])
    objects.append(("blob", _noisy_sphere(c, 0.5, subdiv, 0.02, seed), "metal"))
    scene = make_scene(objects)
    pts = rng.uniform([0.3, 0.3, 0.3], size - 0.3, (12, 3))
    pts = pts[scene.inside_solid(pts) < 0]
    if len(pts) < 3:
        return
    fast, oracle = _both(monkeypatch, scene, pts[:2], pts[2:])
    assert_same_paths(fast, oracle)


@pytest.mark.slow
def test_bundled_hall_every_link_both_bands(monkeypatch):
    from raytrace.scene.metadata import SceneMetadata

    scene = raytrace.load_scene("hall")
    inp = SceneMetadata.from_scene(scene, require=True)
    for f in (3.775e9, 26.85e9):
        fast, oracle = _both(monkeypatch, scene, inp.bs_xyz, inp.point_xyz, f,
                             TraceConfig(max_interactions=3))  # fmt: skip
        assert_same_paths(fast, oracle)
