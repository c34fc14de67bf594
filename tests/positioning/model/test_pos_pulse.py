"""positioning.model.pulse: the raised cosine in periods, its table, envelope and the peak fit
(the one implementation both receivers use), against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from positioning.model.pulse import (
    TABLE_PER_T,
    envelope_table,
    precursor_extent_t,
    pulse_at,
    pulse_table,
    quartic_top,
    raised_cosine,
)

BETA = 0.25
#: Relative tolerance of the closed-form pulse against the textbook formula away from its
#: removable singularity.
REL_TOL = 1e-12
#: Linear interpolation in a table of 2048 samples per T: error below (pi^2/8) / 2048^2 of the
#: peak for a pulse with |h''| <= pi^2/3 (bounded here by 1.1e-7).
TABLE_TOL = 1.1e-7
#: Relative error of the envelope's sidelobe peak on its grid of T/64.
ENVELOPE_GRID_REL = 1e-3
#: Bias of the quartic peak fit on a lone lobe sampled at 8 per T, in T.
QUARTIC_BIAS_T = 1e-5


def textbook(x, beta):
    return np.sinc(x) * np.cos(np.pi * beta * x) / (1.0 - (2.0 * beta * x) ** 2)


def test_raised_cosine_matches_the_textbook_formula_and_its_limits():
    x = np.linspace(-6.0, 6.0, 2401)
    x = x[np.abs(np.abs(x) - 1 / (2 * BETA)) > 1e-3]
    assert np.allclose(raised_cosine(x, BETA), textbook(x, BETA), rtol=REL_TOL, atol=1e-15)
    assert raised_cosine(0.0, BETA) == 1.0
    k = np.arange(1, 9)
    assert np.max(np.abs(raised_cosine(k, BETA))) < 1e-15  # zeros at every other period
    # the removable singularity at x = 1/(2 beta): the limit (pi/4) sinc(1/(2 beta))
    assert raised_cosine(2.0, BETA) == pytest.approx(np.pi / 4 * np.sinc(2.0), abs=1e-15)
    # with a period: h(x T) = T h / T, in 1/s
    assert raised_cosine(0.5, BETA, 1e-8) == pytest.approx(raised_cosine(0.5, BETA) / 1e-8)
    assert np.allclose(raised_cosine(x, 0.0), np.sinc(x))


def test_table_interpolation_error_and_span():
    table = pulse_table(BETA, 16)
    lag_t = np.random.default_rng(1).uniform(-16.0, 16.0, 20000)
    period = 12.5e-9
    got = pulse_at(lag_t * period, period, table)
    assert np.max(np.abs(got - raised_cosine(lag_t, BETA))) < TABLE_TOL
    assert np.all(pulse_at(np.array([16.5, -40.0]) * period, period, table) == 0.0)
    assert table[0].size == 16 * TABLE_PER_T + 3


def test_envelope_is_the_largest_magnitude_beyond_each_lag():
    x, env = envelope_table(BETA, 16)
    assert np.all(np.diff(env) <= 0)
    assert env[0] == 1.0
    # beyond the main lobe (|x| >= 1): the first sidelobe, -14.3 dB for beta = 0.25
    fine = np.linspace(1.0, 1.9, 90001)  # the first sidelobe peaks near 1.4 T
    side = np.max(np.abs(textbook(fine, BETA)))
    # the table's grid of T/64 misses the sidelobe's top by at most half a step: (1/128)^2 |h''| / 2
    assert env[np.searchsorted(x, 1.0)] == pytest.approx(side, rel=ENVELOPE_GRID_REL)
    assert 20 * np.log10(side) == pytest.approx(-14.3, abs=0.05)


def test_precursor_extent_reaches_a_quarter_of_the_threshold():
    for rho_db in (-12.0, -20.0, -30.0):
        rho = 10 ** (rho_db / 20)
        n = precursor_extent_t(BETA, rho, 16)
        x, env = envelope_table(BETA, 16)
        assert env[np.searchsorted(x, n)] < 0.25 * rho
        assert n == 2 or env[np.searchsorted(x, n - 1)] >= 0.25 * rho


def test_quartic_top_is_exact_on_a_quartic_and_unbiased_on_a_lobe():
    rng = np.random.default_rng(2)
    u0 = rng.uniform(-0.9, 0.9, 50)
    k = np.arange(-2.0, 3.0)
    # a concave quartic with its maximum at u0 (no other stationary point in [-1, 1])
    y = 3.0 - (k[None, :] - u0[:, None]) ** 2 - 0.01 * (k[None, :] - u0[:, None]) ** 4
    u, value = quartic_top(y)
    assert np.allclose(u, u0, atol=1e-9)
    assert np.allclose(value, 3.0, atol=1e-9)
    # a lone raised-cosine lobe sampled at T/8, its top between samples
    shift = rng.uniform(-0.5, 0.5, 50)
    y = raised_cosine((k[None, :] - shift[:, None]) / 8.0, BETA)
    u, value = quartic_top(y)
    assert np.max(np.abs(u - shift)) / 8.0 < QUARTIC_BIAS_T
    assert np.allclose(value, 1.0, atol=1e-6)
