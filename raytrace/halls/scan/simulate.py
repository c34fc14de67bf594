"""Simulated scans of a known scene (tests, benchmarks, trying the pipeline): points on its
surfaces that scanner stations see, with gaps and noise.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...scene.facts import floor_level


def simulate_scan(
    scene: Any,
    n_points: int,
    *,
    stations: np.ndarray | None = None,
    noise_m: float = 0.02,
    n_gaps: int = 0,
    gap_radius_m: float = 0.25,
    seed: int = 0,
) -> np.ndarray:
    """A synthetic terrestrial laser scan of a :class:`~raytrace.scene.model.Scene`.

    Points are drawn uniformly over the triangles (``trimesh.sample``); a point is kept when at
    least one scanner station sees it (an Embree segment test), which removes the outer faces of
    the shell and leaves realistic occlusion shadows; then ``n_gaps`` spheres of
    ``gap_radius_m`` around random kept points are cut out (drop-outs) and Gaussian noise of
    ``noise_m`` (standard deviation per coordinate) is added.

    Parameters
    ----------
    scene : Scene
    n_points : int, points drawn before the visibility test
    stations : (S, 3) float, scanner positions, metres; default a 4 x 4 grid over the middle
        70 % of the scene's bounding box at 1.6 m above its floor, those inside solids dropped
    noise_m, n_gaps, gap_radius_m, seed : see above

    Returns
    -------
    (N, 3) float64, metres, N <= n_points
    """
    import trimesh

    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds
    if stations is None:
        gx = np.linspace(lo[0] + 0.15 * (hi[0] - lo[0]), hi[0] - 0.15 * (hi[0] - lo[0]), 4)
        gy = np.linspace(lo[1] + 0.15 * (hi[1] - lo[1]), hi[1] - 0.15 * (hi[1] - lo[1]), 4)
        z0 = floor_level(scene) + 1.6
        stations = np.array([[x, y, z0] for x in gx for y in gy])
        stations = stations[scene.inside_solid(stations) < 0]
    stations = np.asarray(stations, dtype=float).reshape(-1, 3)
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, int(n_points), seed=int(rng.integers(2**31)))
    pts = np.asarray(pts, dtype=float)
    seen = np.zeros(len(pts), dtype=bool)
    for s in stations:
        idx = np.flatnonzero(~seen)
        if idx.size == 0:
            break
        seen[idx] = ~scene.occluded(np.broadcast_to(s, (idx.size, 3)), pts[idx])
    pts = pts[seen]
    if n_gaps > 0 and len(pts):
        from scipy.spatial import cKDTree

        centres = pts[rng.choice(len(pts), size=min(n_gaps, len(pts)), replace=False)]
        near = cKDTree(centres).query(pts, distance_upper_bound=gap_radius_m)[0]
        pts = pts[~np.isfinite(near)]
    return pts + rng.normal(0.0, noise_m, size=pts.shape)
