"""Metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import PositioningError, cdf, error_2d, summarize

#: Tolerance of hand-computed statistics, metres.
STAT_TOL_M = 1e-12


def test_error_2d_ignores_height_and_propagates_nan():
    est = np.array([[3.0, 4.0, 0.0], [1.0, 1.0, 9.0], [np.nan, np.nan, np.nan]])
    true = np.array([[0.0, 0.0, 5.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    e = error_2d(est, true)
    np.testing.assert_allclose(e[:2], [5.0, 0.0], atol=STAT_TOL_M)
    assert np.isnan(e[2])
    np.testing.assert_allclose(error_2d(est[:2, :2], true[:2]), [5.0, 0.0], atol=STAT_TOL_M)


def test_error_2d_rejects_mismatched_shapes():
    with pytest.raises(PositioningError):
        error_2d(np.zeros((2, 3)), np.zeros((3, 3)))


def test_summary_hand_values():
    """Errors 1, 2, 3, 4 (+ one unsolved): mean 2.5, median 2.5, p90 by linear interpolation at
    position (n - 1) * 0.9 = 2.7 of the sorted list: 3 + 0.7 * (4 - 3) = 3.7."""
    s = summarize(np.array([4.0, 1.0, np.nan, 3.0, 2.0]))
    assert s["n"] == 4 and s["n_unsolved"] == 1
    assert s["mean_m"] == pytest.approx(2.5, abs=STAT_TOL_M)
    assert s["median_m"] == pytest.approx(2.5, abs=STAT_TOL_M)
    assert s["p90_m"] == pytest.approx(3.7, abs=STAT_TOL_M)


def test_summary_of_nothing_is_nan():
    s = summarize(np.array([np.nan, np.nan]))
    assert s["n"] == 0 and s["n_unsolved"] == 2 and np.isnan(s["p90_m"])


def test_cdf_hand_values():
    x, y = cdf(np.array([0.3, np.nan, 0.1, 0.2, 0.2]))
    np.testing.assert_array_equal(x, [0.1, 0.2, 0.2, 0.3])
    np.testing.assert_allclose(y, [0.25, 0.5, 0.75, 1.0], atol=STAT_TOL_M)
    x, y = cdf(np.array([]))
    assert x.size == 0 and y.size == 0
