"""The approximate discovery of ``TraceConfig(facet_reach=r)`` (:mod:`raytrace.solver.near`)
against the exact tracer: it must find exactly the exact tracer's paths that obey its rule (a
small facet's reflection paired only with edges and facets within ``r`` of it), with the same
numbers, and nothing else."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box, make_scene, shoebox_sheets
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_candidates_oracle import _noisy_sphere, _signature

import raytrace
import raytrace.solver.kernels as kernels
from raytrace import TraceConfig
from raytrace.scene import accel
from raytrace.solver import near
from raytrace.solver.paths import DIFFRACTION, REFLECTION


def _boxes_within(lo_a, hi_a, lo_b, hi_b, reach) -> bool:
    return bool(np.all(lo_a - reach <= hi_b) and np.all(lo_b <= hi_a + reach))


def obeys_rule(scene, p, i: int, reach: float) -> bool:
    """Whether exact path ``i`` of ``p`` is one the approximate discovery keeps: in a path of
    more than one reflection or diffraction, each small facet it reflects in has the
    interactions next to it on the path (the reflection or diffraction before and after it)
    within ``reach`` (their boxes grown by ``reach`` meet). Written from the rule,
    independently of the lists the tracer makes."""
    fc, w = scene.facets, scene.wedges
    f_lo, f_hi = accel.facet_boxes(fc, 0.0)
    small = accel.facet_spheres(fc)[1] < reach
    kinds = np.asarray(p.interaction[i])
    elems = np.asarray(p.elements[i])
    hits = [(k, e) for k, e in zip(kinds, elems) if k in (REFLECTION, DIFFRACTION)]
    if len(hits) < 2:
        return True

    def element_box(k, e):
        if k == REFLECTION:
            return f_lo[e], f_hi[e]
        return np.minimum(w.start[e], w.end[e]), np.maximum(w.start[e], w.end[e])

    for a, (k, e) in enumerate(hits):
        if k != REFLECTION or not small[e]:
            continue
        for b in (a - 1, a + 1):
            if 0 <= b < len(hits) and not _boxes_within(f_lo[e], f_hi[e],
                                                        *element_box(*hits[b]), reach):
                return False
    return True


def assert_rule_holds(scene, exact, approx, reach: float) -> int:
    """``approx`` is exactly the paths of ``exact`` that obey the rule, with equal delays and
    gains; returns how many exact paths the rule leaves out."""
    ke, ka = _signature(exact), _signature(approx)
    expected = {k for i, k in enumerate(ke) if obeys_rule(scene, exact, i, reach)}
    got = set(ka)
    assert len(got) == len(ka), "a path found twice"
    assert got == expected, (f"{len(expected - got)} lost, {len(got - expected)} extra: "
                             f"{sorted(expected ^ got)[:3]}")  # fmt: skip
    ie = {k: i for i, k in enumerate(ke)}
    rows = np.array([ie[k] for k in ka], dtype=int)
    np.testing.assert_array_equal(approx.delay_s, exact.delay_s[rows])
    np.testing.assert_allclose(approx.gain, exact.gain[rows], rtol=1e-12, atol=0)
    return len(ke) - len(expected)


def _room(subdiv=3, noise=0.01, seed=1, sphere_first=False):
    """A room with a metal machine, a wooden screen and a noisy metal sphere of small facets;
    ``sphere_first``: the sphere's facets before the large ones in the scene's order."""
    objects = shoebox_sheets((12.0, 9.0, 4.0))
    objects += [("machine_a", box((3, 2, 0), (4.5, 3.2, 2.0)), "metal"),
                ("screen", box((8.0, 1.0, 0.0), (8.05, 3.0, 2.5)), "wood")]  # fmt: skip
    sphere = ("sphere", _noisy_sphere((6.0, 3.5, 1.4), 0.7, subdiv, noise, seed), "metal")
    return make_scene([sphere, *objects] if sphere_first else [*objects, sphere])


def _ends(scene, seed=7, n=14):
    rng = np.random.default_rng(seed)
    tx = np.array([[1.0, 1.0, 3.0], [11.0, 8.0, 3.0]])
    rx = np.column_stack([rng.uniform(0.5, 11.5, n), rng.uniform(0.5, 8.5, n),
                          rng.uniform(0.5, 1.6, n)])  # fmt: skip
    return tx, rx[scene.inside_solid(rx) < 0]


@pytest.mark.parametrize("reach, sphere_first", [(0.09, False), (0.15, True), (0.3, False)])
def test_the_approximation_keeps_exactly_the_paths_its_rule_keeps(reach, sphere_first):
    scene = _room(sphere_first=sphere_first)
    tx, rx = _ends(scene)
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1)
    approx = raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(facet_reach=reach), threads=1)
    small = near.small_facets(scene.facets, reach)
    assert small.sum() > 1000 and not small.all()  # the sphere's facets, not the walls'
    assert exact.n_paths > 1000 and (exact.n_reflections == 2).any()
    left_out = assert_rule_holds(scene, exact, approx, reach)
    assert left_out > 0  # the rule bites: a far pairing of a small facet exists here
    assert approx.n_paths > 0.99 * exact.n_paths


def test_with_every_mechanism_and_three_interactions():
    """Reflection-diffraction-reflection and penetrating paths obey the same rule."""
    scene = _room(subdiv=2, noise=0.02, seed=4, sphere_first=True)
    tx, rx = _ends(scene, seed=3, n=8)
    cfg = TraceConfig(max_interactions=3)
    exact = raytrace.trace(scene, tx, rx, 26.85e9, cfg, threads=1)
    approx = raytrace.trace(scene, tx, rx, 26.85e9, cfg.replace(facet_reach=0.2), threads=1)
    assert (exact.n_reflections == 2).any() and (exact.n_diffractions == 1).any()
    assert (exact.n_penetrations > 0).any()
    assert_rule_holds(scene, exact, approx, 0.2)


def test_a_reach_below_every_facet_is_the_exact_trace(monkeypatch):
    """No facet is small: the same paths as the exact trace, here through the trees' walks
    (the approximation never scans the tables)."""
    scene = _room(subdiv=2)
    tx, rx = _ends(scene, n=6)
    monkeypatch.setattr(kernels, "TREES", True)
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1)
    approx = raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(facet_reach=1e-3), threads=1)
    assert not near.small_facets(scene.facets, 1e-3).any()
    assert assert_rule_holds(scene, exact, approx, 1e-3) == 0


def test_a_restricted_trace_obeys_the_rule_too():
    """A trace of some objects only (the snapshots' incremental trace) takes the same rule."""
    scene = _room(subdiv=3)
    tx, rx = _ends(scene, n=8)
    sphere = [i for i, o in enumerate(scene.objects) if o.name == "sphere"]
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1, involving=sphere)
    approx = raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(facet_reach=0.09), threads=1,
                            involving=sphere)  # fmt: skip
    assert exact.n_paths > 100
    assert_rule_holds(scene, exact, approx, 0.09)


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), reach=st.sampled_from([0.05, 0.12, 0.4]))
def test_random_noisy_rooms(seed, reach):
    rng = np.random.default_rng(seed)
    scene = _room(subdiv=int(rng.integers(2, 4)), noise=float(rng.uniform(0.0, 0.03)), seed=seed,
                  sphere_first=bool(seed % 2))
    tx, rx = _ends(scene, seed=seed % 1000, n=6)
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1)
    approx = raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(facet_reach=reach), threads=1)
    assert_rule_holds(scene, exact, approx, reach)


