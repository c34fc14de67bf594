"""The twin's path re-synthesis: moved paths and the re-run receiver against closed forms."""

from __future__ import annotations

import numpy as np

from positioning.model.tdoa import C0
from positioning.twin.lobe import LobeReceiver, move_paths

F = 3.5e9
LAM = C0 / F
T = 1.25 / 100e6  # C-band pulse period (beta = 0.25, 100 MHz)
RX = LobeReceiver(frequency_hz=F, period_s=T, roll_off=0.25, oversampling=8, span=16,
                  noise_std=50.0, alpha=13.8, rho=10 ** (-12 / 20))  # fmt: skip
#: ToA tolerance against the closed form, in pulse periods (the dense grid is T / 20000).
TOL_T = 1e-3


def two_paths(p: np.ndarray, bs: np.ndarray, image: np.ndarray, refl: complex):
    """Line of sight from ``bs`` and a floor reflection (image source ``image``, coefficient
    ``refl``) at ``p``: delays (2,) s, gains (2,), last-segment directions (2, 3), radii (2,)."""
    d = np.array([np.linalg.norm(p - bs), np.linalg.norm(p - image)])
    g = LAM / (4 * np.pi * d) * np.exp(-2j * np.pi * d / LAM) * np.array([1.0, refl])
    u = np.stack([(p - bs) / d[0], (p - image) / d[1]])
    return d / C0, g, u, d


def closed_form_toa(delay: np.ndarray, gain: np.ndarray) -> float:
    """Top of ``|A1 h(t - t1) + A2 h(t - t2)|`` (one merged lobe), by a dense grid."""
    t = np.linspace(delay.min() - T, delay.max() + T, 40001)
    x = (t[:, None] - delay[None]) / T
    b = 0.25
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.sinc(x) * np.cos(np.pi * b * x) / (1 - (2 * b * x) ** 2)
    s = np.abs((h * gain[None]).sum(axis=1))
    return float(t[np.argmax(s)])


def two_ray_toa(p: np.ndarray) -> np.ndarray:
    """(n, 4) noiseless first-lobe ToA, s, of the C-band receiver at ``p`` (n, 3) in the
    two-ray synthetic hall (line of sight + floor reflection from each paper base station)."""
    from pos_synth import CBAND_MODEL, two_ray_paths

    n = len(p)
    delay, gain, _, _ = two_ray_paths(p)
    model = LobeReceiver.from_meta(CBAND_MODEL)
    return model.toa(delay.reshape(4 * n, -1), gain.reshape(4 * n, -1)).reshape(n, 4)


def test_resynthesis_reproduces_the_receiver_0_3_m_from_the_cell():
    """Two paths 0.7 m apart (a fifth of a pulse) merge into one lobe whose top depends on their
    phase difference: moved 0.3 m from the cell, the re-synthesised paths give the closed-form
    ToA at the point, while holding the cell's bias (the v1 twin) is 5 cm off."""
    bs = np.array([0.0, 0.0, 4.0])
    image = np.array([0.0, 0.0, -4.0])  # floor reflection
    cell = np.array([10.0, 2.0, 1.0])
    point = cell + np.array([0.3, 0.0, 0.0])
    d, g, u, r = two_paths(cell, bs, image, -0.7)
    dd, gg = move_paths(d[None], g[None], u[None], r[None], (point - cell)[None], F)
    got = RX.toa(dd, gg)[0]
    dp, gp, _, _ = two_paths(point, bs, image, -0.7)
    want = closed_form_toa(dp, gp)
    assert abs(got - want) <= TOL_T * T
    # the moved paths are the exact ones (spherical waves about the sources)
    np.testing.assert_allclose(dd[0], dp, rtol=0, atol=1e-15)
    np.testing.assert_allclose(gg[0], gp, rtol=1e-9)
    # the v1 model (cell bias held) is measurably wrong here
    toa_cell = RX.toa(d[None], g[None])[0]
    held = toa_cell + (np.linalg.norm(point - bs) - np.linalg.norm(cell - bs)) / C0
    assert abs(held - want) > 10 * TOL_T * T  # 5 cm here, against 4 mm


