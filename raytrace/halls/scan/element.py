"""One reconstructed element of a scan, a plane piece or an object (:class:`Element`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Element:
    """One reconstructed element: a plane piece or an object.

    Attributes
    ----------
    kind : ``plane`` or ``object``
    mesh : trimesh.Trimesh, world coordinates, metres
    closed : bool, a closed solid (slab, box, hull) rather than an open sheet
    material : str
    name : str, node name carrying the material (set when written)
    n_points : int, points explained
    normal, offset : plane ``normal . x = offset`` (planes; normal towards the points)
    bounding : bool, every point on one side (floor, ceiling, outer walls)
    features : dict, the quantities the material rules test
    """

    kind: str
    mesh: Any
    closed: bool
    n_points: int
    normal: np.ndarray | None = None
    offset: float | None = None
    bounding: bool = False
    area_m2: float = 0.0
    polygon: Any = None
    frame: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    material: str = ""
    name: str = ""
    features: dict[str, Any] = field(default_factory=dict)
