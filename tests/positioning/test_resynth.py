"""The twin's path re-synthesis: moved paths and the re-run receiver against closed forms."""

from __future__ import annotations

import numpy as np

from positioning.lobe import C0, LobeReceiver, move_paths

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
    from pos_synth import CBAND_MODEL, PAPER_BS, two_ray_map, two_ray_paths

    from positioning import locate
    from positioning.metrics import error_2d

    fmap = two_ray_map()
    rng = np.random.default_rng(5)
    n = 300
    p = np.column_stack([rng.uniform(3, 26, n), rng.uniform(3, 22, n), np.ones(n)])
    delay, gain, _, _ = two_ray_paths(p)
    model = LobeReceiver.from_meta(CBAND_MODEL)
    toa = model.toa(delay.reshape(4 * n, -1), gain.reshape(4 * n, -1)).reshape(n, 4)
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
    from pos_synth import CBAND_MODEL, PAPER_BS, two_ray_map, two_ray_paths

    import positioning.twin as tw
    from positioning import locate

    fmap = two_ray_map()
    rng = np.random.default_rng(11)
    n = 40
    p = np.column_stack([rng.uniform(3, 26, n), rng.uniform(3, 22, n), np.ones(n)])
    delay, gain, _, _ = two_ray_paths(p)
    toa = LobeReceiver.from_meta(CBAND_MODEL).toa(
        delay.reshape(4 * n, -1), gain.reshape(4 * n, -1)
    ).reshape(n, 4) + rng.normal(0, 0.01, (n, 4)) / C0
    out = {}
    for block in (1, 7, 10_000):
        monkeypatch.setattr(tw, "RESYNTH_CHUNK", block)
        out[block] = locate(toa, PAPER_BS, "twin", height_m=1.0, map=fmap, bias="resynth",
                            fallback="ls")  # fmt: skip
    np.testing.assert_array_equal(out[1], out[10_000])
    np.testing.assert_array_equal(out[7], out[10_000])
