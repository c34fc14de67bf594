"""Deprecated: the safe output layer moved to :mod:`hallray.safe_output` (old names forward for
one release, with a :class:`DeprecationWarning`)."""

from __future__ import annotations

from .deprecated import forward

__getattr__, __dir__ = forward(__name__, {
    name: "hallray.safe_output"
    for name in ("PathLike", "STDOUT", "OutputError", "umask", "check_output", "output_lock",
                 "Writer", "write_file", "replace_atomic", "output_dir")
})  # fmt: skip
