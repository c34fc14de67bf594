"""The scale rule shared by both packages: a factory hall is metres to a few hundred metres
across, never kilometres (standard library only).

One rule for every loader and tool: the ray tracer's scenes, hall sizes and positions
(``raytrace.core.scale``) and the positioning package's datasets (``positioning.io.scale``). A
size beyond :data:`MAX_SCENE_M` is refused before any heavy work, with the unit mistake that most
likely explains it: lengths in millimetres or centimetres read as metres
(:func:`likely_length_unit`), times in milliseconds, microseconds or nanoseconds read as seconds
(:func:`likely_time_unit`). Each package words its own messages.
"""

from __future__ import annotations

import math

#: Largest scene, hall, span of base stations or distance between sites the tools accept, m
#: ("a few km").
MAX_SCENE_M = 5000.0

#: Length units a too-large value was likely given in, largest factor first: (what the value is
#: in metres had it been in this unit = value / factor, unit name).
LENGTH_UNITS = ((1000.0, "millimetres"), (100.0, "centimetres"))

#: Time units a too-large value in seconds was likely given in: (factor, unit name).
TIME_UNITS = ((1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds"))


def likely_length_unit(size_m: float, limit_m: float = MAX_SCENE_M) -> tuple[float, str] | None:
    """The length unit a too-large size was most likely given in.

    Parameters
    ----------
    size_m : float, the size as read, "metres"
    limit_m : float, m, the largest acceptable size

    Returns
    -------
    ``(factor, unit)``: the first of :data:`LENGTH_UNITS` (largest factor first) that brings the
    size to between 1 m and ``limit_m``; None if none does.
    """
    for factor, unit in LENGTH_UNITS:
        if 1.0 <= size_m / factor <= limit_m:
            return factor, unit
    return None


def likely_time_unit(ratio: float) -> tuple[float, str]:
    """The time unit whose factor is nearest, in decades, to ``ratio`` (how many times too large
    a time read as seconds is): ``(factor, unit)`` of :data:`TIME_UNITS`.

    ``ratio`` : float > 0, dimensionless.
    """
    return min(TIME_UNITS, key=lambda fu: abs(math.log10(fu[0]) - math.log10(ratio)))
