"""Locate the scenes bundled with the package (the reference hall and the canonical test scenes).

Installed, the repository's ``scenes/`` directory is the package ``raytrace._scenes``; in a source
checkout it is ``scenes/`` beside ``raytrace/``. Both are found the same way.
"""

from __future__ import annotations

from pathlib import Path


def scenes_dir() -> Path:
    """Directory holding the bundled scenes (``hall.glb``, ``hall.yaml``, ``canonical/``)."""
    try:
        from importlib.resources import files

        path = Path(str(files("raytrace._scenes")))
        if (path / "hall.yaml").exists():
            return path
    except ModuleNotFoundError:
        pass
    return Path(__file__).resolve().parents[2] / "scenes"


def resolve_scene(name_or_path: str | Path) -> Path:
    """Path of a scene given as a file path or as a bundled name.

    ``"hall"`` is the bundled reference hall (``hall.glb``); ``"canonical/shoebox"`` a canonical
    scene. An existing file is returned unchanged (a directory of the same name as a bundled
    scene does not hide it).
    """
    path = Path(name_or_path)
    if path.is_file():
        return path
    base = scenes_dir()
    for candidate in (base / f"{name_or_path}.glb", base / str(name_or_path)):
        if candidate.exists():
            return candidate
    return path
