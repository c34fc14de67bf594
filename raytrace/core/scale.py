"""The scale sanity rule: a factory hall is metres to a few hundred metres across, never km.

One rule for every loader and tool (scenes, hall sizes, transmitter and receiver positions); the
positioning package applies the same rule to datasets (:mod:`positioning.io.scale`). Both take its
constants from :mod:`hallray.units`. A size beyond :data:`MAX_SCENE_M` is refused before any heavy
work, with the unit mistake that most likely explains it (millimetres or centimetres read as
metres).
"""

from __future__ import annotations

import math

from hallray.units import LENGTH_UNITS as UNIT_FACTORS
from hallray.units import (
    MAX_HALL_HEIGHT_M,
    MAX_SCENE_M,
    MIN_SCENE_M,
    frequency_problem,
    likely_small_length_unit,
)

from .errors import HallrayError


class ScaleError(HallrayError):
    """A size or position beyond what a hall can be: most likely a unit mistake."""


#: Short names of :data:`hallray.units.LENGTH_UNITS`, as a scene's ``--unit`` takes them.
UNIT_ABBREVIATIONS = {"millimetres": "mm", "centimetres": "cm", "kilometres": "km"}


def unit_hint(size_m: float, limit_m: float = MAX_SCENE_M, option: str | None = None) -> str:
    """The likely unit mistake behind a too-large size, as a clause for a message; with
    ``option`` (a scene's ``"--unit"``), the fix is that option with the unit's short name."""
    for factor, unit in UNIT_FACTORS:
        if size_m / factor <= limit_m and size_m / factor >= 1.0:
            fix = (f"read it with {option} {UNIT_ABBREVIATIONS[unit]}" if option
                   else "scale them to metres")  # fmt: skip
            return f"the numbers are probably in {unit} (x{factor:g}): {fix}"
    return "give coordinates in metres"


def check_size(
    size_m: float, what: str, limit_m: float = MAX_SCENE_M, option: str | None = None
) -> None:
    """Refuse a size (an extent, a span of positions) over ``limit_m``, naming the unit mistake.

    Parameters
    ----------
    size_m : float, the largest extent, m
    what : str, what is measured, e.g. ``"scene hall.obj"`` (the message starts with it)
    limit_m : float, the largest acceptable size, m
    option : str, optional, the option that reads the numbers in another unit (``"--unit"``)

    Raises
    ------
    ScaleError
    """
    if math.isfinite(size_m) and size_m > limit_m:
        raise ScaleError(
            f"{what} is {size_m:,.0f} m, beyond the {limit_m / 1000:g} km a hall can span: "
            f"{unit_hint(size_m, limit_m, option)}"
        )


def check_extent(
    size_m: tuple[float, float, float] | list[float], what: str, option: str | None = None
) -> None:
    """The scale rule on a hall's or scene's extent ``(x, y, z)`` in metres: at most
    :data:`MAX_SCENE_M` across, at most :data:`~hallray.units.MAX_HALL_HEIGHT_M` high, and at
    least :data:`~hallray.units.MIN_SCENE_M` across (a hall in kilometres). Raises
    :class:`ScaleError` naming the likely unit mistake (and ``option``, :func:`check_size`).
    """
    x, y, z = (float(v) for v in size_m)
    check_size(max(x, y, z), what, option=option)
    if math.isfinite(z) and z > MAX_HALL_HEIGHT_M:
        raise ScaleError(
            f"{what} is {z:,.0f} m high, more than the {MAX_HALL_HEIGHT_M:g} m a hall can be: "
            f"{unit_hint(z, MAX_HALL_HEIGHT_M, option)}"
        )
    big = max(x, y, z)
    if math.isfinite(big) and big < MIN_SCENE_M:
        found = likely_small_length_unit(big)
        hint = (
            f"the numbers are probably in {found[1]} (x{found[0]:g}): "
            + (f"read it with {option} {UNIT_ABBREVIATIONS[found[1]]}" if option
               else "scale them to metres")
            if found
            else "give coordinates in metres"
        )
        raise ScaleError(f"{what} is {big:g} m across, less than the {MIN_SCENE_M:g} m of a hall: {hint}")


def check_frequency(frequency_hz: float, what: str = "frequency") -> float:
    """The scale rule on a carrier frequency (:func:`hallray.units.frequency_problem`); returns
    it as a float. Raises :class:`ScaleError`."""
    problem = frequency_problem(frequency_hz)
    if problem is not None:
        raise ScaleError(f"{what}: {problem}")
    return float(frequency_hz)
