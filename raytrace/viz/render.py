"""Pictures of scenes and paths: a top view and a perspective view, as PNG (matplotlib, Agg).

:func:`render_scene` draws

* a **top view** (:func:`raytrace.viz.topview.plot_top_view`): the triangles projected from above, lowest first (so a machine stands on the
  floor), filled by material, the ceiling and anything above ``cut_height_m`` left out, vertical
  sheets as lines;
* a **perspective view** (``mpl_toolkits.mplot3d``): a cut-away from the camera's side (the
  ceiling and the outer walls facing the camera are left out), faces coloured by material with
  Lambert shading from a fixed light;
* the base stations and points of interest, and the paths of the chosen links coloured by their
  main mechanism (:data:`raytrace.viz.export.KIND_COLOURS`: LoS, reflection, penetration,
  diffraction), each link's first arrival drawn bold.

Large triangles are split for the perspective view only (mplot3d sorts whole polygons by depth).
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.constants import C0
from ..core.errors import HallrayError
from ..core.fileio import write_atomic
from ..scene.model import Scene
from ..solver.paths import Paths
from .export import KIND_COLOURS, path_category, path_polylines
from .topview import SceneView, plot_top_view

#: Default picture size, pixels, and resolution.
DEFAULT_SIZE_PX = (2000, 1000)
DEFAULT_DPI = 150
#: Light direction (towards the light) for the perspective shading, and the ambient share.
LIGHT_DIR = np.array([-0.35, -0.55, 0.76])
AMBIENT = 0.45
#: Font size of the picture's labels, points.
_FS = 7.5
#: Category names in the legend.
CATEGORY_LABELS = {
    "los": "line of sight",
    "reflection": "reflection",
    "penetration": "penetration only",
    "diffraction": "diffraction",
}


@dataclass
class LinkPaths:
    """The paths of one link to draw: names, the polylines and their categories."""

    tx_name: str
    rx_name: str
    lines: list[np.ndarray]  # each (k, 3), metres, tx -> interactions -> rx
    categories: list[str]
    first: int  # index into lines of the first arrival, -1 if none
    first_kind: str
    first_delay_s: float
    distance_m: float
    strongest_kind: str = "-"
    strongest_power_db: float = float("nan")


def link_paths(
    paths: Paths,
    links: Sequence[int],
    tx_names: Sequence[str],
    rx_names: Sequence[str],
    *,
    max_paths: int = 8,
) -> list[LinkPaths]:
    """The first arrival and the ``max_paths`` strongest other paths of each link.

    Parameters
    ----------
    paths : Paths
    links : link indices (``tx_index * R + rx_index``)
    tx_names, rx_names : names for the labels
    max_paths : int, strongest paths per link besides the first arrival (0: first arrival only;
        negative: all)
    """
    n_rx = len(paths.rx)
    first = paths.first_arrival()
    strongest = paths.strongest()
    cats = path_category(paths)
    kinds = paths.kind_label
    power = paths.power_db
    out = []
    for link in links:
        t, r = divmod(int(link), n_rx)
        idx = np.flatnonzero(paths.link == link)
        f = int(first[link]) if link < len(first) else -1
        others = idx[idx != f]
        others = others[np.argsort(-power[others], kind="stable")]
        if max_paths >= 0:
            others = others[:max_paths]
        chosen = ([f] if f >= 0 else []) + others.tolist()
        out.append(
            LinkPaths(
                tx_name=tx_names[t] if t < len(tx_names) else f"tx{t}",
                rx_name=rx_names[r] if r < len(rx_names) else f"rx{r}",
                lines=path_polylines(paths, np.asarray(chosen, dtype=int)),
                categories=[str(cats[i]) for i in chosen],
                first=0 if f >= 0 else -1,
                first_kind=str(kinds[f]) if f >= 0 else "-",
                first_delay_s=float(paths.delay_s[f]) if f >= 0 else float("nan"),
                distance_m=float(np.linalg.norm(paths.tx[t] - paths.rx[r])),
                strongest_kind=str(kinds[strongest[link]]) if f >= 0 else "-",
                strongest_power_db=float(power[strongest[link]]) if f >= 0 else float("nan"),
            )
        )
    return out


def _shade(rgb: np.ndarray, normals: np.ndarray, two_sided: bool) -> np.ndarray:
    """(F, 3) colours lit by :data:`LIGHT_DIR` (Lambert, plus ambient)."""
    light = LIGHT_DIR / np.linalg.norm(LIGHT_DIR)
    lam = normals @ light
    lam = np.abs(lam) if two_sided else np.clip(lam, 0.0, None)
    k = AMBIENT + (1.0 - AMBIENT) * lam
    return np.clip(rgb[None, :] * k[:, None] + 0.06, 0.0, 1.0)


def _subdivide(tri: np.ndarray, max_edge: float) -> np.ndarray:
    """Split triangles (F, 3, 3) at edge midpoints until no edge is longer than ``max_edge``."""
    for _ in range(8):
        e = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1)
        big = e > max_edge
        if not big.any():
            break
        t = tri[big]
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        parts = np.concatenate(
            [
                np.stack([a, ab, ca], 1),
                np.stack([ab, b, bc], 1),
                np.stack([ca, bc, c], 1),
                np.stack([ab, bc, ca], 1),
            ]
        )
        tri = np.concatenate([tri[~big], parts])
    return tri


def _camera_cut(objs: list[dict[str, Any]], lo: np.ndarray, hi: np.ndarray, azim: float) -> set:
    """Objects left out of the cut-away: large ones on the faces of the scene's bounding box
    that face the camera (the ceiling and the two outer walls nearest the camera)."""
    span = hi - lo
    tol = 0.02 * span.max()
    cam = np.array([np.cos(np.radians(azim)), np.sin(np.radians(azim))])
    faces = [(2, 1)]  # (axis, +1: the max face / -1: the min face)
    faces.append((0, 1 if cam[0] > 0 else -1))
    faces.append((1, 1 if cam[1] > 0 else -1))
    out = set()
    for o in objs:
        for axis, side in faces:
            on_face = hi[axis] - o["hi"][axis] < tol if side > 0 else o["lo"][axis] - lo[axis] < tol
            # the object lies against that face (thin in that direction) and covers much of it
            thin = (o["hi"][axis] - o["lo"][axis]) < 0.1 * span[axis]
            other = [a for a in range(3) if a != axis]
            wide = all((o["hi"][a] - o["lo"][a]) > 0.6 * span[a] for a in other)
            if on_face and thin and wide:
                out.add(o["index"])
    return out


def render_scene(
    scene: Scene,
    out_path: str | os.PathLike[str],
    *,
    links: Sequence[LinkPaths] = (),
    base_stations: Sequence[tuple[str, Sequence[float]]] | None = None,
    points: Sequence[tuple[str, Sequence[float]]] | None = None,
    size_px: tuple[int, int] = DEFAULT_SIZE_PX,
    dpi: int = DEFAULT_DPI,
    title: str | None = None,
    subtitle: str | None = None,
    cut_height_m: float | None = None,
    elev: float = 32.0,
    azim: float = -125.0,
    frequency_hz: float | None = None,
) -> dict[str, Any]:
    """Draw a scene (top view and perspective view) with positions and paths into a PNG.

    Parameters
    ----------
    scene : Scene
    out_path : output .png, written atomically
    links : LinkPaths to draw (see :func:`link_paths`)
    base_stations, points : (name, xyz) pairs; default: the scene's ``hallray`` metadata
    size_px : (width, height) of the picture, pixels
    dpi : resolution (sets the size of text and lines relative to the picture)
    title, subtitle : text above the views (default: the scene's name and its size)
    cut_height_m : objects lying wholly above this height are left out of the top view
        (default: 90 % of the way from the floor to the top of the scene)
    elev, azim : perspective camera elevation and azimuth, degrees (default from the south-west)
    frequency_hz : the paths' frequency, for the subtitle

    Returns
    -------
    dict: ``size_px``, ``objects_drawn``, ``triangles_drawn``, ``paths_drawn``
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    out = Path(out_path)
    if out.suffix.lower() != ".png":
        raise HallrayError(f"output {out} must end in .png")
    if not out.parent.is_dir():
        raise HallrayError(f"output directory {out.parent} does not exist")
    w, h = (int(v) for v in size_px)
    if not (200 <= w <= 10000 and 150 <= h <= 10000):
        raise HallrayError(f"picture size must be 200..10000 x 150..10000 pixels, got {w}x{h}")
    meta = scene.metadata.get("hallray", {}) if isinstance(scene.metadata, dict) else {}
    if base_stations is None:
        base_stations = [(b["name"], b["xyz"]) for b in meta.get("base_stations", []) or []]
    if points is None:
        points = [(p["name"], p["xyz"]) for p in meta.get("points", []) or []]
    view = SceneView.of(scene, cut_height_m)

    fig = plt.figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax2 = fig.add_axes((0.045, 0.17, 0.40, 0.70))
    ax3 = fig.add_axes((0.46, 0.08, 0.54, 0.78), projection="3d")
    n_tri = plot_top_view(ax2, view, fontsize=_FS)
    hidden = _draw_perspective(ax3, view, elev, azim)
    used_cats = _draw_paths(ax2, ax3, links)
    _draw_sites(ax2, ax3, view, base_stations, points)
    _draw_legend(fig, view, used_cats, bool(links), bool(base_stations), bool(points))
    _draw_titles(fig, scene, view, meta, links, title, subtitle, frequency_hz)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    write_atomic(out, buf.getvalue())
    return {
        "size_px": [w, h],
        "objects_drawn": len(view.objs) - len(hidden),
        "triangles_drawn": n_tri,
        "paths_drawn": sum(len(lk.lines) for lk in links),
    }


def _draw_perspective(ax: Any, view: SceneView, elev: float, azim: float) -> set:
    """The cut-away perspective view, Lambert-shaded; returns the objects left out."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    lo, hi = view.lo, view.hi
    hidden = _camera_cut(view.objs, lo, hi, azim)
    max_edge = 0.12 * float(np.max(hi - lo))
    floor_polys, floor_cols, polys, cols, edges = [], [], [], [], []
    for o in view.objs:
        if o["index"] in hidden:
            continue
        tri, nrm = o["tri"], o["normal"]
        col = _shade(view.rgb[o["material"]], nrm, not o["closed"])
        if (
            o["hi"][2] <= view.floor + 0.05
            and o["lo"][2] < view.floor + 0.05
            and (o["hi"] - o["lo"])[:2].min() > 0.3 * (hi - lo)[:2].min()
        ):
            floor_polys.append(tri)
            floor_cols.append(col)
            continue
        big = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2).max(axis=1) > max_edge
        edge = np.clip(col * 0.7, 0, 1)
        if big.any():
            # split for the depth sort; the pieces get no outline (it would draw the split)
            parts = [_subdivide(tri[i : i + 1], max_edge) for i in np.flatnonzero(big)]
            counts = [len(p) for p in parts]
            tri = np.concatenate([tri[~big], *parts])
            edge = np.concatenate([edge[~big], np.repeat(col[big], counts, axis=0)])
            col = np.concatenate([col[~big], np.repeat(col[big], counts, axis=0)])
        polys.append(tri)
        cols.append(col)
        edges.append(edge)
    ax.computed_zorder = False
    if floor_polys:
        fp = np.concatenate(floor_polys)
        ax.add_collection3d(
            Poly3DCollection(fp, facecolors=np.concatenate(floor_cols), edgecolors="none", zorder=1)
        )
    if polys:
        ax.add_collection3d(
            Poly3DCollection(
                np.concatenate(polys),
                facecolors=np.concatenate(cols),
                edgecolors=np.concatenate(edges),
                linewidths=0.15,
                zorder=2,
            )
        )
    span = hi - lo
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(span / span.max()), zoom=1.25)
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()
    return hidden


def _draw_paths(ax2: Any, ax3: Any, links: Sequence[LinkPaths]) -> list[str]:
    """The links' paths in both views, coloured by category, first arrivals bold; returns the
    categories drawn, in drawing order."""
    from matplotlib.collections import LineCollection
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    used_cats: list[str] = []
    for lk in links:
        for k, (line, cat) in enumerate(zip(lk.lines, lk.categories)):
            c = np.array(KIND_COLOURS[cat][:3]) / 255.0
            bold = k == lk.first
            lw, alpha = (2.2, 1.0) if bold else (0.8, 0.55)
            ax2.add_collection(
                LineCollection([line[:, :2]], colors=[(*c, alpha)], linewidths=lw, zorder=20 + bold)
            )
            ax3.add_collection3d(
                Line3DCollection([line], colors=[(*c, alpha)], linewidths=lw, zorder=20 + bold)
            )
            if cat not in used_cats:
                used_cats.append(cat)
    return used_cats


def _draw_sites(
    ax2: Any,
    ax3: Any,
    view: SceneView,
    base_stations: Sequence[tuple[str, Sequence[float]]],
    points: Sequence[tuple[str, Sequence[float]]],
) -> None:
    """Base stations (gold triangles, named) and points (red squares) in both views."""
    span = view.hi - view.lo
    for name, xyz in base_stations:
        x, y, z = (float(v) for v in xyz)
        ax2.plot(x, y, marker="^", ms=8, mfc="gold", mec="k", mew=0.8, zorder=30)
        ax2.annotate(name, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=_FS - 0.5,
                     weight="bold", zorder=31)  # fmt: skip
        ax3.plot([x], [y], [z], marker="^", ms=7, mfc="gold", mec="k", mew=0.8, zorder=30)
        ax3.text(x, y, z + 0.04 * span[2] + 0.3, name, fontsize=_FS - 1, weight="bold", zorder=31)
    for name, xyz in points:
        x, y, z = (float(v) for v in xyz)
        ax2.plot(x, y, marker="s", ms=3.5, mfc="red", mec="darkred", mew=0.5, zorder=30)
        ax2.annotate(name, (x, y), xytext=(3, -7), textcoords="offset points",
                     fontsize=_FS - 2, color="darkred", zorder=31)  # fmt: skip
        ax3.plot([x], [y], [z], marker="s", ms=2.5, mfc="red", mec="darkred", mew=0.4, zorder=30)


def _draw_legend(
    fig: Any, view: SceneView, used_cats: list[str], links: bool, base_stations: bool, points: bool
) -> None:
    """Materials (most triangles first), path categories drawn, and the markers shown."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    objs = view.objs
    mats = sorted(
        {o["material"] for o in objs},
        key=lambda m: -sum(len(o["tri"]) for o in objs if o["material"] == m),
    )
    handles: list[Any] = [
        Patch(facecolor=view.rgb[m], edgecolor="0.3", lw=0.5, label=m.replace("_", " "))
        for m in mats
    ]
    for cat in KIND_COLOURS:
        if cat in used_cats:
            c = np.array(KIND_COLOURS[cat][:3]) / 255.0
            handles.append(Line2D([], [], color=c, lw=2.0, label=CATEGORY_LABELS[cat]))
    if links:
        handles.append(Line2D([], [], color="0.2", lw=2.2, label="first arrival (bold)"))
    if base_stations:
        handles.append(
            Line2D([], [], marker="^", ls="", mfc="gold", mec="k", ms=7, label="base station")
        )
    if points:
        handles.append(
            Line2D([], [], marker="s", ls="", mfc="red", mec="darkred", ms=4, label="point")
        )
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 9), fontsize=_FS,
               frameon=False, bbox_to_anchor=(0.5, 0.0))  # fmt: skip


