"""A big scene's preprocessing kept on disk beside its file, so the next load skips it.

Building a :class:`~raytrace.scene.model.Scene` from a mesh of 10^5-10^6 triangles (trimesh's
processing, facets, wedges, buried and junction edges) takes 10 s to a minute; reading back the
built arrays takes a fraction of a second. :func:`cached_build` keeps the built scene (its
arrays, objects, materials and metadata: what a pickled scene carries, not the Embree scene or
the trees, rebuilt in well under a second) in ``.hallray-cache/`` beside the scene file.

The key is a SHA-256 of everything the built scene depends on: the scene file's bytes (for a
Mitsuba XML also every mesh file it names and its hallray sidecar), the materials (file bytes
or content), the default material, the smooth angle, the package version and the source of the
modules that build scenes. A changed input is a new key: the stale file of the same scene is
deleted when the new one is written. The cache is safe to delete at any time.

A cache file is a pickle, read with the trust given to the directory it sits in (as Python
trusts the ``__pycache__`` beside a module): do not load scenes from directories that others
can write to, or pass ``cache=False``.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import re
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["CACHE_DIR", "CACHE_MIN_TRIANGLES", "cache_key", "cache_path", "cached_build"]

#: Folder of the cache, beside the scene file.
CACHE_DIR = ".hallray-cache"
#: Scenes with at least this many triangles are cached by default (smaller ones build in well
#: under a second, faster than their cache would be hashed, written and read).
CACHE_MIN_TRIANGLES = 20_000
#: Format of the cached object; raise it when what is pickled changes shape.
CACHE_FORMAT = 1
#: Modules whose code decides the built scene: a changed line is a new key (a development
#: checkout edits code without changing the version).
_BUILDERS = ("construction.py", "elements.py", "model.py", "io.py", "mitsuba.py", "diskcache.py")
_FILENAME = re.compile(r'name\s*=\s*"filename"\s+value\s*=\s*"([^"]+)"|value\s*=\s*"([^"]+)"\s+name\s*=\s*"filename"')


def _code_digest() -> str:
    from ..core.version import __version__

    h = hashlib.sha256(f"{__version__} {CACHE_FORMAT}".encode())
    here = Path(__file__).parent
    for name in _BUILDERS:
        h.update((here / name).read_bytes())
    return h.hexdigest()


def _scene_files(path: Path) -> list[Path]:
    """The files a scene is read from: the file itself, and for a Mitsuba XML the mesh files it
    names and its sidecar."""
    files = [path]
    if path.suffix.lower() == ".xml":
        from .mitsuba import SIDECAR_SUFFIX

        text = path.read_text(errors="replace")
        for m in _FILENAME.finditer(text):
            ref = path.parent / (m.group(1) or m.group(2))
            if ref.is_file():
                files.append(ref)
        side = path.with_name(path.stem + SIDECAR_SUFFIX)
        if side.is_file():
            files.append(side)
    return files


def _materials_digest(materials: Any) -> str:
    if materials is None:
        return "none"
    if isinstance(materials, str | Path):
        return hashlib.sha256(Path(materials).read_bytes()).hexdigest()
    if isinstance(materials, dict):
        return hashlib.sha256(json.dumps(materials, sort_keys=True, default=repr).encode()).hexdigest()
    return hashlib.sha256(pickle.dumps(materials, protocol=5)).hexdigest()


def cache_key(path: Path, materials: Any, options: dict[str, Any]) -> str:
    """SHA-256 (hex) of the scene's files, the materials, the build options and the code.

    Parameters
    ----------
    path : Path
        The scene file.
    materials : MaterialLibrary, YAML path, dict or None
        As given to :func:`~raytrace.scene.io.load_scene`.
    options : dict
        The other build options (default material, smooth angle), JSON-serialisable.
    """
    h = hashlib.sha256(_code_digest().encode())
    for f in _scene_files(path):
        h.update(f.name.encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 22), b""):
                h.update(block)
    h.update(_materials_digest(materials).encode())
    h.update(json.dumps(options, sort_keys=True).encode())
    return h.hexdigest()


def cache_path(path: Path, key: str) -> Path:
    """Where the scene ``path`` built under ``key`` is kept."""
    return path.parent / CACHE_DIR / f"{path.name}.{key[:24]}.scene.pkl"


def _read(file: Path) -> Any | None:
    try:
        with open(file, "rb") as fh:
            head = pickle.load(fh)
            if head != ("hallray-scene", CACHE_FORMAT):
                return None
            return pickle.load(fh)
    except FileNotFoundError:
        return None
    except Exception:  # a truncated or foreign file: rebuilt and replaced
        return None


def _write(file: Path, scene: Any, stem: str) -> None:
    """Write atomically (temporary file, then rename); drop the scene's older cache files. A
    directory that cannot be written is a warning, not an error: the scene is built anyway."""
    try:
        file.parent.mkdir(exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=file.parent, prefix=".tmp-", suffix=".pkl")
        try:
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(("hallray-scene", CACHE_FORMAT), fh, protocol=5)
                pickle.dump(scene, fh, protocol=5)
            os.replace(tmp, file)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        for old in file.parent.glob(f"{stem}.*.scene.pkl"):
            if old != file:
                old.unlink(missing_ok=True)
    except OSError as exc:
        warnings.warn(f"scene cache not written ({exc.strerror or exc}): {file.parent}",
                      stacklevel=3)  # fmt: skip


def cached_build(
    path: Path,
    materials: Any,
    options: dict[str, Any],
    build: Callable[[], Any],
    cache: bool | None = None,
) -> Any:
    """The scene ``build()`` makes from ``path``, from the disk cache when it holds it.

    Parameters
    ----------
    path : Path
        The scene file (resolved).
    materials, options
        What the built scene depends on besides the file (:func:`cache_key`).
    build : callable
        Builds the scene (reads and processes the file).
    cache : bool, optional
        True: always cache; False: never read or write the cache; None: read it if present and
        write it for scenes of at least :data:`CACHE_MIN_TRIANGLES` triangles.
    """
    if cache is False:
        return build()
    key = cache_key(path, materials, options)
    file = cache_path(path, key)
    scene = _read(file)
    if scene is not None:
        scene.source = str(path)
        return scene
    scene = build()
    if cache or len(scene.faces) >= CACHE_MIN_TRIANGLES:
        _write(file, scene, path.name)
    return scene
