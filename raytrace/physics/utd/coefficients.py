"""UTD wedge diffraction coefficients: the transition function and the scalar soft and hard
coefficients (Kouyoumjian-Pathak 1974; Luebbers 1984). Conventions: :mod:`raytrace.physics.utd`.

* :func:`transition_function` ``F(x)``, and ``G(x) = F(x) / sqrt(x)``
  (:func:`transition_over_sqrt`: the Faddeeva function near a boundary, :func:`g_faddeeva`, the
  large-argument series from :data:`X_SERIES` on, :func:`g_large1`);
* the four terms' ``cot(...) F(...)`` in a form finite at the boundaries (:func:`four_factors1`,
  :func:`wedge_factors`) and ``C (D1 + D2)``, ``C D3``, ``C D4`` (:func:`utd_terms`);
* :func:`utd_coefficients`: ``D_s``, ``D_h`` with the faces' scalar reflection coefficients.

The dyadic coefficient built from these terms is in :mod:`raytrace.physics.utd.operators`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import wofz

from ...core.errors import TraceInputError
from ...core.jit import carray as _c
from ...core.jit import inline, kernel
from ...core.vec import broadcast_rows

__all__ = ["X_SERIES", "C_NUMERATOR", "g_large1", "transition_over_sqrt", "g_faddeeva",
           "transition_function", "four_factors1", "wedge_factors", "reflection_pair", "utd_terms",
           "utd_coefficients"]

_TWO_PI = 2.0 * np.pi


#: From this argument on, ``G(x)`` is summed from the large-argument series of ``F``
#: (:func:`g_large1`) instead of the Faddeeva function: eleven terms, the first one left out is
#: below 7e-16 of ``F`` there.
X_SERIES = 100.0


#: Terms of the series (``m = 0 .. _SERIES_TERMS - 1``).
_SERIES_TERMS = 11


@inline
def g_large1(x):
    """``G(x) = F(x) / sqrt(x)`` for ``x >= X_SERIES`` from KP's large-argument series
    ``F(x) ~ sum_m (2m-1)!! (j / 2x)^m``, summed by Horner's rule in ``y^2 = (1 / 2x)^2``
    separately over the even (real) and odd (imaginary) terms."""
    y = 0.5 / x
    y2 = y * y
    re = 0.0
    im = 0.0
    # coefficients (2m-1)!! (-1)^floor(m/2), highest first
    top = _SERIES_TERMS - 1
    for m in range(top - top % 2, -1, -2):  # even m: (2m-1)!! (-1)^(m/2) y^m
        re = re * y2 + _DOUBLE_FACTORIAL[m] * (1.0 if m % 4 == 0 else -1.0)
    for m in range(top - (top + 1) % 2, 0, -2):  # odd m: (2m-1)!! (-1)^((m-1)/2) y^m
        im = im * y2 + _DOUBLE_FACTORIAL[m] * (1.0 if m % 4 == 1 else -1.0)
    im *= y
    r = np.sqrt(x)
    return complex(re / r, im / r)


#: (2m - 1)!! for m = 0 .. _SERIES_TERMS - 1 ((-1)!! = 1)
_DOUBLE_FACTORIAL = np.array([float(np.prod(np.arange(2 * m - 1, 0, -2))) for m in range(11)])


@kernel("c16[::1](f8[::1])")
def _g_series(x):
    """:func:`g_large1` over n arguments."""
    out = np.empty(len(x), dtype=np.complex128)
    for i in range(len(x)):
        out[i] = g_large1(x[i])
    return out


def transition_over_sqrt(x: np.ndarray) -> np.ndarray:
    """``G(x) = F(x) / sqrt(x)``, finite at 0: ``G(0) = sqrt(pi) exp(j pi/4)``.

    ``int_u^inf exp(-j t^2) dt = exp(-j u^2) (sqrt(pi)/2) exp(-j pi/4) w(u exp(j 3pi/4))`` with the
    Faddeeva function ``w(z) = exp(-z^2) erfc(-j z)`` (scipy.special.wofz), stable for all u >= 0:
    no cancellation between ``1/2`` and a Fresnel integral at large argument. From
    :data:`X_SERIES` on (most diffractions away from a shadow or reflection boundary), the
    large-argument series (:func:`g_large1`), about five times cheaper, agrees with it to about
    1e-15 relative.
    """
    x = np.asarray(x, dtype=float)
    flat = x.reshape(-1)
    out = np.empty(flat.shape, dtype=complex)
    large = flat >= X_SERIES
    if large.any():
        out[large] = _g_series(_c(flat[large]))
    near = np.flatnonzero(~large)
    if len(near):
        out[near] = g_faddeeva(flat[near])
    return out.reshape(x.shape)


def g_faddeeva(x: np.ndarray) -> np.ndarray:
    """``G(x)`` of :func:`transition_over_sqrt` from the Faddeeva function, (n,) -> (n,)."""
    u = np.sqrt(x)
    return np.sqrt(np.pi) * np.exp(0.25j * np.pi) * wofz(u * np.exp(0.75j * np.pi))


def transition_function(x: float | np.ndarray) -> np.ndarray:
    """UTD transition function ``F(x) = 2j sqrt(x) exp(jx) int_sqrt(x)^inf exp(-j t^2) dt``.

    Kouyoumjian and Pathak, Proc. IEEE 62(11), 1974. ``F -> 1`` for large x (the GTD limit),
    ``F ~ sqrt(pi x) exp(j (pi/4 + x))`` for small x.

    Parameters
    ----------
    x : float or (...) float array, >= 0

    Returns
    -------
    (...) complex128
    """
    x = np.asarray(x, dtype=float)
    if np.any(x < 0) or not np.all(np.isfinite(x)):
        raise TraceInputError("transition_function needs finite x >= 0")
    return np.sqrt(x) * transition_over_sqrt(x)


@inline
def _wedge_factor(beta, sign, n, kl):
    """``cot((pi + sign beta) / 2n) F(kL a^sign(beta))`` in a form finite at the boundaries,
    as ``(x, f)`` with the term ``= f G(x)`` (``G`` = :func:`transition_over_sqrt`).

    With ``N`` the integer nearest to ``(sign beta + pi) / (2 pi n)`` (KP's ``N^+`` for
    sign = +1, ``-N^-`` for sign = -1) and ``eps = pi + sign beta - 2 pi n N`` in ``[-n pi, n pi]``,
    exactly ``cot((pi + sign beta)/2n) = cot(eps/2n)`` and ``a^sign(beta) = 2 sin^2(eps/2)``, so
    the term is ``cot(eps/2n) sqrt(x) G(x)``, ``x = 2 kL sin^2(eps/2)``, ``G = F / sqrt(x)``, and
    ``cot(eps/2n) |sin(eps/2)| = sgn(eps) sin(eps/2) cos(eps/2n) / sin(eps/2n)`` (``sin(eps/2)``
    has the sign of ``eps`` for ``|eps| <= 2 pi``), so
    ``f = sgn(eps) sin(eps/2) cos(eps/2n) / sin(eps/2n) sqrt(2 kL)``; the ratio of the two sines
    is well conditioned and tends to ``n`` as eps -> 0 (``n`` at eps = 0). The term's limit for
    eps -> 0 is ``n sqrt(2 pi kL) sgn(eps) exp(j pi/4)`` (KP's boundary value); the jump of
    sgn(eps) is the one that cancels the jump of the geometrical-optics field. ``eps > 0`` is the
    side where that field is (the incident field at a shadow boundary, the reflected one at a
    reflection boundary), and exactly on the boundary (``eps = 0``) the term takes that side's
    value: there the tracer counts the geometrical-optics field (a ray that grazes an edge only
    touches it; a reflection point on a facet's edge is in the facet), so the total field is
    its limit from either side, half the geometrical-optics field.
    """
    big_n = np.rint((sign * beta + np.pi) / (_TWO_PI * n))
    eps = np.pi + sign * beta - _TWO_PI * n * big_n
    s = np.sin(0.5 * eps)
    x = 2.0 * kl * (s * s)
    a = eps / (2.0 * n)
    sa = np.sin(a)
    ratio = s * np.cos(a) / sa if sa != 0.0 else n
    return x, (1.0 if eps >= 0.0 else -1.0) * ratio * np.sqrt(2.0 * kl)


@inline
def four_factors1(n, phi, phi_in, kl):
    """:func:`_wedge_factor`'s ``(x, f)`` of ``D1``, ``D2`` (``beta = phi - phi'``, sign +1, -1)
    and ``D3``, ``D4`` (``beta = phi + phi'``) of one diffraction, flat."""
    b_m, b_p = phi - phi_in, phi + phi_in
    x1, f1 = _wedge_factor(b_m, 1.0, n, kl)
    x2, f2 = _wedge_factor(b_m, -1.0, n, kl)
    x3, f3 = _wedge_factor(b_p, 1.0, n, kl)
    x4, f4 = _wedge_factor(b_p, -1.0, n, kl)
    return x1, f1, x2, f2, x3, f3, x4, f4


@kernel("Tuple((f8[:, ::1], f8[:, ::1]))(f8[::1], f8[::1], f8[::1], f8[::1])")
def wedge_factors(n, phi, phi_in, kl):
    """:func:`_wedge_factor` of the four terms of P diffractions, (P, 4) each: ``D1``, ``D2``
    (``beta = phi - phi'``, sign +1, -1) and ``D3``, ``D4`` (``beta = phi + phi'``)."""
    p = len(n)
    x, f = np.empty((p, 4)), np.empty((p, 4))
    for r in range(p):
        (x[r, 0], f[r, 0], x[r, 1], f[r, 1], x[r, 2], f[r, 2], x[r, 3],
         f[r, 3]) = four_factors1(n[r], phi[r], phi_in[r], kl[r])  # fmt: skip
    return x, f


def reflection_pair(
    r: tuple[np.ndarray, np.ndarray] | None, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    if r is None:  # perfect conductor: R_soft = -1, R_hard = +1
        return np.full(shape, -1.0 + 0j), np.full(shape, 1.0 + 0j)
    soft, hard = r
    return (
        np.broadcast_to(np.asarray(soft, dtype=complex), shape),
        np.broadcast_to(np.asarray(hard, dtype=complex), shape),
    )


#: ``-exp(-j pi / 4)``, the numerator of KP's ``C`` (:func:`utd_terms`).
C_NUMERATOR = complex(-np.exp(-0.25j * np.pi))


def utd_terms(n, phi, phi_in, sin_beta0, distance_m, wavenumber):
    """``C (D1 + D2)``, ``C D3``, ``C D4`` of (D7) (broadcast, complex): the polarisation-free
    parts of the KP coefficient, before the face reflection coefficients multiply D3 and D4."""
    shape, (n, phi, phi_in, sin_beta0, dist, k) = broadcast_rows(
        *(np.asarray(v, dtype=float) for v in (n, phi, phi_in, sin_beta0, distance_m, wavenumber))
    )
    x, f = wedge_factors(n, phi, phi_in, k * dist)
    w = f * transition_over_sqrt(x)  # the four terms, one Faddeeva call for all
    c = C_NUMERATOR / (2.0 * n * np.sqrt(_TWO_PI * k) * sin_beta0)
    return (
        (c * (w[:, 0] + w[:, 1])).reshape(shape),
        (c * w[:, 2]).reshape(shape),
        (c * w[:, 3]).reshape(shape),
    )


def utd_coefficients(
    n: float | np.ndarray,
    phi: float | np.ndarray,
    phi_in: float | np.ndarray,
    sin_beta0: float | np.ndarray,
    distance_m: float | np.ndarray,
    wavenumber: float | np.ndarray,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Soft and hard UTD wedge diffraction coefficients (KP 1974; Luebbers 1984), scalar form.

    ``D = C [D1 + D2 + R_n D3 + R_0 D4]`` with ``C = -exp(-j pi/4) / (2n sqrt(2 pi k) sin beta0)``
    and ``D1 = cot((pi + (phi - phi'))/2n) F(kL a+(phi - phi'))``,
    ``D2 = cot((pi - (phi - phi'))/2n) F(kL a-(phi - phi'))``,
    ``D3 = cot((pi + (phi + phi'))/2n) F(kL a+(phi + phi'))``,
    ``D4 = cot((pi - (phi + phi'))/2n) F(kL a-(phi + phi'))``,
    ``a+-(beta) = 2 cos^2((2 n pi N+- - beta)/2)``, ``N+-`` the integers nearest to solving
    ``2 pi n N+- - beta = +-pi``. For a perfect conductor (``r_0 = r_n = None``) ``R = -1`` (soft)
    and ``+1`` (hard): KP's ``D_s,h = C [D1 + D2 -+ (D3 + D4)]``. Finite and continuous apart from
    the jumps at shadow and reflection boundaries that make the total field continuous.

    This is the two-dimensional (normal incidence on the edge) form: the caller chooses the angles
    at which ``R_0`` and ``R_n`` are taken (see :class:`~raytrace.physics.utd.WedgeGeometry`
    ``cos_theta_0/_n`` for the labelling-independent rule).
    :func:`~raytrace.physics.utd.diffracted_field` uses the same terms with the faces' reflection
    as 2 x 2 matrices (:func:`~raytrace.physics.utd.face_reflection_matrix`), exact at oblique
    incidence.

    Parameters
    ----------
    n : wedge parameter (exterior angle / pi)
    phi, phi_in : rad; ``phi`` (receiver) and ``phi'`` (source) from face 0, in ``[0, n pi]``
    sin_beta0 : sine of the angle between the incident ray and the edge
    distance_m : metres; distance parameter ``L`` (``s s' sin^2 beta0 / (s + s')`` for a
        spherical wave)
    wavenumber : rad/m; ``k = 2 pi f / c``
    r_0, r_n : (soft, hard) reflection coefficients of face 0 and face n, e.g. Fresnel
        ``(r_te, r_tm)`` at :attr:`raytrace.physics.utd.WedgeGeometry.cos_theta_0` /
        ``cos_theta_n``; None for a perfect conductor.

    Returns
    -------
    d_soft, d_hard : complex128 arrays (broadcast shape), sqrt(metres)
    """
    d12, d3, d4 = utd_terms(n, phi, phi_in, sin_beta0, distance_m, wavenumber)
    r0s, r0h = reflection_pair(r_0, d12.shape)
    rns, rnh = reflection_pair(r_n, d12.shape)
    return d12 + rns * d3 + r0s * d4, d12 + rnh * d3 + r0h * d4
