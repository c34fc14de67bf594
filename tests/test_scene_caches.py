"""raytrace.scene.caches: everything a scene derives is a named field of ``scene.caches``, never
pickled, and a copy of a scene starts without it."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from conftest import box, make_scene
from test_diffraction_paths import _cluttered_scene

from raytrace.scene.caches import (
    EMBREE_LOCAL_M,
    SceneCaches,
    bounds_of,
    convex_flags,
    embree_origin_of,
    margin_of,
)
from raytrace.solver.config import TraceConfig
from raytrace.solver.tracer import trace

#: The fields a trace with reflections, penetrations and diffractions fills on this scene (all).
#: (``extends`` is not derived: extend_scene sets it on a snapshot)
FILLED_BY_A_TRACE = {f.name for f in dataclasses.fields(SceneCaches)} - {"extends"}


def _traced():
    sc, tx, rx = _cluttered_scene(5)
    cfg = TraceConfig(max_reflections=2, max_penetrations=1, max_diffractions=1,
                      max_interactions=3)  # fmt: skip
    paths = trace(sc, tx, rx, 3.775e9, cfg, threads=1)
    assert paths.n_paths > 0 and (paths.n_penetrations > 0).any()
    return sc


def _filled(value) -> bool:
    return value is not None and not (isinstance(value, dict) and not value)


def test_a_traced_scene_keeps_what_it_derived_in_named_caches_only():
    """After a trace with every mechanism, the scene's attributes are its dataclass fields (no
    hidden state beside them), every cache field is filled, and no other can be added."""
    sc = _traced()
    assert set(vars(sc)) == {f.name for f in dataclasses.fields(sc)}
    filled = {f.name for f in dataclasses.fields(SceneCaches)
              if _filled(getattr(sc.caches, f.name))}  # fmt: skip
    assert filled == FILLED_BY_A_TRACE
    with pytest.raises(AttributeError):
        sc.caches.something_else = 1  # type: ignore[attr-defined]


def test_a_pickled_scene_carries_no_caches_and_rebuilds_its_intersector():
    sc = _traced()
    state = sc.__getstate__()
    assert "caches" not in state
    assert not any(isinstance(v, SceneCaches) for v in state.values())
    copy = pickle.loads(pickle.dumps(sc))
    # the intersector and what it is built from, nothing of the solver's
    rebuilt = {f.name for f in dataclasses.fields(SceneCaches)
               if _filled(getattr(copy.caches, f.name))}  # fmt: skip
    assert rebuilt == {"embree", "prim_start", "prim_face", "embree_meshes", "embree_origin",
                       "bounds"}
    o, d = np.array([[5.0, 5.0, 10.0]]), np.array([[0.0, 0.0, -1.0]])
    assert copy.intersect(o, d)[2].tolist() == sc.intersect(o, d)[2].tolist()


def test_a_replaced_scene_starts_with_empty_caches():
    """``dataclasses.replace`` (a snapshot's posed and joined scenes) gives new caches: none of
    the original's derived arrays can describe the new geometry."""
    sc = _traced()
    moved = dataclasses.replace(sc, vertices=sc.vertices + [1.0, 0.0, 0.0])
    assert moved.caches is not sc.caches
    assert not any(_filled(getattr(moved.caches, f.name)) for f in dataclasses.fields(SceneCaches))
    np.testing.assert_array_equal(moved.bounds, sc.bounds + [1.0, 0.0, 0.0])


def test_scene_layer_builders_against_their_definitions():
    """bounds, margin and convexity from their closed forms: a box and an L-shaped prism (not
    convex), and a sheet (not a solid)."""
    import trimesh

    # an L-shaped prism, 2 m high: the polygon fanned from its corner at the origin
    ring = np.array([(0, 0), (3, 0), (3, 1), (1, 1), (1, 3), (0, 3)], dtype=float)
    verts = np.concatenate([np.c_[ring, np.zeros(6)], np.c_[ring, np.full(6, 2.0)]])
    fan = [(0, i, i + 1) for i in range(1, 5)]
    sides = [q for i in range(6)
             for q in ((i, (i + 1) % 6, 6 + (i + 1) % 6), (i, 6 + (i + 1) % 6, 6 + i))]  # fmt: skip
    top = [tuple(6 + np.array(t)) for t in fan]
    ell = trimesh.Trimesh(verts, [t[::-1] for t in fan] + top + sides)
    sc = make_scene([("box", box((4, 4, 0), (5, 6, 1)), "wood"), ("ell", ell, "concrete"),
                     ("sheet", trimesh.Trimesh([[0, 0, 5], [6, 0, 5], [0, 6, 5]], [[0, 1, 2]]),
                      "glass")])  # fmt: skip
    np.testing.assert_array_equal(bounds_of(sc.vertices), [[0, 0, 0], [6, 6, 5]])
    assert sc.bounds.flags.writeable is False
    assert margin_of(0.0) == 1e-4 and margin_of(1e3) == pytest.approx(2e-3, rel=1e-15)
    assert sc.margin == margin_of(np.sqrt(36 + 36 + 25))
    convex = convex_flags(sc.vertices, sc.faces, sc.objects, sc.facets, sc.object_closed,
                          sc.extent)  # fmt: skip
    assert sc.object_closed.tolist() == [True, True, False]
    assert convex.tolist() == [True, False, False]
    assert sc.convex_objects() is sc.caches.convex


def test_embree_origin_is_zero_near_the_origin_and_the_rounded_centre_far_out():
    assert embree_origin_of(np.array([[-5.0, 0, 0], [EMBREE_LOCAL_M, 30, 8]])).tolist() == [0, 0, 0]
    far = np.array([[1e5 - 0.3, 2e6 + 10.2, -0.3], [1e5 + 30.3, 2e6 + 30.2, 8.3]])
    assert embree_origin_of(far).tolist() == [100015.0, 2000020.0, 4.0]
    sc = make_scene([("b", box((1e5, 1e5, 0), (1e5 + 2, 1e5 + 3, 1)), "metal")])
    assert sc.embree_origin().tolist() == [100001.0, 100002.0, 0.0]
    # the Embree meshes are relative to it, the answers are in the scene's coordinates
    pts = sc.embree_meshes()[0][0]
    assert np.abs(pts).max() <= 2.0
    t, _, obj = sc.intersect(np.array([[1e5 + 1, 1e5 + 1, 5.0]]), np.array([[0.0, 0, -1]]))
    assert obj.tolist() == [0] and t[0] == pytest.approx(4.0, abs=1e-6)


def test_a_box_with_welding_gaps_is_convex():
    """Facets whose corners lie off their plane by up to 1e-5 m (a box welded from a mesh with
    gaps): convex within twice that, not within the rounding of a clean mesh; an L-shaped prism
    with the same noise stays non-convex."""
    import trimesh

    from raytrace.scene.accel import facet_off_plane

    rng = np.random.default_rng(2)
    ring = np.array([(0, 0), (3, 0), (3, 1), (1, 1), (1, 3), (0, 3)], dtype=float)
    verts = np.concatenate([np.c_[ring, np.zeros(6)], np.c_[ring, np.full(6, 2.0)]])
    fan = [(0, i, i + 1) for i in range(1, 5)]
    sides = [q for i in range(6)
             for q in ((i, (i + 1) % 6, 6 + (i + 1) % 6), (i, 6 + (i + 1) % 6, 6 + i))]  # fmt: skip
    ell = trimesh.Trimesh(verts + [10.0, 0, 0], [t[::-1] for t in fan]
                          + [tuple(6 + np.array(t)) for t in fan] + sides)  # fmt: skip
    objects = []
    for name, m in (("b", box((0, 0, 0), (3, 2, 1))), ("ell", ell)):
        noisy = np.asarray(m.vertices) + rng.uniform(-1e-5, 1e-5, m.vertices.shape)
        objects.append((name, trimesh.Trimesh(noisy, m.faces), "metal"))
    sc = make_scene(objects)
    off = facet_off_plane(sc.facets)
    assert 1e-7 < off[sc.facets.object == 0].max() < 4e-5
    assert sc.object_closed.all() and sc.convex_objects().tolist() == [True, False]
