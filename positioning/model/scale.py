"""The scale rule on positioning input, before any solve: the same checks for the commands (on a
dataset, :mod:`positioning.io.scale`) and for :func:`positioning.locate` (on arrays).

The rule is the one of :mod:`hallray.units`, shared with the ray tracer: a hall spans metres to a
few hundred metres, never more than :data:`~hallray.units.MAX_SCENE_M` and never less than
:data:`~hallray.units.MIN_SCENE_M`. Values beyond it are refused with the unit mistake that most
likely explains them: base stations in millimetres or kilometres, ToAs in milliseconds,
microseconds or nanoseconds, a height in millimetres.
"""

from __future__ import annotations

import numpy as np

from hallray.units import (
    MAX_SCENE_M,
    MIN_SCENE_M,
    TIME_UNITS,
    likely_length_unit,
    likely_small_length_unit,
)

from ..errors import PositioningError
from .tdoa import C0

#: ToA-difference ranges beyond this many station spans (and beyond 1 km) mean a unit mistake.
RANGE_SPANS = 10.0
#: Largest plausible ratio of a ToA difference's range to the stations' span (a range difference
#: is at most the distance between the two stations, plus the multipath excess).
MAX_RANGE_RATIO = 3.0


class ScaleError(PositioningError):
    """Values beyond what a hall can be: most likely a unit mistake (one-line message)."""


def length_hint(size_m: float) -> str:
    """The likely unit mistake behind a size outside the hall scale, as a clause."""
    found = likely_length_unit(size_m) if size_m > MAX_SCENE_M else likely_small_length_unit(size_m)
    if found is None:
        return "give metres"
    factor, unit = found
    return f"probably in {unit} (x{factor:g}): give metres"


def check_stations(bs_xyz: np.ndarray, where: str) -> None:
    """Refuse base stations spread over more than :data:`MAX_SCENE_M` (millimetres), or over less
    than :data:`~hallray.units.MIN_SCENE_M` (kilometres).

    bs_xyz : (N, 3) float, metres; where : the file or argument, for the message.
    """
    span = float(np.max(np.ptp(bs_xyz, axis=0))) if len(bs_xyz) else 0.0
    if span > MAX_SCENE_M:
        raise ScaleError(
            f"{where}: the base stations span {span:,.0f} m, beyond the "
            f"{MAX_SCENE_M / 1000:g} km a hall can span: coordinates {length_hint(span)}"
        )
    if len(bs_xyz) >= 2 and 0 < span < MIN_SCENE_M:
        raise ScaleError(
            f"{where}: the base stations span {span:.3g} m, less than the {MIN_SCENE_M:g} m of a "
            f"hall: coordinates {length_hint(span)}"
        )


def likely_time_factor(ratio: float) -> tuple[float, str]:
    """The time unit of ToAs whose differences are ``ratio`` station spans (range): the smallest
    factor of :data:`~hallray.units.TIME_UNITS` that brings the ratio to a plausible one
    (at most :data:`MAX_RANGE_RATIO`; a range difference is at most the stations' distance),
    else the largest. (Nearest in decades would call microseconds nanoseconds whenever the range
    differences are small against the span.)"""
    for factor, unit in TIME_UNITS:
        if ratio / factor <= MAX_RANGE_RATIO:
            return factor, unit
    return TIME_UNITS[-1]


