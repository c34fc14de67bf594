"""The base of every error a user can cause by bad input (standard library only).

:class:`InputError` derives from :class:`ValueError`. Its message is one line that names the bad
thing; the command harness (:func:`hallray.harness.run_command`) shows it as ``error: <message>``
on stderr with exit status 2, never a traceback. ``positioning.PositioningError`` and the safe
output layer's :class:`~hallray.safe_output.OutputError` derive from it; the ray tracer's
``raytrace.core.errors.HallrayError`` is given to the harness as a bad-input type of its own.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input to a command or a library function (one-line message, shown as is)."""