def test_the_reach_is_checked():
    for bad in (-0.1, float("inf"), float("-inf"), float("nan"), "1", True):
        with pytest.raises(raytrace.TraceInputError, match="facet_reach must be a finite number >= 0"):
            TraceConfig(facet_reach=bad)
    assert TraceConfig(facet_reach=0).facet_reach == 0


def test_recall_counts_paths_and_first_arrivals():
    scene = _room(subdiv=2)
    tx, rx = _ends(scene, n=6)
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1)
    r = near.recall(exact, exact)
    assert (r.paths, r.first_arrivals, r.n_extra) == (1.0, 1.0, 0)
    # the first path of each link's delay order dropped: every first arrival changes
    order = np.lexsort((exact.delay_s, exact.rx_index, exact.tx_index))
    link = exact.tx_index[order] * 1000 + exact.rx_index[order]
    first = order[np.r_[True, link[1:] != link[:-1]]]
    keep = np.ones(exact.n_paths, bool)
    keep[first] = False
    r = near.recall(exact, exact.select(keep))
    assert r.n_found == exact.n_paths - len(first) and r.first_arrivals == 0.0
    assert r.paths == pytest.approx(1 - len(first) / exact.n_paths, abs=1e-15)
    # and a path the exact trace lacks is counted as extra
    r = near.recall(exact.select(keep), exact)
    assert r.n_extra == len(first) and r.paths == 1.0


def test_a_moving_object_of_small_facets_retraced_incrementally():
    """The snapshots' incremental retrace (the static paths re-evaluated, plus the paths
    involving the moved object) gives the full retrace's paths under the same rule."""
    from raytrace.solver.paths import Paths
    from raytrace.solver.tracer import reevaluate

    static = shoebox_sheets((12.0, 9.0, 4.0)) + [
        ("sphere", _noisy_sphere((6.0, 3.5, 1.4), 0.7, 2, 0.02, 5), "metal")]
    mover = ("cart", _noisy_sphere((3.0, 6.0, 0.8), 0.5, 2, 0.02, 6), "metal")
    cfg = TraceConfig(facet_reach=0.2)
    s0, s1 = make_scene(static), make_scene(static + [mover])
    tx, rx = _ends(s1, n=6)
    assert near.small_facets(s1.facets, 0.2)[s1.facets.object == len(static)].all()
    base = raytrace.trace(s0, tx, rx, 3.775e9, cfg, threads=1)
    full = raytrace.trace(s1, tx, rx, 3.775e9, cfg, threads=1)
    new = raytrace.trace(s1, tx, rx, 3.775e9, cfg, threads=1, involving=[len(static)])
    inc = Paths.concatenate([reevaluate(s1, base, cfg), new])
    assert new.n_paths > 0
    r = near.recall(full, inc)
    assert (r.n_found, r.n_extra, inc.n_paths) == (full.n_paths, 0, full.n_paths)


def test_double_reflections_made_for_the_receivers_only_obey_the_rule_too(monkeypatch):
    """A large scene's transmitter images beyond its share of the kept bytes are made for the
    trace's receivers only (forced here): the same paths."""
    import raytrace.solver.specular as specular

    scene = _room(sphere_first=True)
    tx, rx = _ends(scene)
    exact = raytrace.trace(scene, tx, rx, 3.775e9, threads=1)
    monkeypatch.setattr(specular, "SECOND_IMAGES_KEPT_BYTES", 0)
    approx = raytrace.trace(scene, tx, rx, 3.775e9, TraceConfig(facet_reach=0.15), threads=1)
    kept = scene.facets.cache.get("second_images", {})
    assert not [k for k in kept if k[-1] == 0.15]  # made for these receivers, not kept
    assert (approx.n_reflections == 2).sum() > 50
    assert_rule_holds(scene, exact, approx, 0.15)