def check_toa_scale(
    toa_s: np.ndarray, bs_xyz: np.ndarray, where: str, schedule_s: np.ndarray | None = None
) -> None:
    """Refuse ToAs whose differences between base stations imply ranges far beyond the stations.

    Within one fix, ``c * |ToA_i - ToA_j|`` is at most the distance between stations i and j
    (plus the multipath excess), whatever the device's clock offset. A median over the fixes far
    beyond the stations' span is a time unit mistake (milliseconds read as seconds).

    Parameters
    ----------
    toa_s : (F, N) float, s, schedule removed, NaN = not received
    bs_xyz : (N, 3) float, m
    where : the file or argument, for the message
    schedule_s : (F, N) float, s, optional, the schedule that was removed: when the ToAs are in
        another unit but the schedule in seconds, the differences are the schedule's scaled by the
        unit (that is recognised, rather than the ranges' ratio to the span)
    """
    with np.errstate(all="ignore"):
        fin = np.isfinite(toa_s)
        n_ok = fin.sum(axis=1)
        spread = C0 * (np.nanmax(toa_s, axis=1, initial=-np.inf, where=fin)
                       - np.nanmin(toa_s, axis=1, initial=np.inf, where=fin))  # fmt: skip
    spread = spread[n_ok >= 2]
    if spread.size == 0:
        return
    typical = float(np.median(spread))
    span = max(float(np.linalg.norm(np.ptp(bs_xyz, axis=0))), 1.0)
    if typical <= max(RANGE_SPANS * span, 1000.0):
        return
    factor, unit = _schedule_factor(toa_s, schedule_s) or likely_time_factor(typical / span)
    raise ScaleError(
        f"{where}: the ToA differences imply range differences of {typical:,.0f} m (median) "
        f"between base stations {span:,.0f} m apart: the ToAs are probably in {unit} "
        f"(x{factor:g}), give seconds"
    )


def _schedule_factor(toa_s: np.ndarray, schedule_s: np.ndarray | None) -> tuple[float, str] | None:
    """The time unit when the unscheduled ToAs still hold the schedule scaled by it (ToAs in
    another unit, schedule in seconds): the median of (ToA_i - ToA_j) / (sched_i - sched_j)."""
    if schedule_s is None:
        return None
    sched = np.broadcast_to(np.asarray(schedule_s, dtype=float), toa_s.shape)
    raw = toa_s + sched  # the ToAs as given
    ds = sched[:, :, None] - sched[:, None, :]
    dt = raw[:, :, None] - raw[:, None, :]
    ok = np.isfinite(dt) & (np.abs(ds) > 1e-6)
    if not ok.any():
        return None
    k = float(np.median(dt[ok] / ds[ok]))
    for factor, unit in TIME_UNITS:
        if 0.5 * factor <= k <= 2.0 * factor:
            return factor, unit
    return None


def check_height(height: str | float | np.ndarray, bs_xyz: np.ndarray, name: str = "--height") -> None:
    """Refuse a known device height far from the base stations' heights.

    Allowed: within the stations' height range widened by their span (at least 100 m).
    ``height``: ``"true"``/``"3d"`` (nothing to check), metres, or (F,) metres; ``name``: how the
    message calls it (``--height``, ``height_m``).
    """
    if isinstance(height, str) or height is None:
        return
    h = np.asarray(height, dtype=float).reshape(-1)
    if h.size == 0:
        return
    z = bs_xyz[:, 2]
    span = max(float(np.linalg.norm(np.ptp(bs_xyz, axis=0))), 100.0)
    bad = h[~((z.min() - span <= h) & (h <= z.max() + span))]
    if bad.size:
        value = float(bad[0])
        hint = length_hint(abs(value)) if abs(value) > MAX_SCENE_M else "give metres"
        raise ScaleError(
            f"{name} {value:g} m is far from the base stations' heights "
            f"({z.min():.1f} .. {z.max():.1f} m): {hint}"
        )


def check_truth(true_xyz: np.ndarray, bs_xyz: np.ndarray, where: str) -> None:
    """Refuse true positions that are not in the stations' hall: farther from the stations' box
    than the scale rule allows, or spread over more than :data:`MAX_SCENE_M` (millimetres)."""
    t = np.asarray(true_xyz, dtype=float).reshape(-1, 3)
    t = t[np.isfinite(t).all(axis=1)]
    if t.size == 0:
        return
    lo, hi = bs_xyz.min(axis=0), bs_xyz.max(axis=0)
    span = max(float(np.linalg.norm(hi - lo)), MIN_SCENE_M)
    out = np.linalg.norm(np.maximum(np.maximum(lo - t, t - hi), 0.0), axis=1)
    far = float(out.max())
    spread = float(np.max(np.ptp(t, axis=0)))
    if far > max(RANGE_SPANS * span, 1000.0) or spread > MAX_SCENE_M:
        size = max(far, spread)
        raise ScaleError(
            f"{where}: the true positions lie up to {far:,.0f} m outside the base stations' box "
            f"(they span {spread:,.0f} m): x_true, y_true, z_true {length_hint(size)}"
        )
