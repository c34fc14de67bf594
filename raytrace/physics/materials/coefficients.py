"""Fresnel and slab coefficients and the slab's group delay (ITU-R P.2040-3 sections 2.2.1 and
2.2.2.2, section 3). Conventions: :mod:`raytrace.physics.materials`.

The coefficients are computed one row at a time by compiled scalar helpers (numba,
:mod:`raytrace.core.jit`: :func:`clipped_cos1`, :func:`interface1`, :func:`slab1`,
:func:`group_delay1`, :func:`reflection1`): the tracer's kernels call them for every reflection,
wedge face and penetration of a path, and the array functions (:func:`fresnel`,
:func:`fresnel_reflection`, :func:`face_reflection`, :func:`slab`, :func:`slab_group_delay`,
:func:`slab_excess_delay`) run them over their broadcast inputs, so that there is one
implementation of each formula.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from ...core.constants import C0
from ...core.errors import MaterialError
from ...core.jit import carray, inline, kernel
from ...core.vec import broadcast_rows

__all__ = ["clipped_cos1", "interface1", "slab1", "group_delay1", "reflection1", "fresnel",
           "fresnel_reflection", "face_reflection", "slab", "slab_group_delay",
           "slab_excess_delay"]


@inline
def clipped_cos1(c):
    """``|cos theta|`` clipped to 1, as every coefficient here takes the incidence cosine (the
    angle to the normal *line*; a NaN stays NaN, as with ``np.minimum``): a compiled scalar
    helper for kernels."""
    c = abs(c)
    return 1.0 if c > 1.0 else c


@inline
def _sqrt_decaying(z):
    """Complex square root on the branch ``Im <= 0`` (decaying ``exp(-j k0 s z)``, e^{j w t})."""
    s = np.sqrt(z)
    return -s if s.imag > 0 else s


@inline
def interface1(eta, c):
    """``r_te, r_tm`` of :func:`fresnel` of one row at ``c = |cos theta|`` (clipped to 1), and
    ``s``, ``cos + s``, ``eta cos + s`` (a compiled scalar helper for kernels). Only ``eta = 1``
    at exactly grazing incidence makes a denominator vanish: no interface at all, ``r = 0``."""
    s = _sqrt_decaying(eta - (1.0 - c * c))
    d_te = c + s
    d_tm = eta * c + s
    r_te = (c - s) / d_te if d_te != 0 else 0j
    r_tm = (eta * c - s) / d_tm if d_tm != 0 else 0j
    return r_te, r_tm, s, d_te, d_tm


@inline
def _expm1(z):
    """``exp(z) - 1`` of a complex ``z``, accurate for small ``|z|`` (numpy's formula)."""
    a = np.sin(0.5 * z.imag)
    return complex(np.expm1(z.real) * np.cos(z.imag) - 2.0 * a * a, np.exp(z.real) * np.sin(z.imag))


@inline
def _slab_pair(n, k, s, u, phase):
    """``R, T`` of :func:`slab` from ``N``, ``K`` of one polarisation (its docstring)."""
    den = k + n * n * u
    if den == 0:  # only without an interface (eta = 1 at grazing incidence)
        return 0j, phase
    inv = 1.0 / den
    # N (N + 2 s) = N D: D = cos + s = N + 2 s (TE), D = eta cos + s = N + 2 s (TM)
    return n * (n + 2.0 * s) * u * inv, k * phase * inv


@inline
def slab1(eta, c, d, f, p2040):
    """``R_te, R_tm, T_te, T_tm`` of :func:`slab` of one row at ``c = |cos theta|`` (clipped to
    1), thickness ``d`` (m), frequency ``f`` (Hz), ``T``'s phase reference P.2040's where
    ``p2040`` (a compiled scalar helper for kernels)."""
    if d == 0.0:
        return 0j, 0j, 1.0 + 0j, 1.0 + 0j
    s = _sqrt_decaying(eta - (1.0 - c * c))
    k0d = 2.0 * np.pi * f * d / C0
    q = k0d * s
    u = -_expm1(-2j * q)  # 1 - e^{-j2q}, accurate for a thin slab
    if p2040:
        phase = np.exp(-1j * q)
    else:
        # e^{-jq} e^{+j k0 d cos}: Im(s - cos) = Im(s) <= 0, so this never grows
        phase = np.exp(-1j * k0d * (s - c))
    r_te, t_te = _slab_pair(c - s, 4.0 * c * s, s, u, phase)
    r_tm, t_tm = _slab_pair(eta * c - s, 4.0 * eta * c * s, s, u, phase)
    return r_te, r_tm, t_te, t_tm


@inline
def group_delay1(eta, c, d, slope):
    """:func:`slab_group_delay` of one row at ``c = |cos theta|`` (clipped to 1), seconds (a
    compiled scalar helper for kernels)."""
    s = np.sqrt(eta - (1.0 - c * c))  # principal branch: Re(s) >= 0, Im(s) <= 0 for Im(eta) <= 0
    sl = slope / (2.0 * s) if s != 0 else 0j
    return d * ((s + sl).real - c) / C0


@inline
def reflection1(eta, c, two_sided, d, f):
    """``r_te, r_tm`` of a face at ``c = |cos theta|`` (clipped to 1): a closed solid's face is
    a half-space interface (:func:`interface1`), an open sheet (``two_sided``) a slab of
    thickness ``d`` (:func:`slab1`)."""
    if two_sided:
        r_te, r_tm, _, _ = slab1(eta, c, d, f, False)
        return r_te, r_tm
    r_te, r_tm, _, _, _ = interface1(eta, c)
    return r_te, r_tm


_C16 = "c16[::1]"


@kernel(f"Tuple(({_C16}, {_C16}, {_C16}, {_C16}))(c16[::1], f8[::1], b1)")
def _fresnel_rows(eta, cos, transmission):
    """:func:`fresnel` over n rows (``t_te``, ``t_tm`` left zero unless ``transmission``)."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    t_te, t_tm = np.zeros(n, np.complex128), np.zeros(n, np.complex128)
    for i in range(n):
        e, c = eta[i], clipped_cos1(cos[i])
        r_te[i], r_tm[i], _, d_te, d_tm = interface1(e, c)
        if transmission:
            t_te[i] = 2.0 * c / d_te if d_te != 0 else 1.0 + 0j
            t_tm[i] = 2.0 * _sqrt_decaying(e) * c / d_tm if d_tm != 0 else 1.0 + 0j
    return r_te, r_tm, t_te, t_tm


@kernel(f"Tuple(({_C16}, {_C16}, {_C16}, {_C16}))(c16[::1], f8[::1], f8[::1], f8[::1], b1)")
def _slab_rows(eta, cos, d, f, p2040):
    """:func:`slab` over n rows."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    t_te, t_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    for i in range(n):
        r_te[i], r_tm[i], t_te[i], t_tm[i] = slab1(eta[i], clipped_cos1(cos[i]), d[i], f[i],
                                                   p2040)  # fmt: skip
    return r_te, r_tm, t_te, t_tm


@kernel("f8[::1](c16[::1], f8[::1], f8[::1], c16[::1])")
def _group_delay_rows(eta, cos, d, slope):
    """:func:`slab_group_delay` over n rows."""
    out = np.empty(len(cos))
    for i in range(len(cos)):
        out[i] = group_delay1(eta[i], clipped_cos1(cos[i]), d[i], slope[i])
    return out


@kernel(f"Tuple(({_C16}, {_C16}))(c16[::1], f8[::1], i8[::1], f8[::1], b1[::1], f8)")
def _face_rows(eta, thickness, mat, cos, two_sided, f):
    """:func:`face_reflection` over n rows."""
    n = len(cos)
    r_te, r_tm = np.empty(n, np.complex128), np.empty(n, np.complex128)
    for i in range(n):
        m = mat[i]
        r_te[i], r_tm[i] = reflection1(eta[m], clipped_cos1(cos[i]), two_sided[i], thickness[m],
                                       f)  # fmt: skip
    return r_te, r_tm


def _out(x: np.ndarray) -> Any:
    """0-d arrays to numpy scalars, arrays unchanged."""
    return x[()] if x.ndim == 0 else x


def fresnel(eta: complex | np.ndarray, cos_theta: float | np.ndarray) -> tuple[Any, Any, Any, Any]:
    """Fresnel coefficients of a single air -> medium interface (P.2040-3 section 2.2.1).

    ``s = sqrt(eta - sin^2 theta)`` (branch ``Im(s) <= 0``);
    ``r_te = (cos - s) / (cos + s)``, ``r_tm = (eta cos - s) / (eta cos + s)``,
    ``t_te = 2 cos / (cos + s)``, ``t_tm = 2 sqrt(eta) cos / (eta cos + s)``: the interface
    coefficients of P.2040-3 section 2.2.1.1 with air as the incident medium (section 2.2.1.5).

    The coefficients are ratios of complex electric-field components in the TE (perpendicular) /
    TM (parallel) bases of P.2040-3 section 2.2.1: ``e_perp`` normal to the plane of incidence,
    common to all waves; ``e_par = e_perp x k_hat`` for each wave with its own direction. Hence
    ``r_tm(normal) = -r_te(normal) = (sqrt(eta) - 1) / (sqrt(eta) + 1)``; a perfect conductor has
    ``r_te = -1``, ``r_tm = +1``. For a reflection in a 3D tracer, build ``e_perp`` from
    ``k_i x n`` and ``e_par`` as above for the incident and the reflected direction and scale the two
    components by ``r_te`` and ``r_tm``.

    Parameters
    ----------
    eta : complex or (...) complex array
        Relative permittivity of the medium (``Im(eta) <= 0`` for a lossy one).
    cos_theta : float or (...) float array
        Cosine of the incidence angle to the surface normal; the sign is ignored (``|cos|``), values
        are clipped to 1. Broadcasts with ``eta``.

    Returns
    -------
    r_te, r_tm, t_te, t_tm : complex128 (broadcast shape of the inputs)
    """
    shape, (e, c) = broadcast_rows(np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float))
    return tuple(_out(x.reshape(shape)) for x in _fresnel_rows(e, c, True))