def _draw_titles(
    fig: Any,
    scene: Scene,
    view: SceneView,
    meta: dict[str, Any],
    links: Sequence[LinkPaths],
    title: str | None,
    subtitle: str | None,
    frequency_hz: float | None,
) -> None:
    """Title (the scene's name), subtitle (its size) and one line per link: first arrival and
    strongest path."""
    name = meta.get("name") or Path(scene.source).stem or "scene"
    size = " x ".join(f"{v:.1f}" for v in view.hi - view.lo)
    fig.text(0.045, 0.965, title or f"{name}", fontsize=_FS + 4, weight="bold", va="top")
    sub = subtitle or f"{len(view.objs)} objects, {len(scene.faces)} triangles, {size} m" + (
        f"; paths traced at {frequency_hz / 1e9:.4g} GHz" if frequency_hz and links else ""
    )
    fig.text(0.045, 0.925, sub, fontsize=_FS + 0.5, va="top", color="0.25")
    if links:
        lines = [
            f"{lk.tx_name} \u2192 {lk.rx_name}  {lk.distance_m:5.1f} m  "
            + (
                f"first arrival {lk.first_kind:<3} {lk.first_delay_s * 1e9:7.2f} ns "
                f"(+{lk.first_delay_s * C0 - lk.distance_m:.2f} m), "
                f"strongest {lk.strongest_kind:<3} {lk.strongest_power_db:6.1f} dB"
                if lk.first >= 0
                else "no path"
            )
            for lk in links
        ]
        fig.text(0.47, 0.925, "\n".join(lines), fontsize=_FS, va="top", family="monospace")
