"""Per-wedge frames (utd.wedge_frames) taken per diffraction give bitwise wedge_geometry; the
compiled per-diffraction geometry against its formulas written out in numpy."""

from __future__ import annotations

import dataclasses

import numpy as np

from raytrace.physics import utd


def _random_wedges(rng: np.random.Generator, n_wedges: int):
    """Edges along random directions with face normals at random angles (convex and sheets)."""
    e = rng.normal(size=(n_wedges, 3))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    helper = np.cross(e, rng.normal(size=(n_wedges, 3)))
    u = helper / np.linalg.norm(helper, axis=1, keepdims=True)
    v = np.cross(e, u)
    ang = rng.uniform(0.1, np.pi - 0.1, n_wedges)
    n0 = u
    nn = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    sheet = rng.random(n_wedges) < 0.3
    nn[sheet] = -n0[sheet]
    face0 = np.cross(n0, e)  # into face 0 for both kinds
    return e, n0, nn, face0


def test_framed_geometry_and_validity_bitwise_as_wedge_geometry() -> None:
    rng = np.random.default_rng(14)
    e, n0, nn, face0 = _random_wedges(rng, 20)
    frames = utd.wedge_frames(e, n0, nn, face0)
    idx = rng.integers(0, 20, 500)
    start = rng.normal(size=(20, 3))
    src = rng.normal(size=(500, 3)) * 10
    dst = rng.normal(size=(500, 3)) * 10
    kp = utd.keller_points(src, dst, start[idx], start[idx] + 5 * e[idx])
    point = np.where(kp.on_edge[:, None], kp.point, start[idx])
    ref = utd.wedge_geometry(src, dst, point, e[idx], n0[idx], nn[idx], face0[idx])
    got = utd.framed_wedge_geometry(frames.take(idx), src, dst, point)
    for f in dataclasses.fields(ref):
        a, b = getattr(ref, f.name), getattr(got, f.name)
        assert np.array_equal(a, b, equal_nan=True), f.name
    assert 0 < ref.valid.sum() < len(idx)  # both outcomes are exercised
    assert np.array_equal(utd.diffraction_valid(frames.take(idx), src, dst, point), ref.valid)


def test_compiled_geometry_against_the_vectorised_formulas() -> None:
    """The compiled per-diffraction geometry against the formulas written out in numpy here:
    unit legs, KP angles from face 0 (``atan2(w . n0, w . t0)`` in ``[0, 2 pi)``), the ray-fixed
    unit vectors, the face rule's angles and the incidence cosines on the faces (rounding:
    arctan2, sin and cos of numpy and of the compiled code may differ in the last bit)."""
    rng = np.random.default_rng(5)
    e, n0, nn, face0 = _random_wedges(rng, 30)
    frames = utd.wedge_frames(e, n0, nn, face0)
    idx = rng.integers(0, 30, 2000)
    start = rng.normal(size=(30, 3))
    src, dst = rng.normal(size=(2000, 3)) * 10, rng.normal(size=(2000, 3)) * 10
    kp = utd.keller_points(src, dst, start[idx], start[idx] + 5 * e[idx])
    point = np.where(kp.on_edge[:, None], kp.point, start[idx])
    g = utd.framed_wedge_geometry(frames.take(idx), src, dst, point)
    ee, t0, n0f, _, n = frames.take(idx)
    s_in = np.linalg.norm(point - src, axis=1)
    s_out = np.linalg.norm(dst - point, axis=1)
    np.testing.assert_allclose(g.s_in, s_in, rtol=1e-14)
    np.testing.assert_allclose(g.s_hat_out, (dst - point) / s_out[:, None], atol=1e-14)

    def angle(w):
        return np.mod(np.arctan2((w * n0f).sum(1), (w * t0).sum(1)), 2 * np.pi)

    v = g.valid
    assert 0.2 < v.mean() < 0.95
    np.testing.assert_allclose(g.phi_in[v], angle(src - point)[v], atol=1e-12)
    np.testing.assert_allclose(g.phi[v], angle(dst - point)[v], atol=1e-12)
    # outside the wedge where valid; an end with an angle beyond n pi (by more than rounding)
    # makes the diffraction invalid
    assert np.all(g.phi_in[v] <= n[v] * np.pi) and np.all(g.phi[v] <= n[v] * np.pi)
    beyond = (angle(src - point) > n * np.pi + 1e-6) | (angle(dst - point) > n * np.pi + 1e-6)
    assert not (v & beyond).any() and beyond.any()
    cross_in = np.cross(ee, g.s_hat_in)
    sin_b = np.linalg.norm(cross_in, axis=1)
    np.testing.assert_allclose(g.sin_beta0, sin_b, rtol=1e-13)
    np.testing.assert_allclose(g.phi_hat_in[v], -cross_in[v] / sin_b[v, None], atol=1e-13)
    np.testing.assert_allclose(g.beta_hat_out[v], np.cross(g.s_hat_out, g.phi_hat_out)[v],
                               atol=1e-13)  # fmt: skip
    npi = n * np.pi
    # the face rule (D8a) for face n: each end at its angle from face n, in front of its plane
    a_in, a_out = npi - g.phi_in, npi - g.phi
    psi_n = np.arctan2(g.s_out * np.abs(np.sin(a_out)) + g.s_in * np.abs(np.sin(a_in)),
                       g.s_in * np.cos(a_in) - g.s_out * np.cos(a_out))  # fmt: skip
    np.testing.assert_allclose(g.psi_n[v], psi_n[v], atol=1e-12)
    np.testing.assert_allclose(g.cos_theta_0[v], (sin_b * np.abs(np.sin(g.psi_0)))[v], atol=1e-13)
    np.testing.assert_array_equal(g.lit_n, npi - g.phi_in <= np.pi)
