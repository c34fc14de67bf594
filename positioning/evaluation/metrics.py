"""Positioning error metrics: 2D error per fix, mean / median / 90th percentile, empirical CDF."""

from __future__ import annotations

import numpy as np

from ..errors import PositioningError


def error_2d(estimate_xyz: np.ndarray, true_xyz: np.ndarray) -> np.ndarray:
    """Horizontal (2D) error of each fix, ``hypot(dx, dy)``, metres.

    Parameters
    ----------
    estimate_xyz : (E, 3) or (E, 2) float, metres -- NaN rows (unsolved fixes) give NaN
    true_xyz : (E, 3) or (E, 2) float, metres

    Returns
    -------
    (E,) float, metres. The paper's figure of merit (Table II, Fig. 2) is this 2D error.
    """
    est = np.asarray(estimate_xyz, dtype=float)
    tru = np.asarray(true_xyz, dtype=float)
    if est.ndim != 2 or tru.ndim != 2 or est.shape[0] != tru.shape[0]:
        raise PositioningError(
            f"error_2d needs (E, 2|3) arrays of equal length, got {est.shape} and {tru.shape}"
        )
    if est.shape[1] < 2 or tru.shape[1] < 2:
        raise PositioningError("error_2d needs at least x and y columns")
    return np.hypot(est[:, 0] - tru[:, 0], est[:, 1] - tru[:, 1])


def summarize(errors_m: np.ndarray) -> dict[str, float | int]:
    """Mean, median and 90th percentile of the finite errors.

    The percentile is numpy's default ``method="linear"`` (type 7 of Hyndman and Fan): for the
    sorted finite errors ``x_0 <= ... <= x_{n-1}`` the p-th percentile is the linear
    interpolation at position ``(n - 1) p / 100``. NaN errors (unsolved fixes) are excluded from
    the statistics and counted in ``n_unsolved``.

    Returns
    -------
    dict with ``n`` (finite errors), ``n_unsolved`` (NaN errors), ``mean_m``, ``median_m``,
    ``p90_m`` (NaN when ``n == 0``).
    """
    e = np.asarray(errors_m, dtype=float).ravel()
    finite = e[np.isfinite(e)]
    n = int(finite.size)
    out: dict[str, float | int] = {"n": n, "n_unsolved": int(e.size - n)}
    if n == 0:
        out.update(mean_m=float("nan"), median_m=float("nan"), p90_m=float("nan"))
    else:
        out.update(
            mean_m=float(np.mean(finite)),
            median_m=float(np.median(finite)),
            p90_m=float(np.percentile(finite, 90.0, method="linear")),
        )
    return out


def cdf(errors_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Empirical CDF of the finite errors: ``x`` sorted ascending, ``y_i = i / n`` (i = 1..n).

    Returns
    -------
    x : (n,) float, metres; y : (n,) float in (0, 1]. Empty arrays when no error is finite.
    """
    e = np.asarray(errors_m, dtype=float).ravel()
    x = np.sort(e[np.isfinite(e)])
    n = x.size
    return x, np.arange(1, n + 1, dtype=float) / max(n, 1)
