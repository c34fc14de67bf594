"""The UTD dyadic diffraction operator and the diffracted field. Conventions:
:mod:`raytrace.physics.utd`.

* :func:`face_reflection_matrix`: a face's Fresnel (or slab) reflection as a 2 x 2 matrix in the
  ray-fixed (``beta0``, ``phi``) components, exact at oblique incidence on the edge;
* :func:`diffraction_matrix`: the dyadic coefficient ``D = C(D1 + D2) I - C D3 T_n - C D4 T_0``
  and the spreading factor of P diffractions, which :func:`diffracted_field` applies to an
  incident field (KP for perfect conductors; for lossy faces Luebbers' heuristic with the face
  rule D8a, which makes the field independent of how the mesh labels the faces);
* :func:`chain_diffraction`: the same for the diffractions of a tracer's unfolded paths,
  compiled end to end around one Faddeeva call, with the faces' ITU-R P.2040 reflection.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...core.constants import C0
from ...core.errors import TraceInputError
from ...core.jit import carray as _c
from ...core.jit import inline, kernel
from ...core.vec import dot3
from ..materials import clipped_cos1, fresnel, reflection1
from .coefficients import (
    C_NUMERATOR,
    X_SERIES,
    four_factors1,
    g_faddeeva,
    g_large1,
    reflection_pair,
    utd_terms,
)
from .frames import WedgeFrame, WedgeGeometry, face_rule_cs1, legs1, ray_fixed1

__all__ = ["face_reflection_matrix", "DiffractedField", "diffraction_matrix", "diffracted_field",
           "ChainDiffraction", "chain_diffraction"]

_TWO_PI = 2.0 * np.pi


def face_reflection_matrix(
    r_te: np.ndarray, r_tm: np.ndarray, cos_beta: np.ndarray, psi: np.ndarray
) -> np.ndarray:
    """Reflection by a wedge face as a 2 x 2 matrix in ray-fixed edge components.

    Frame of the face: ``e_f`` along the edge, ``t_f`` in the face pointing away from the edge,
    ``n_f = e_f x t_f`` the outward normal (for face 0 of
    :func:`~raytrace.physics.utd.wedge_geometry` ``e_f = e``, for face n ``e_f = -e``). A ray on
    Keller's cone, ``s' = c e_f - s (cos psi t_f + sin psi n_f)`` (``c = cos beta``, signed,
    ``s = sin beta``; the source seen from the edge at in-plane angle ``psi`` from the face), is
    reflected into the specular ray. The Fresnel reflection
    (``E_r = R_TE (E . u) u + R_TM (E . p_i) p_r`` with ``u = s' x n_f / |s' x n_f|``,
    ``p = u x k``; P.2040 convention, as the tracer's reflections) written from the incident
    components ``(E . beta0'_hat, E . phi'_hat)`` to the reflected ray's ``(E . beta0_hat,
    E . phi_hat)`` (KP ray-fixed vectors) is, with ``m^2 = s^2 cos^2 psi + c^2`` (the squared
    sine of the incidence angle on the face)::

        T = 1/m^2 [[ -R_TE cos^2 psi + R_TM c^2 sin^2 psi,   -c sin psi cos psi (R_TE + R_TM) ],
                   [  c sin psi cos psi (R_TE + R_TM),        R_TE c^2 sin^2 psi - R_TM cos^2 psi ]]

    (docs/diffraction.md, (D8b)). A perfect conductor gives ``diag(1, -1)`` at any obliquity
    (KP's ``-+`` signs); at normal incidence on the edge (``c = 0``) ``diag(-R_TE, -R_TM)``
    (Luebbers' soft = TE, hard = TM); at oblique incidence a lossy face couples the two
    components. Reversing ``e_f`` together with the ray-fixed vectors leaves ``T`` unchanged.

    Parameters
    ----------
    r_te, r_tm : (P,) complex; Fresnel (or slab) coefficients at incidence cosine
        ``sin(beta) |sin(psi)|``
    cos_beta : (P,) float; ``s' . e_f`` (signed)
    psi : (P,) float, rad

    Returns
    -------
    (P, 2, 2) complex128; rows (beta0, phi) of the reflected ray, columns (beta0', phi') of the
    incident one
    """
    r_te, r_tm = np.asarray(r_te, dtype=complex), np.asarray(r_tm, dtype=complex)
    c, psi = np.asarray(cos_beta, dtype=float), np.asarray(psi, dtype=float)
    shape = np.broadcast(r_te, r_tm, c, psi).shape
    r_te, r_tm, c, psi = (np.broadcast_to(x, shape).reshape(-1) for x in (r_te, r_tm, c, psi))
    out = _face_matrices(_c(r_te, complex), _c(r_tm, complex), _c(c), _c(np.cos(psi)),
                         _c(np.sin(psi)))  # fmt: skip
    return out.reshape(shape + (2, 2))


@inline
def _face_matrix1(r_te, r_tm, c, cp, sp):
    """:func:`face_reflection_matrix` of one face, from ``cos psi``, ``sin psi``: its entries
    ``t00, t01, t10, t11`` (complex)."""
    cb2 = c * c
    m2 = (1.0 - cb2) * cp * cp + cb2
    # normal incidence on the face (m -> 0): R_TM = -R_TE there and T -> diag(-R_TE, -R_TM)
    if m2 < 1e-24:
        return -r_te, 0j, 0j, -r_tm
    inv = 1.0 / m2
    cross = c * sp * cp * (r_te + r_tm) * inv
    return ((-r_te * cp * cp + r_tm * cb2 * sp * sp) * inv, -cross, cross,
            (r_te * cb2 * sp * sp - r_tm * cp * cp) * inv)  # fmt: skip


@kernel("c16[:, :, ::1](c16[::1], c16[::1], f8[::1], f8[::1], f8[::1])")
def _face_matrices(r_te, r_tm, c, cp, sp):
    """:func:`_face_matrix1` over P rows, (P, 2, 2)."""
    out = np.empty((len(c), 2, 2), dtype=np.complex128)
    for r in range(len(c)):
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _face_matrix1(
            r_te[r], r_tm[r], c[r], cp[r], sp[r]
        )
    return out


@inline
def _dyadic1(r0_te, r0_tm, rn_te, rn_tm, cos_b, cp0, sp0, cpn, spn, d12, d3, d4):
    """The entries ``d00, d01, d10, d11`` of :func:`_dyadic`'s ``D`` of one diffraction."""
    a00, a01, a10, a11 = _face_matrix1(r0_te, r0_tm, cos_b, cp0, sp0)
    b00, b01, b10, b11 = _face_matrix1(rn_te, rn_tm, -cos_b, cpn, spn)
    return (-d3 * b00 - d4 * a00 + d12, -d3 * b01 - d4 * a01, -d3 * b10 - d4 * a10,
            -d3 * b11 - d4 * a11 + d12)  # fmt: skip


@kernel(
    "c16[:, :, ::1](c16[::1], c16[::1], c16[::1], c16[::1], f8[::1], f8[::1], f8[::1], f8[::1], "
    "f8[::1], c16[::1], c16[::1], c16[::1])"
)
def _dyadic(r0_te, r0_tm, rn_te, rn_tm, cos_b, cp0, sp0, cpn, spn, d12, d3, d4):
    """``D = C(D1 + D2) I - C D3 T_n - C D4 T_0`` of :func:`diffraction_matrix` over P rows
    (P, 2, 2): ``T_0`` of face 0 at ``cos_b``, ``T_n`` of face n at ``-cos_b``
    (:func:`_face_matrix1`, from ``cos psi``, ``sin psi`` of each face)."""
    out = np.empty((len(cos_b), 2, 2), dtype=np.complex128)
    for r in range(len(cos_b)):
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _dyadic1(
            r0_te[r], r0_tm[r], rn_te[r], rn_tm[r], cos_b[r], cp0[r], sp0[r], cpn[r], spn[r],
            d12[r], d3[r], d4[r],
        )
    return out


_F8, _F8_2 = "f8[::1]", "f8[:, ::1]"


@kernel(
    f"Tuple(({_F8_2}, {_F8_2}, c16[:, ::1], i8[::1], f8[:, :, ::1], c16[::1], {_F8_2}, {_F8}, "
    f"b1[::1], {_F8}))({_F8_2}, {_F8_2}, {_F8_2}, {_F8}, i8[::1], f8[:, :, ::1], i8, {_F8_2}, f8)"
)
def _chain_geometry(e, t0, n0, n, wedge, chain, j, seg_len, k):
    """The geometry of the diffraction at vertex ``j`` of P unfolded chains, and what the UTD
    coefficient needs of it (:func:`chain_diffraction`): the wedge factors ``x, f`` (P, 4) of
    :func:`~raytrace.physics.utd.coefficients.wedge_factors`, ``G(x)`` (P, 4) where
    ``x >= X_SERIES`` (:func:`g_large1`) and the flat indices of the others (for the Faddeeva function),
    the ray-fixed basis (P, 4, 3), KP's ``C`` (P,), per row ``cos_b``, ``cos psi_0``,
    ``sin psi_0``, ``cos psi_n``, ``sin psi_n``, ``cos_theta_0``, ``cos_theta_n`` (P, 7), the
    spreading ``A`` (P,), the validity and the incident leg's unfolded length ``s'`` along the path
    (P,).

    The unfolded source and receiver are recovered from the chain as
    :func:`raytrace.solver.diffraction.field_model` did in numpy (the path is straight on either
    side of the edge once unfolded), and each quantity is computed as
    :func:`raytrace.physics.utd.frames._geometry` and :func:`diffraction_matrix` compute it, in
    the same order."""
    p = len(wedge)
    x, f = np.empty((p, 4)), np.empty((p, 4))
    g = np.empty((p, 4), dtype=np.complex128)
    near = np.empty(4 * p, dtype=np.int64)
    n_near = 0
    basis = np.empty((p, 4, 3))
    c = np.empty(p, dtype=np.complex128)
    reals = np.empty((p, 7))
    spreading, s_path = np.empty(p), np.empty(p)
    valid = np.empty(p, dtype=np.bool_)
    sq = np.sqrt(_TWO_PI * k)
    for r in range(p):
        w = wedge[r]
        s_in = seg_len[r, 0]
        for i in range(1, j):
            s_in += seg_len[r, i]
        s_out = seg_len[r, j]
        for i in range(j + 1, seg_len.shape[1]):
            s_out += seg_len[r, i]
        px, py, pz = chain[r, j, 0], chain[r, j, 1], chain[r, j, 2]
        ax, ay, az = px - chain[r, j - 1, 0], py - chain[r, j - 1, 1], pz - chain[r, j - 1, 2]
        na = np.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / na, ay / na, az / na
        bx, by, bz = chain[r, j + 1, 0] - px, chain[r, j + 1, 1] - py, chain[r, j + 1, 2] - pz
        nb = np.sqrt(bx * bx + by * by + bz * bz)
        bx, by, bz = bx / nb, by / nb, bz / nb
        (ix, iy, iz, si, ox, oy, oz, so, pin, pout, cix, ciy, ciz, sin_in, cox, coy, coz,
         sin_out, ok) = legs1(e, t0, n0, n, w, px - s_in * ax, py - s_in * ay, pz - s_in * az,
                              px + s_out * bx, py + s_out * by, pz + s_out * bz, px, py, pz)  # fmt: skip
        (basis[r, 0, 0], basis[r, 0, 1], basis[r, 0, 2], basis[r, 1, 0], basis[r, 1, 1],
         basis[r, 1, 2], basis[r, 2, 0], basis[r, 2, 1], basis[r, 2, 2], basis[r, 3, 0],
         basis[r, 3, 1], basis[r, 3, 2]) = ray_fixed1(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz,
                                                      cox, coy, coz, sin_out)  # fmt: skip
        npi = n[w] * np.pi
        cp0, sp0 = face_rule_cs1(pin, pout, si, so)
        cpn, spn = face_rule_cs1(npi - pin, npi - pout, si, so)
        reals[r, 1], reals[r, 2], reals[r, 3], reals[r, 4] = cp0, sp0, cpn, spn
        reals[r, 5], reals[r, 6] = sin_in * sp0, sin_in * spn
        # diffraction_matrix: an invalid row gets harmless stand-ins
        g_in, g_out, sin_b = (si, so, sin_in) if ok else (1.0, 1.0, 1.0)
        nw, ph, ph_in = (n[w], pout, pin) if ok else (2.0, 0.0, 0.0)
        dist = g_in * g_out * (sin_b * sin_b) / (g_in + g_out)
        (x[r, 0], f[r, 0], x[r, 1], f[r, 1], x[r, 2], f[r, 2], x[r, 3],
         f[r, 3]) = four_factors1(nw, ph, ph_in, k * dist)  # fmt: skip
        for q in range(4):
            if x[r, q] >= X_SERIES:
                g[r, q] = g_large1(x[r, q])
            else:
                near[n_near] = 4 * r + q
                n_near += 1
        c[r] = C_NUMERATOR / (2.0 * nw * sq * sin_b)
        reals[r, 0] = dot3(ix, iy, iz, e[w, 0], e[w, 1], e[w, 2]) if ok else 0.0
        spreading[r] = np.sqrt(g_in / (g_out * (g_in + g_out)))
        valid[r] = ok
        s_path[r] = s_in
    return x, f, g, near[:n_near].copy(), basis, c, reals, spreading, valid, s_path


@kernel(
    "c16[:, :, ::1](f8[:, ::1], c16[:, ::1], c16[::1], f8[:, ::1], c16[::1], f8[::1], i8[::1], "
    "b1[::1], f8)"
)
def _chain_dyadic(f, g, c, reals, eta, thickness, material, two_sided, freq):
    """``D = C(D1 + D2) I - C D3 T_n - C D4 T_0`` (:func:`_dyadic`) of P diffractions from
    :func:`_chain_geometry`'s output and ``G(x)`` (P, 4), with each face's ITU-R P.2040
    reflection (:func:`raytrace.physics.materials.reflection1`: Fresnel for a solid's face, a
    slab for an open sheet's) at its incidence cosine."""
    out = np.empty((len(c), 2, 2), dtype=np.complex128)
    for r in range(len(c)):
        m = material[r]
        ct0, ctn = reals[r, 5], reals[r, 6]
        r0_te, r0_tm = reflection1(eta[m], clipped_cos1(ct0), two_sided[r], thickness[m], freq)
        rn_te, rn_tm = reflection1(eta[m], clipped_cos1(ctn), two_sided[r], thickness[m], freq)
        cr = c[r]
        d12 = cr * (f[r, 0] * g[r, 0] + f[r, 1] * g[r, 1])
        d3, d4 = cr * (f[r, 2] * g[r, 2]), cr * (f[r, 3] * g[r, 3])
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _dyadic1(
            r0_te, r0_tm, rn_te, rn_tm, reals[r, 0], reals[r, 1], reals[r, 2], reals[r, 3],
            reals[r, 4], d12, d3, d4,
        )
    return out


class ChainDiffraction(NamedTuple):
    """The diffractions of unfolded paths (:func:`chain_diffraction`), P rows.

    Attributes
    ----------
    d_matrix : (P, 2, 2) complex128, sqrt(metres), the dyadic coefficient (rows ``beta0_hat``,
        ``phi_hat`` of the diffracted ray, columns ``beta0'_hat``, ``phi'_hat`` of the incident
        one), as :func:`diffraction_matrix`
    basis : (P, 4, 3) float, ``beta0'_hat, phi'_hat, beta0_hat, phi_hat``
    spreading : (P,) float, 1/sqrt(metres), ``A = sqrt(s' / (s (s' + s)))`` (1 where not valid)
    valid : (P,) bool, as :attr:`WedgeGeometry.valid`
    s_in : (P,) float, metres, the unfolded incident leg ``s'`` along the path
    """

    d_matrix: np.ndarray
    basis: np.ndarray
    spreading: np.ndarray
    valid: np.ndarray
    s_in: np.ndarray


def chain_diffraction(
    frame: WedgeFrame,
    wedge: np.ndarray,
    chain: np.ndarray,
    j: int,
    seg_len: np.ndarray,
    frequency_hz: float,
    eta: np.ndarray,
    thickness_m: np.ndarray,
    material: np.ndarray,
    two_sided: np.ndarray,
) -> ChainDiffraction:
    """The UTD diffraction at vertex ``j`` of P unfolded vertex chains (a tracer's paths), in
    two compiled passes around the Faddeeva function:
    :func:`~raytrace.physics.utd.framed_wedge_geometry` and :func:`diffraction_matrix` with the
    faces' ITU-R P.2040 reflection coefficients at :attr:`WedgeGeometry.cos_theta_0` /
    ``cos_theta_n``, for the source and receiver unfolded
    along the chain (the path is straight on either side of the edge once unfolded: the source
    at ``s'`` = the length of the chain up to the edge, back along the incident segment).

    Parameters
    ----------
    frame : WedgeFrame, one row per wedge of the scene (:func:`~raytrace.physics.utd.wedge_frames`)
    wedge : (P,) int, the wedge of each diffraction
    chain : (P, k + 2, 3) float, metres, the transmitter, the vertices and the receiver
    j : int, 1..k, the vertex of the diffraction in the chain
    seg_len : (P, k + 1) float, metres, the chain's segment lengths
    frequency_hz : float
    eta : (n_materials,) complex, thickness_m : (n_materials,) float, m: the materials' relative
        permittivity and open-sheet thickness
    material : (P,) int, the wedge's material; two_sided : (P,) bool, the wedge is an open
        sheet's (its faces reflect as slabs)

    Returns
    -------
    ChainDiffraction

    Raises
    ------
    TraceInputError
        Shapes that do not match, ``j`` not a vertex of the chain, a wedge or material index
        out of range, a frequency that is not positive.
    """
    if not (np.isscalar(frequency_hz) and np.isfinite(frequency_hz) and frequency_hz > 0):
        raise TraceInputError(f"frequency_hz must be a positive number, got {frequency_hz!r}")
    chain, seg_len = np.asarray(chain, dtype=float), np.asarray(seg_len, dtype=float)
    wedge, material = np.asarray(wedge).reshape(-1), np.asarray(material).reshape(-1)
    p = len(wedge)
    if chain.ndim != 3 or chain.shape[0] != p or chain.shape[2] != 3:
        raise TraceInputError(f"chain must have shape ({p}, k + 2, 3), got {chain.shape}")
    if seg_len.shape != (p, chain.shape[1] - 1):
        raise TraceInputError(f"seg_len must have shape ({p}, {chain.shape[1] - 1}), got {seg_len.shape}")
    if not 1 <= int(j) <= chain.shape[1] - 2:
        raise TraceInputError(f"j must be a vertex of the chain (1..{chain.shape[1] - 2}), got {j}")
    if len(material) != p or np.shape(two_sided) != (p,):
        raise TraceInputError("material and two_sided need one value per diffraction")
    if p and (wedge.min() < 0 or wedge.max() >= len(frame.n)):
        raise TraceInputError(f"wedge indices must be in 0..{len(frame.n) - 1}")
    if p and (material.min() < 0 or material.max() >= len(eta) or len(eta) != len(thickness_m)):
        raise TraceInputError(f"material indices must be in 0..{len(eta) - 1} (one thickness each)")
    k = _TWO_PI * float(frequency_hz) / C0
    e, t0, n0, _, n = frame
    x, f, g, near, basis, c, reals, spreading, valid, s_in = _chain_geometry(
        _c(e), _c(t0), _c(n0), _c(n), _c(wedge, np.int64), _c(chain), int(j), _c(seg_len), k
    )
    if len(near):  # G(x) of the terms near a boundary: one Faddeeva call for all
        g.reshape(-1)[near] = g_faddeeva(x.reshape(-1)[near])
    d_mat = _chain_dyadic(f, g, c, reals, _c(eta, complex), _c(thickness_m),
                          _c(material, np.int64), _c(two_sided, bool), float(frequency_hz))  # fmt: skip
    return ChainDiffraction(d_mat, basis, spreading, valid, s_in)


class DiffractedField(NamedTuple):
    """Diffracted field of P candidates (see :func:`diffracted_field`).

    Attributes
    ----------
    field : (P, 3) complex128; field vector at ``dst`` (zero where not ``valid``)
    length_m : (P,) float, metres; unfolded path length ``s' + s``
    delay_s : (P,) float, seconds; ``(s' + s) / c``
    d_soft, d_hard : (P,) complex128, sqrt(metres); UTD coefficients ``D_s``, ``D_h`` (the
        diagonal of ``d_matrix``)
    d_matrix : (P, 2, 2) complex128, sqrt(metres); the dyadic coefficient in ray-fixed components,
        rows (beta0, phi) of the diffracted ray, columns (beta0', phi') of the incident one:
        ``[E_beta0, E_phi] = -d_matrix [E_beta0', E_phi'] A exp(-j k s)``; off-diagonal terms
        only for lossy faces at oblique incidence
    spreading : (P,) float, 1/sqrt(metres); ``A = sqrt(s' / (s (s' + s)))``
    valid : (P,) bool; as :attr:`WedgeGeometry.valid`
    """

    field: np.ndarray
    length_m: np.ndarray
    delay_s: np.ndarray
    d_soft: np.ndarray
    d_hard: np.ndarray
    d_matrix: np.ndarray
    spreading: np.ndarray
    valid: np.ndarray


def _fresnel_pair(eta: object, cos_theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r_te, r_tm, _, _ = fresnel(np.asarray(eta, dtype=complex), cos_theta)
    return np.asarray(r_te, dtype=complex), np.asarray(r_tm, dtype=complex)


def diffraction_matrix(
    geometry: WedgeGeometry,
    frequency_hz: float,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
    eta_0: complex | np.ndarray | None = None,
    eta_n: complex | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The dyadic diffraction coefficient and the spreading factor of :func:`diffracted_field`,
    which applies them to an incident field (arguments as there).

    Returns
    -------
    d_matrix : (P, 2, 2) complex128, sqrt(metres); ``D = C(D1 + D2) I - C D3 T_n - C D4 T_0``
        in ray-fixed components (rows ``beta0_hat``, ``phi_hat`` of the diffracted ray, columns
        ``beta0'_hat``, ``phi'_hat`` of the incident one); finite but meaningless where
        ``geometry.valid`` is False
    spreading : (P,) float, 1/sqrt(metres); ``A = sqrt(s' / (s (s' + s)))`` (1 where not valid)
    """
    g = geometry
    p = len(g)
    if not (np.isscalar(frequency_hz) and np.isfinite(frequency_hz) and frequency_hz > 0):
        raise TraceInputError(f"frequency_hz must be a positive number, got {frequency_hz!r}")
    k = _TWO_PI * float(frequency_hz) / C0
    if r_0 is None and eta_0 is not None:
        r_0 = _fresnel_pair(eta_0, g.cos_theta_0)
    if r_n is None and eta_n is not None:
        r_n = _fresnel_pair(eta_n, g.cos_theta_n)
    ok = g.valid
    s_in = np.where(ok, g.s_in, 1.0)
    s_out = np.where(ok, g.s_out, 1.0)
    sin_b = np.where(ok, g.sin_beta0, 1.0)
    dist = s_in * s_out * sin_b**2 / (s_in + s_out)
    d12, d3, d4 = utd_terms(
        np.where(ok, g.n, 2.0),
        np.where(ok, g.phi, 0.0),
        np.where(ok, g.phi_in, 0.0),
        sin_b,
        dist,
        k,
    )
    # each face's reflection in its own frame (e_f = e for face 0, -e for face n)
    cos_b = np.where(ok, np.einsum("ij,ij->i", g.s_hat_in, g.edge_dir), 0.0)
    faces = [_c(x, complex) for x in (*reflection_pair(r_0, (p,)), *reflection_pair(r_n, (p,)))]
    d_mat = _dyadic(*faces, _c(cos_b), _c(np.cos(g.psi_0)), _c(np.sin(g.psi_0)),
                    _c(np.cos(g.psi_n)), _c(np.sin(g.psi_n)), _c(d12, complex), _c(d3, complex),
                    _c(d4, complex))  # fmt: skip
    return d_mat, np.sqrt(s_in / (s_out * (s_in + s_out)))


def diffracted_field(
    geometry: WedgeGeometry,
    e_in: np.ndarray,
    frequency_hz: float,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
    eta_0: complex | np.ndarray | None = None,
    eta_n: complex | np.ndarray | None = None,
    phase: bool = True,
) -> DiffractedField:
    """Field diffracted by the edge towards the receiver (UTD, spherical incidence).

    ``[E_beta0, E_phi](dst) = -D [E_i . beta0'_hat, E_i . phi'_hat] A exp(-j k s)`` with the
    dyadic coefficient (ray-fixed components, KP 1974; Luebbers 1984 for lossy faces)

        ``D = C(D1 + D2) I - C D3 T_n - C D4 T_0``

    ``T_0``, ``T_n`` the faces' reflection matrices (:func:`face_reflection_matrix`, perfect
    conductor: ``diag(1, -1)``, which is KP's ``D_s,h = C[D1 + D2 -+ (D3 + D4)]``), evaluated per
    face at the angle ``psi_0`` / ``psi_n`` of :class:`WedgeGeometry` (the specular
    reflection off the face's plane between the two ends, D8a), ``A = sqrt(s' / (s (s' +
    s)))``, ``L = s s' sin^2(beta0) / (s + s')``. Continuous with the geometrical-optics field at
    both reflection boundaries, also at oblique incidence on lossy faces, and independent of which
    face the caller calls face 0.

    Parameters
    ----------
    geometry : WedgeGeometry
        From :func:`~raytrace.physics.utd.wedge_geometry`; ``s' = geometry.s_in`` is the
        (unfolded) incident length, ``s = geometry.s_out`` the diffracted one.
    e_in : (P, 3) complex
        Incident field vector at the diffraction point, in the tracer's normalisation (free-space
        field relative to the transmitted one, ``|E| = lambda / (4 pi d)`` at distance d from an
        isotropic source), including the phase ``exp(-j k s')`` and any reflection / penetration
        coefficients met before the edge. Its component along the incident ray is ignored.
    frequency_hz : float, Hz
    r_0, r_n : (TE, TM) pairs of (P,) complex, optional
        Reflection coefficients of face 0 and face n at ``geometry.cos_theta_0`` /
        ``cos_theta_n`` (P.2040 convention, ``R_TM -> +1`` for a perfect conductor). Use them
        for thin sheets (slab coefficients).
    eta_0, eta_n : complex or (P,) complex, optional
        Relative permittivities of the faces, used (through :func:`raytrace.physics.materials.fresnel`,
        half-space Fresnel coefficients) where ``r_0`` / ``r_n`` are not given. Neither given:
        perfect conductor (KP).
    phase : bool
        Include ``exp(-j k s)`` of the diffracted leg (default). False if the caller applies the
        phase of the whole unfolded length itself.

    Returns
    -------
    DiffractedField
        ``field (P, 3)`` at ``dst``; for a path reflected after the edge, ``dst`` is the image
        receiver, and the caller applies the reflection to this field. ``delay_s = (s' + s) / c``.
    """
    g = geometry
    p = len(g)
    e_in = np.asarray(e_in, dtype=complex)
    if e_in.shape != (p, 3):
        raise TraceInputError(f"e_in must have shape ({p}, 3), got {e_in.shape}")
    if not np.all(np.isfinite(e_in)):
        raise TraceInputError("e_in contains NaN or infinite values")
    d_mat, spreading = diffraction_matrix(g, frequency_hz, r_0=r_0, r_n=r_n, eta_0=eta_0,
                                          eta_n=eta_n)  # fmt: skip
    ok = g.valid
    length = g.s_in + g.s_out
    comp_in = np.stack(
        [np.einsum("ij,ij->i", e_in, g.beta_hat_in), np.einsum("ij,ij->i", e_in, g.phi_hat_in)],
        axis=1,
    )
    comp_out = -np.einsum("pij,pj->pi", d_mat, comp_in)
    k = _TWO_PI * float(frequency_hz) / C0
    amp = spreading * (np.exp(-1j * k * np.where(ok, g.s_out, 1.0)) if phase else 1.0)
    field = (comp_out[:, :1] * g.beta_hat_out + comp_out[:, 1:] * g.phi_hat_out) * amp[:, None]
    field = np.where(ok[:, None], field, 0.0)
    d_mat = np.where(ok[:, None, None], d_mat, 0.0)
    return DiffractedField(
        field=field,
        length_m=length,
        delay_s=length / C0,
        d_soft=d_mat[:, 0, 0].copy(),
        d_hard=d_mat[:, 1, 1].copy(),
        d_matrix=d_mat,
        spreading=np.where(ok, spreading, 0.0),
        valid=ok,
    )
