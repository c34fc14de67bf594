"""The one reader of a scene's deployment metadata (``metadata["hallray"]``).

Scenes built by the hall tools (and any glb/XML that carries the same block) name their base
stations, points of interest, forklift routes, hall size and 2D obstacle footprints there; every
tool that needs them reads them through :class:`SceneMetadata`, with the same validation and
one-line :class:`~raytrace.core.errors.SceneError` messages.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import SceneError
from .motion import Route


def _block(metadata: Any) -> dict[str, Any]:
    """The ``hallray`` block of a scene's metadata ({} if absent or malformed)."""
    if not isinstance(metadata, Mapping):
        return {}
    block = metadata.get("hallray", {})
    return dict(block) if isinstance(block, Mapping) else {}


def named_positions(raw: Any, what: str) -> tuple[list[str], np.ndarray]:
    """Names and ``(n, 3)`` float positions of a list of ``{"name", "xyz"}`` entries.

    Raises :class:`SceneError` for a missing list, an entry without a name or a finite xyz, or
    duplicate names.
    """
    if not isinstance(raw, list) or not raw:
        raise SceneError(f"the scene has no {what} (metadata['hallray']['{what}'])")
    names, xyz = [], []
    for i, entry in enumerate(raw):
        try:
            name = str(entry["name"])
            p = np.asarray(entry["xyz"], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise SceneError(f"scene metadata: {what}[{i}] needs a name and an xyz") from None
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise SceneError(f"scene metadata: {what}[{i}] ('{name}') needs a finite xyz")
        names.append(name)
        xyz.append(p)
    if len(set(names)) != len(names):
        raise SceneError(f"scene metadata: duplicate names in {what}")
    return names, np.array(xyz)


def routes_from_metadata(metadata: Mapping[str, Any]) -> list[Route]:
    """Routes stored in a scene's metadata (``metadata["hallray"]["routes"]``); [] if none."""
    block = metadata.get("hallray", metadata) if isinstance(metadata, Mapping) else {}
    raw = block.get("routes") if isinstance(block, Mapping) else None
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise SceneError("scene metadata: 'routes' must be a list")
    routes = [Route.from_dict(r, f"routes[{k}]") for k, r in enumerate(raw)]
    names = [r.name for r in routes]
    if len(set(names)) != len(names):
        raise SceneError("scene metadata: duplicate route names")
    return routes


@dataclass(frozen=True)
class SceneMetadata:
    """Base stations, points and routes of a scene (empty where the scene names none).

    Attributes
    ----------
    bs_names : list of str; bs_xyz : (B, 3) float, metres
    point_names : list of str; point_xyz : (P, 3) float, metres
    routes : list of Route
    block : dict, the whole ``hallray`` block (hall size, area of interest, obstacles, ...)
    """

    bs_names: list[str]
    bs_xyz: np.ndarray
    point_names: list[str]
    point_xyz: np.ndarray
    routes: list[Route]
    block: dict[str, Any]

    @classmethod
    def from_metadata(cls, metadata: Any, *, require: bool = False) -> SceneMetadata:
        """Read and validate the block.

        Parameters
        ----------
        metadata : the scene's ``metadata`` dict
        require : bool, the base stations and points must be present (a dataset needs them);
            otherwise missing lists give empty arrays (malformed ones still raise)
        """
        block = _block(metadata)
        sites = []
        for key in ("base_stations", "points"):
            if block.get(key) or require:
                sites.append(named_positions(block.get(key), key))
            else:
                sites.append(([], np.zeros((0, 3))))
        (bs_names, bs_xyz), (pt_names, pt_xyz) = sites
        return cls(bs_names, bs_xyz, pt_names, pt_xyz, routes_from_metadata(metadata), block)

    @classmethod
    def from_scene(cls, scene: Any, *, require: bool = False) -> SceneMetadata:
        """:meth:`from_metadata` of ``scene.metadata``."""
        return cls.from_metadata(getattr(scene, "metadata", {}), require=require)

    @property
    def hall_size(self) -> tuple[float, float, float] | None:
        """``hall.size`` (width x, depth y, height z), metres, if the scene states it."""
        hall = self.block.get("hall")
        try:
            w, d, h = (float(v) for v in hall["size"][:3])  # type: ignore[index]
        except (TypeError, KeyError, ValueError, IndexError):
            return None
        return w, d, h
