"""The cells of a map: a lattice over the scene's service area at device height, without the
cells inside solids, shifted so that no cell centre is nearer than the clearance to a test
point (:func:`make_grid`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.errors import HallrayError
from ...scene.facts import SceneFacts
from ...scene.model import Scene
from .settings import FALLBACK_HEIGHT_M, OFFSET_CANDIDATES, MapSettings


@dataclass(frozen=True)
class MapGrid:
    """The cells of a map.

    Attributes
    ----------
    cell_xyz : (N, 3) float, m, cell centres (z = device height)
    ij : (N, 2) int, lattice indices: ``cell_xy = origin_xy + ij * step_m``
    origin_xy : (2,) float, m, centre of lattice cell (0, 0)
    step_m : float, m
    shape : (2,) int, lattice size in x and y
    area_xy : (K, 2) float, m, polygon the cells lie in
    test_names : list of str; test_xyz : (P, 3) float, m, the scene's test points
    test_distance_m : (P,) float, m, horizontal distance of each test point to its nearest cell
    """

    cell_xyz: np.ndarray
    ij: np.ndarray
    origin_xy: np.ndarray
    step_m: float
    shape: tuple[int, int]
    area_xy: np.ndarray
    test_names: list[str]
    test_xyz: np.ndarray
    test_distance_m: np.ndarray

    def raster(self, values: np.ndarray) -> np.ndarray:
        """(nx, ny) float: per-cell ``values`` (N,) on the lattice, NaN where there is no cell."""
        out = np.full(self.shape, np.nan)
        out[self.ij[:, 0], self.ij[:, 1]] = values
        return out


def area_polygon(scene: Scene, block: dict[str, Any]) -> np.ndarray:
    """(K, 2) float, m: where cells may lie (the dataset's service area, else the bounding box;
    :attr:`raytrace.scene.facts.SceneFacts.area_xy`)."""
    return SceneFacts.of(scene, block).area_xy


def lattice_distance(points_xy: np.ndarray, offset_xy: np.ndarray, step_m: float) -> np.ndarray:
    """(..., P) float, m: horizontal distance of each point to the nearest node of the infinite
    lattice ``offset_xy + step_m * Z^2`` (``offset_xy`` (..., 2) broadcasts over candidates)."""
    d = np.mod(points_xy - offset_xy[..., None, :], step_m)
    d = np.minimum(d, step_m - d)
    return np.hypot(d[..., 0], d[..., 1])


def grid_offset(
    lo_xy: np.ndarray, step_m: float, test_xy: np.ndarray, clearance_m: float
) -> np.ndarray:
    """(2,) float, m: the offset of the first cell centre from ``lo_xy`` in ``[0, step)^2``.

    Among :data:`OFFSET_CANDIDATES`^2 offsets, the one closest to the centred lattice (offset
    ``step / 2``: cells that tile the area from its corner) whose every node is at least
    ``clearance_m`` from every test point. Raises :class:`HallrayError` when none is.
    """
    half = 0.5 * step_m
    if len(test_xy) == 0:
        return np.array([half, half])
    u = np.arange(OFFSET_CANDIDATES) * (step_m / OFFSET_CANDIDATES)
    cand = np.stack(np.meshgrid(u, u, indexing="ij"), axis=-1).reshape(-1, 2)
    cand = cand[np.argsort(np.hypot(*(cand - half).T), kind="stable")]
    dist = lattice_distance(np.asarray(test_xy)[:, :2], np.asarray(lo_xy) + cand, step_m)
    ok = dist.min(axis=1) >= clearance_m
    if not ok.any():
        raise HallrayError(
            f"no grid origin keeps every cell {clearance_m:g} m from the test points with "
            f"--step {step_m:g} m (largest possible: {dist.min(axis=1).max():.3f} m); lower "
            "--clearance or change --step"
        )
    return cand[int(np.argmax(ok))]


def device_height(
    scene: Scene, settings: MapSettings, test_xyz: np.ndarray, facts: SceneFacts | None = None
) -> float:
    """The map's device height, m, checked against the hall's floor and ceiling
    (``facts``: the scene's, when the caller has read them)."""
    facts = SceneFacts.of(scene) if facts is None else facts
    h = settings.height_m
    if h is None:
        h = float(np.median(test_xyz[:, 2])) if len(test_xyz) else FALLBACK_HEIGHT_M
    floor, top = facts.height_range
    if not floor < h < top:
        raise HallrayError(
            f"--height {h:g} m is outside the hall (floor {floor:.2f} m, ceiling {top:.2f} m)"
        )
    return float(h)


def make_grid(
    scene: Scene,
    settings: MapSettings,
    test_names: Sequence[str],
    test_xyz: np.ndarray,
    area_xy: np.ndarray | None = None,
    facts: SceneFacts | None = None,
) -> MapGrid:
    """The cells: a lattice over the area at device height, outside solids (module docstring).

    ``area_xy`` (K, 2) float, m: the cells' polygon (default: the scene's service area, else its
    bounding box); ``facts``: the scene's, when the caller has read them
    (:class:`raytrace.scene.facts.SceneFacts`). Raises :class:`HallrayError` when the step gives
    no cell or more than ``max_cells``.
    """
    import shapely

    facts = SceneFacts.of(scene) if facts is None else facts
    area = facts.area_xy if area_xy is None else np.asarray(area_xy, dtype=float)
    h = device_height(scene, settings, test_xyz, facts)
    step = float(settings.step_m)
    lo, hi = area.min(axis=0), area.max(axis=0)
    n_lattice = np.floor((hi - lo) / step).astype(np.int64) + 1
    if int(np.prod(n_lattice.astype(float))) > 4 * settings.max_cells:  # before allocating it
        raise HallrayError(
            f"--step {step:g} m gives about {int(np.prod(n_lattice.astype(float)))} cells, more "
            f"than the limit of {settings.max_cells} (raise --step or --max-cells)"
        )
    origin = lo + grid_offset(lo, step, test_xyz, settings.clearance_m)
    nx, ny = (int(n) for n in np.floor((hi - origin) / step).astype(np.int64) + 1)
    ij = np.stack(np.meshgrid(np.arange(max(nx, 0)), np.arange(max(ny, 0)), indexing="ij"),
                  axis=-1).reshape(-1, 2)  # fmt: skip
    xy = origin + ij * step
    poly = shapely.Polygon(area)
    keep = shapely.contains_xy(poly, xy[:, 0], xy[:, 1]) if len(xy) else np.zeros(0, bool)
    ij, xy = ij[keep], xy[keep]
    xyz = np.column_stack([xy, np.full(len(xy), h)])
    if len(xyz):
        free = scene.inside_solid(xyz) < 0
        ij, xyz = ij[free], xyz[free]
    if len(xyz) == 0:
        raise HallrayError(f"--step {step:g} m at height {h:g} m gives no cell on the floor")
    if len(xyz) > settings.max_cells:
        raise HallrayError(
            f"--step {step:g} m gives {len(xyz)} cells, more than the limit of "
            f"{settings.max_cells} (raise --step or --max-cells)"
        )
    test_xyz = np.asarray(test_xyz, dtype=float).reshape(-1, 3)
    dist = (np.hypot(*(test_xyz[:, None, :2] - xyz[None, :, :2]).transpose(2, 0, 1)).min(axis=1)
            if len(test_xyz) else np.zeros(0))  # fmt: skip
    return MapGrid(xyz, ij, origin, step, (max(nx, 1), max(ny, 1)), area, list(test_names),
                   test_xyz, dist)  # fmt: skip
