"""Tests of raytrace.physics.materials against closed forms and independent computations.

Independent references used here:
* the P.2040-3 Table 3 power laws evaluated by hand;
* 3D boundary conditions (continuity of tangential E and H) for the interface coefficients, with
  the field vectors built explicitly in the stated TE/TM basis;
* a characteristic-matrix (transfer-matrix) solution of a single layer, derived from the wave
  equation in the layer, not from Fresnel coefficients;
* geometric optics (Snell's law and path lengths) for the excess delay of a slab.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from raytrace.core.constants import C0, EPS0
from raytrace.core.errors import HallrayError, MaterialError
from raytrace.physics.materials import (
    DEFAULT_USER_THICKNESS_M,
    ExtrapolationWarning,
    Material,
    MaterialLibrary,
    face_reflection,
    fresnel,
    fresnel_reflection,
    permittivity,
    slab,
    slab_excess_delay,
    slab_group_delay,
)

F_C = 3.775e9  # C-band carrier of the paper, Hz
F_MM = 26.85e9  # mmWave carrier of the paper, Hz

PERMITTIVITY_RTOL = 1e-12  # evaluation of the same closed form in another order
COEFF_TOL = 1e-12  # Fresnel / slab closed forms, absolute on unit-order complex numbers
METAL_TOL = 1e-3  # metal -> perfect conductor limit (issue's tolerance)
ENERGY_TOL = 1e-12  # |R|^2 + |T|^2 = 1 for a lossless slab
TMM_TOL = 1e-10  # slab formula vs characteristic matrix (2x2 solve, cos/sin of complex phase)
BOUNDARY_TOL = 1e-12  # tangential field continuity residual
GRAZING_TOL = 1e-6  # r_te -> -1 as cos(theta) -> 0
DELAY_TOL_S = 1e-18  # excess delay, seconds (values ~1e-9 s)
THICK_T_MAX = 1e-20  # |T| of a slab many skin depths thick
GROUP_DELAY_RTOL = 1e-7  # closed-form group delay vs central difference of the phase (h^2 error)
WALL_GROUP_DELAY_RTOL = 0.01  # single-pass group delay vs the full slab T of a thick lossy wall

ITU_NAMES = {
    "concrete",
    "brick",
    "plasterboard",
    "wood",
    "glass",
    "ceiling_board",
    "chipboard",
    "plywood",
    "marble",
    "floorboard",
    "metal",
    "very_dry_ground",
    "medium_dry_ground",
    "wet_ground",
}


@pytest.fixture(scope="module")
def itu() -> MaterialLibrary:
    return MaterialLibrary.itu()


# --------------------------------------------------------------------------------------------------
# Table and permittivity
# --------------------------------------------------------------------------------------------------
def test_itu_table_names_thicknesses_and_ranges(itu):
    assert set(itu.names) == ITU_NAMES
    assert len(itu) == 14
    thickness = {
        "concrete": 0.2,
        "brick": 0.1,
        "plasterboard": 0.0125,
        "wood": 0.03,
        "glass": 0.01,
        "ceiling_board": 0.015,
        "chipboard": 0.02,
        "plywood": 0.02,
        "marble": 0.03,
        "floorboard": 0.02,
        "metal": 0.002,
        "very_dry_ground": 1.0,
        "medium_dry_ground": 1.0,
        "wet_ground": 1.0,
    }
    for name, t in thickness.items():
        assert itu[name].thickness_m == t
    ranges_ghz = {
        "concrete": (1, 100),
        "brick": (1, 40),
        "wood": (0.001, 100),
        "glass": (0.1, 100),
        "plywood": (1, 40),
        "marble": (1, 60),
        "floorboard": (50, 100),
        "wet_ground": (1, 10),
    }
    for name, (lo, hi) in ranges_ghz.items():
        assert itu[name].f_min_hz == pytest.approx(lo * 1e9, rel=1e-15)
        assert itu[name].f_max_hz == pytest.approx(hi * 1e9, rel=1e-15)
    assert "P.2040-3" in itu["concrete"].source


def test_concrete_permittivity_at_c_band():
    eta = permittivity("concrete", F_C)
    sigma = 0.0462 * 3.775**0.7822
    assert isinstance(eta, complex)
    assert eta.real == pytest.approx(5.24, rel=PERMITTIVITY_RTOL)
    assert eta.imag == pytest.approx(-sigma / (2 * np.pi * F_C * EPS0), rel=PERMITTIVITY_RTOL)
    # The P.2040 shorthand eta'' = 17.98 sigma / f_GHz (4 significant digits).
    assert -eta.imag == pytest.approx(17.98 * sigma / 3.775, rel=1e-3)
    assert MaterialLibrary.itu()["concrete"].properties(F_C) == pytest.approx((5.24, sigma))


def test_power_law_with_nonzero_exponent_b():
    f_ghz = 5.0
    eta_r, sigma = MaterialLibrary.itu()["medium_dry_ground"].properties(f_ghz * 1e9)
    assert eta_r == pytest.approx(15 * f_ghz**-0.1, rel=PERMITTIVITY_RTOL)
    assert sigma == pytest.approx(0.035 * f_ghz**1.63, rel=PERMITTIVITY_RTOL)


def test_permittivity_vectorised_over_frequency():
    f = np.array([[1e9, 3.775e9], [26.85e9, 100e9]])
    eta = permittivity("glass", f)
    assert eta.shape == f.shape and eta.dtype == np.complex128
    for idx in np.ndindex(f.shape):
        assert eta[idx] == pytest.approx(permittivity("glass", float(f[idx])), rel=1e-15)


def test_metal_is_a_very_good_conductor():
    eta = permittivity("metal", F_C)
    assert eta.real == 1.0
    assert -eta.imag == pytest.approx(1e7 / (2 * np.pi * F_C * EPS0), rel=PERMITTIVITY_RTOL)


def test_out_of_range_frequency_is_a_one_line_error():
    with pytest.raises(MaterialError) as exc:
        permittivity("floorboard", F_C)
    msg = str(exc.value)
    assert "\n" not in msg
    assert "floorboard" in msg and "3.775 GHz" in msg and "50-100 GHz" in msg
    with pytest.raises(MaterialError, match="very_dry_ground.*26.85"):
        permittivity("very_dry_ground", np.array([2e9, F_MM]))
    assert issubclass(MaterialError, HallrayError)


def test_extrapolation_warns_and_evaluates_the_power_law():
    assert issubclass(ExtrapolationWarning, UserWarning)
    with pytest.warns(ExtrapolationWarning, match="floorboard.*50-100 GHz") as rec:
        eta = permittivity("floorboard", F_C, extrapolate=True)
    assert rec[0].filename == __file__  # points at the caller, not at the library
    sigma = 0.0044 * 3.775**1.3515
    assert eta == pytest.approx(3.66 - 1j * sigma / (2 * np.pi * F_C * EPS0), rel=1e-14)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        permittivity("concrete", F_C, extrapolate=True)  # in range: no warning
        permittivity("concrete", 1e9)  # range boundaries are inclusive
        permittivity("concrete", 100e9)


@pytest.mark.parametrize("freq", [0.0, -1e9, np.nan, np.inf])
def test_bad_frequency_is_rejected(freq):
    with pytest.raises(MaterialError, match="frequency"):
        permittivity("wood", freq, extrapolate=True)


# --------------------------------------------------------------------------------------------------
# Single interface
# --------------------------------------------------------------------------------------------------
ETAS = [4.0, 2.5 - 0.0j, 5.24 - 0.6218j, 6.31 - 0.1j, 1.48 - 0.004j, 30.0 - 20.0j]


@pytest.mark.parametrize("eta", ETAS + [permittivity("metal", F_C)])
def test_fresnel_normal_incidence(eta):
    r_te, r_tm, t_te, t_tm = fresnel(eta, 1.0)
    n = np.sqrt(complex(eta))
    expected = (1 - n) / (1 + n)
    assert abs(r_te - expected) < COEFF_TOL
    assert abs(r_tm + expected) < COEFF_TOL  # r_tm(normal) = -r_te(normal) in this basis
    assert abs(t_te - 2 / (1 + n)) < COEFF_TOL
    assert abs(t_tm - 2 / (1 + n)) < COEFF_TOL


def test_metal_reflects_like_a_perfect_conductor():
    eta = permittivity("metal", F_C)
    cos = np.array([1.0, 0.9, 0.5, 0.2, 0.05])
    r_te, r_tm, _, _ = fresnel(eta, cos)
    np.testing.assert_allclose(r_te, -1.0, atol=METAL_TOL)
    # PEC: tangential E vanishes -> r_tm = +1 with e_par = e_perp x k_hat (away from grazing).
    np.testing.assert_allclose(r_tm[:3], 1.0, atol=METAL_TOL)
    assert np.all(np.isfinite(r_tm))


@pytest.mark.parametrize("eta", [1.5, 4.0, 6.31, 7.074])
def test_brewster_angle_of_lossless_dielectric(eta):
    theta_b = np.arctan(np.sqrt(eta))
    _, r_tm, _, _ = fresnel(eta, np.cos(theta_b))
    assert abs(r_tm) < COEFF_TOL
    # And r_tm changes sign through the Brewster angle (real for a lossless medium).
    _, r_lo, _, _ = fresnel(eta, np.cos(theta_b - 0.1))
    _, r_hi, _, _ = fresnel(eta, np.cos(theta_b + 0.1))
    assert r_lo.real > 0 > r_hi.real


@pytest.mark.parametrize("eta", [5.24 - 0.6218j, 4.0, permittivity("metal", F_C)])
def test_grazing_incidence_gives_minus_one(eta):
    r_te, r_tm, t_te, _ = fresnel(eta, np.array([1e-9, 0.0]))
    np.testing.assert_allclose(r_te, -1.0, atol=GRAZING_TOL)
    assert abs(r_te[1] + 1) < COEFF_TOL and abs(r_tm[1] + 1) < COEFF_TOL and t_te[1] == 0.0


def test_fresnel_ignores_sign_of_cos_and_broadcasts():
    eta = np.array([[4.0], [5.24 - 0.6j], [6.31 - 0.1j]])  # (3, 1)
    cos = np.linspace(0.05, 1.0, 5)  # (5,)
    out = fresnel(eta, cos)
    out_neg = fresnel(eta, -cos)
    for a, b in zip(out, out_neg, strict=True):
        assert a.shape == (3, 5)
        np.testing.assert_array_equal(a, b)
    for i in range(3):
        for j in range(5):
            single = fresnel(complex(eta[i, 0]), float(cos[j]))
            for arr, val in zip(out, single, strict=True):
                assert arr[i, j] == val


def test_fresnel_reflection_is_fresnels_r_bitwise():
    """The reflection-only form the tracer uses gives fresnel's r_te, r_tm to the bit, at
    grazing and normal incidence, for eta = 1 (no interface) and for scalars."""
    eta = np.array([[4.0], [5.24 - 0.6j], [1.0 + 0j], [1e7 - 1e8j]])  # (4, 1)
    cos = np.concatenate([[0.0, 1e-9, 1.0, -0.3], np.linspace(0.01, 0.99, 50)])
    r_te, r_tm, _, _ = fresnel(eta, cos)
    got_te, got_tm = fresnel_reflection(eta, cos)
    assert got_te.shape == (4, 54)
    np.testing.assert_array_equal(got_te, r_te)
    np.testing.assert_array_equal(got_tm, r_tm)
    assert fresnel_reflection(4.0, 0.5) == fresnel(4.0, 0.5)[:2]


def test_face_reflection_is_fresnel_on_solids_and_the_slab_on_sheets_bitwise():
    """The tracer's per-face coefficients (material indices into tables): a solid's face is
    fresnel's interface, an open sheet the slab of its material's thickness, to the bit; the
    written-out interface formula agrees to rounding."""
    eta = np.array([4.0 + 0j, 5.24 - 0.6j, 1.0 + 0j, 1e7 - 1e8j])
    thick = np.array([0.1, 0.25, 0.01, 0.002])
    rng = np.random.default_rng(5)
    n = 400
    mat = rng.integers(0, 4, n)
    cos = np.concatenate([[0.0, 1e-9, 1.0, -0.3, 1.2], rng.uniform(-1, 1, n - 5)])
    sheet = rng.uniform(size=n) < 0.5
    got_te, got_tm = face_reflection(eta, thick, mat, cos, sheet, F_C)
    f_te, f_tm, _, _ = fresnel(eta[mat], cos)
    s_te, s_tm, _, _ = slab(eta[mat], cos, thick[mat], F_C)
    np.testing.assert_array_equal(got_te, np.where(sheet, s_te, f_te))
    np.testing.assert_array_equal(got_tm, np.where(sheet, s_tm, f_tm))
    # fresnel against its formula in numpy (branch Im(s) <= 0), away from eta = 1 at grazing
    c = np.minimum(np.abs(cos), 1.0)
    s = np.sqrt(eta[mat] - (1 - c**2))
    s = np.where(s.imag > 0, -s, s)
    ok = np.abs(c + s) > 1e-6
    c, s, e_c = c[ok], s[ok], (eta[mat] * c)[ok]  # the formula only where it is defined
    np.testing.assert_allclose(f_te[ok], (c - s) / (c + s), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(f_tm[ok], (e_c - s) / (e_c + s), rtol=1e-14, atol=1e-15)
    # NaN in, NaN out (not a clipped cosine)
    assert np.isnan(fresnel(4.0, np.nan)[0])
    # an index outside the tables, or tables that do not match: one-line errors
    with pytest.raises(MaterialError, match="material indices"):
        face_reflection(eta, thick, np.array([4]), cos[:1], sheet[:1], F_C)
    with pytest.raises(MaterialError, match="thicknesses"):
        face_reflection(eta, thick[:2], mat, cos, sheet, F_C)
    with pytest.raises(MaterialError, match="one value per face"):
        face_reflection(eta, thick, mat, cos[:3], sheet, F_C)


def _field_vectors(eta: complex, theta: float):
    """Unit vectors of the stated basis: e_perp common, e_par = e_perp x k for each wave.

    Interface z = 0, air below (z < 0), medium above; plane of incidence x-z.
    Returns e_perp, (k_i, e_par_i), (k_r, e_par_r), (kappa_t, e_par_t) where kappa_t is the
    transmitted wave vector divided by k0 (complex) and e_par_t uses kappa_t / sqrt(eta).
    """
    s = np.sqrt(complex(eta) - np.sin(theta) ** 2)
    if s.imag > 0:
        s = -s
    k_i = np.array([np.sin(theta), 0.0, np.cos(theta)], dtype=complex)
    k_r = np.array([np.sin(theta), 0.0, -np.cos(theta)], dtype=complex)
    kappa_t = np.array([np.sin(theta), 0.0, s], dtype=complex)
    n_t = np.sqrt(complex(eta))
    if n_t.imag > 0:
        n_t = -n_t
    # Normal to the plane of incidence (k_i x n / |k_i x n| up to sign; defined at normal incidence).
    e_perp = np.array([0.0, 1.0, 0.0], dtype=complex)
    return (
        e_perp,
        (k_i, np.cross(e_perp, k_i)),
        (k_r, np.cross(e_perp, k_r)),
        (kappa_t, np.cross(e_perp, kappa_t / n_t)),
    )


@pytest.mark.parametrize("eta", ETAS + [permittivity("concrete", F_MM)])
def test_fresnel_satisfies_boundary_conditions_in_stated_basis(eta):
    """Tangential E and H continuous at the interface: independent of the coefficient formulas."""
    for theta in np.deg2rad([0.0, 10.0, 37.0, 63.0, 85.0]):
        r_te, r_tm, t_te, t_tm = fresnel(eta, np.cos(theta))
        e_perp, (k_i, p_i), (k_r, p_r), (kap_t, p_t) = _field_vectors(eta, theta)
        # H ~ kappa x E (common factor 1 / (omega mu0) dropped; kappa = k / k0).
        for amp_perp, amp_par in ((1.0, 0.0), (0.0, 1.0)):
            e_i = amp_perp * e_perp + amp_par * p_i
            e_r = r_te * amp_perp * e_perp + r_tm * amp_par * p_r
            e_t = t_te * amp_perp * e_perp + t_tm * amp_par * p_t
            h_i, h_r, h_t = np.cross(k_i, e_i), np.cross(k_r, e_r), np.cross(kap_t, e_t)
            assert np.max(np.abs((e_i + e_r - e_t)[:2])) < BOUNDARY_TOL
            assert np.max(np.abs((h_i + h_r - h_t)[:2])) < BOUNDARY_TOL * max(1, abs(eta))
            assert abs(np.dot(kap_t, e_t)) < BOUNDARY_TOL * max(1, abs(eta))  # transverse wave


@pytest.mark.parametrize("eta", [1.5, 4.0, 7.074])
def test_fresnel_power_balance_lossless(eta):
    cos = np.linspace(1e-3, 1.0, 101)
    r_te, r_tm, t_te, t_tm = fresnel(eta, cos)
    s = np.sqrt(eta - (1 - cos**2))
    np.testing.assert_allclose(np.abs(r_te) ** 2 + s / cos * np.abs(t_te) ** 2, 1, atol=1e-12)
    np.testing.assert_allclose(np.abs(r_tm) ** 2 + s / cos * np.abs(t_tm) ** 2, 1, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Slab
# --------------------------------------------------------------------------------------------------
def _slab_transfer_matrix(eta: complex, cos: float, d: float, f: float):
    """Single layer by the characteristic matrix of the tangential fields (exp(+j w t)).

    State (U, V) with U = E_y (TE) or H_y (TM) and V = g / k0 dU/dz, g = 1 (TE) or 1 / eta (TM);
    in the layer U = A cos(k0 s z) + B sin(k0 s z). Air on both sides; returns (r, t) per
    polarisation, t referenced to the exit face at the same lateral position (P.2040 convention).
    """
    k0 = 2 * np.pi * f / C0
    s = np.sqrt(complex(eta) - (1 - cos**2))
    if s.imag > 0:
        s = -s
    delta = k0 * s * d
    out = []
    for g in (1.0, 1.0 / complex(eta)):
        m = np.array(
            [[np.cos(delta), np.sin(delta) / (g * s)], [-g * s * np.sin(delta), np.cos(delta)]]
        )
        # Incident side: U(0) = 1 + r, V(0) = -j cos (1 - r); exit: U(d) = t, V(d) = -j cos t.
        a = np.array(
            [
                [m[0, 0] + 1j * cos * m[0, 1], -1.0],
                [m[1, 0] + 1j * cos * m[1, 1], 1j * cos],
            ]
        )
        b = np.array([-m[0, 0] + 1j * cos * m[0, 1], -m[1, 0] + 1j * cos * m[1, 1]])
        r, t = np.linalg.solve(a, b)
        out.append((r, t))
    (r_te, t_te), (r_tm, t_tm) = out
    return r_te, r_tm, t_te, t_tm


@pytest.mark.parametrize(
    ("eta", "d", "f"),
    [
        (4.0, 0.05, F_C),
        (6.31, 0.01, F_MM),
        (permittivity("concrete", F_C), 0.2, F_C),
        (permittivity("plasterboard", F_MM), 0.0125, F_MM),
        (permittivity("glass", F_MM), 0.01, F_MM),
        (2.5 - 0.3j, 0.137, 7e9),
    ],
)
def test_slab_matches_transfer_matrix(eta, d, f):
    for cos in (1.0, 0.93, 0.6, 0.31, 0.05):
        got = slab(eta, cos, d, f, reference="p2040")
        ref = _slab_transfer_matrix(eta, cos, d, f)
        for g, r in zip(got, ref, strict=True):
            assert abs(g - r) < TMM_TOL
        # The free-space reference differs by exp(+j k0 d cos) only.
        k0 = 2 * np.pi * f / C0
        _, _, t_te_fs, t_tm_fs = slab(eta, cos, d, f)
        assert abs(t_te_fs - ref[2] * np.exp(1j * k0 * d * cos)) < TMM_TOL
        assert abs(t_tm_fs - ref[3] * np.exp(1j * k0 * d * cos)) < TMM_TOL


def test_zero_thickness_slab_is_exactly_transparent():
    etas = np.array([4.0, 5.24 - 0.62j, permittivity("metal", F_C), 1.0])[:, None]
    cos = np.array([1.0, 0.7, 0.2, 1e-9, 0.0])
    for reference in ("free_space", "p2040"):
        r_te, r_tm, t_te, t_tm = slab(etas, cos, 0.0, F_C, reference=reference)
        np.testing.assert_array_equal(r_te, 0)
        np.testing.assert_array_equal(r_tm, 0)
        np.testing.assert_array_equal(t_te, 1)
        np.testing.assert_array_equal(t_tm, 1)


def test_lossless_slab_conserves_energy():
    rng = np.random.default_rng(2040)
    eta = rng.uniform(1.2, 9.0, size=(40, 1, 1))
    cos = np.concatenate([[1.0, 1e-6], rng.uniform(0.0, 1.0, size=18)])[None, :, None]
    d = np.concatenate([[1e-6, 0.2, 3.0], rng.uniform(0.0, 0.5, size=7)])[None, None, :]
    for f in (F_C, F_MM):
        r_te, r_tm, t_te, t_tm = slab(eta, cos, d, f)
        assert r_te.shape == (40, 20, 10)
        np.testing.assert_allclose(np.abs(r_te) ** 2 + np.abs(t_te) ** 2, 1, atol=ENERGY_TOL)
        np.testing.assert_allclose(np.abs(r_tm) ** 2 + np.abs(t_tm) ** 2, 1, atol=ENERGY_TOL)


def test_lossy_slab_absorbs():
    cos = np.linspace(0.05, 1.0, 20)
    for name, f in (("concrete", F_C), ("glass", F_MM), ("plywood", F_C), ("wood", F_MM)):
        eta = permittivity(name, f)
        r_te, r_tm, t_te, t_tm = slab(eta, cos, MaterialLibrary.itu()[name].thickness_m, f)
        assert np.all(np.abs(r_te) ** 2 + np.abs(t_te) ** 2 < 1)
        assert np.all(np.abs(r_tm) ** 2 + np.abs(t_tm) ** 2 < 1)


@pytest.mark.parametrize(
    ("name", "d", "f"),
    [("metal", 0.002, F_C), ("metal", 10.0, 1e9), ("concrete", 1.0, F_MM), ("metal", 0.1, 100e9)],
)
def test_thick_lossy_slab_tends_to_interface_reflection(name, d, f):
    eta = permittivity(name, f)
    cos = np.array([1.0, 0.7, 0.3, 0.01, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow / invalid-value warnings
        r_te, r_tm, t_te, t_tm = slab(eta, cos, d, f)
        r0_te, r0_tm, _, _ = fresnel(eta, cos)
    for x in (r_te, r_tm, t_te, t_tm):
        assert np.all(np.isfinite(x))
    assert np.all(np.abs(t_te) < THICK_T_MAX) and np.all(np.abs(t_tm) < THICK_T_MAX)
    np.testing.assert_allclose(r_te, r0_te, atol=COEFF_TOL)
    np.testing.assert_allclose(r_tm, r0_tm, atol=COEFF_TOL)


def test_air_slab_is_invisible_with_free_space_reference():
    cos = np.array([1.0, 0.5, 0.1, 0.0])
    d = 0.37
    r_te, r_tm, t_te, t_tm = slab(1.0, cos, d, F_C)
    np.testing.assert_allclose(r_te, 0, atol=COEFF_TOL)
    np.testing.assert_allclose(r_tm, 0, atol=COEFF_TOL)
    np.testing.assert_allclose(t_te, 1, atol=COEFF_TOL)
    np.testing.assert_allclose(t_tm, 1, atol=COEFF_TOL)
    _, _, t_p, _ = slab(1.0, cos, d, F_C, reference="p2040")
    k0 = 2 * np.pi * F_C / C0
    np.testing.assert_allclose(t_p, np.exp(-1j * k0 * d * cos), atol=COEFF_TOL)


def test_slab_grazing_incidence():
    eta = permittivity("concrete", F_C)
    r_te, r_tm, t_te, t_tm = slab(eta, np.array([1e-9, 0.0]), 0.2, F_C)
    np.testing.assert_allclose(r_te, -1, atol=GRAZING_TOL)
    np.testing.assert_allclose(r_tm, -1, atol=GRAZING_TOL)
    assert t_te[1] == 0 and t_tm[1] == 0


def test_slab_broadcasts_over_all_inputs():
    eta = np.array([4.0, 5.24 - 0.6j])[:, None, None, None]
    cos = np.array([1.0, 0.4, 0.1])[None, :, None, None]
    d = np.array([0.0, 0.01, 0.2])[None, None, :, None]
    f = np.array([F_C, F_MM])[None, None, None, :]
    out = slab(eta, cos, d, f)
    for idx in np.ndindex(2, 3, 3, 2):
        single = slab(
            eta[idx[0], 0, 0, 0], cos[0, idx[1], 0, 0], d[0, 0, idx[2], 0], f[..., idx[3]]
        )
        for arr, val in zip(out, single, strict=True):
            assert arr.shape == (2, 3, 3, 2)
            assert abs(arr[idx] - val) < 1e-15


def test_slab_rejects_bad_input():
    with pytest.raises(MaterialError, match="thickness"):
        slab(4.0, 1.0, -0.1, F_C)
    with pytest.raises(MaterialError, match="frequency"):
        slab(4.0, 1.0, 0.1, 0.0)
    with pytest.raises(MaterialError, match="reference"):
        slab(4.0, 1.0, 0.1, F_C, reference="exit")  # type: ignore[arg-type]


def test_slab_excess_delay_matches_ray_geometry():
    eta_r, d = 5.24, 0.2
    theta = np.deg2rad(np.array([0.0, 20.0, 45.0, 70.0, 89.0]))
    theta_t = np.arcsin(np.sin(theta) / np.sqrt(eta_r))
    inside = d / np.cos(theta_t)  # refracted segment length
    # Free-space reference: the straight line's projection of the same stretch of the wave front,
    # i.e. the displaced exit point projected on the incident direction.
    free = inside * np.cos(theta - theta_t)
    expected = (np.sqrt(eta_r) * inside - free) / C0
    got = slab_excess_delay(eta_r - 0.6j, np.cos(theta), d)
    np.testing.assert_allclose(got, expected, atol=DELAY_TOL_S)
    assert slab_excess_delay(eta_r, 1.0, d) == pytest.approx((np.sqrt(eta_r) - 1) * d / C0)


def test_slab_group_delay_lossless_closed_forms():
    # normal incidence: (n - 1) d / c; oblique: the optical path excess of geometric optics
    assert slab_group_delay(2.25, 1.0, 0.3) == pytest.approx(0.5 * 0.3 / C0, rel=1e-14)
    eta_r, d = 3.1, 0.05
    theta = np.deg2rad(np.array([0.0, 30.0, 60.0, 85.0]))
    theta_t = np.arcsin(np.sin(theta) / np.sqrt(eta_r))
    inside = d / np.cos(theta_t)
    expected = (np.sqrt(eta_r) * inside - inside * np.cos(theta - theta_t)) / C0
    np.testing.assert_allclose(
        slab_group_delay(eta_r, np.cos(theta), d), expected, atol=DELAY_TOL_S
    )
    assert slab_group_delay(4.0, 0.5, 0.0) == 0.0  # no slab, no delay
    # the lossless limit is slab_excess_delay's (which ignores Im(eta))
    assert slab_group_delay(eta_r, 0.7, d) == slab_excess_delay(eta_r - 2j, 0.7, d)


@pytest.mark.parametrize("name", ["concrete", "glass", "wood", "brick", "medium_dry_ground"])
@pytest.mark.parametrize("f", [F_C, 5e9])
def test_slab_group_delay_is_the_phase_slope_of_the_through_ray(itu, name, f):
    """-d(phase)/d(omega) of exp(-j k0 d (s - cos)) by a central difference on the material's own
    permittivity model, against the closed form with ``f d eta/d f``."""
    mat, d = itu[name], 0.2
    for cos in (1.0, 0.6, 0.15):

        def phase(ff, cos=cos):
            s = np.sqrt(mat.permittivity(ff) - (1 - cos**2))
            return -np.real(2 * np.pi * ff / C0 * d * (s - cos))

        h = f * 1e-5
        numeric = -(phase(f + h) - phase(f - h)) / (2 * np.pi * 2 * h)
        got = slab_group_delay(mat.permittivity(f), cos, d, mat.permittivity_slope(f))
        assert got == pytest.approx(numeric, rel=GROUP_DELAY_RTOL)


def test_permittivity_slope_of_the_power_law(itu):
    # concrete: b = 0, so f d eta / d f = -j (d - 1) eta'' with eta'' = -Im(eta)
    con = itu["concrete"]
    eta = con.permittivity(F_C)
    assert con.permittivity_slope(F_C) == pytest.approx(1j * (0.7822 - 1) * eta.imag, rel=1e-12)
    ground = itu["medium_dry_ground"]  # b = -0.1: the real part disperses too
    h = 1e-6 * F_C
    numeric = F_C * (ground.permittivity(F_C + h) - ground.permittivity(F_C - h)) / (2 * h)
    assert abs(ground.permittivity_slope(F_C) - numeric) < 1e-6 * abs(numeric)


def test_thick_lossy_wall_group_delay_matches_the_full_slab(itu):
    """A 0.2 m concrete wall damps the internal reflections: the group delay of P.2040's full
    slab transmission (with them) equals the single-pass one to 1 %."""
    mat, d = itu["concrete"], 0.2
    for f in (F_C, F_MM):
        for cos in (1.0, 0.5):
            h = f * 1e-5

            def t_te(ff, cos=cos):
                return slab(mat.permittivity(ff), cos, d, ff)[2]

            full = -np.angle(t_te(f + h) / t_te(f - h)) / (2 * np.pi * 2 * h)
            single = slab_group_delay(mat.permittivity(f), cos, d, mat.permittivity_slope(f))
            assert single == pytest.approx(full, rel=WALL_GROUP_DELAY_RTOL)
            assert single > 0.8e-9  # ~26 cm of extra path at normal incidence


# --------------------------------------------------------------------------------------------------
# Library, YAML and matching
# --------------------------------------------------------------------------------------------------
def test_lookup_spellings_and_unknown_name(itu):
    assert itu["ITU_Concrete"] is itu["concrete"]
    assert itu["Ceiling-Board"].name == "ceiling_board"
    assert "itu_metal" in itu and "Metal" in itu and "steel" not in itu and 3 not in itu
    assert itu.get("steel") is None and itu.get("Wood") is itu["wood"]
    assert dict(itu.items())["glass"] is itu["glass"]
    with pytest.raises(MaterialError) as exc:
        itu["steel"]
    msg = str(exc.value)
    assert "steel" in msg and "concrete" in msg and "wet_ground" in msg and "\n" not in msg


@pytest.mark.parametrize(
    ("obj", "expected"),
    [
        ("crate_plywood", "plywood"),
        ("Wall_Concrete_01", "concrete"),
        ("ceiling_board_3", "ceiling_board"),
        ("Ceiling-Board", "ceiling_board"),
        ("CeilingBoard.002", "ceiling_board"),
        ("mat-itu_glass", "glass"),
        ("itu_metal_shelf", "metal"),
        ("floorboard_2", "floorboard"),
        ("wet-ground", "wet_ground"),
        ("glass_door_metal_frame", "glass"),  # equal length: the first in the name wins
        ("box_17", None),
        ("", None),
    ],
)
def test_match_object_names(itu, obj, expected):
    assert itu.match(obj) == expected


YAML_TEXT = """
materials:
  plastic: {eta_real: 2.5, sigma: 0.002, thickness: 0.004}
  rubber: {a: 2.8, b: 0.0, c: 0.004, d: 1.2, f_range_ghz: [1, 60]}
  concrete: {thickness: 0.3}
  Itu_Glass: {thickness: 0.006}
