"""The compiled walks of :mod:`raytrace.solver.kernels.reach` against the forms they replace:
the (end, facet, wedge) triples of the edges' tree against the table scan
(:func:`raytrace.solver.kernels.prune.facet_wedge_pairs`), and the second facets of double
reflections against the numpy passes over :func:`raytrace.scene.accel.beam_facets`' hits. Same
sets, same numbers bit for bit (the same arithmetic), whatever the buffers' sizes."""

import numpy as np
import pytest
import trimesh
from conftest import box, make_scene, quad

from raytrace.scene import accel
from raytrace.scene.dynamic import extend_scene
from raytrace.solver import diffraction, kernels, specular
from raytrace.solver import reflection as refl
from raytrace.solver.config import TraceConfig
from raytrace.solver.context import TraceContext


def _machines(seed: int):
    """A room with two boxes, a pane and a noisy (non-convex) metal sphere."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(2, 0.7)
    sphere.vertices += rng.normal(0.0, 0.01, sphere.vertices.shape)
    sphere.apply_translation((6.0, 3.5, 1.4))
    return make_scene([
        ("floor", quad((0, 0, 0), (12, 0, 0), (0, 9, 0)), "concrete"),
        ("wall", box((0, 8.7, 0), (12, 9, 4)), "concrete"),
        ("machine", box((3, 2, 0), (4.5, 3.2, 2.0)), "metal"),
        ("pane", quad((8, 1, 0.2), (0, 3, 0), (0, 0, 2)), "glass"),
        ("sphere", sphere, "metal"),
    ])  # fmt: skip


def _ends(scene, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(0.5, 11.5, 12), rng.uniform(0.5, 8.5, 12),
                         rng.uniform(0.3, 3.5, 12)])  # fmt: skip
    return p[scene.inside_solid(p) < 0]


def _triples(monkeypatch, ctx, ends, trees: bool) -> dict:
    monkeypatch.setattr(kernels, "TREES", trees)
    monkeypatch.setattr(kernels, "EXHAUSTIVE", not trees)
    e, f, w, img, lo, hi = diffraction._facet_wedge_pairs(ctx, ends)
    assert len(set(zip(e, f, w))) == len(e)  # no triple twice
    return {(a, b, c): (tuple(i), lo_, hi_) for a, b, c, i, lo_, hi_ in zip(e, f, w, img, lo, hi)}


@pytest.mark.parametrize("seed", [1, 2])
def test_tree_triples_are_the_table_triples(monkeypatch, seed):
    scene = _machines(seed)
    ends = _ends(scene, seed)
    ctx = TraceContext(scene, ends[:2], ends, 3.775e9, TraceConfig())
    want = _triples(monkeypatch, ctx, ends, trees=False)
    # tiny buffers: every end's triples come in many chunks, some facets' alone
    monkeypatch.setattr(diffraction, "PAIRS_PER_END", 4)
    monkeypatch.setattr(diffraction, "TRIPLE_CHUNK", 16)
    got = _triples(monkeypatch, ctx, ends, trees=True)
    assert len(want) > 1000
    assert got == want


def test_tree_triples_of_a_restricted_trace(monkeypatch):
    scene = _machines(3)
    ends = _ends(scene, 3)
    sphere = [i for i, name in enumerate(scene.object_names) if name == "sphere"]
    ctx = TraceContext(scene, ends[:2], ends, 3.775e9, TraceConfig(), sphere)
    want = _triples(monkeypatch, ctx, ends, trees=False)
    got = _triples(monkeypatch, ctx, ends, trees=True)
    assert len(want) > 100
    assert got == want


def _numpy_second_facets(fc, f1, b1, side1, mask):
    """The numpy passes :func:`raytrace.solver.kernels.second_facets` replaced."""
    masked = None if mask is None else mask[f1]
    a, f2 = accel.beam_facets(fc, b1, fc.normal[f1], fc.offset[f1], side1, mask, masked)
    img1 = b1.apex
    s_img = refl.side_of(fc, img1[a], f2)
    ok = (s_img != 0) & accel.facing(fc, f1[a], f2)
    a, f2, s_img = a[ok], f2[ok], s_img[ok]
    centre, radius = accel.facet_spheres(fc)
    beam = refl.cone_reaches(img1[a], centre[f1[a]], radius[f1[a]], centre[f2], radius[f2])
    return a[beam], f2[beam], s_img[beam]


@pytest.mark.parametrize("restricted", [False, True])
@pytest.mark.parametrize("block", [1 << 15, 7])
def test_second_facets_are_the_numpy_passes(monkeypatch, restricted, block):
    monkeypatch.setattr(specular, "SECOND_FACETS_BLOCK", block)  # 7: the first facets in blocks
    base = _machines(4)
    extra = make_scene([("cart", box((4, 5, 0.05), (6, 6, 1.5)), "metal")])
    scene = extend_scene(base, extra)  # two trees: the static scene's and the cart's
    fc = scene.facets
    assert len(accel.facet_forest(fc)) == 2
    tx = np.array([1.0, 7.5, 3.0])
    side_t = refl.reflecting_side(fc, tx[None])[0]
    f1 = np.flatnonzero(side_t != 0)
    img1 = refl.mirror(np.broadcast_to(tx, (len(f1), 3)), fc.normal[f1], fc.offset[f1])
    centre, radius = accel.facet_spheres(fc)
    b1 = refl.beam(img1, centre[f1], radius[f1])
    mask = None
    if restricted:
        mask = np.zeros(len(fc), bool)
        mask[fc.object == scene.object_names.index("sphere")] = True
    want = _numpy_second_facets(fc, f1, b1, side_t[f1], mask)
    got = specular._second_facets(fc, f1, b1, side_t[f1], mask)
    key = lambda r: np.lexsort((r[1], r[0]))  # noqa: E731
    assert len(want[0]) > 500 and (want[1] >= len(base.facets)).any()
    assert block > len(f1) or len(f1) > 10 * block
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g[key(got)], w[key(want)])
