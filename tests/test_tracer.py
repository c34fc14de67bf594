"""Tracer against closed forms: LoS, one plane, shoebox image sources, a box between tx and rx."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from conftest import admit_every_beam, box, make_scene, quad, shoebox_sheets

from raytrace.core.constants import C0
from raytrace.core.errors import TraceInputError
from raytrace.physics.materials import Material, MaterialLibrary, fresnel, slab, slab_group_delay
from raytrace.solver.config import TraceConfig
from raytrace.solver.tracer import trace

DELAY_TOL_S = 1e-12
GAIN_TOL_DB = 0.01
POINT_TOL_M = 1e-9
F_C = 3.775e9


def friis(d, f=F_C):
    lam = C0 / f
    return lam / (4 * np.pi * d)


def db(x):
    return 20 * np.log10(np.abs(x))


def far_floor():
    # a floor far below so the scene has an extent but nothing interferes
    return make_scene([("floor", quad((-50, -50, -8), (100, 0, 0), (0, 100, 0)), "concrete")])


def test_line_of_sight_delay_and_friis_gain():
    sc = far_floor()
    rng = np.random.default_rng(1)
    tx = rng.uniform(-5, 5, (3, 3))
    rx = rng.uniform(-5, 5, (5, 3))
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=0, max_penetrations=0, max_diffractions=0)
    )
    los = p.select(p.los)
    assert los.n_paths == 15
    d = np.linalg.norm(tx[los.tx_index] - rx[los.rx_index], axis=1)
    np.testing.assert_allclose(los.delay_s, d / C0, rtol=0, atol=DELAY_TOL_S)
    np.testing.assert_allclose(db(los.gain), db(friis(d)), atol=GAIN_TOL_DB)
    # the phase is the free-space phase exp(-j k d)
    np.testing.assert_allclose(
        np.angle(los.gain / np.exp(-2j * np.pi * F_C * d / C0)), 0, atol=1e-6
    )


def test_one_wall_reflection_te_closed_form():
    """A vertical concrete slab (closed solid): tx, rx at one height -> pure TE reflection."""
    wall = box((-20, 5.0, 0), (20, 5.3, 6))
    sc = make_scene([("wall", wall, "concrete")])
    tx = np.array([[0.0, 0.0, 2.0]])
    rx = np.array([[6.0, 1.5, 2.0]])
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=0)
    )
    r = p.select(p.n_reflections == 1)
    assert r.n_paths == 1
    image = np.array([0.0, 10.0, 2.0])
    d = np.linalg.norm(image - rx[0])
    assert abs(r.delay_s[0] - d / C0) < DELAY_TOL_S
    # geometric reflection point: where the line rx -> image crosses y = 5
    u = (5.0 - rx[0, 1]) / (image[1] - rx[0, 1])
    expected_point = rx[0] + u * (image - rx[0])
    np.testing.assert_allclose(r.points[0, 0], expected_point, atol=POINT_TOL_M)
    cos_i = abs(image[1] - 5.0) / np.linalg.norm(image - expected_point)
    eta = MaterialLibrary.itu()["concrete"].permittivity(F_C)
    r_te, _, _, _ = fresnel(eta, cos_i)
    expected = friis(d) * np.exp(-2j * np.pi * F_C * d / C0) * r_te
    assert abs(db(r.gain[0]) - db(expected)) < GAIN_TOL_DB
    assert abs(np.angle(r.gain[0] / expected)) < 1e-6


def test_floor_reflection_tm_magnitude():
    """Vertical polarisation over a horizontal floor: pure TM (plane of incidence vertical)."""
    floor = box((-30, -30, -0.5), (30, 30, 0.0))
    sc = make_scene([("floor", floor, "concrete")])
    tx = np.array([[0.0, 0.0, 4.0]])
    rx = np.array([[10.0, 3.0, 1.0]])
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=0)
    )
    r = p.select(p.n_reflections == 1)
    assert r.n_paths == 1
    image = np.array([0.0, 0.0, -4.0])
    d = np.linalg.norm(image - rx[0])
    assert abs(r.delay_s[0] - d / C0) < DELAY_TOL_S
    cos_i = 5.0 / d
    eta = MaterialLibrary.itu()["concrete"].permittivity(F_C)
    _, r_tm, _, _ = fresnel(eta, cos_i)
    assert abs(db(r.gain[0]) - db(friis(d) * r_tm)) < GAIN_TOL_DB
    assert r.points[0, 0, 2] == pytest.approx(0.0, abs=POINT_TOL_M)


def _shoebox_images(src, size, max_order):
    """Analytic image sources of a rectangular room, with their reflection order."""
    out = []
    per_axis = []
    for c, length in zip(src, size):
        opts = []
        for n in range(-2, 3):
            opts.append((2 * n * length + c, 2 * abs(n)))  # even: 2|n| reflections
            opts.append((2 * n * length - c, abs(2 * n - 1)))  # odd
        per_axis.append(opts)
    for (x, ox), (y, oy), (z, oz) in itertools.product(*per_axis):
        if ox + oy + oz <= max_order:
            out.append(((x, y, z), ox + oy + oz))
    return out


@pytest.mark.parametrize("rx", [(7.0, 5.0, 1.2), (5.0, 5.0, 2.0), (1.0, 7.0, 0.5)])
def test_shoebox_image_sources_up_to_order_two(rx):
    size = (10.0, 8.0, 3.0)
    sc = make_scene(shoebox_sheets(size))
    tx = np.array([[2.0, 3.0, 1.5]])
    rxa = np.array([rx])
    p = trace(
        sc, tx, rxa, F_C, TraceConfig(max_reflections=2, max_penetrations=0, max_diffractions=0)
    )
    images = _shoebox_images(tx[0], size, 2)
    assert len(images) == 25
    expected = np.sort([np.linalg.norm(np.array(img) - rxa[0]) / C0 for img, _ in images])
    got = np.sort(p.delay_s)
    assert len(got) == len(expected), "paths found must be exactly the valid image sources"
    np.testing.assert_allclose(got, expected, rtol=0, atol=DELAY_TOL_S)
    # orders agree too
    exp_orders = sorted(o for _, o in images)
    assert sorted(p.n_reflections.tolist()) == exp_orders


def test_shoebox_extra_paths_only_with_penetrations(shoebox):
    tx = np.array([[2.0, 3.0, 1.5]])
    rx = np.array([[7.0, 5.0, 1.2]])
    p0 = trace(shoebox, tx, rx, F_C, TraceConfig(max_penetrations=0, max_diffractions=0))
    p2 = trace(shoebox, tx, rx, F_C, TraceConfig(max_penetrations=2, max_diffractions=0))
    assert p2.n_paths >= p0.n_paths
    no_pen = p2.select(p2.n_penetrations == 0)
    np.testing.assert_allclose(np.sort(no_pen.delay_s), np.sort(p0.delay_s), atol=DELAY_TOL_S)


def _box_scene(material):
    return make_scene(
        [
            ("floor", quad((-50, -50, -10), (100, 0, 0), (0, 100, 0)), "concrete"),
            ("block", box((4.0, -1.0, 0.0), (5.0, 1.0, 3.0)), material),
        ]
    )


def test_penetrable_box_one_penetration_through_the_chord():
    sc = _box_scene("concrete")
    tx = np.array([[0.0, 0.0, 1.5]])
    rx = np.array([[10.0, 0.5, 1.5]])
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=0, max_penetrations=2, max_diffractions=0)
    )
    assert not p.los.any()
    t = p.select(p.n_penetrations == 1)
    assert t.n_paths == 1
    d = np.linalg.norm(rx[0] - tx[0])
    cos_i = (rx[0] - tx[0])[0] / d
    # group delay of the 1 m equivalent slab (closed form tested in test_materials)
    mat = MaterialLibrary.itu()["concrete"]
    tau = slab_group_delay(mat.permittivity(F_C), cos_i, 1.0, mat.permittivity_slope(F_C))
    assert abs(t.delay_s[0] - d / C0 - tau) < DELAY_TOL_S
    free = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=0, max_diffractions=0, slab_delay=False)
    )
    assert abs(free.delay_s[0] - d / C0) < DELAY_TOL_S  # switched off: the geometric delay
    np.testing.assert_allclose(free.gain, t.gain, rtol=1e-12)  # the field is the same
    # entry point on the face x = 4
    direction = (rx[0] - tx[0]) / d
    entry = tx[0] + (4.0 - tx[0, 0]) / direction[0] * direction
    np.testing.assert_allclose(t.points[0, 0], entry, atol=1e-5)
    # chord x in [4, 5]; equivalent slab thickness = chord * cos(incidence) = 1 m
    cos_i = direction[0]
    eta = MaterialLibrary.itu()["concrete"].permittivity(F_C)
    _, _, t_te, _ = slab(eta, cos_i, 1.0, F_C)
    # tx, rx at one height: the field is vertical = TE for the vertical entry face
    assert abs(db(t.gain[0]) - db(friis(d) * t_te)) < GAIN_TOL_DB


def test_lossless_slab_delays_a_penetrating_path_as_geometric_optics():
    """A lossless dielectric block (n = 1.5) between tx and rx at oblique incidence: the path is
    late by the optical path excess of the refracted ray through it, ``(n L_in - L_free) / c``,
    built here from Snell's law (independent of the tracer's formula)."""
    n, d_slab = 1.5, 0.6
    plastic = Material("lossless_plastic", n * n, 0.0, 0.0, 0.0, 1e6, 1e12, 0.01)
    lib = MaterialLibrary.itu()
    lib = MaterialLibrary({**{k: lib[k] for k in lib}, plastic.name: plastic})
    sc = make_scene(
        [
            ("floor", quad((-50, -50, -10), (100, 0, 0), (0, 100, 0)), "concrete"),
            ("block", box((4.0, -3.0, 0.0), (4.0 + d_slab, 3.0, 3.0)), plastic.name),
        ],
        lib,
    )
    tx = np.array([[0.0, 0.0, 1.5]])
    rx = np.array([[10.0, 2.5, 1.5]])
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=0, max_penetrations=1, max_diffractions=0)
    )
    assert p.n_paths == 1 and p.n_penetrations[0] == 1
    d = np.linalg.norm(rx[0] - tx[0])
    theta = np.arccos((rx[0] - tx[0])[0] / d)
    theta_t = np.arcsin(np.sin(theta) / n)
    inside = d_slab / np.cos(theta_t)
    free = inside * np.cos(theta - theta_t)  # the same stretch of wave front in free space
    expected = d / C0 + (n * inside - free) / C0
    assert abs(p.delay_s[0] - expected) < DELAY_TOL_S
    assert p.delay_s[0] - d / C0 > 0.1e-9  # visibly late: ~3 cm


def test_metal_box_carries_no_penetration_power():
    sc = _box_scene("metal")
    tx = np.array([[0.0, 0.0, 1.5]])
    rx = np.array([[10.0, 0.5, 1.5]])
    p = trace(
        sc, tx, rx, F_C, TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=0)
    )
    assert not p.los.any()
    assert (p.n_penetrations == 0).all()


def test_identical_runs_and_receiver_order_independence(shoebox):
    tx = np.array([[2.0, 3.0, 1.5], [8.0, 1.0, 2.5]])
    rx = np.array([[7.0, 5.0, 1.2], [5.0, 5.0, 2.0], [1.0, 7.0, 0.5]])
    a = trace(shoebox, tx, rx, F_C, TraceConfig(max_diffractions=0))
    b = trace(shoebox, tx, rx, F_C, TraceConfig(max_diffractions=0))
    np.testing.assert_array_equal(a.delay_s, b.delay_s)
    np.testing.assert_array_equal(a.gain, b.gain)
    perm = np.array([2, 0, 1])
    c = trace(shoebox, tx, rx[perm], F_C, TraceConfig(max_diffractions=0))
    for new_r, old_r in enumerate(perm):
        for t in range(len(tx)):
            ma = (a.tx_index == t) & (a.rx_index == old_r)
            mc = (c.tx_index == t) & (c.rx_index == new_r)
            np.testing.assert_array_equal(a.delay_s[ma], c.delay_s[mc])
            np.testing.assert_array_equal(a.gain[ma], c.gain[mc])


def test_bad_positions(shoebox):
    with pytest.raises(TraceInputError, match="NaN"):
        trace(shoebox, [[np.nan, 0, 0]], [[1, 1, 1]], F_C)
    with pytest.raises(TraceInputError, match="outside the scene"):
        trace(shoebox, [[2, 3, 1.5]], [[2e6, 3, 1.5]], F_C)  # beyond the scale rule
    with pytest.raises(TraceInputError, match="positive"):
        trace(shoebox, [[2, 3, 1.5]], [[5, 3, 1.5]], -1.0)
    sc = _box_scene("concrete")
    with pytest.raises(TraceInputError, match="inside the solid 'block'"):
        trace(sc, [[4.5, 0, 1]], [[10, 0, 1]], F_C)


def test_beam_pruning_loses_no_path(monkeypatch):
    """The cone pre-tests are necessary conditions: switching them off changes nothing."""

    rng = np.random.default_rng(3)
    objs = [("floor", box((-1, -1, -0.3), (21, 21, 0.0)), "concrete")]
    for i in range(12):
        lo = np.append(rng.uniform(1, 17, 2), 0.0)
        objs.append(
            (
                f"b{i}",
                box(lo, lo + np.append(rng.uniform(0.5, 2.5, 2), rng.uniform(0.5, 4))),
                "metal",
            )
        )
    sc = make_scene(objs)
    tx = np.array([[0.5, 0.5, 4.5], [19.5, 19.5, 4.5]])
    rx = np.array([[10.0, 0.5, 1.0], [0.5, 19.5, 1.5], [19.5, 0.5, 0.8]])
    rx = rx[sc.inside_solid(rx) < 0]
    pruned = trace(sc, tx, rx, F_C)

    admit_every_beam(monkeypatch)
    full = trace(sc, tx, rx, F_C)
    assert pruned.n_paths == full.n_paths > 0
    np.testing.assert_array_equal(pruned.delay_s, full.delay_s)


def test_opaque_objects_are_metals_of_realistic_thickness():
    from raytrace.solver.context import TraceContext, opaque_objects

    lib = MaterialLibrary.itu().with_yaml(
        {"materials": {"foil": {"eta_real": 1.0, "sigma": 1e7, "thickness": 1e-8}}}
    )
    sc = make_scene(
        [
            ("metal_box", box((0, 0, 0), (1, 1, 1)), "metal"),
            ("metal_sheet", quad((3, 0, 0), (0, 1, 0), (0, 0, 1)), "metal"),
            ("foil_sheet", quad((4, 0, 0), (0, 1, 0), (0, 0, 1)), "foil"),
            ("concrete_box", box((5, 0, 0), (6, 1, 1)), "concrete"),
            ("glass_sheet", quad((7, 0, 0), (0, 1, 0), (0, 0, 1)), "glass"),
        ],
        lib,
    )
    for f in (F_C, 26.85e9):
        ctx = TraceContext(
            sc, np.array([[2.0, 3, 0.5]]), np.array([[2.0, 4, 0.5]]), f, TraceConfig()
        )
        op = opaque_objects(sc, f, -250.0)
        np.testing.assert_array_equal(op, ctx.opaque)
        # a 10 nm foil transmits: what decides is the slab loss, not the material's name
        np.testing.assert_array_equal(op, [True, True, False, False, False])


def test_opaque_prepass_changes_no_path():
    """Dropping paths through metal before the crossing analysis is what the slab model gives
    (zero transmission): switching the pre-pass off changes nothing."""
    from test_diffraction_paths import _cluttered_scene

    sc, tx, rx = _cluttered_scene(7)
    stats: dict[str, int] = {}
    with_prepass = trace(sc, tx, rx, F_C, stats=stats)
    assert stats["paths_blocked_opaque"] > 0
    without = trace(sc, tx, rx, F_C, opaque=np.zeros(len(sc.objects), bool))
    assert with_prepass.n_paths == without.n_paths > 0
    np.testing.assert_array_equal(with_prepass.delay_s, without.delay_s)
    np.testing.assert_array_equal(with_prepass.elements, without.elements)
    np.testing.assert_array_equal(with_prepass.gain, without.gain)
    with pytest.raises(TraceInputError, match="one flag per object"):
        trace(sc, tx, rx, F_C, opaque=[True])


def test_reevaluate_groups_the_sequences_as_numpy_unique_over_rows():
    """reevaluate's grouping of paths by interaction sequence (rows read as integers) equals
    ``np.unique(axis=0)``: the same sequences in the same order, the same groups; also with no
    path and no vertex."""
    from raytrace.solver.tracer import _unique_rows

    rng = np.random.default_rng(3)
    for n, k in ((0, 2), (6, 0), (1, 3), (4000, 2), (4000, 4)):
        kinds = rng.integers(0, 4, (n, k)).astype(np.int8)
        want_seq, want_group = np.unique(kinds, axis=0, return_inverse=True)
        seq, group = _unique_rows(kinds)
        np.testing.assert_array_equal(seq, want_seq)
        np.testing.assert_array_equal(group.reshape(-1), want_group.reshape(-1))


def test_no_penetration_is_the_full_trace_without_its_crossing_paths():
    """With max_penetrations = 0 every object blocks (the shadows and the one-query opaque test
    prune what the crossing walk would drop): the paths are exactly those of a trace allowing two
    penetrations that cross nothing, bit for bit (interaction arrays trimmed to their depth)."""
    from raytrace.scene.io import load_scene
    from raytrace.scene.metadata import SceneMetadata

    hall = load_scene("hall")
    inp = SceneMetadata.from_scene(hall)
    none = trace(hall, inp.bs_xyz, inp.point_xyz, 3.775e9, TraceConfig(max_penetrations=0))
    full = trace(hall, inp.bs_xyz, inp.point_xyz, 3.775e9, TraceConfig(max_penetrations=2))
    assert (full.n_penetrations > 0).sum() > 1000  # the hall's racks and walls are crossed
    crossing_nothing = full.select(full.n_penetrations == 0)
    depth = none.interaction.shape[1]
    for k in none.PER_PATH:
        a, b = getattr(none, k), getattr(crossing_nothing, k)
        if a.ndim > 1:
            b = b[:, :depth]
        np.testing.assert_array_equal(a, b, err_msg=k)
