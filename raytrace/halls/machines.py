"""A hall made large: the bundled hall plus generated metal machines whose triangles are not
coplanar (icospheres with vertex noise, as a scanned or CAD-modelled machine is), from 10^3 to
10^6 triangles. The scenes of the scale benchmark (``tools/bench.py --scene-scale``) and of the
tests of large scenes (issue 36).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["SCALE_STEPS", "machine_centres", "hall_with_machines", "write_hall_with_machines"]

#: The benchmark's scenes as (machines, icosphere subdivisions): 1 280, 6 400, 21 760, 83 200,
#: 247 040 and 984 320 triangles (a subdivision-s sphere has 20 x 4^s triangles).
SCALE_STEPS = ((0, 0), (4, 3), (4, 4), (4, 5), (12, 5), (48, 5))


def machine_centres(n: int, radius: float = 0.6, seed: int = 0, base: str = "hall") -> np.ndarray:
    """(n, 3) float, metres: centres of ``n`` spheres of ``radius`` at seeded free places of the
    hall: not in or against a solid, 0.3 m apart, 1 m clear of every base station and point."""
    from ..scene.io import load_scene
    from ..scene.metadata import SceneMetadata

    hall = load_scene(base)
    inp = SceneMetadata.from_scene(hall)
    ends = np.vstack([inp.bs_xyz, inp.point_xyz]) if len(inp.bs_xyz) else np.zeros((0, 3))
    lo, hi = hall.bounds
    rng = np.random.default_rng(seed)
    cube = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)])
    probe = cube * (radius + 0.05)
    out: list[np.ndarray] = []
    for _ in range(200 * max(n, 1)):
        if len(out) == n:
            break
        c = rng.uniform(lo + [1.5, 1.5, radius + 0.2], hi - [1.5, 1.5, radius + 2.0])
        if (hall.inside_solid(c + probe) >= 0).any():
            continue
        if out and np.min(np.linalg.norm(np.array(out) - c, axis=1)) < 2 * radius + 0.3:
            continue
        if len(ends) and np.min(np.linalg.norm(ends - c, axis=1)) < radius + 1.0:
            continue
        out.append(c)
    if len(out) < n:
        raise ValueError(f"only {len(out)} of {n} machines of radius {radius} m fit in {base}")
    return np.array(out).reshape(-1, 3)


def hall_with_machines(
    n: int, subdivisions: int, radius: float = 0.6, noise_m: float = 0.01, seed: int = 0
) -> Any:
    """The bundled hall (a ``trimesh.Scene``, with its metadata: base stations, points,
    materials) plus ``n`` metal icospheres of ``subdivisions`` (20 x 4^s triangles each) with
    Gaussian vertex noise of ``noise_m`` metres, seeded."""
    import trimesh

    from ..scene.bundled import resolve_scene

    scene = trimesh.load(str(resolve_scene("hall")), force="scene", process=False)
    rng = np.random.default_rng(seed + 1)
    for i, c in enumerate(machine_centres(n, radius, seed)):
        m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
        m.vertices += rng.normal(0.0, noise_m, m.vertices.shape) + c
        name = f"machine_{i:03d}_itu_metal"
        scene.add_geometry(m, node_name=name, geom_name=name)
    return scene


def write_hall_with_machines(path: str | Path, n: int, subdivisions: int, **kw: Any) -> int:
    """Write :func:`hall_with_machines` as a glb (through a temporary file, then renamed);
    returns its triangle count."""
    import os
    import tempfile

    scene = hall_with_machines(n, subdivisions, **kw)
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".glb")
    os.close(fd)
    try:
        scene.export(tmp)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)
    return int(sum(len(g.faces) for g in scene.geometry.values()))
