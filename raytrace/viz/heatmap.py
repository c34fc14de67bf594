"""Heatmaps over a hall's top view: one quantity per grid cell, the solids and base stations drawn.

Used by the accuracy map (:mod:`raytrace.studies.accuracy_map`): the cells are squares of a
lattice (``origin_xy + (i, j) * step_m``), NaN cells are left white, each solid is drawn as the
outline of its footprint (convex hull of its vertices seen from above) when it reaches the
device height band, the base stations as gold triangles and the test points as small crosses.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np

from ..scene.model import Scene

#: Picture size, inches, and resolution.
FIG_SIZE_IN = (6.4, 6.0)
DPI = 120
#: Objects whose footprint covers more than this share of the scene's horizontal box (floor,
#: ceiling) are not outlined.
LARGE_FOOTPRINT = 0.5


def footprints(scene: Scene) -> list[np.ndarray]:
    """(K, 2) float outlines, m, of the objects seen from above (convex hull of each object's
    vertices), leaving out slabs that cover the whole hall."""
    import shapely

    lo, hi = scene.bounds
    box_area = max(float((hi[0] - lo[0]) * (hi[1] - lo[1])), 1e-9)
    out = []
    for o in scene.objects:
        idx = np.unique(scene.faces[o.face_start : o.face_start + o.face_count])
        hull = shapely.MultiPoint(scene.vertices[idx, :2]).convex_hull
        if hull.geom_type != "Polygon" or hull.area > LARGE_FOOTPRINT * box_area:
            if hull.geom_type == "LineString":  # a vertical sheet: its trace on the floor
                out.append(np.asarray(hull.coords))
            continue
        out.append(np.asarray(hull.exterior.coords))
    return out


def heatmap_png(
    scene: Scene,
    values: np.ndarray,
    origin_xy: np.ndarray,
    step_m: float,
    *,
    title: str,
    label: str,
    bs_xyz: np.ndarray,
    bs_names: Sequence[str],
    points_xy: np.ndarray | None = None,
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    discrete: bool = False,
    log: bool = False,
    outlines: list[np.ndarray] | None = None,
) -> bytes:
    """One heatmap as PNG bytes.

    Parameters
    ----------
    scene : Scene, for the solids' outlines and the axes' extent
    values : (nx, ny) float, one value per lattice cell (NaN: no cell)
    origin_xy : (2,) float, m, centre of cell (0, 0); step_m : float, m
    title, label : picture title and colour-bar label
    bs_xyz : (B, 3) float, m; bs_names : their names
    points_xy : (P, 2) float, m, optional, test points
    cmap, vmin, vmax : colour map and limits (default: the finite values' range)
    discrete : integer values (one colour per value, e.g. a count of base stations)
    log : logarithmic colour scale (values below ``vmin`` take its colour)
    outlines : optional, :func:`footprints` computed once for several pictures
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    v = np.asarray(values, dtype=float)
    nx, ny = v.shape
    x_edges = origin_xy[0] + (np.arange(nx + 1) - 0.5) * step_m
    y_edges = origin_xy[1] + (np.arange(ny + 1) - 0.5) * step_m
    finite = v[np.isfinite(v)]
    lo = vmin if vmin is not None else (float(finite.min()) if finite.size else 0.0)
    hi = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
    fig, ax = plt.subplots(figsize=FIG_SIZE_IN, dpi=DPI)
    colours = plt.get_cmap(cmap, int(hi - lo + 1) if discrete else None)
    if discrete:
        lo, hi = lo - 0.5, hi + 0.5
    if log:
        from matplotlib.colors import LogNorm

        norm = LogNorm(vmin=lo, vmax=max(hi, lo * 1.01), clip=True)
    else:
        from matplotlib.colors import Normalize

        norm = Normalize(vmin=lo, vmax=max(hi, lo + 1e-12))
    mesh = ax.pcolormesh(x_edges, y_edges, np.ma.masked_invalid(v).T, cmap=colours, norm=norm,
                         shading="flat")  # fmt: skip
    bar = fig.colorbar(mesh, ax=ax, shrink=0.85)
    bar.set_label(label)
    if discrete:
        bar.set_ticks(np.arange(np.ceil(lo), np.floor(hi) + 1))
    lines = footprints(scene) if outlines is None else outlines
    ax.add_collection(LineCollection(lines, colors="0.15", linewidths=0.7, zorder=5))
    for name, (x, y, _) in zip(bs_names, np.asarray(bs_xyz, dtype=float)):
        ax.plot(x, y, marker="^", ms=9, mfc="gold", mec="k", mew=0.8, zorder=10)
        ax.annotate(name, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8,
                    weight="bold", zorder=11)  # fmt: skip
    if points_xy is not None and len(points_xy):
        ax.plot(points_xy[:, 0], points_xy[:, 1], "x", ms=4, color="red", mew=1.0, zorder=9,
                label="test points")  # fmt: skip
        ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    b = scene.bounds
    ax.set_xlim(b[0, 0], b[1, 0])
    ax.set_ylim(b[0, 1], b[1, 1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=10)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
