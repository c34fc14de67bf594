"""The top view of a hall: one plotter for a hall's description and for a scene's triangles.

:func:`plot_top_view` draws a hall seen from above on a matplotlib axes, from either

* a **hall description** (a :class:`raytrace.halls.spec.HallSpec`, a trimesh scene with its
  ``metadata["hallray"]`` block, e.g. a loaded GLB, or that block itself): the shell, the
  obstacles' footprints filled by material (taller ones on top, vertical sheets as thick lines,
  horizontal sheets hatched), the area of interest, forklift routes, base stations and points of
  interest (the hall pictures of docs/hall.md and docs/inf.md); or
* a **scene's triangles** (a :class:`raytrace.scene.model.Scene`, or the :class:`SceneView` a
  picture shares with its perspective view): every object's faces seen from above, lowest object
  first, filled by material, the ceiling and anything above the cut height left out, objects on
  the floor faint, vertical sheets as lines (the left half of
  :func:`raytrace.viz.render.render_scene`).

Both become a list of :class:`Footprint` records, drawn by one primitive,
:func:`draw_footprints`; colours are those of :mod:`raytrace.core.palette`. Lengths in metres.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from ..core.palette import material_colors
from ..halls.spec.build import hall_metadata
from ..halls.spec.model import HallSpec
from ..scene.facts import floor_level
from ..scene.model import Scene


@dataclass(frozen=True)
class Footprint:
    """One object seen from above, and how it is drawn.

    Attributes
    ----------
    xy : (K, 2) float, m, an outline (K >= 3: a polygon; K = 2: a line, a vertical sheet), or
        (T, 3, 2) float, m, triangles (one collection)
    face : colour or (T, 4) float colours, the fill (None: not filled)
    edge : colour, or a one-element list of one, the outline
    lw : float, points, the outline's width
    zorder : float, drawing order (1 + 0.001 * the object's top height, m)
    hatch : str or None, hatching of an unfilled outline (a see-through ceiling)
    label : str or None, written at the outline's centre
    """

    xy: np.ndarray
    face: Any
    edge: Any
    lw: float
    zorder: float
    hatch: str | None = None
    label: str | None = None


def draw_footprints(ax: Any, footprints: Sequence[Footprint]) -> None:
    """Draw ``footprints`` on a matplotlib ``ax``, in the given order (each with its label)."""
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Polygon

    for fp in footprints:
        xy = fp.xy
        if xy.ndim == 3:
            ax.add_collection(PolyCollection(xy, facecolors=fp.face, edgecolors=fp.edge,
                                             linewidths=fp.lw, zorder=fp.zorder))  # fmt: skip
        elif len(xy) == 2:
            ax.plot(xy[:, 0], xy[:, 1], color=fp.edge, lw=fp.lw, solid_capstyle="butt",
                    zorder=fp.zorder)  # fmt: skip
        elif fp.face is None:
            ax.add_patch(Polygon(xy, closed=True, fill=False, hatch=fp.hatch, ec=fp.edge,
                                 lw=fp.lw, zorder=fp.zorder))  # fmt: skip
        else:
            ax.add_patch(Polygon(xy, closed=True, facecolor=fp.face, edgecolor=fp.edge,
                                 lw=fp.lw, zorder=fp.zorder))  # fmt: skip
        if fp.label is not None:
            c = xy.reshape(-1, 2).mean(axis=0)
            ax.text(c[0], c[1], fp.label, fontsize=4, ha="center", va="center", zorder=9)


def plot_top_view(
    ax: Any,
    source: HallSpec | trimesh.Scene | Mapping[str, Any] | Scene | SceneView,
    *,
    show_points: bool = True,
    show_routes: bool = True,
    show_legend: bool = True,
    label_objects: bool = False,
    cut_height_m: float | None = None,
    fontsize: float | None = None,
) -> int:
    """Draw a hall seen from above on a matplotlib ``ax`` (module docstring).

    Parameters
    ----------
    ax : matplotlib axes
    source : a hall description (HallSpec, trimesh scene with ``metadata["hallray"]``, or that
        mapping), or a Scene or SceneView (its triangles)
    show_points, show_routes, show_legend, label_objects : a hall description's points of
        interest, forklift routes, legend (materials and markers) and object names
    cut_height_m : float, m, a scene's objects lying wholly above this height are left out
        (default: :class:`SceneView`'s)
    fontsize : float, points, a scene's axis labels, ticks (one less) and title (one more);
        None: matplotlib's defaults and no title

    Returns
    -------
    int, the footprints drawn: obstacles of a hall description, triangles of a scene
    """
    if isinstance(source, (Scene, SceneView)):
        view = source if isinstance(source, SceneView) else SceneView.of(source, cut_height_m)
        return _plot_scene(ax, view, fontsize)
    if isinstance(source, HallSpec):
        meta: Mapping[str, Any] = hall_metadata(source)
    elif isinstance(source, trimesh.Scene):
        meta = source.metadata["hallray"]
    else:
        meta = source
    sx, sy, _ = meta["hall"]["size"]
    footprints, handles = _hall_footprints(meta, label_objects)
    draw_footprints(ax, footprints)
    handles += _draw_area(ax, meta.get("area_of_interest"))
    if show_routes:
        handles += _draw_routes(ax, meta.get("routes") or [])
    points = (meta.get("points") or []) if show_points else []
    handles += _draw_sites(ax, meta.get("base_stations") or [], points)
    ax.set_xlim(-1.5, sx + 1.5)
    ax.set_ylim(-1.5, sy + 1.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if show_legend:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7.5)
    return len(footprints) - 2  # the obstacles, without the shell and the interior


# -- a hall description ---------------------------------------------------------------------


def _hall_footprints(
    meta: Mapping[str, Any], label_objects: bool
) -> tuple[list[Footprint], list[Any]]:
    """The shell, the interior and the obstacles (lowest first); legend patches of their
    materials."""
    from matplotlib.patches import Patch

    sx, sy, _ = meta["hall"]["size"]
    t = meta["hall"].get("wall_thickness", 0.3)
    shell = meta["hall"].get("material", "concrete")
    colors = material_colors([shell, *(o["material"] for o in meta["obstacles_2d"])])
    out = [
        Footprint(_rectangle(-t, -t, sx + t, sy + t), colors[shell], "k", 1, 0.4),
        Footprint(_rectangle(0, 0, sx, sy), "white", "k", 0.8, 0.5),
    ]
    used: dict[str, tuple[float, float, float]] = {}
    for obs in sorted(meta["obstacles_2d"], key=lambda o: (o["z"][1], o["name"])):
        rgb = used[obs["material"]] = colors[obs["material"]]
        xy = np.asarray(obs["xy"], dtype=float)
        z = 1.0 + 0.001 * obs["z"][1]
        label = obs["name"] if label_objects else None
        if len(xy) == 2:  # vertical sheet: a thick line
            out.append(Footprint(xy, None, rgb, 2.2, z, label=label))
        elif obs["kind"] == "sheet":  # horizontal or tilted sheet (a ceiling): hatched, see-through
            out.append(Footprint(xy, None, rgb, 0.8, z, hatch="///", label=label))
        else:
            out.append(Footprint(xy, rgb, "0.15", 0.4, z, label=label))
    legend = [
        Patch(facecolor=rgb, edgecolor="0.15", label=m.replace("_", " ")) for m, rgb in used.items()
    ]
    return out, legend


def _rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """(4, 2) float, m: the corners of an axis-aligned rectangle, counter-clockwise."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def _draw_area(ax: Any, aoi: Mapping[str, Any] | None) -> list[Any]:
    """The area of interest as a dashed green rectangle (if any); its legend line."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    if aoi is None:
        return []
    (x0, y0), (x1, y1) = aoi["min"], aoi["max"]
    ax.add_patch(
        Rectangle(
            (x0, y0), x1 - x0, y1 - y0, fill=False, ls=(0, (6, 3)), lw=1.4, ec="green", zorder=6
        )
    )
    return [Line2D([], [], color="green", ls="--", label="area of interest")]


def _draw_routes(ax: Any, routes: Sequence[Mapping[str, Any]]) -> list[Any]:
    """Forklift routes as dashed polylines with an arrow on every leg; one legend line."""
    from matplotlib.lines import Line2D

    for route in routes:
        wp = np.asarray(route["waypoints"], dtype=float)
        if route["mode"] == "loop":
            wp = np.vstack([wp, wp[:1]])
        ax.plot(wp[:, 0], wp[:, 1], ls=(0, (4, 3)), color="0.25", lw=1.2, zorder=5)
        for a, b in zip(wp[:-1], wp[1:], strict=True):
            mid = 0.5 * (a + b)
            d = 0.01 * (b - a) / max(np.linalg.norm(b - a), 1e-9)
            ax.annotate(
                "",
                xy=mid + d,
                xytext=mid - d,
                arrowprops={"arrowstyle": "-|>", "color": "0.25", "lw": 1.0},
                zorder=5,
            )
        ax.text(wp[0, 0], wp[0, 1] + 0.6, route["name"], fontsize=6.5, color="0.2", zorder=7)
    return [Line2D([], [], color="0.25", ls="--", label="forklift route")] if routes else []


def _draw_sites(
    ax: Any, base_stations: Sequence[Mapping[str, Any]], points: Sequence[Mapping[str, Any]]
) -> list[Any]:
    """Base stations (gold triangles, name and height) and points of interest (red squares,
    numbered); their legend markers."""
    from matplotlib.lines import Line2D

    handles: list[Any] = []
    for bs in base_stations:
        x, y, z = bs["xyz"]
        ax.plot(x, y, marker="^", ms=10, mfc="gold", mec="k", zorder=8)
        ax.text(x + 0.5, y + 0.5, f"{bs['name']}\n{z:g} m", fontsize=7, weight="bold", zorder=9)
    if base_stations:
        handles.append(
            Line2D([], [], marker="^", ls="", mfc="gold", mec="k", ms=8, label="base station")
        )
    for p in points:
        x, y, _ = p["xyz"]
        ax.plot(x, y, marker="s", ms=5, mfc="red", mec="darkred", zorder=8)
        label = re.sub(r"^\D*0*(?=\d)", "", p["name"]) or p["name"]
        ax.text(x + 0.35, y - 0.75, label, fontsize=6.5, color="darkred", zorder=9)
    if points:
        handles.append(
            Line2D(
                [], [], marker="s", ls="", mfc="red", mec="darkred", ms=6, label="point of interest"
            )
        )
    return handles


# -- a scene's triangles --------------------------------------------------------------------


def object_arrays(scene: Scene) -> list[dict[str, Any]]:
    """Per object of ``scene``: ``index``, ``name``, ``material``, ``closed``, its triangles
    ``tri`` (F, 3, 3) float m, face ``normal`` (F, 3) float, and its bounds ``lo``, ``hi`` (3,)
    float m."""
    out = []
    for k, o in enumerate(scene.objects):
        sl = slice(o.face_start, o.face_start + o.face_count)
        tri = scene.vertices[scene.faces[sl]]
        out.append(
            {
                "index": k,
                "name": o.name,
                "material": o.material,
                "closed": o.closed,
                "tri": tri,
                "normal": scene.face_normal[sl],
                "lo": tri.reshape(-1, 3).min(axis=0),
                "hi": tri.reshape(-1, 3).max(axis=0),
            }
        )
    return out


@dataclass
class SceneView:
    """What the pictures of a scene draw: its objects (:func:`object_arrays`), their colours
    and the scene's heights.

    Attributes
    ----------
    objs : list of dict, :func:`object_arrays`
    rgb : dict material -> (3,) float colour
    lo, hi : (3,) float, m, the scene's bounds
    floor : float, m, its floor level (:func:`raytrace.scene.facts.floor_level`)
    cut : float, m, objects lying wholly above this height are left out of the top view
    """

    objs: list[dict[str, Any]]
    rgb: dict[str, np.ndarray]
    lo: np.ndarray
    hi: np.ndarray
    floor: float
    cut: float

    @classmethod
    def of(cls, scene: Scene, cut_height_m: float | None) -> SceneView:
        """The view of ``scene``; the cut defaults to 90 % of the way from the floor to the top."""
        lo, hi = scene.bounds
        floor = floor_level(scene)
        cut = cut_height_m if cut_height_m is not None else floor + 0.9 * (hi[2] - floor)
        rgb = {m: np.array(c) for m, c in material_colors(scene.material_names).items()}
        return cls(object_arrays(scene), rgb, lo, hi, floor, cut)


def _scene_footprints(view: SceneView) -> list[Footprint]:
    """Every object's faces seen from above (the upward ones of solids, every face of a sheet),
    lowest object first, those above the cut left out; on the floor faint, horizontal sheets
    half see-through, other sheets outlined thick."""
    shown = [o for o in view.objs if o["lo"][2] < view.cut]
    out = []
    for o in sorted(shown, key=lambda o: (o["hi"][2], o["index"])):
        tri = o["tri"]
        vis = np.ones(len(tri), bool) if not o["closed"] else o["normal"][:, 2] > -1e-6
        tri = tri[vis]
        if len(tri) == 0:
            continue
        base = view.rgb[o["material"]]
        on_floor = o["hi"][2] <= view.floor + 0.05
        face = np.clip(base * (0.82 + 0.18 * np.abs(o["normal"][vis, 2]))[:, None], 0, 1)
        horizontal_sheet = (not o["closed"]) and (o["hi"][2] - o["lo"][2] < 0.05) and not on_floor
        alpha = 0.28 if on_floor else (0.45 if horizontal_sheet else 1.0)
        edge = np.clip(base * 0.55, 0, 1)
        lw = 1.4 if (not o["closed"] and not horizontal_sheet and not on_floor) else 0.15
        if on_floor:
            lw = 0.0
        out.append(
            Footprint(
                tri[:, :, :2],
                np.column_stack([face, np.full(len(face), alpha)]),
                [(*edge, 0.9 if lw > 1 else 0.35)],
                lw,
                1 + 0.001 * o["hi"][2],
            )
        )
    return out


def _plot_scene(ax: Any, view: SceneView, fontsize: float | None) -> int:
    """:func:`plot_top_view` of a scene's triangles; the number of triangles drawn."""
    footprints = _scene_footprints(view)
    draw_footprints(ax, footprints)
    lo, hi = view.lo, view.hi
    ax.set_xlim(lo[0] - 0.02 * (hi[0] - lo[0]), hi[0] + 0.02 * (hi[0] - lo[0]))
    ax.set_ylim(lo[1] - 0.02 * (hi[1] - lo[1]), hi[1] + 0.02 * (hi[1] - lo[1]))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)", fontsize=fontsize)
    ax.set_ylabel("y (m)", fontsize=fontsize)
    if fontsize is not None:
        ax.tick_params(labelsize=fontsize - 0.5)
        ax.set_title("top view", fontsize=fontsize + 1, loc="left")
    return sum(len(fp.xy) for fp in footprints)
