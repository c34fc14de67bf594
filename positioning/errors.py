"""Exceptions of the positioning package.

``positioning`` never imports ``raytrace``, so it has its own error class. It derives from
:class:`hallray.errors.InputError` (a :class:`ValueError`); every error a user can cause by bad
input is a :class:`PositioningError` with a one-line message naming the bad thing, and the
command harness (:mod:`hallray.harness`) turns it into ``error: <message>`` on stderr and exit
status 2.
"""

from __future__ import annotations

from hallray.errors import InputError


class PositioningError(InputError):
    """Bad input to the positioning functions or tools (one-line message, shown as is)."""
