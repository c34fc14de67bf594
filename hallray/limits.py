"""Size limits checked before any work: counts and products of counts, with their memory and
time estimates (standard library only).

A command (or a library call) that would run for hours or exhaust memory because a count is
absurd (``--duration 1e9``, ``--draws 1e9``, a hall YAML ``repeat`` of a million) is refused up
front with one line that names the count, what it would cost and the limit, instead of a
``MemoryError`` traceback after minutes. Every limit is in :data:`LIMITS`, one table, documented
in docs/reliability.md; the callers only name the limit and give the count (:func:`check_size`).

Those who mean it set the environment variable ``HALLRAY_NO_LIMITS=1`` (:data:`OVERRIDE_ENV`):
the checks are then skipped (the estimates stay in the messages of the checks that remain, e.g.
the scale rule of :mod:`hallray.units`, which is not a size limit but a unit mistake).

The estimates are rough (a 2-core machine of 2024; per-unit costs measured on the bundled hall,
docs/reliability.md): they are there to tell a typo (hours, terabytes) from a large but meant
run, not to predict run times.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from .errors import InputError

#: Set to 1 (or yes, true) to skip every size limit.
OVERRIDE_ENV = "HALLRAY_NO_LIMITS"


@dataclass(frozen=True)
class Limit:
    """A documented upper bound on a count.

    Attributes
    ----------
    maximum : int, the largest count accepted
    unit : str, what is counted (plural), e.g. ``"epochs"``
    bytes_each : float, bytes of memory one unit needs at once (0: not estimated)
    seconds_each : float, seconds one unit takes on one core (0: not estimated)
    """

    maximum: int
    unit: str
    bytes_each: float = 0.0
    seconds_each: float = 0.0


#: Every size limit, by name (docs/reliability.md lists them with their reasons).
LIMITS: dict[str, Limit] = {
    # a dataset: 600 epochs in the paper (60 s at 10 Hz); epochs are streamed to disk, so memory
    # stays flat; a semi-dynamic epoch of the bundled hall is traced in about 0.15 s
    "epochs": Limit(100_000, "epochs", seconds_each=0.15),
    # rows of one dataset's toa.csv (epochs x points x base stations), ~170 bytes each on disk
    "dataset rows": Limit(50_000_000, "rows", bytes_each=170.0),
    # accuracy map: noise draws per cell (100 by default); memory per chunk of cells
    "draws": Limit(10_000, "draws per cell", bytes_each=100_000.0),
    # accuracy map: positioning fixes in all (cells x draws x methods), ~20 us each
    "map fixes": Limit(200_000_000, "fixes", seconds_each=2e-5),
    # accuracy map: paths stored per cell and base station (16 by default), and in all
    "paths per link": Limit(10_000, "paths per link"),
    "map paths": Limit(20_000_000, "stored paths", bytes_each=72.0),
    # halls: objects after repeat, sides of a cylinder, triangles of the mesh
    "hall objects": Limit(50_000, "objects", bytes_each=4_000.0),
    "cylinder sections": Limit(1_024, "sides"),
    "hall triangles": Limit(5_000_000, "triangles", bytes_each=400.0),
    # generated halls (make-hall, hall-los-check, sweep cells): test points and base stations
    "points": Limit(100_000, "points", bytes_each=200.0),
    "base stations": Limit(1_000, "base stations"),
    # hall-los-check: halls generated and their links (segment tests)
    "seeds": Limit(10_000, "halls", seconds_each=0.5),
    "los links": Limit(100_000_000, "links", bytes_each=100.0, seconds_each=2e-6),
    # a sweep's cells
    "sweep cells": Limit(100_000, "cells", seconds_each=5.0),
    # render-scene: pixels of the picture
    "pixels": Limit(100_000_000, "pixels", bytes_each=12.0),
    # a YAML file's values after its aliases are expanded (a billion-laughs file is refused)
    "yaml values": Limit(1_000_000, "values", bytes_each=200.0),
}


class SizeError(InputError):
    """A count above its documented limit (one-line message: the count, its cost, the limit)."""


def overridden() -> bool:
    """Whether the user switched the limits off (``HALLRAY_NO_LIMITS=1``)."""
    return os.environ.get(OVERRIDE_ENV, "").strip().lower() in ("1", "yes", "true", "on")


def human_bytes(n: float) -> str:
    """``1.5 GB``-style size (decimal units)."""
    for unit, f in (("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n:.0f} bytes"


def human_seconds(s: float) -> str:
    """``3.2 h``-style duration."""
    for unit, f in (("years", 3.15e7), ("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if s >= f:
            return f"{s / f:.3g} {unit}"
    return f"{s:.2g} s"


def estimate(name: str, count: float) -> str:
    """What ``count`` units of limit ``name`` cost, as a clause (``"about 3 GB of memory and
    2 h"``), or an empty string when the limit has no estimate."""
    lim = LIMITS[name]
    parts = []
    if lim.bytes_each:
        parts.append(f"{human_bytes(count * lim.bytes_each)} of memory")
    if lim.seconds_each:
        parts.append(human_seconds(count * lim.seconds_each))
    return f"about {' and '.join(parts)}" if parts else ""


def check_size(name: str, count: float, what: str) -> None:
    """Refuse a count above the limit ``name`` of :data:`LIMITS` (unless overridden).

    Parameters
    ----------
    name : key of :data:`LIMITS`
    count : the count (an int, or a float product of counts that may overflow an int)
    what : how the message names it, e.g. ``"--duration 1e+06 s x --rate 10 Hz"``

    Raises
    ------
    SizeError
        ``what = <count> <unit>: about <memory> and <time>, above the limit of <max> <unit>;
        reduce it, or set HALLRAY_NO_LIMITS=1 to run it anyway``.
    """
    lim = LIMITS[name]
    if not count > lim.maximum or overridden():  # NaN counts are the callers' checks' business
        return
    cost = estimate(name, count)
    shown = f"{count:,.0f}" if count < 1e15 else f"{count:.3g}"
    raise SizeError(
        f"{what} = {shown} {lim.unit}{': ' + cost if cost else ''}, above the limit of "
        f"{lim.maximum:,} {lim.unit} (docs/reliability.md); reduce it, or set "
        f"{OVERRIDE_ENV}=1 to run it anyway"
    )
