"""The scale rule on a ToA dataset, before any solve.

The rule is the one of :mod:`hallray.units`, shared with the ray tracer: a hall spans metres to a
few hundred metres, never more than :data:`~hallray.units.MAX_SCENE_M`. Values beyond it are
refused with the unit mistake that most likely explains them: base stations in millimetres, ToAs
in milliseconds, a height in mm. (Whether the fixes' station geometry can determine a position is
judged after the solve: :mod:`positioning.evaluation.trust`.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hallray.units import MAX_SCENE_M, likely_length_unit, likely_time_unit

from ..errors import PositioningError
from ..model.tdoa import C0

#: ToA-difference ranges beyond this many station spans (and beyond 1 km) mean a unit mistake.
RANGE_SPANS = 10.0


class ScaleError(PositioningError):
    """Values beyond what a hall can be: most likely a unit mistake (one-line message)."""


def _length_hint(size_m: float) -> str:
    found = likely_length_unit(size_m)
    if found is None:
        return "give metres"
    factor, unit = found
    return f"probably in {unit} (x{factor:g}): give metres"


def check_stations(bs_xyz: np.ndarray, where: str) -> None:
    """Refuse base stations spread over more than :data:`MAX_SCENE_M` (a unit mistake).

    bs_xyz : (N, 3) float, metres; where : the file, for the message.
    """
    span = float(np.max(np.ptp(bs_xyz, axis=0))) if len(bs_xyz) else 0.0
    if span > MAX_SCENE_M:
        raise ScaleError(
            f"{where}: the base stations span {span:,.0f} m, beyond the "
            f"{MAX_SCENE_M / 1000:g} km a hall can span: coordinates {_length_hint(span)}"
        )


def check_toa_scale(toa_s: np.ndarray, bs_xyz: np.ndarray, where: str) -> None:
    """Refuse ToAs whose differences between base stations imply ranges far beyond the stations.

    Within one fix, ``c * |ToA_i - ToA_j|`` is at most the distance between stations i and j
    (plus the multipath excess), whatever the device's clock offset. A median over the fixes far
    beyond the stations' span is a time unit mistake (milliseconds read as seconds).

    toa_s : (F, N) float, s, schedule removed, NaN = not received; bs_xyz : (N, 3) float, m.
    """
    with np.errstate(all="ignore"):
        n_ok = np.isfinite(toa_s).sum(axis=1)
        spread = C0 * (np.nanmax(toa_s, axis=1, initial=-np.inf, where=np.isfinite(toa_s))
                       - np.nanmin(toa_s, axis=1, initial=np.inf, where=np.isfinite(toa_s)))  # fmt: skip
    spread = spread[n_ok >= 2]
    if spread.size == 0:
        return
    typical = float(np.median(spread))
    span = max(float(np.linalg.norm(np.ptp(bs_xyz, axis=0))), 1.0)
    if typical > max(RANGE_SPANS * span, 1000.0):
        ratio = typical / span
        factor, unit = likely_time_unit(ratio)
        raise ScaleError(
            f"{where}: the ToA differences imply range differences of {typical:,.0f} m (median) "
            f"between base stations {span:,.0f} m apart: the ToAs are probably in {unit} "
            f"(x{factor:g}), give seconds"
        )


def check_height(height: str | float, bs_xyz: np.ndarray) -> None:
    """Refuse a known device height (``--height``) far from the base stations' heights.

    Allowed: within the stations' height range widened by their span (at least 100 m).
    """
    if isinstance(height, str):
        return
    z = bs_xyz[:, 2]
    span = max(float(np.linalg.norm(np.ptp(bs_xyz, axis=0))), 100.0)
    if not (z.min() - span <= height <= z.max() + span):
        hint = _length_hint(abs(height)) if abs(height) > MAX_SCENE_M else "give metres"
        raise ScaleError(
            f"--height {height:g} m is far from the base stations' heights "
            f"({z.min():.1f} .. {z.max():.1f} m): {hint}"
        )


def check_dataset(ds: Any) -> None:
    """The scale rule on a loaded :class:`~positioning.io.dataset.ToaDataset` (stations, ToAs)."""
    where = str(ds.path)
    check_stations(ds.bs_xyz, where)
    check_toa_scale(ds.toa_unscheduled_s, ds.bs_xyz, where)
