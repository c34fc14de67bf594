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
from hallray.units import MAX_SCENE_M

from .errors import HallrayError


class ScaleError(HallrayError):
    """A size or position beyond what a hall can be: most likely a unit mistake."""


def unit_hint(size_m: float, limit_m: float = MAX_SCENE_M) -> str:
    """The likely unit mistake behind a too-large size, as a clause for a message."""
    for factor, unit in UNIT_FACTORS:
        if size_m / factor <= limit_m and size_m / factor >= 1.0:
            return f"the numbers are probably in {unit} (x{factor:g}): scale them to metres"
    return "give coordinates in metres"


def check_size(size_m: float, what: str, limit_m: float = MAX_SCENE_M) -> None:
    """Refuse a size (an extent, a span of positions) over ``limit_m``, naming the unit mistake.

    Parameters
    ----------
    size_m : float, the largest extent, m
    what : str, what is measured, e.g. ``"scene hall.obj"`` (the message starts with it)
    limit_m : float, the largest acceptable size, m

    Raises
    ------
    ScaleError
    """
    if math.isfinite(size_m) and size_m > limit_m:
        raise ScaleError(
            f"{what} is {size_m:,.0f} m, beyond the {limit_m / 1000:g} km a hall can span: "
            f"{unit_hint(size_m, limit_m)}"
        )
