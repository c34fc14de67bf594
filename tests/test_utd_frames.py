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


def _reflect(p: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Mirror points in planes ``normal . x = offset`` (unit normals)."""
    return p - 2.0 * ((p * normal).sum(axis=1) - offset)[:, None] * normal


def test_chain_diffraction_unfolds_the_reflections_and_matches_the_public_chain() -> None:
    """RD and DR chains (a reflection on a random plane before or after the edge): the
    compiled diffraction of the chain equals the public functions applied to the source or
    receiver mirrored in the plane (built independently here): ``framed_wedge_geometry``, the
    faces' coefficients (``fresnel`` for a solid's face, ``slab`` for an open sheet's) at
    ``cos_theta_0/n`` and ``diffraction_matrix``, to rounding (the chain's angles are computed
    without arctan2 and the wedge terms with one sine less)."""
    from raytrace.physics import materials

    rng = np.random.default_rng(21)
    n_w, p, f_hz = 25, 3000, 3.775e9
    e, n0, nn, face0 = _random_wedges(rng, n_w)
    frames = utd.wedge_frames(e, n0, nn, face0)
    start = rng.normal(size=(n_w, 3))
    wedge = rng.integers(0, n_w, p)
    # a plane per chain, and a diffraction point on its wedge's edge line
    normal = rng.normal(size=(p, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = rng.normal(size=p) * 3
    point = start[wedge] + rng.uniform(-3, 3, p)[:, None] * e[wedge]
    far = rng.normal(size=(p, 3)) * 8  # the other end
    img = rng.normal(size=(p, 3)) * 8  # the unfolded end beyond the plane
    # the reflection point: where the straight unfolded leg img -> point crosses the plane
    t = (offset - (img * normal).sum(axis=1)) / ((point - img) * normal).sum(axis=1)
    refl = img + t[:, None] * (point - img)
    ok = (t > 0.05) & (t < 0.95)
    wedge, normal, offset, point, far, img, refl = (x[ok] for x in (wedge, normal, offset,
                                                                    point, far, img, refl))  # fmt: skip
    end = _reflect(img, normal, offset)  # the real end, on the other side of the plane
    eta = np.array([5.3 - 0.4j, 1e6 - 1e7j, 2.1 - 0.02j])
    thick = np.array([0.2, 0.002, 0.05])
    material = rng.integers(0, 3, len(wedge))
    sheet = rng.random(len(wedge)) < 0.4
    for before in (True, False):  # RD: tx -> refl -> point -> rx; DR: tx -> point -> refl -> rx
        if before:
            chain = np.stack([end, refl, point, far], axis=1)
            j, src, dst = 2, img, far
        else:
            chain = np.stack([far, point, refl, end], axis=1)
            j, src, dst = 1, far, img
        seg_len = np.linalg.norm(chain[:, 1:] - chain[:, :-1], axis=2)
        got = utd.chain_diffraction(frames, wedge, chain, j, seg_len, f_hz, eta, thick, material,
                                    sheet)  # fmt: skip
        geo = utd.framed_wedge_geometry(frames.take(wedge), src, dst, point)
        faces = []
        for cos in (geo.cos_theta_0, geo.cos_theta_n):
            r_te, r_tm, _, _ = materials.fresnel(eta[material], cos)
            s_te, s_tm, _, _ = materials.slab(eta[material], cos, thick[material], f_hz)
            faces.append((np.where(sheet, s_te, r_te), np.where(sheet, s_tm, r_tm)))
        d_mat, spreading = utd.diffraction_matrix(geo, f_hz, r_0=faces[0], r_n=faces[1])
        v = geo.valid
        assert 0.2 < v.mean() < 0.95  # valid and invalid diffractions are both exercised
        np.testing.assert_array_equal(got.valid, v)
        scale = np.abs(d_mat[v]).max(axis=(1, 2))[:, None, None]
        err = np.abs(got.d_matrix[v] - d_mat[v]) / scale
        assert err.max() < 1e-12, err.max()
        np.testing.assert_allclose(got.spreading[v], spreading[v], rtol=1e-13)
        basis = np.stack([geo.beta_hat_in, geo.phi_hat_in, geo.beta_hat_out, geo.phi_hat_out], 1)
        np.testing.assert_allclose(got.basis[v], basis[v], rtol=0, atol=1e-12)
        # the incident leg along the chain is the distance from the unfolded source
        np.testing.assert_allclose(got.s_in, np.linalg.norm(point - src, axis=1), rtol=1e-12)


def test_chain_diffraction_rejects_bad_input() -> None:
    """One-line errors, not an out-of-bounds read in the compiled passes."""
    import pytest

    from raytrace.core.errors import TraceInputError

    rng = np.random.default_rng(2)
    e, n0, nn, face0 = _random_wedges(rng, 3)
    frames = utd.wedge_frames(e, n0, nn, face0)
    chain = rng.normal(size=(4, 3, 3))
    seg = np.linalg.norm(chain[:, 1:] - chain[:, :-1], axis=2)
    eta, thick = np.array([4.0 + 0j]), np.array([0.1])
    ok = dict(frequency_hz=3.775e9, eta=eta, thickness_m=thick, material=np.zeros(4, int),
              two_sided=np.zeros(4, bool))  # fmt: skip
    assert utd.chain_diffraction(frames, np.arange(4) % 3, chain, 1, seg, **ok).d_matrix.shape == (4, 2, 2)
    bad = [
        ((frames, np.array([0, 1, 2, 3]), chain, 1, seg), {}, "wedge indices"),
        ((frames, np.zeros(4, int), chain, 2, seg), {}, "vertex of the chain"),
        ((frames, np.zeros(4, int), chain, 1, seg[:, :1]), {}, "seg_len"),
        ((frames, np.zeros(3, int), chain, 1, seg), {}, "chain must have shape"),
        ((frames, np.zeros(4, int), chain, 1, seg), {"material": np.ones(4, int)}, "material"),
        ((frames, np.zeros(4, int), chain, 1, seg), {"frequency_hz": 0.0}, "frequency_hz"),
    ]
    for args, change, match in bad:
        with pytest.raises(TraceInputError, match=match):
            utd.chain_diffraction(*args, **{**ok, **change})


def _leg_end(p, t0, n0, e, phi, r, along):
    """The end of a leg from edge point ``p`` at azimuth ``phi`` from face 0, ``r`` m from the
    edge line and ``along`` m along it."""
    return p + r * (np.cos(phi) * t0 + np.sin(phi) * n0) + along * e


def test_validity_on_the_faces_and_for_any_wedge_angle() -> None:
    """diffraction_valid skips the azimuth where a leg is on face 0's side of the edge plane
    (``w . n0 >= 0``): the same verdicts as the full geometry for ends exactly in that plane
    (either sign of zero), within the snap angle of either face, just inside the wedge, and for
    exterior angles below pi as well (where that side is not all exterior)."""
    rng = np.random.default_rng(21)
    e, n0, nn, face0 = _random_wedges(rng, 12)
    base = utd.wedge_frames(e, n0, nn, face0)
    src_l, dst_l, pt_l, idx_l = [], [], [], []
    for w in range(12):
        ee, t0, nrm0 = base.edge_dir[w], base.face0_tangent[w], base.normal_0[w]
        p = rng.normal(size=3)
        # azimuths on face 0 (0, -0 offsets), face 0's plane behind the edge (pi), near the snap
        # angle of both faces, inside, and random; lengths and along-edge offsets random
        npi = base.n[w] * np.pi
        phis = [0.0, np.pi, -1e-10, 1e-10, -2e-9, npi, npi + 1e-10, npi + 2e-9,
                0.5 * (npi + 2 * np.pi), *rng.uniform(0, 2 * np.pi, 6)]
        for a in phis:
            for b in phis[::2]:
                src_l.append(_leg_end(p, t0, nrm0, ee, a, rng.uniform(1, 5), rng.normal()))
                dst_l.append(_leg_end(p, t0, nrm0, ee, b, rng.uniform(1, 5), rng.normal()))
                pt_l.append(p)
                idx_l.append(w)
    src, dst, point, idx = np.array(src_l), np.array(dst_l), np.array(pt_l), np.array(idx_l)
    # exactly in face 0's plane: w . n0 is +0.0 or -0.0 for legs along t0 (n0 has exact zeros)
    axis = utd.wedge_frames(np.array([[0.0, 0, 1]]), np.array([[0.0, 1, 0]]),
                            np.array([[1.0, 0, 0]]), np.array([[1.0, 0, 0]]))  # fmt: skip
    for n_value in (None, 0.5, 0.9, 1.0, 1.5, 2.0):
        frames = base if n_value is None else base._replace(n=np.full(12, n_value))
        got = utd.diffraction_valid(frames.take(idx), src, dst, point)
        ref = utd.framed_wedge_geometry(frames.take(idx), src, dst, point).valid
        assert np.array_equal(got, ref), n_value
        assert 0 < ref.sum() < len(ref) or n_value == 2.0  # (a half-plane has no inside)
        fr = axis if n_value is None else axis._replace(n=np.array([n_value]))
        s = np.array([[1.0, 0.0, 0.0], [1.0, -0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -0.0, 0.0],
                      [1.0, -1e-300, 0.0], [-1.0, 1e-300, 0.0]])  # fmt: skip
        d = np.tile([[0.3, 2.0, 1.0]], (len(s), 1))
        pts = np.zeros((len(s), 3))
        one = fr.take(np.zeros(len(s), dtype=int))
        assert np.array_equal(utd.diffraction_valid(one, s, d, pts),
                              utd.framed_wedge_geometry(one, s, d, pts).valid)  # fmt: skip