def test_plane_wave_when_the_radius_is_infinite():
    """radius inf: the delay changes by u . disp / c and the amplitude is kept."""
    u = np.array([[[0.6, 0.8, 0.0]]])
    dd, gg = move_paths(np.array([[1e-7]]), np.array([[1.0 + 0j]]), u, np.array([[np.inf]]),
                        np.array([[0.5, 0.25, 0.0]]), F)  # fmt: skip
    dt = (0.6 * 0.5 + 0.8 * 0.25) / C0
    np.testing.assert_allclose(dd, [[1e-7 + dt]], rtol=0, atol=1e-18)
    np.testing.assert_allclose(gg, [[np.exp(-2j * np.pi * F * dt)]], rtol=1e-12)


def test_twin_with_paths_removes_the_overlap_bias_the_cell_model_keeps():
    """Synthetic hall, line of sight + floor reflection everywhere (C-band: the two rays merge
    into one lobe whose top moves with their phase). Devices off the grid measure the
    receiver's ToA on the exact rays (+ 1 cm noise); the v1 refinement (cell bias held) keeps
    the bias change between cell and device, the re-synthesis removes it."""
    from pos_synth import PAPER_BS, two_ray_map

    from positioning import locate
    from positioning.evaluation.metrics import error_2d

    fmap = two_ray_map()
    rng = np.random.default_rng(5)
    n = 300
    p = np.column_stack([rng.uniform(3, 26, n), rng.uniform(3, 22, n), np.ones(n)])
    toa = two_ray_toa(p)
    bias = C0 * toa - np.linalg.norm(p[:, None] - PAPER_BS[None], axis=2)
    assert np.percentile(np.abs(bias), 90) > 0.1  # the receiver's overlap bias is there
    toa = toa + rng.normal(0, 0.01, toa.shape) / C0 + rng.uniform(0, 1e-3, (n, 1))
    err = {}
    for b in ("cell", "resynth"):
        xyz = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias=b, fallback="ls")
        err[b] = np.percentile(error_2d(xyz, p), 90)
    assert err["resynth"] < 0.05
    assert err["cell"] > 2 * err["resynth"]


def test_resynth_needs_a_map_with_paths():
    """bias=resynth on a version-1 map is refused in one line; bias=auto falls back to cell."""
    import pytest
    from pos_synth import PAPER_BS, synth_map, synth_toa

    from positioning import PositioningError, locate

    fmap = synth_map()
    toa, _ = synth_toa(20)
    with pytest.raises(PositioningError, match="needs a map with paths") as info:
        locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias="resynth")
    assert "\n" not in str(info.value)
    auto = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap)
    cell = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias="cell")
    np.testing.assert_array_equal(auto, cell)


def test_resynth_in_blocks_equals_all_at_once(monkeypatch):
    """The re-synthesis runs in blocks of fixes to bound memory; the fixes do not depend on the
    block size (one fix per block, a block that does not divide the fixes, all at once)."""
    from pos_synth import PAPER_BS, two_ray_map

    import positioning.twin.estimator as tw
    from positioning import locate

    fmap = two_ray_map()
    rng = np.random.default_rng(11)
    n = 40
    p = np.column_stack([rng.uniform(3, 26, n), rng.uniform(3, 22, n), np.ones(n)])
    toa = two_ray_toa(p) + rng.normal(0, 0.01, (n, 4)) / C0
    out = {}
    for block in (1, 7, 10_000):
        monkeypatch.setattr(tw, "RESYNTH_CHUNK", block)
        out[block] = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias="resynth",
                            fallback="ls")  # fmt: skip
    np.testing.assert_array_equal(out[1], out[10_000])
    np.testing.assert_array_equal(out[7], out[10_000])