def fresnel_reflection(eta: complex | np.ndarray, cos_theta: float | np.ndarray) -> tuple[Any, Any]:
    """``r_te, r_tm`` of :func:`fresnel` alone (the same arithmetic, without the transmission
    coefficients and their square root): what a reflection needs."""
    shape, (e, c) = broadcast_rows(np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float))
    r_te, r_tm, _, _ = _fresnel_rows(e, c, False)
    return _out(r_te.reshape(shape)), _out(r_tm.reshape(shape))


def face_reflection(
    eta: np.ndarray,
    thickness_m: np.ndarray,
    material: np.ndarray,
    cos_theta: np.ndarray,
    two_sided: np.ndarray,
    frequency_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """TE/TM reflection coefficients of faces: a closed solid's face is a half-space interface
    (:func:`fresnel`), an open sheet a slab of its material's thickness (:func:`slab`,
    ITU-R P.2040-3 section 2.2.2.2).

    Parameters
    ----------
    eta : (n_materials,) complex, relative permittivity of each material
    thickness_m : (n_materials,) float, m, slab thickness of each material
    material : (n,) int, the material of each face
    cos_theta : (n,) float, cosine of the incidence angle (sign ignored, clipped to 1)
    two_sided : (n,) bool, the face is an open sheet's
    frequency_hz : float, Hz

    Returns
    -------
    r_te, r_tm : (n,) complex128

    Raises
    ------
    MaterialError
        Tables of different lengths, a material index outside them, per-face arrays of
        different lengths.
    """
    eta, thickness = carray(eta, complex).reshape(-1), carray(thickness_m).reshape(-1)
    material = carray(material, np.int64).reshape(-1)
    cos, sheet = carray(cos_theta).reshape(-1), carray(two_sided, bool).reshape(-1)
    if len(eta) != len(thickness):
        raise MaterialError(f"{len(eta)} permittivities but {len(thickness)} thicknesses")
    if not len(material) == len(cos) == len(sheet):
        raise MaterialError("material, cos_theta and two_sided need one value per face")
    if len(material) and (material.min() < 0 or material.max() >= len(eta)):
        raise MaterialError(f"material indices must be in 0..{len(eta) - 1}")
    return _face_rows(eta, thickness, material, cos, sheet, float(frequency_hz))


def slab(
    eta: complex | np.ndarray,
    cos_theta: float | np.ndarray,
    thickness_m: float | np.ndarray,
    frequency_hz: float | np.ndarray,
    *,
    reference: Literal["free_space", "p2040"] = "free_space",
) -> tuple[Any, Any, Any, Any]:
    """Reflection and transmission of a homogeneous slab in air (P.2040-3 section 2.2.2.2).

    With ``R'`` the interface coefficient of :func:`fresnel` (TE or TM), ``s = sqrt(eta - sin^2)``
    and ``q = (2 pi d / lambda) s``:

        ``R = R' (1 - e^{-j2q}) / (1 - R'^2 e^{-j2q})``,
        ``T = (1 - R'^2) e^{-jq} / (1 - R'^2 e^{-j2q})``.

    They are evaluated in a form that never divides by ``cos + s`` and never forms ``1 - R'^2`` by
    cancellation: with ``N = cos - s`` (TE) or ``eta cos - s`` (TM), ``K = 4 cos s`` (TE) or
    ``4 eta cos s`` (TM), ``u = 1 - e^{-j2q}`` (``expm1``),
    ``R = N (N + 2 s) u / (K + N^2 u)``, ``T = K e^{-jq} / (K + N^2 u)``. Because ``Im(q) <= 0``,
    ``|e^{-jq}| <= 1``: a thick lossy (or metal) slab gives ``T -> 0`` and ``R -> R'`` without
    overflow or NaN. ``thickness_m == 0`` gives exactly ``R = 0``, ``T = 1``.

    Phase reference of ``T``
        ``reference="p2040"`` returns ``T`` as printed in P.2040: the transmitted field at the exit face
        relative to the incident field at the entry face, at the same position along the surface
        (the two points a normal apart). ``reference="free_space"`` (default) returns
        ``T * exp(+j k0 d cos theta)``: the transmitted field relative to the field that would be at
        the same point without the slab. That is the factor a tracer multiplies into the free-space
        term computed over the full unfolded straight path (air slab: ``T == 1``). The two differ
        only in phase. ``R`` is referenced to the front face in both cases (image method).

    Parameters
    ----------
    eta : complex or (...) complex array
        Relative permittivity of the slab.
    cos_theta : float or (...) float array
        Cosine of the incidence angle (sign ignored, clipped to 1).
    thickness_m : float or (...) float array, m
        Slab thickness ``d >= 0``.
    frequency_hz : float or (...) float array, Hz
    reference : {"free_space", "p2040"}
        Phase reference of ``T`` (see above).

    Returns
    -------
    R_te, R_tm, T_te, T_tm : complex128, broadcast shape of the inputs
        Field ratios in the bases of :func:`fresnel` (air on both sides, so ``|R|^2 + |T|^2`` is
        the power balance: 1 for a lossless slab, < 1 for a lossy one).

    Raises
    ------
    MaterialError
        Negative or non-finite thickness, non-positive frequency, unknown ``reference``.
    """
    if reference not in ("free_space", "p2040"):
        raise MaterialError(f"slab reference must be 'free_space' or 'p2040', got {reference!r}")
    d = np.asarray(thickness_m, dtype=float)
    f = np.asarray(frequency_hz, dtype=float)
    if np.any(~np.isfinite(d) | (d < 0)):
        raise MaterialError("slab thickness must be finite and >= 0 m")
    if np.any(~np.isfinite(f) | (f <= 0)):
        raise MaterialError("slab frequency must be finite and > 0 Hz")
    shape, (e, c, dd, ff) = broadcast_rows(np.asarray(eta, dtype=complex),
                                           np.asarray(cos_theta, dtype=float), d, f)  # fmt: skip
    out = _slab_rows(e, c, dd, ff, reference == "p2040")
    return tuple(_out(x.reshape(shape)) for x in out)


def slab_group_delay(
    eta: complex | np.ndarray,
    cos_theta: float | np.ndarray,
    thickness_m: float | np.ndarray,
    eta_slope: complex | np.ndarray = 0.0,
) -> Any:
    """Group delay of the ray straight through a slab, relative to free space over the same line.

    The through-ray carries ``exp(-j k0 d (s - cos theta))`` with ``s = sqrt(eta - sin^2 theta)``
    (the phase of :func:`slab`'s ``T`` with ``reference="free_space"``, without the interface
    factors); its group delay ``-d phase / d omega`` is

        ``tau = (d / c) [Re(s + f (d eta / d f) / (2 s)) - cos theta]``,

    since ``d(omega s)/d omega = s + omega (d s / d omega)`` and ``d s / d eta = 1 / (2 s)``. With
    ``eta`` real and constant it is the optical path excess ``d (n cos theta_t - cos theta) / c`` of
    geometric optics. Multiple internal reflections (Fabry-Perot ripple, damped out in any lossy
    wall) are neglected.

    Parameters
    ----------
    eta : complex or (...) complex array, relative permittivity of the slab
    cos_theta : float or (...) float array, cosine of the incidence angle (sign ignored, <= 1)
    thickness_m : float or (...) float array, m
    eta_slope : complex or (...) complex array
        ``f d eta / d f`` at the carrier
        (:meth:`~raytrace.physics.materials.Material.permittivity_slope`); 0 for a
        frequency-independent permittivity.

    Returns
    -------
    tau : float or (...) float64, seconds (>= 0 for the building materials of P.2040)
    """
    shape, (e, c, d, s) = broadcast_rows(
        np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float),
        np.asarray(thickness_m, dtype=float), np.asarray(eta_slope, dtype=complex),
    )
    return _out(_group_delay_rows(e, c, d, s).reshape(shape))


def slab_excess_delay(
    eta: complex | np.ndarray, cos_theta: float | np.ndarray, thickness_m: float | np.ndarray
) -> Any:
    """Extra delay of the ray straight through a slab, relative to free space over the same line.

    ``tau = d (Re sqrt(eta' - sin^2 theta) - cos theta) / c`` (optical path ``d (n cos theta_t -
    cos theta)`` of geometric optics). It is the group delay of the through-ray when ``eta'`` does not
    depend on frequency (all P.2040-3 building materials except the grounds have ``b = 0``) and
    the slab is lossless; :func:`slab_group_delay` is the general form (loss and dispersion), of
    which this is the limit for ``Im(eta) = 0``.

    Parameters
    ----------
    eta : complex or (...) complex array
        Slab permittivity (only ``Re(eta)`` is used).
    cos_theta : float or (...) float array
        Cosine of the incidence angle (sign ignored, clipped to 1).
    thickness_m : float or (...) float array, m

    Returns
    -------
    tau : float or (...) float64, seconds (>= 0 for ``eta' >= 1``)
    """
    return slab_group_delay(np.real(np.asarray(eta, dtype=complex)), cos_theta, thickness_m)
