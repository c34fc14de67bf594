"""The report's files: each written to a temporary file in the target directory and renamed
(:func:`hallray.safe_output.replace_atomic`), so a failed run never leaves a half-written file."""

from __future__ import annotations

import io
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any


def atomic_write(path: str | Path, write: Callable[[Any], None], *, binary: bool = False) -> None:
    """Call ``write(fh)`` on a temporary file beside ``path``, then rename it to ``path``
    (:func:`hallray.safe_output.replace_atomic`: the umask's mode, symlinks followed)."""
    from hallray.safe_output import replace_atomic

    real = Path(os.path.realpath(path))
    replace_atomic(real, write if binary else lambda fh: _write_text(fh, write))


def _write_text(fh: Any, write: Callable[[Any], None]) -> None:
    text = io.TextIOWrapper(fh, encoding="utf-8", newline="")
    write(text)
    text.flush()
    text.detach()  # leave the binary file open for the caller's fsync


def is_report_dir(path: Path) -> bool:
    """Whether a directory holds a previous report (``table.md``): accuracy-report replaces it."""
    return (path / "table.md").is_file()


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_write`."""
    atomic_write(path, lambda fh: fh.write(text))


def save_figure(fig: Any, path: str | Path, dpi: int = 120) -> None:
    """Save a matplotlib Figure as PNG atomically."""
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi), binary=True)


def safe_name(text: str) -> str:
    """File-name-safe version of a dataset name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "dataset"
