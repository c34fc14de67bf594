"""Sionna RT 2.2's diffraction coefficient transcribed to numpy (float64), and the antennas."""

from __future__ import annotations

import numpy as np

from raytrace.physics.utd import face_reflection_matrix, face_rule_angle, transition_function


def vpol(direction: np.ndarray) -> np.ndarray:
    """Vertical polarisation of an isotropic antenna for a ray along ``direction``: z made
    perpendicular to the ray (hallray's convention; Sionna's "V" is -theta_hat, the same vector
    up to a sign that cancels between the two ends)."""
    d = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    v = np.array([0.0, 0.0, 1.0]) - d[..., 2:3] * d
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


# exact solution of the perfectly conducting wedge for a point source (Biot-Tolstoy-Medwin)
def _rotator(k, s_cur, s_tgt):
    """Sionna's jones_matrix_rotator (utils/jones.py lines 70-91): components in the basis
    (s_cur, k x s_cur) -> (s_tgt, k x s_tgt)."""
    c = dot(s_cur, s_tgt)
    s = dot(k, np.cross(s_cur, s_tgt))
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], -2)


def sionna_d_terms(phi, phi_p, ext, beta0, ell, k):
    """The four diffraction terms D1..D4 of Kouyoumjian-Pathak as Sionna computes them (the
    cotangents times the transition function, in ``RadioMaterial._diffraction_matrix``), for the
    exterior angle ``ext`` = n pi, angles ``phi``, ``phi_p`` from face 0, obliquity ``beta0``,
    distance parameter ``ell`` (m) and wavenumber ``k`` (rad/m)."""
    n = ext / np.pi

    def a_pm(beta):
        n_p = np.round((beta + np.pi) / (2 * ext))
        n_m = np.round((beta - np.pi) / (2 * ext))
        return 2 * np.cos(ext * n_p - beta / 2) ** 2, 2 * np.cos(ext * n_m - beta / 2) ** 2

    a1, a2 = a_pm(phi - phi_p)
    a3, a4 = a_pm(phi + phi_p)
    fac = -np.exp(-0.25j * np.pi) / (2 * n * np.sqrt(2 * np.pi * k) * np.sin(beta0))

    def cf(psi, x):
        return np.cos(psi) / np.sin(psi) * transition_function(x)

    return (
        fac * cf((np.pi + phi - phi_p) / (2 * n), k * ell * a1),
        fac * cf((np.pi - (phi - phi_p)) / (2 * n), k * ell * a2),
        fac * cf((np.pi + phi + phi_p) / (2 * n), k * ell * a3),
        fac * cf((np.pi - (phi + phi_p)) / (2 * n), k * ell * a4),
    )