def _raster_and_map(h: float = 0.05):
    from pos_synth import two_ray_map

    import positioning.twin.lattice as tw
    from positioning.twin.resynth import PathMap, ToaRaster

    fmap = two_ray_map(step=0.5, area=(6.0, 5.0))
    _, lat = tw.load(fmap)
    pmap = PathMap.from_map(fmap)
    return ToaRaster(pmap, lat.node_cell, lat.x0, lat.y0, lat.step, 1.0, h), pmap, lat


def test_raster_samples_are_the_receiver_on_the_nearest_cells_paths():
    """At a raster sample the value is the receiver run on the paths of the map node whose
    square holds the sample, moved there (to float rounding)."""
    r, pmap, lat = _raster_and_map()
    rng = np.random.default_rng(3)
    kx, ky = rng.integers(0, r.NX, 50), rng.integers(0, r.NY, 50)
    xy = np.column_stack([r.X0 + (kx + 0.5) * r.h, r.Y0 + (ky + 0.5) * r.h])
    val, _ = r.predict(xy)
    cell = lat.node_cell[ky // r.m, kx // r.m]
    assert (cell >= 0).all()  # the synthetic map has no holes
    want = pmap.predict(cell, np.column_stack([xy, np.ones(len(xy))]))
    np.testing.assert_allclose(val, want, rtol=0, atol=1e-9)


def test_raster_is_bilinear_between_samples_with_its_slope():
    """Between four samples the value is their bilinear blend and the gradient its slope
    (finite differences of the raster itself, 1e-6 m steps inside one raster square)."""
    r, _, _ = _raster_and_map()
    rng = np.random.default_rng(4)
    k = np.column_stack([rng.integers(0, r.NX - 1, 40), rng.integers(0, r.NY - 1, 40)])
    f = rng.uniform(0.05, 0.95, (40, 2))
    xy = np.column_stack([r.X0 + (k[:, 0] + 0.5 + f[:, 0]) * r.h,
                          r.Y0 + (k[:, 1] + 0.5 + f[:, 1]) * r.h])  # fmt: skip
    corner = [r.predict(np.column_stack([r.X0 + (k[:, 0] + 0.5 + a) * r.h,
                                         r.Y0 + (k[:, 1] + 0.5 + b) * r.h]))[0]
              for b in (0, 1) for a in (0, 1)]  # fmt: skip
    fx, fy = f[:, :1], f[:, 1:]
    want = ((1 - fx) * (1 - fy) * corner[0] + fx * (1 - fy) * corner[1]
            + (1 - fx) * fy * corner[2] + fx * fy * corner[3])  # fmt: skip
    val, grad = r.predict(xy)
    np.testing.assert_allclose(val, want, rtol=0, atol=1e-9)
    e = 1e-6
    gx = (r.predict(xy + [e, 0])[0] - r.predict(xy - [e, 0])[0]) / (2 * e)
    gy = (r.predict(xy + [0, e])[0] - r.predict(xy - [0, e])[0]) / (2 * e)
    np.testing.assert_allclose(grad, np.stack([gx, gy], -1), rtol=0, atol=1e-5)


def test_raster_tiles_are_computed_on_first_use_only():
    """Queries near one point re-synthesise the few tiles around it, once."""
    r, _, _ = _raster_and_map()
    total = r.NX * r.NY * r.B
    xy = np.array([[3.0, 2.5]]) + np.random.default_rng(0).uniform(-0.1, 0.1, (100, 2))
    r.predict(xy)
    first = r.links
    assert 0 < first <= 4 * 9 * 9 * r.B < total
    r.predict(xy[::-1])
    assert r.links == first


def test_twin_on_the_raster_matches_the_exact_resynthesis():
    """The default raster (5 cm) and the exact re-synthesis (the receiver re-run at every
    iterate) give the same accuracy on the two-ray hall: p90 within 2 cm."""
    from pos_synth import PAPER_BS, two_ray_map

    from positioning import locate
    from positioning.evaluation.metrics import error_2d

    fmap = two_ray_map()
    rng = np.random.default_rng(8)
    n = 150
    p = np.column_stack([rng.uniform(3, 26, n), rng.uniform(3, 22, n), np.ones(n)])
    toa = two_ray_toa(p) + rng.normal(0, 0.01, (n, 4)) / C0
    p90 = {}
    for step in (0.0, 0.05):
        xyz = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, fallback="ls",
                     resynth_step=step)  # fmt: skip
        p90[step] = np.percentile(error_2d(xyz, p), 90)
    assert p90[0.0] < 0.05
    assert abs(p90[0.05] - p90[0.0]) < 0.02


