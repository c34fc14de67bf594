"""Deprecated: ``positioning.command`` moved to :mod:`hallray.harness`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    name: "hallray.harness"
    for name in ("EXIT_OK", "EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_BROKEN_PIPE",
                 "OneLineParser", "one_line", "run_command")
}  # fmt: skip

__getattr__, __dir__ = forward(__name__, MOVED)
