"""Exceptions of the ray tracer.

Every error a user can cause by bad input is a :class:`HallrayError`; the command-line tools turn it
into a one-line message and a non-zero exit status, never a traceback.
"""

from __future__ import annotations

from hallray.errors import InputError


class HallrayError(InputError):
    """Bad input to the tracer or its tools (message is one line, shown to the user as is).

    An :class:`hallray.errors.InputError` (a ``ValueError``), like the positioning package's
    errors and the size limits' :class:`hallray.limits.SizeError`."""


class MaterialError(HallrayError):
    """Unknown material, bad material definition, or a frequency outside a material's range."""


class SceneError(HallrayError):
    """A scene file that cannot be read, is empty, or has objects without a material."""


class TraceInputError(HallrayError):
    """Bad transmitter/receiver positions or tracer settings."""
