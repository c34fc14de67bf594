"""What a scene says about its hall: the floor's height, the hall's outline and the service area.

A dataset's ``meta.json`` and an accuracy map both record where a device can be; the map also
needs the floor and the ceiling to check its device height. They are facts of the scene (its
facets and the ``hallray`` block of its metadata), so they are read here, once per scene
(:meth:`SceneFacts.of`), and the upper floors take them from this one place:

* **floor level** (:func:`floor_level`): the lowest large upward-facing facet, else the bottom
  of the scene;
* **hall outline** (:func:`hall_xy`): the hall interior ``[[x0, y0], [x1, y1]]``, from the
  metadata's ``hall.size`` (its corner at the origin), else the scene's bounding box;
* **service area** (:func:`service_area`): the floor outline inside the walls
  (:meth:`raytrace.scene.model.Scene.floor_outline`), else the rectangle of ``hall.size``, else
  none; :attr:`SceneFacts.area_xy` falls back to the bounding box;
* **floor and ceiling** of a device's height (:attr:`SceneFacts.height_range`).

Distances in metres.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .metadata import SceneMetadata


def floor_level(scene: Any) -> float:
    """Height of a scene's floor, m: the lowest large upward-facing facet (normal within 8 deg
    of vertical, at least 5 % of the largest facet's area), else the bottom of the scene."""
    f = scene.facets
    if len(f) == 0:
        return float(scene.bounds[0, 2])
    up = (f.normal[:, 2] > 0.99) & (f.area > 0.05 * f.area.max())
    return float(f.offset[up].min()) if up.any() else float(scene.bounds[0, 2])


def hall_width_depth(block: Mapping[str, Any]) -> tuple[float, float] | None:
    """Width (x) and depth (y) of ``hall.size`` in the scene's ``hallray`` block, m, if stated
    (two numbers are enough: the height is not needed)."""
    hall = block.get("hall") if isinstance(block, Mapping) else None
    try:
        w, d = (float(v) for v in hall["size"][:2])  # type: ignore[index]
    except (TypeError, KeyError, ValueError, IndexError):
        return None
    return w, d


def hall_xy(scene: Any, block: Mapping[str, Any]) -> list[list[float]]:
    """The hall interior ``[[x0, y0], [x1, y1]]``, m (a dataset's ``meta.json`` ``hall_xy``):
    ``hall.size`` of the ``hallray`` block from the origin, else the scene's bounding box."""
    return _hall_xy(scene.bounds, block)


def _hall_xy(bounds: np.ndarray, block: Mapping[str, Any]) -> list[list[float]]:
    """:func:`hall_xy` from the scene's bounding box (2, 3)."""
    wd = hall_width_depth(block)
    if wd is not None:
        return [[0.0, 0.0], [wd[0], wd[1]]]
    lo, hi = bounds
    return [[float(lo[0]), float(lo[1])], [float(hi[0]), float(hi[1])]]


def _service_area(outline: np.ndarray | None, block: Mapping[str, Any]) -> dict[str, Any] | None:
    """:func:`service_area` from a floor outline already computed."""
    if outline is not None:
        src = "floor outline of the scene inside its walls"
        return {"polygon": [[float(x), float(y)] for x, y in outline], "source": src}
    wd = hall_width_depth(block)
    if wd is None:
        return None
    w, d = wd
    return {"polygon": [[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]], "source": "hall size"}


def service_area(scene: Any, block: Mapping[str, Any]) -> dict[str, Any] | None:
    """A scene's service area: where a device can be, as positioning bounds its fixes.

    Parameters
    ----------
    scene : Scene
    block : mapping, the scene's ``hallray`` metadata block

    Returns
    -------
    dict ``{"polygon": [[x, y], ...], "source": str}`` (m; a dataset's ``meta.json``
    ``service_area``): the scene's floor outline inside its walls
    (:meth:`~raytrace.scene.model.Scene.floor_outline`); for a scene without a floor, the
    rectangle of the metadata's hall size; otherwise None.
    """
    return _service_area(scene.floor_outline(), block)


@dataclass(frozen=True)
class SceneFacts:
    """A scene's hall facts, read once (module docstring): plain values, so that what is built
    from them (a dataset's ``meta.json``, a map's grid) does not go back to the scene.

    Attributes
    ----------
    sha256 : str, :meth:`~raytrace.scene.model.Scene.content_hash`
    hall_xy : [[x0, y0], [x1, y1]], m, :func:`hall_xy`
    service_area : dict or None, :func:`service_area`
    area_xy : (K, 2) float, m, the service area's polygon, else the scene's bounding box
    height_range : (floor, ceiling), m, of a device in the hall: the floor level (the bottom of
        the scene when it has no floor: it is open below) and the top of the scene, lowered to
        the floor plus the metadata's hall height if that is less
    """

    sha256: str
    hall_xy: list[list[float]]
    service_area: dict[str, Any] | None
    area_xy: np.ndarray
    height_range: tuple[float, float]

    @classmethod
    def of(cls, scene: Any, block: Mapping[str, Any] | None = None) -> SceneFacts:
        """The facts of ``scene``; ``block`` is its ``hallray`` metadata block when the caller
        has read it already (:attr:`raytrace.scene.metadata.SceneMetadata.block`)."""
        if block is None:
            block = SceneMetadata.from_scene(scene).block
        bounds = scene.bounds
        outline = scene.floor_outline()
        area = _service_area(outline, block)
        if area is not None:
            area_xy = np.asarray(area["polygon"], dtype=float)
        else:
            (x0, y0, _), (x1, y1, _) = bounds
            area_xy = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
        floor = floor_level(scene) if outline is not None else float(bounds[0, 2])
        top = float(bounds[1, 2])
        size = SceneMetadata.from_metadata({"hallray": block}).hall_size
        if size is not None:
            top = min(top, floor + size[2])
        return cls(scene.content_hash(), _hall_xy(bounds, block), area, area_xy, (floor, top))
