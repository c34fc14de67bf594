"""Deprecated: the command harness moved to :mod:`hallray.harness` (old names forward for one
release, with a :class:`DeprecationWarning`)."""

from __future__ import annotations

from .deprecated import forward

__getattr__, __dir__ = forward(__name__, {
    name: "hallray.harness"
    for name in ("EXIT_OK", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_BROKEN_PIPE",
                 "OneLineParser", "one_line", "run_command")
})  # fmt: skip