def test_window_match_grouped_equals_per_fix(monkeypatch):
    """Fixes grouped by window centre (matrix products) and one gather per fix give the same
    candidates and misfits (the misfit's expansion is centred: rho carries a clock offset)."""
    from pos_synth import PAPER_BS, synth_map, synth_toa

    import positioning.twin.match as tw
    from positioning.model.problem import make_problem
    from positioning.twin.lattice import load

    fmap = synth_map()
    _, lat = load(fmap)
    toa, xyz = synth_toa(200)
    toa = toa + 1e-3  # a large common clock offset
    prob = make_problem(toa, PAPER_BS, None, np.full(len(toa), 1.0))
    prob.valid[::7, 2] = False  # some fixes without base station 2
    prior = np.round(xyz[:, :2] / 3.0) * 3.0  # few distinct window centres
    out = {}
    for g in (1, 10**9):
        monkeypatch.setattr(tw, "WINDOW_GROUP", g)
        out[g] = tw.window_match(prob, lat, prior, 4.0, top=3)
    np.testing.assert_array_equal(out[1][0], out[10**9][0])
    np.testing.assert_allclose(out[1][1], out[10**9][1], rtol=0, atol=1e-6)


def test_normal_step_is_the_damped_least_squares_solution():
    """The closed-form 2 x 2 step equals numpy's solve of the damped normal equations."""
    from positioning.twin.resynth import normal_step

    rng = np.random.default_rng(2)
    J, r = rng.normal(size=(50, 4, 2)), rng.normal(size=(50, 4))
    want = np.linalg.solve(J.transpose(0, 2, 1) @ J + 1e-3 * np.eye(2),
                           J.transpose(0, 2, 1) @ r[..., None])[..., 0]  # fmt: skip
    np.testing.assert_allclose(normal_step(J, r, 1e-3), want, rtol=1e-10, atol=1e-12)
    assert not np.isfinite(normal_step(np.zeros((1, 4, 2)), np.ones((1, 4)), 0.0)).any()


def test_prepare_fills_the_raster_and_later_fixes_only_look_up(tmp_path):
    """``prepare`` re-synthesises the whole raster once; the fixes after it spend no receiver
    run and equal those of a lazily filled raster."""
    import pytest
    from pos_synth import PAPER_BS, two_ray_map

    import positioning.twin.lattice as tw
    from positioning import PositioningError, locate
    from positioning.twin.fingerprint import write_map

    fmap = two_ray_map(step=0.5, area=(8.0, 6.0))
    eager = write_map(tmp_path / "eager.npz", fmap)
    lazy = write_map(tmp_path / "lazy.npz", fmap)
    spent = tw.prepare(eager, 1.0)
    _, lat = tw.load(eager)
    (raster,) = lat.rasters.values()
    assert spent == raster.nty * raster.ntx * 81 * 4 == raster.links
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(2, 6, 20), rng.uniform(2, 4, 20), np.ones(20)])
    toa = two_ray_toa(p)
    a = locate(toa, PAPER_BS, "twin", height_m=1.0, map=str(eager), fallback="ls")
    assert raster.links == spent
    b = locate(toa, PAPER_BS, "twin", height_m=1.0, map=str(lazy), fallback="ls")
    np.testing.assert_array_equal(a, b)
    with pytest.raises(PositioningError, match="resynth_step"):
        tw.prepare(eager, 1.0, resynth_step=0.0)


