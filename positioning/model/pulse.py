"""The raised-cosine pulse of eq. 2 in units of its period, its tabulation, and the sub-sample
peak fit: the one home of what the tracer's receivers (:mod:`raytrace.emulation.receivers`) and
the twin's (:mod:`positioning.twin`) both need.

``positioning`` never imports ``raytrace``; ``raytrace.emulation`` may import this layer
(``tools/check_layers.py``), so the two receivers evaluate the same pulse with the same code.

* :func:`raised_cosine`: ``h(x T) = (1/T) sinc(x) cos(pi beta x) / (1 - (2 beta x)^2)`` at ``x``
  periods (with ``period_s = 1``: the dimensionless ``T h(x T)``, 1 at 0).
* :func:`pulse_table` / :func:`pulse_at`: the pulse tabulated at ``T / 2048`` and interpolated
  linearly (error below 1.1e-7 of its peak), the fast evaluation of every window.
* :func:`envelope_table` / :func:`precursor_extent_t`: the pulse's sidelobe envelope
  ``max_{|u| >= x} |T h(u T)|`` and how far before a path its ringing reaches a given level.
* :func:`quartic_top`: the maximum of the quartic through five samples around a lobe's top.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: Samples per T of the tabulated pulse (linear interpolation error below 1.1e-7 of its peak).
TABLE_PER_T = 2048

#: Quartic through samples -2..2: coefficient rows (c0..c4) from the five values.
QUARTIC = np.linalg.inv(np.vander(np.arange(-2.0, 3.0), 5, increasing=True))


def raised_cosine(x: np.ndarray | float, roll_off: float, period_s: float = 1.0) -> np.ndarray:
    """Raised cosine of eq. 2 at ``x`` periods: ``sinc(x) cos(pi beta x) / (1 - (2 beta x)^2) / T``.

    The factor ``cos(pi u / 2) / (1 - u^2)`` with ``u = 2 beta x`` is evaluated as
    ``sin(pi e / 2) / (e (2 - e))`` with ``e = 1 - |u|``, the same function written without the
    cancellation near ``|u| = 1``; at ``x = +-1/(2 beta)`` exactly it takes its limit ``pi/4``.

    Parameters
    ----------
    x : (...) float, time in periods T
    roll_off : float, beta in [0, 1]; 0 is the sinc pulse
    period_s : float, s, the period T (default 1: the dimensionless ``T h(x T)``)

    Returns
    -------
    (...) float, ``h(x T)`` in 1/s (``T h(x T)``, 1 at 0, with ``period_s = 1``)
    """
    x = np.asarray(x, dtype=float)
    out = np.sinc(x) / period_s
    if roll_off == 0.0:
        return out
    e = 1.0 - np.abs(2.0 * roll_off * x)
    denom = e * (2.0 - e)
    factor = np.divide(np.sin(0.5 * np.pi * e), denom, out=np.full_like(e, np.pi / 4), where=e != 0)
    return out * factor


@lru_cache(maxsize=32)
def envelope_table(
    roll_off: float, span: int, oversampling: int = 64
) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (periods) and ``max_{|u| >= x} |T h(u T)|`` on a grid of ``1 / oversampling`` up to
    ``span``: the pulse's sidelobe envelope at lags of ``x`` periods and beyond."""
    x = np.arange(0, span * oversampling + 1) / oversampling
    h = np.abs(raised_cosine(x, roll_off))
    return x, np.maximum.accumulate(h[::-1])[::-1]


def precursor_extent_t(roll_off: float, rho: float, span: int) -> int:
    """Whole periods before a path beyond which the pulse stays below ``rho / 4`` of its peak
    (at least 2, at most ``span``)."""
    x, env = envelope_table(float(roll_off), int(span))
    below = np.flatnonzero(env < 0.25 * rho)
    return int(max(2, math.ceil(x[below[0]]))) if below.size else int(span)


@lru_cache(maxsize=32)
def pulse_table(roll_off: float, span: int) -> tuple[np.ndarray, np.ndarray]:
    """``T h(x T)`` at ``x = 0, 1/R, ..., span`` (R = :data:`TABLE_PER_T`), zero-padded, and its
    forward differences (for linear interpolation with one gather)."""
    x = np.arange(0, span * TABLE_PER_T + 1) / TABLE_PER_T
    value = np.concatenate([raised_cosine(x, roll_off), [0.0, 0.0]])
    return value, np.append(np.diff(value), 0.0)


def pulse_at(lag: np.ndarray, period: float, table: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``T h(lag)`` (dimensionless, any shape) by linear interpolation in ``table``
    (:func:`pulse_table`); 0 beyond its span.

    Parameters
    ----------
    lag : (...) float, s, time from the path
    period : float, s, T
    table : from :func:`pulse_table`
    """
    value, step = table
    u = np.abs(lag)
    u *= TABLE_PER_T / period
    np.minimum(u, value.size - 2, out=u)
    i = u.astype(np.intp)
    u -= i
    u *= step[i]
    u += value[i]
    return u


def quartic_top(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-sample offset (in samples, ``|u| <= 1``) and value of the maximum of the quartic
    through ``y (n, 5)`` at -2..2 (Newton on its derivative from the parabola's vertex).

    On a lone raised-cosine lobe sampled at 8 per T the offset's bias is below 1e-5 T.
    """
    c = y @ QUARTIC.T  # (n, 5): c0 + c1 u + c2 u^2 + c3 u^3 + c4 u^4
    curv = y[:, 1] - 2.0 * y[:, 2] + y[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(curv < 0, 0.5 * (y[:, 1] - y[:, 3]) / curv, 0.0)
    u = np.clip(u, -1.0, 1.0)
    for _ in range(4):
        d1 = c[:, 1] + 2 * c[:, 2] * u + 3 * c[:, 3] * u**2 + 4 * c[:, 4] * u**3
        d2 = 2 * c[:, 2] + 6 * c[:, 3] * u + 12 * c[:, 4] * u**2
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(d2 < 0, d1 / d2, 0.0)
        u = np.clip(u - step, -1.0, 1.0)
    value = c[:, 0] + c[:, 1] * u + c[:, 2] * u**2 + c[:, 3] * u**3 + c[:, 4] * u**4
    return u, value
