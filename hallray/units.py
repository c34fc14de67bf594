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

#: Tallest hall the tools accept, m (the tallest halls are about 160 m high): a height in the
#: kilometres of MAX_SCENE_M is a plan in millimetres or centimetres.
MAX_HALL_HEIGHT_M = 200.0
#: Smallest extent a scene, a hall or a set of base stations may have, m: below it, a hall was
#: given in kilometres.
MIN_SCENE_M = 0.5
#: Carrier frequencies the tracer accepts, Hz (100 MHz .. 1 THz): geometric optics needs the
#: wavelength (3 m .. 0.3 mm) small against the hall; 3.5 "Hz" is 3.5 GHz in the wrong unit.
MIN_FREQUENCY_HZ = 1e8
MAX_FREQUENCY_HZ = 1e12

#: Length units a too-large value was likely given in, largest factor first: (what the value is
#: in metres had it been in this unit = value / factor, unit name).
LENGTH_UNITS = ((1000.0, "millimetres"), (100.0, "centimetres"))
#: Length units a too-small value was likely given in: (factor, unit name), value / factor in m.
SMALL_LENGTH_UNITS = ((0.001, "kilometres"),)
#: Frequency units a too-low value in Hz was likely given in: (factor, unit name).
FREQUENCY_UNITS = ((1e9, "GHz"), (1e6, "MHz"), (1e3, "kHz"))

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


def likely_small_length_unit(size_m: float) -> tuple[float, str] | None:
    """The length unit a too-small size (below :data:`MIN_SCENE_M`) was likely given in:
    ``(factor, unit)`` of :data:`SMALL_LENGTH_UNITS` bringing it to between
    :data:`MIN_SCENE_M` and :data:`MAX_SCENE_M` (value / factor), or None."""
    for factor, unit in SMALL_LENGTH_UNITS:
        if size_m > 0 and MIN_SCENE_M <= size_m / factor <= MAX_SCENE_M:
            return factor, unit
    return None


def frequency_problem(frequency_hz: float) -> str | None:
    """Why a carrier frequency is not one the tracer takes (None: it is), naming the likely unit
    mistake: ``"3.5 Hz is below 100 MHz: probably in GHz (x1e9), give Hz"``."""
    f = float(frequency_hz)
    if not (math.isfinite(f) and f > 0):
        return f"{f:g} Hz is not a positive number"
    if MIN_FREQUENCY_HZ <= f <= MAX_FREQUENCY_HZ:
        return None
    if f > MAX_FREQUENCY_HZ:
        return f"{f:g} Hz is above {MAX_FREQUENCY_HZ:g} Hz (1 THz): give the carrier in Hz"
    for factor, unit in FREQUENCY_UNITS:
        if MIN_FREQUENCY_HZ <= f * factor <= MAX_FREQUENCY_HZ:
            return f"{f:g} Hz is below {MIN_FREQUENCY_HZ:g} Hz (100 MHz): probably in {unit} (x{factor:g}), give Hz"
    return f"{f:g} Hz is below {MIN_FREQUENCY_HZ:g} Hz (100 MHz), where a hall is not many wavelengths across"
