"""Exceptions of the ray tracer.

Every error a user can cause by bad input is a :class:`HallrayError`; the command-line tools turn it
into a one-line message and a non-zero exit status, never a traceback.
"""

from __future__ import annotations


class HallrayError(ValueError):
    """Bad input to the tracer or its tools (message is one line, shown to the user as is)."""


class MaterialError(HallrayError):
    """Unknown material, bad material definition, or a frequency outside a material's range."""


class SceneError(HallrayError):
    """A scene file that cannot be read, is empty, or has objects without a material."""


class TraceInputError(HallrayError):
    """Bad transmitter/receiver positions or tracer settings."""
