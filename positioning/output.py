"""Deprecated: ``positioning.output`` moved to :mod:`hallray.safe_output`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    name: "hallray.safe_output"
    for name in ("PathLike", "STDOUT", "OutputError", "umask", "check_output", "output_lock",
                 "Writer", "write_file", "replace_atomic", "output_dir")
}  # fmt: skip

__getattr__, __dir__ = forward(__name__, MOVED)