bind: {"forklift_*": metal, "crate_*": Plastic}
default: concrete
"""


def test_with_yaml_file(tmp_path, itu):
    path = tmp_path / "materials.yaml"
    path.write_text(YAML_TEXT)
    lib = itu.with_yaml(path)
    assert set(lib.names) == ITU_NAMES | {"plastic", "rubber"}
    plastic = lib["plastic"]
    assert (plastic.a, plastic.b, plastic.c, plastic.d, plastic.thickness_m) == (
        2.5,
        0.0,
        0.002,
        0.0,
        0.004,
    )
    eta = permittivity("plastic", F_MM, library=lib)
    assert eta == pytest.approx(2.5 - 1j * 0.002 / (2 * np.pi * F_MM * EPS0), rel=1e-14)
    assert lib["rubber"].thickness_m == DEFAULT_USER_THICKNESS_M
    assert lib["rubber"].f_max_hz == pytest.approx(60e9)
    with pytest.raises(MaterialError, match="rubber"):
        lib["rubber"].permittivity(70e9)
    assert lib["concrete"].thickness_m == 0.3
    assert lib["concrete"].a == 5.24 and lib["concrete"].f_max_hz == 100e9
    assert lib["glass"].thickness_m == 0.006
    assert lib.bind == {"forklift_*": "metal", "crate_*": "plastic"}
    assert lib.default == "concrete"
    assert lib.match("blue_plastic_box") == "plastic"
    # The source library is unchanged.
    assert itu["concrete"].thickness_m == 0.2 and "plastic" not in itu
    assert itu.bind == {} and itu.default is None


def test_with_yaml_dict_chains_and_merges(itu):
    first = itu.with_yaml({"bind": {"rack_*": "metal"}, "default": "concrete"})
    second = first.with_yaml({"materials": {"foam": {"eta_real": 1.1, "sigma": 0.0}}})
    assert second.bind == {"rack_*": "metal"} and second.default == "concrete"
    third = second.with_yaml({"bind": {"rack_*": "foam"}})
    assert third.bind == {"rack_*": "foam"}
    assert permittivity("foam", 1e12, library=third) == 1.1  # no range given: any frequency
    redefined = itu.with_yaml({"materials": {"concrete": {"eta_real": 6.0, "sigma": 0.1}}})
    assert redefined["concrete"].a == 6.0 and redefined["concrete"].thickness_m == 0.2


def test_empty_yaml_file_changes_nothing(tmp_path, itu):
    path = tmp_path / "empty.yaml"
    path.write_text("# nothing yet\n")
    assert itu.with_yaml(path).names == itu.names


@pytest.mark.parametrize(
    ("data", "pattern"),
    [
        ({"materialz": {}}, "materialz"),
        ({"materials": {"plastic": {"eta_real": 2.5, "sigma": 0.0, "colour": 3}}}, "colour"),
        ({"materials": {"plastic": {"eta_real": -2.5, "sigma": 0.0}}}, "plastic.*eta_real"),
        ({"materials": {"plastic": {"eta_real": 2.5}}}, "plastic.*missing sigma"),
        ({"materials": {"plastic": {"sigma": 0.1}}}, "plastic.*missing eta_real"),
        ({"materials": {"plastic": {"eta_real": 2.5, "sigma": -1}}}, "plastic.*sigma"),
        ({"materials": {"plastic": {"eta_real": "2.5", "sigma": 0}}}, "plastic.*number"),
        ({"materials": {"plastic": {"thickness": 0.1}}}, "plastic.*not known"),
        ({"materials": {"plastic": None}}, "plastic"),
        ({"materials": {"concrete": {"thickness": -0.1}}}, "concrete.*thickness"),
        ({"materials": {"concrete": {"thickness": 0}}}, "concrete.*thickness"),
        ({"materials": {"x": {"a": 2, "b": 0, "c": 0.1, "d": 1}}}, "'x'.*f_range_ghz"),
        ({"materials": {"x": {"a": 2, "b": 0, "c": 0, "d": 1, "f_range_ghz": [5, 1]}}}, "'x'"),
        ({"materials": {"x": {"a": 2, "b": 0, "c": 0, "d": 1, "sigma": 1}}}, "'x'.*missing"),
        ({"materials": {"2x": {"eta_real": 2, "sigma": 0}}}, "2x"),
        ({"materials": ["plastic"]}, "materials"),
        ({"bind": {"forklift_*": "unobtainium"}}, "forklift_\\*.*unobtainium"),
        ({"bind": ["metal"]}, "bind"),
        ({"default": "unobtainium"}, "default.*unobtainium"),
    ],
)
def test_bad_material_definitions_are_one_line_errors(itu, data, pattern):
    with pytest.raises(MaterialError, match=pattern) as exc:
        itu.with_yaml(data)
    assert "\n" not in str(exc.value)


def test_bad_yaml_files(tmp_path, itu):
    with pytest.raises(MaterialError, match="not found.*missing.yaml"):
        itu.with_yaml(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("materials:\n  plastic: {eta_real: 2.5, sigma: [\n")
    with pytest.raises(MaterialError, match="broken.yaml.*line") as exc:
        itu.with_yaml(broken)
    assert "\n" not in str(exc.value)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("concrete\n")
    with pytest.raises(MaterialError, match="top level"):
        itu.with_yaml(scalar)


def test_material_validates_itself():
    with pytest.raises(MaterialError, match="a must be > 0"):
        Material("foo", -1.0, 0.0, 0.0, 0.0, 1e9, 2e9, 0.1)
    with pytest.raises(MaterialError, match="thickness"):
        Material("foo", 2.0, 0.0, 0.0, 0.0, 1e9, 2e9, 0.0)
    with pytest.raises(MaterialError, match="frequency range"):
        Material("foo", 2.0, 0.0, 0.0, 0.0, 2e9, 1e9, 0.1)
    with pytest.raises(MaterialError, match="name"):
        Material("Foo Bar", 2.0, 0.0, 0.0, 0.0, 1e9, 2e9, 0.1)


def test_docs_yaml_example_loads(itu):
    """The YAML example of docs/materials.md is valid."""
    doc = Path(__file__).resolve().parents[1] / "docs" / "materials.md"
    blocks = re.findall(r"```yaml\n(.*?)```", doc.read_text(), flags=re.S)
    assert blocks, "docs/materials.md has no yaml example"
    import yaml

    lib = itu.with_yaml(yaml.safe_load(blocks[0]))
    assert "plastic" in lib and lib.bind
