"""An output directory built whole or not at all: built in a temporary directory beside it
(:func:`stage_output`) and renamed into place when complete (:func:`hallray.safe_output.commit_dir`,
the one rename of both packages). Datasets and accuracy maps are written this way.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ...core.errors import HallrayError


def stage_output(out: Path, force: bool) -> Path:
    """Check an output directory and create the temporary one beside it, where the output is
    built whole before :func:`hallray.safe_output.commit_dir` renames it into place (datasets, accuracy maps).

    Parameters
    ----------
    out : Path, the output directory (must not exist or be empty, unless ``force``)
    force : bool, a non-empty ``out`` will be replaced

    Returns
    -------
    Path, the new temporary directory (``.<name>.*.tmp`` beside ``out``, readable by others as
    the umask allows)

    Raises
    ------
    HallrayError
        ``out`` is a file, is not empty (without ``force``), or its parent does not exist.
    """
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise HallrayError(f"output directory {out} is not empty (use --force to replace it)")
    parent = out.resolve().parent
    if not parent.is_dir():
        raise HallrayError(f"parent directory of {out} does not exist")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    umask = os.umask(0o022)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700: a dataset is for others to read too
    return tmp
