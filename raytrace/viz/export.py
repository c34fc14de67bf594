"""Write a scene with traced paths as coloured polylines (glTF binary, for any viewer or Blender)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import HallrayError
from ..core.fileio import write_atomic
from ..scene.model import Scene
from ..solver.paths import Paths

#: RGBA colour of a path by its main mechanism.
KIND_COLOURS = {
    "los": (40, 160, 40, 255),
    "reflection": (30, 90, 220, 255),
    "penetration": (230, 140, 20, 255),
    "diffraction": (200, 30, 160, 255),
}


def path_category(paths: Paths) -> np.ndarray:
    """(P,) str: ``los``, ``diffraction`` (any D), ``reflection`` (any R) or ``penetration``."""
    cat = np.full(paths.n_paths, "penetration", dtype=object)
    cat[paths.n_reflections > 0] = "reflection"
    cat[paths.n_diffractions > 0] = "diffraction"
    cat[paths.los] = "los"
    return cat.astype(str)


def path_polylines(paths: Paths, index: np.ndarray) -> list[np.ndarray]:
    """Vertices (tx, interaction points, rx) of the chosen paths, each (k + 2, 3) in metres."""
    out = []
    for i in np.asarray(index, dtype=int):
        pts = paths.points[i][paths.interaction[i] > 0]
        out.append(np.vstack([paths.tx[paths.tx_index[i]], pts, paths.rx[paths.rx_index[i]]]))
    return out


def export_paths_glb(scene: Scene, paths: Paths, links: list[int], path: str | Path) -> None:
    """Write the scene's triangles (one node per object, named as in the scene) and the paths of
    the given links as polylines coloured by kind (see :data:`KIND_COLOURS`)."""
    import trimesh

    out = trimesh.Scene()
    for o in scene.objects:
        f = scene.faces[o.face_start : o.face_start + o.face_count]
        used, inv = np.unique(f, return_inverse=True)
        out.add_geometry(
            trimesh.Trimesh(scene.vertices[used], inv.reshape(-1, 3), process=False),
            node_name=o.name,
            geom_name=o.name,
        )
    sel = np.flatnonzero(np.isin(paths.link, np.asarray(links)))
    if sel.size == 0:
        raise HallrayError(f"no paths on the chosen link(s) {links}")
    cats = path_category(paths)
    kinds = paths.kind_label
    for i, line in zip(sel, path_polylines(paths, sel)):
        segs = np.stack([line[:-1], line[1:]], axis=1)
        p3 = trimesh.load_path(segs)
        p3.colors = np.tile(KIND_COLOURS[cats[i]], (len(p3.entities), 1))
        name = f"path_link{paths.link[i]}_{kinds[i]}_{i}"
        out.add_geometry(p3, node_name=name, geom_name=name)
    write_atomic(path, out.export(file_type="glb"))