def test_raster_sample_index_and_position_round_trip():
    """A sample's position maps back to its own index; a point maps to the sample within half
    a spacing of it."""
    r, _, _ = _raster_and_map()
    rng = np.random.default_rng(6)
    kx, ky = rng.integers(0, r.NX, 30), rng.integers(0, r.NY, 30)
    np.testing.assert_array_equal(r.sample_index(r.sample_xy(kx, ky)), (kx, ky))
    xy = r.sample_xy(kx, ky) + rng.uniform(-0.49, 0.49, (30, 2)) * r.h
    inside = (kx > 0) & (ky > 0) & (kx < r.NX - 1) & (ky < r.NY - 1)
    np.testing.assert_array_equal(np.column_stack(r.sample_index(xy))[inside],
                                  np.column_stack([kx, ky])[inside])  # fmt: skip


def test_raster_solution_is_the_best_sample_near_gauss_newton(monkeypatch):
    """With SNAP > 0 the raster's solution is the raster sample of least exact misfit within
    SNAP samples of the Gauss-Newton solution (SNAP = 0), checked by exhaustive look-ups."""
    from pos_synth import PAPER_BS

    import positioning.twin.resynth as rs

    r, pmap, _ = _raster_and_map()
    rng = np.random.default_rng(9)
    n = 20
    p = np.column_stack([rng.uniform(1.5, 4.5, n), rng.uniform(1.5, 3.5, n), np.ones(n)])
    rho = C0 * two_ray_toa(p) + rng.normal(0, 0.02, (n, 4))
    valid = np.ones((n, 4), dtype=bool)
    start = p[:, :2] + rng.uniform(-0.2, 0.2, (n, 2))
    args = (rho, valid, np.ones(n), PAPER_BS, pmap, None, start, np.zeros(n, int), 100.0)
    monkeypatch.setattr(rs, "SNAP", 0)
    gn, _ = rs.refine_resynth(*args, search_m=0.0, raster=r)
    monkeypatch.setattr(rs, "SNAP", 2)
    xy, rms = rs.refine_resynth(*args, search_m=0.0, raster=r)
    k0x, k0y = r.sample_index(gn)
    kx, ky = r.sample_index(xy)
    np.testing.assert_allclose(r.sample_xy(kx, ky), xy, atol=1e-12)
    assert (np.abs(kx - k0x) <= 2).all() and (np.abs(ky - k0y) <= 2).all()
    best = np.full(n, np.inf)
    for dx in range(-2, 3):
        for dy in range(-2, 3):
            best = np.minimum(best, rs.residual_rms(rho, valid, r.nearest(r.sample_xy(k0x + dx, k0y + dy))))
    np.testing.assert_allclose(rms, best, rtol=0, atol=1e-12)


def test_rasters_kept_per_map_are_bounded_least_recently_used_first(monkeypatch):
    """A long-running service sees devices at many heights: at most ``MAX_RASTERS`` rasters stay
    with a loaded map, the least recently used dropped first; a kept one is reused as it is."""
    from pos_synth import two_ray_map

    import positioning.twin.lattice as tw
    from positioning.twin.resynth import PathMap

    monkeypatch.setattr(tw, "MAX_RASTERS", 3)
    fmap = two_ray_map(step=0.5, area=(8.0, 6.0))
    _, lat = tw.load(fmap)
    pmap = PathMap.from_map(fmap, None)
    first = tw.raster_for(lat, pmap, None, 0.05, 1000)
    for h_mm in (1100, 1200):
        tw.raster_for(lat, pmap, None, 0.05, h_mm)
    assert tw.raster_for(lat, pmap, None, 0.05, 1000) is first  # reused, now the most recent
    tw.raster_for(lat, pmap, None, 0.05, 1300)  # a fourth: the least recently used (1100) goes
    assert sorted(k[2] for k in lat.rasters) == [1000, 1200, 1300]
    assert tw.raster_for(lat, pmap, None, 0.05, 1000) is first
