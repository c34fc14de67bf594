"""The arrays a scene is made of: objects, planar facets and wedges (structure of arrays).

Plain containers without behaviour beyond their shapes; :mod:`raytrace.scene.model` builds them
from meshes and :mod:`raytrace.scene.accel` derives the arrays the mechanisms prune with.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np


class _ElementArrays:
    """Structure-of-arrays behaviour shared by :class:`Facets` and :class:`Wedges`.

    Every dataclass field but the trailing ``cache`` is an array with one row per element. The
    cache is not an argument of the constructor, so a copy made by ``dataclasses.replace`` (a
    posed snapshot's moved facets) starts with an empty one instead of sharing the original's.
    """

    def __len__(self) -> int:
        return int(getattr(self, fields(self)[0].name).shape[0])  # type: ignore[arg-type]

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-element arrays by field name (everything but the cache)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "cache"}  # type: ignore[arg-type]

    def __getstate__(self) -> dict[str, Any]:
        # the cache is derived: a pickled copy (a worker's scene) starts without it, so that the
        # bytes of a scene, and the digest its kept pool is found by, do not change once traced
        return {**self.arrays(), "cache": {}}

    def __setstate__(self, state: dict[str, Any]) -> None:
        for k, v in state.items():
            object.__setattr__(self, k, v)


@dataclass(frozen=True)
class Facets(_ElementArrays):
    """Planar facets (connected coplanar triangles of one object), structure of arrays.

    Attributes
    ----------
    normal : (K, 3) float, unit outward normal (for open sheets: the stored one; both sides reflect)
    offset : (K,) float, metres; the plane is ``normal . x = offset``
    object : (K,) int, object index
    material : (K,) int, index into ``Scene.material_names``
    two_sided : (K,) bool, True for facets of open sheets
    area : (K,) float, m^2
    tri_start, tri_count : (K,) int, the facet's triangles are
        ``Facets.triangles[tri_start[k] : tri_start[k] + tri_count[k]]``
    triangles : (M, 3, 3) float, vertices of the facets' triangles, metres
    """

    normal: np.ndarray
    offset: np.ndarray
    object: np.ndarray
    material: np.ndarray
    two_sided: np.ndarray
    area: np.ndarray
    tri_start: np.ndarray
    tri_count: np.ndarray
    triangles: np.ndarray
    #: Derived arrays (bounding boxes, spheres, facing pairs), computed on first use by
    #: :mod:`raytrace.scene.accel`; never copied to another Facets.
    cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)


@dataclass(frozen=True)
class Wedges(_ElementArrays):
    """Diffracting edges, structure of arrays.

    Attributes
    ----------
    start, end : (W, 3) float, edge end points, metres
    direction : (W, 3) float, unit vector from start to end
    length : (W,) float, metres
    normal0, normal1 : (W, 3) float, outward unit normals of the two faces (for the free edge of a
        sheet, the sheet normal and its opposite)
    face0_dir : (W, 3) float, unit vector perpendicular to the edge, from the edge into face 0
    n : (W,) float, exterior wedge angle over pi (2 for a half-plane, 1.5 for a right-angle corner)
    object : (W,) int
    material : (W,) int
    """

    start: np.ndarray
    end: np.ndarray
    direction: np.ndarray
    length: np.ndarray
    normal0: np.ndarray
    normal1: np.ndarray
    face0_dir: np.ndarray
    n: np.ndarray
    object: np.ndarray
    material: np.ndarray
    #: Derived arrays (groups by object), computed on first use by :mod:`raytrace.scene.accel`.
    cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)


@dataclass
class SceneObject:
    """One object of the scene (one Embree geometry)."""

    name: str
    material: str
    closed: bool
    face_start: int
    face_count: int
