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


#: Characters of a value's ``repr`` shown in an error message (:func:`brief`).
BRIEF_CHARS = 60


def brief(value: object, limit: int = BRIEF_CHARS) -> str:
    """``repr(value)`` for an error message, cut to ``limit`` characters: a message never prints
    an unbounded value (a list of a million items, a YAML alias chain). Containers are cut before
    their repr is built, so the cost is bounded too."""
    if isinstance(value, (list, tuple, set, frozenset, dict)) and len(value) > limit:
        kind = type(value).__name__
        return f"<{kind} of {len(value):,} items>"
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 3]}... ({len(text):,} characters)"