def sionna_diffraction_gain(tx, q, rx, e, na, nb, refl, k, grouping="sionna", faces="sionna"):
    """Gain of a diffracted path tx -> q -> rx as Sionna RT 2.2 computes it, in numpy float64.

    A transcription of ``RadioMaterial._diffraction_matrix``
    (sionna/rt/radio_materials/radio_material.py lines 997-1192) with the face labelling of
    ``sample_wedge_diffraction_point`` (utils/wedges.py line 276: face 0 is a face the source
    lights), the field calculator's spreading ``1/sqrt(s s' (s + s'))`` and ``lambda / sqrt(4 pi)``
    receive scaling (path_solvers/field_calculator.py lines 356-365, 425), and isotropic
    vertically polarised antennas at both ends.

    Parameters
    ----------
    tx, q, rx : (P, 3) float, m; transmitter, diffraction point, receiver
    e : (P, 3) float; edge direction with ``na x e`` pointing into face a
    na, nb : (P, 3) float; outward normals of the two faces
    refl : callable(cos_theta) -> (r_te, r_tm); the face's reflection coefficients
    k : float, rad/m
    grouping : "sionna" for ``R_0 (D1 - D4) + R_n (D2 - D3)`` (lines 1167-1176), or "kp" for
        Kouyoumjian-Pathak / Luebbers' ``-(D1 + D2) I + D4 R_0 + D3 R_n`` with the same matrices
    faces : "sionna" for Sionna's face matrices (the incident ray's reflection, and ``R_n = -I``
        when the source does not light face n, lines 1162-1165), or "d8a": hallray's, both faces
        at the angle of the face rule (D8a, the specular reflection between the two ends, each
        taken in front of the face) in the construction of
        :func:`raytrace.physics.utd.face_reflection_matrix`

    Returns
    -------
    (P,) complex, field ratio including exp(-j k (s + s'))
    """
    ki, ko = unit(q - tx), unit(rx - q)
    s_p, s = np.linalg.norm(q - tx, axis=1), np.linalg.norm(rx - q, axis=1)
    swap = dot(ki, na) > 0  # utils/wedges.py line 276
    n0 = np.where(swap[:, None], nb, na)
    nn = np.where(swap[:, None], na, nb)
    e = np.where(swap[:, None], -e, e)
    beta0 = np.arccos(np.clip(np.abs(dot(ki, e)), 0, 1))
    ext = 2 * np.pi - np.arccos(np.clip(-dot(n0, nn), -1, 1))
    t0 = unit(np.cross(n0, e))
    kip = unit(ki - dot(ki, e)[:, None] * e)
    kop = unit(ko - dot(ko, e)[:, None] * e)
    phi_p = (np.pi - np.arccos(np.clip(-dot(kip, t0), -1, 1))) * -np.sign(-dot(kip, n0)) + np.pi
    phi = (np.pi - np.arccos(np.clip(dot(kop, t0), -1, 1))) * -np.sign(dot(kop, n0)) + np.pi
    ell = s * s_p / (s + s_p) * np.sin(beta0) ** 2
    d1, d2, d3, d4 = sionna_d_terms(phi, phi_p, ext, beta0, ell, k)

    k_sb0 = ki - 2 * dot(ki, n0)[:, None] * n0
    k_sbn = unit(ki - 2 * dot(ki, nn)[:, None] * nn)
    phi_hat_p = unit(np.cross(ki, e))
    phi_sb0 = -unit(np.cross(k_sb0, e))
    phi_sbn = -unit(np.cross(k_sbn, e))
    phi_hat = -unit(np.cross(ko, e))
    es0, esn = unit(np.cross(ki, n0)), unit(np.cross(ki, nn))

    def face(k_sb, es, phi_sb, nrm):
        r_te, r_tm = refl(np.abs(dot(ki, nrm)))
        dia = np.zeros((len(ki), 2, 2), complex)
        dia[:, 0, 0], dia[:, 1, 1] = r_te, r_tm
        return _rotator(k_sb, es, phi_sb) @ dia @ _rotator(ki, phi_hat_p, es)

    r0 = face(k_sb0, es0, phi_sb0, n0)
    rn = face(k_sbn, esn, phi_sbn, nn)
    if faces == "sionna":
        rn[ext > np.pi + phi_p] = -np.eye(2)
    else:
        # D8a: each face reflects at the in-plane angle of the specular reflection off its plane
        # between the two ends (each mirrored in front of it); hallray's face matrix, reordered
        # from (beta0, phi) to Sionna's (phi, beta0) components; face n's edge direction is -e
        def d8a(a_in, a_out, sign):
            psi = face_rule_angle(a_in, a_out, s_p, s)
            r_te, r_tm = refl(np.sin(beta0) * np.abs(np.sin(psi)))
            return face_reflection_matrix(r_te, r_tm, dot(ki, sign * e), psi)[:, ::-1, ::-1]

        r0, rn = d8a(phi_p, phi, 1.0), d8a(ext - phi_p, ext - phi, -1.0)
    eye = np.broadcast_to(np.eye(2), r0.shape)
    if grouping == "sionna":
        jm = r0 * (d1 - d4)[:, None, None] + rn * (d2 - d3)[:, None, None]
    else:
        jm = -eye * (d1 + d2)[:, None, None] + r0 * d4[:, None, None] + rn * d3[:, None, None]
    e_in = vpol(ki)
    comp_in = np.stack([dot(e_in, phi_hat_p), dot(e_in, np.cross(ki, phi_hat_p))], 1)
    comp_out = np.einsum("pij,pj->pi", jm, comp_in)
    e_out = comp_out[:, :1] * phi_hat + comp_out[:, 1:] * np.cross(ko, phi_hat)
    lam = 2 * np.pi / k
    return (lam / (4 * np.pi) * dot(vpol(ko), e_out)
            * np.exp(-1j * k * (s + s_p)) / np.sqrt(s * s_p * (s + s_p)))


