"""An interactive 3D view of a scene, its positions, traced paths and an accuracy map (plotly).

:func:`preview` returns a :class:`plotly.graph_objects.Figure` (shown in a notebook as it is);
:func:`view_html` makes it one self-contained HTML page with plotly's JavaScript embedded, which
works offline (``hallray-view`` writes it). What is drawn:

* the **objects**, merged into one mesh per material and role, coloured by material (the palette
  of :mod:`raytrace.core.palette`), one legend entry per material that toggles all of it. The
  shell (objects lying against a face of the scene's bounding box and covering most of it:
  outer walls, ceiling, floor) is see-through, so that the inside shows from any side. Hovering
  a face names its object. Above :data:`DEFAULT_MAX_TRIANGLES` the meshes are decimated by vertex
  clustering (the HTML stays a few megabytes);
* the **base stations** (gold diamonds) and **points** (red squares), labelled;
* the **paths** of the chosen links, coloured by kind (:data:`VIEW_KIND_COLOURS`: line of sight,
  reflection, penetration, diffraction, mixed), each link's first arrival bold. Hovering a path
  gives its link, interaction sequence with object names (``R(wall_north) D(machine_3)``),
  delay, excess delay over the straight line, and power;
* an **accuracy map** (``accuracy-map``'s ``map.npz``) as coloured cells on the floor, with a
  menu choosing the quantity (p90 / mean error and availability per method, GDOP, base stations
  in line of sight).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.constants import C0
from ..core.errors import HallrayError
from ..core.palette import material_colors
from ..scene.model import Scene
from ..solver.paths import DIFFRACTION, PENETRATION, REFLECTION, Paths
from .export import KIND_COLOURS

#: Triangles drawn at most; a scene with more is decimated (vertex clustering) to about this.
DEFAULT_MAX_TRIANGLES = 200_000
#: Paths drawn per link besides its first arrival, strongest first.
DEFAULT_MAX_PATHS = 8
#: RGB (0..255) of a path by kind: :data:`raytrace.viz.export.KIND_COLOURS` plus ``mixed`` (more
#: than one kind of interaction: a reflection and a diffraction, ...).
VIEW_KIND_COLOURS = {**{k: v[:3] for k, v in KIND_COLOURS.items()}, "mixed": (0, 150, 150)}
KIND_LABELS = {
    "los": "line of sight",
    "reflection": "reflection",
    "penetration": "penetration",
    "diffraction": "diffraction",
    "mixed": "mixed",
}
#: Opacity of shell parts: outer walls, the ceiling, the floor; other objects are opaque.
SHELL_OPACITY = {"wall": 0.22, "ceiling": 0.10, "floor": 0.85, "solid": 1.0}
#: A path is drawn with a hover point at least every this many metres along it.
HOVER_SPACING_M = 2.0
#: Vertices above which faces carry no per-vertex object name (it would bloat the page).
MAX_NAMED_VERTICES = 60_000
_LETTER = {REFLECTION: "R", PENETRATION: "T", DIFFRACTION: "D"}


def _rgb(c: Sequence[float], alpha: float | None = None) -> str:
    r, g, b = (int(round(x)) for x in c)
    return f"rgb({r},{g},{b})" if alpha is None else f"rgba({r},{g},{b},{alpha})"


# -- the objects -------------------------------------------------------------------------------
def object_roles(scene: Scene) -> list[str]:
    """Per object: ``floor``, ``ceiling``, ``wall`` (lying against that face of the scene's
    bounding box, thin across it and covering more than 60 % of it in both other directions) or
    ``solid`` (everything else)."""
    lo, hi = scene.bounds
    span = hi - lo
    tol = 0.02 * float(span.max())
    out = []
    for o in scene.objects:
        v = scene.vertices[scene.faces[o.face_start : o.face_start + o.face_count]].reshape(-1, 3)
        olo, ohi = v.min(axis=0), v.max(axis=0)
        role = "solid"
        for axis in (2, 0, 1):
            other = [a for a in range(3) if a != axis]
            thin = ohi[axis] - olo[axis] < 0.1 * span[axis]
            wide = all(ohi[a] - olo[a] > 0.6 * span[a] for a in other)
            if not (thin and wide):
                continue
            if olo[axis] - lo[axis] < tol:
                role = "floor" if axis == 2 else "wall"
            elif hi[axis] - ohi[axis] < tol:
                role = "ceiling" if axis == 2 else "wall"
            if role != "solid":
                break
        out.append(role)
    return out


def cluster_decimate(
    vertices: np.ndarray, faces: np.ndarray, cell_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in one cube of side ``cell_m`` merge into their mean; faces
    that collapse (two corners in one cube) or repeat are dropped.

    Parameters
    ----------
    vertices : (V, 3) float, metres; faces : (F, 3) int
    cell_m : float, metres

    Returns
    -------
    (V', 3) float and (F', 3) int, F' <= F
    """
    key = np.floor((vertices - vertices.min(axis=0)) / cell_m).astype(np.int64)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n = int(inv.max()) + 1
    count = np.bincount(inv, minlength=n).astype(float)
    merged = np.stack([np.bincount(inv, vertices[:, k], n) / count for k in range(3)], axis=1)
    f = inv[faces]
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[ok]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return merged, f[np.sort(first)]


def _groups(scene: Scene) -> dict[tuple[str, str], list[int]]:
    """Objects by (material, role), materials with the most triangles first."""
    roles = object_roles(scene)
    size: dict[str, int] = {}
    for o in scene.objects:
        size[o.material] = size.get(o.material, 0) + o.face_count
    groups: dict[tuple[str, str], list[int]] = {}
    for k, o in sorted(enumerate(scene.objects), key=lambda t: (-size[t[1].material], t[0])):
        groups.setdefault((o.material, roles[k]), []).append(k)
    return groups


def _group_mesh(scene: Scene, members: list[int]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The merged vertices, faces and per-vertex object names of some objects."""
    verts, faces, names, offset = [], [], [], 0
    for k in members:
        o = scene.objects[k]
        f = scene.faces[o.face_start : o.face_start + o.face_count]
        used, inv = np.unique(f, return_inverse=True)
        verts.append(scene.vertices[used])
        faces.append(inv.reshape(-1, 3) + offset)
        names += [o.name] * len(used)
        offset += len(used)
    return np.concatenate(verts), np.concatenate(faces), names


def scene_traces(scene: Scene, max_triangles: int = DEFAULT_MAX_TRIANGLES) -> tuple[list, dict]:
    """The objects as plotly ``Mesh3d`` traces; returns (traces, info) with ``triangles`` drawn,
    ``triangles_in_scene`` and ``decimation_m`` (cluster size, 0 if none)."""
    import plotly.graph_objects as go

    colours = {m: np.array(c) * 255 for m, c in material_colors(scene.material_names).items()}
    meshes = [(key, *_group_mesh(scene, members)) for key, members in _groups(scene).items()]
    total = sum(len(f) for _, _, f, _ in meshes)
    cell = 0.0
    if total > max_triangles:
        cell = scene.extent / 2000.0
        while True:
            trial = [(k, *cluster_decimate(v, f, cell), None) for k, v, f, _ in meshes]
            if sum(len(f) for _, _, f, _ in trial) <= max_triangles:
                meshes = trial
                break
            cell *= 1.5
    named = sum(len(v) for _, v, _, _ in meshes) <= MAX_NAMED_VERTICES
    traces, shown = [], set()
    for (mat, role), v, f, names in meshes:
        if len(f) == 0:
            continue
        label = mat.replace("_", " ")
        hover = (
            f"%{{text}}<br>{label}<extra></extra>" if names and named else f"{label}<extra></extra>"
        )
        traces.append(
            go.Mesh3d(
                x=v[:, 0].astype(np.float32), y=v[:, 1].astype(np.float32),
                z=v[:, 2].astype(np.float32), i=f[:, 0].astype(np.int32),
                j=f[:, 1].astype(np.int32), k=f[:, 2].astype(np.int32),
                color=_rgb(colours[mat]), opacity=SHELL_OPACITY[role], flatshading=True,
                lighting={"ambient": 0.55, "diffuse": 0.65, "specular": 0.05, "roughness": 0.9},
                lightposition={"x": -1e4, "y": -2e4, "z": 3e4},
                name=label, legendgroup=f"material:{mat}", showlegend=mat not in shown,
                legendgrouptitle={"text": "materials"} if not shown else None,
                text=names if names and named else None, hovertemplate=hover,
            )
        )  # fmt: skip
        shown.add(mat)
    drawn = sum(len(f) for _, _, f, _ in meshes)
    return traces, {"triangles": drawn, "triangles_in_scene": total, "decimation_m": cell}


# -- sites -------------------------------------------------------------------------------------
def site_traces(
    base_stations: Sequence[tuple[str, Sequence[float]]],
    points: Sequence[tuple[str, Sequence[float]]],
    label_lift_m: float = 0.5,
) -> list:
    """Base stations (gold diamonds) and points (red squares) as ``Scatter3d`` markers, each
    with its name ``label_lift_m`` above it (a text trace of the same legend group, so that the
    marker does not hide the name)."""
    import plotly.graph_objects as go

    out: list = []
    for sites, name, marker, font in (
        (base_stations, "base stations",
         {"symbol": "diamond", "size": 7, "color": "gold", "line": {"color": "black", "width": 1}},
         {"size": 13, "color": "black"}),
        (points, "points", {"symbol": "square", "size": 3.5, "color": "red"},
         {"size": 10, "color": "darkred"}),
    ):  # fmt: skip
        if not sites:
            continue
        xyz = np.array([s[1] for s in sites], dtype=float)
        names = [str(s[0]) for s in sites]
        out.append(
            go.Scatter3d(
                x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], mode="markers", text=names,
                marker=marker, name=name, legendgroup=name,
                legendgrouptitle={"text": "positions"} if not out else None,
                hovertemplate="<b>%{text}</b><br>x %{x:.2f} m, y %{y:.2f} m, z %{z:.2f} m"
                "<extra></extra>",
            )
        )  # fmt: skip
        out.append(
            go.Scatter3d(
                x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2] + label_lift_m, mode="text", text=names,
                textfont=font, name=f"{name} (names)", legendgroup=name, showlegend=False,
                hoverinfo="skip",
            )
        )  # fmt: skip
    return out


# -- paths -------------------------------------------------------------------------------------
def view_category(paths: Paths) -> np.ndarray:
    """(P,) str: ``los`` (no interaction), ``reflection``, ``penetration`` or ``diffraction``
    (interactions of that one kind only), ``mixed`` (more than one kind)."""
    kinds = ((paths.n_reflections > 0).astype(int) + (paths.n_penetrations > 0)
             + (paths.n_diffractions > 0))  # fmt: skip
    cat = np.full(paths.n_paths, "mixed", dtype=object)
    cat[kinds == 0] = "los"
    cat[(kinds == 1) & (paths.n_reflections > 0)] = "reflection"
    cat[(kinds == 1) & (paths.n_penetrations > 0)] = "penetration"
    cat[(kinds == 1) & (paths.n_diffractions > 0)] = "diffraction"
    return cat.astype(str)


def interaction_text(paths: Paths, i: int, object_names: Sequence[str]) -> str:
    """A path's interaction sequence with object names: ``R(wall_north) D(machine_3)``, or
    ``LoS``."""
    parts = []
    for code, obj in zip(paths.interaction[i], paths.objects[i]):
        if code:
            name = object_names[obj] if 0 <= obj < len(object_names) else "?"
            parts.append(f"{_LETTER[int(code)]}({name})")
    return " ".join(parts) or "LoS"


def _densify(line: np.ndarray) -> np.ndarray:
    """A polyline with points added every :data:`HOVER_SPACING_M` or less (plotly hovers on
    points only), at most 12 per segment."""
    out = [line[:1]]
    for a, b in zip(line[:-1], line[1:]):
        n = min(12, max(1, math.ceil(float(np.linalg.norm(b - a)) / HOVER_SPACING_M)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def choose_paths(paths: Paths, links: Sequence[int], max_paths: int) -> list[tuple[int, bool]]:
    """(path index, is first arrival) of the first arrival and the ``max_paths`` strongest other
    paths (negative: all) of each link."""
    first = paths.first_arrival()
    power = paths.power_db
    out: list[tuple[int, bool]] = []
    for link in links:
        idx = np.flatnonzero(paths.link == link)
        f = int(first[link]) if 0 <= link < len(first) else -1
        others = idx[idx != f]
        others = others[np.argsort(-power[others], kind="stable")]
        if max_paths >= 0:
            others = others[:max_paths]
        out += ([(f, True)] if f >= 0 else []) + [(int(i), False) for i in others]
    return out


def path_traces(
    paths: Paths, chosen: list[tuple[int, bool]], tx_names: Sequence[str],
    rx_names: Sequence[str], object_names: Sequence[str],
) -> list:  # fmt: skip
    """One ``Scatter3d`` of lines per kind (and per kind for the bold first arrivals), with a
    hover text on every point of a path."""
    import plotly.graph_objects as go

    cats = view_category(paths)
    power = paths.power_db
    lines: dict[tuple[str, bool], tuple[list, list]] = {}
    for i, first in chosen:
        t, r = int(paths.tx_index[i]), int(paths.rx_index[i])
        pts = paths.points[i][paths.interaction[i] > 0]
        line = _densify(np.vstack([paths.tx[t], pts, paths.rx[r]]))
        los_s = float(np.linalg.norm(paths.rx[r] - paths.tx[t])) / C0
        excess = float(paths.delay_s[i]) - los_s
        text = (f"<b>{tx_names[t]} \u2192 {rx_names[r]}</b>"
                f"{' (first arrival)' if first else ''}<br>{interaction_text(paths, i, object_names)}"
                f"<br>delay {paths.delay_s[i] * 1e9:.3f} ns, excess {excess * 1e9:.3f} ns "
                f"({excess * C0:.2f} m)<br>power {power[i]:.1f} dB")  # fmt: skip
        xyz, texts = lines.setdefault((str(cats[i]), first), ([], []))
        xyz += [line, np.full((1, 3), np.nan)]
        texts += [text] * len(line) + [None]
    out: list = []
    for cat in VIEW_KIND_COLOURS:
        for first in (False, True):
            if (cat, first) not in lines:
                continue
            xyz, texts = lines[(cat, first)]
            v = np.concatenate(xyz)
            out.append(
                go.Scatter3d(
                    x=v[:, 0], y=v[:, 1], z=v[:, 2], mode="lines", text=texts,
                    line={"color": _rgb(VIEW_KIND_COLOURS[cat]), "width": 9 if first else 3},
                    opacity=1.0 if first else 0.75,
                    name=KIND_LABELS[cat] + (" (first arrival)" if first else ""),
                    legendgroup=f"kind:{cat}",
                    legendgrouptitle={"text": "paths (first arrival bold)"} if not out else None,
                    hovertemplate="%{text}<extra></extra>", connectgaps=False,
                )
            )  # fmt: skip
    return out


# -- the accuracy map --------------------------------------------------------------------------
#: Errors below this are drawn as this on the accuracy map's log colour scale, metres.
ERR_FLOOR_M = 0.01


def _map_quantities(fmap: Any) -> list[tuple[str, np.ndarray, str, tuple[float, float], bool]]:
    """(label, (N,) values, colour scale, (min, max) of the scale, log scale) of the quantities
    the map menu offers: as the heatmaps of ``accuracy-map`` (errors on a log scale from 1 cm)."""
    out = []
    for key, what in (("err_p90_m", "p90"), ("err_mean_m", "mean")):
        for k, m in enumerate(fmap.methods):
            err = np.asarray(getattr(fmap, key)[k], dtype=float)
            top = float(np.nanmax(err)) if np.isfinite(err).any() else 1.0
            out.append((f"{what} 2D error, {m} (m)", err, "Turbo",
                        (ERR_FLOOR_M, max(top, 10 * ERR_FLOOR_M)), True))  # fmt: skip
    gdop = np.asarray(fmap.gdop, dtype=float)
    top = float(np.nanpercentile(gdop, 95)) if np.isfinite(gdop).any() else 1.0
    out.append(("GDOP", gdop, "Viridis", (1.0, max(top, 1.5)), False))
    n_bs = float(fmap.los.shape[1])
    out.append(("base stations in line of sight", fmap.los.sum(axis=1).astype(float), "Blues",
                (0.0, n_bs), False))  # fmt: skip
    for k, m in enumerate(fmap.methods):
        out.append((f"share of draws with a fix, {m}", np.asarray(fmap.availability[k], float),
                    "Cividis", (0.0, 1.0), False))  # fmt: skip
    return out


def check_accuracy_map(fmap: Any, scene: Scene) -> Any:
    """A loaded fingerprint map (:func:`positioning.twin.fingerprint.read_map` of
    ``accuracy-map``'s ``map.npz``), checked to be of this scene. The viz layer does not read
    the file itself: it may not import positioning (docs/architecture.md); ``hallray-view
    --map`` reads it.

    Raises
    ------
    HallrayError
        A path instead of a loaded map, or a map computed for another scene (its
        ``scene_sha256``).
    """
    if isinstance(fmap, (str, os.PathLike)):
        raise HallrayError(
            f"accuracy_map={fmap!s}: pass a loaded map "
            "(positioning.twin.fingerprint.read_map(path)), not a path"
        )
    want = fmap.meta.get("scene_sha256")
    if want and want != scene.content_hash():
        raise HallrayError(
            "the accuracy map was computed for another scene (its scene_sha256 differs from "
            "this scene's content hash)"
        )
    return fmap


def map_traces(fmap: Any, floor_z: float) -> list:
    """One ``Mesh3d`` of square cells per quantity of :func:`_map_quantities`, just above the
    floor, the first visible; returns the traces (the menu switches between them)."""
    import plotly.graph_objects as go

    xy = np.asarray(fmap.cell_xyz, float)[:, :2]
    step = float(fmap.meta.get("step_m") or 0.0)
    if not step > 0:
        d = np.diff(np.unique(np.round(xy[:, 0], 6)))
        step = float(d.min()) if d.size else 1.0
    h = step / 2
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    v = (xy[:, None, :] + corners[None]).reshape(-1, 2)
    n = len(xy)
    base = 4 * np.arange(n)
    tri = np.concatenate([np.stack([base, base + 1, base + 2], 1),
                          np.stack([base, base + 2, base + 3], 1)])  # fmt: skip
    z = np.full(len(v), floor_z + 0.03, dtype=np.float32)
    out = []
    for k, (label, values, scale, (lo, hi), log) in enumerate(_map_quantities(fmap)):
        vals = np.asarray(values, dtype=float)
        text = [f"{label}: {x:.3g}" if np.isfinite(x) else f"{label}: -" for x in vals]
        bar: dict[str, Any] = {"title": {"text": label, "side": "right"}, "len": 0.6, "x": 1.0}
        if log:
            vals = np.log10(np.clip(vals, ERR_FLOOR_M, None))
            lo, hi = math.log10(lo), math.log10(hi)
            ticks = np.arange(math.floor(lo), math.ceil(hi) + 1)
            bar.update(tickvals=ticks, ticktext=[f"{10.0**t:g}" for t in ticks])
        out.append(
            go.Mesh3d(
                x=v[:, 0].astype(np.float32), y=v[:, 1].astype(np.float32), z=z,
                i=tri[:, 0].astype(np.int32), j=tri[:, 1].astype(np.int32),
                k=tri[:, 2].astype(np.int32), intensity=np.concatenate([vals, vals]),
                intensitymode="cell", colorscale=scale, cmin=lo, cmax=hi, colorbar=bar,
                text=np.repeat(text, 4), hovertemplate="%{text}<extra>accuracy map</extra>",
                name="accuracy map", legendgroup="accuracy map", showlegend=k == 0,
                legendgrouptitle={"text": "accuracy map"}, visible=k == 0, flatshading=True,
                lighting={"ambient": 1.0, "diffuse": 0.0, "specular": 0.0},
            )
        )  # fmt: skip
    return out


# -- the figure --------------------------------------------------------------------------------
def site_names(xyz: np.ndarray, names: Sequence[str], stored: np.ndarray, prefix: str) -> list[str]:
    """A name per position: the scene's name of the stored position within 1 mm of it, else
    ``prefix`` and its index (``tx0``, ``rx3``)."""
    out = [f"{prefix}{i}" for i in range(len(xyz))]
    if len(names) and len(xyz):
        d = np.linalg.norm(np.asarray(xyz)[:, None, :] - np.asarray(stored)[None], axis=2)
        near = d.argmin(axis=1)
        for i, k in enumerate(near):
            if d[i, k] <= 1e-3:
                out[i] = str(names[k])
    return out if len(set(out)) == len(out) else [f"{prefix}{i}" for i in range(len(xyz))]


def resolve_links(
    links: Sequence[int | str | tuple[str, str]] | None, paths: Paths,
    tx_names: Sequence[str], rx_names: Sequence[str],
) -> list[int]:  # fmt: skip
    """Link indices of ``links`` (indices, ``"TX,RX"`` or ``(TX, RX)`` by name); None: every link
    of ``paths`` that has a path."""
    if links is None:
        return sorted({int(k) for k in paths.link})
    out = []
    for item in links:
        if isinstance(item, (int, np.integer)):
            if not 0 <= int(item) < paths.n_links:
                raise HallrayError(f"link {item} is not one of the paths' {paths.n_links} links")
            out.append(int(item))
            continue
        pair = item.split(",") if isinstance(item, str) else list(item)
        if len(pair) != 2:
            raise HallrayError(f"a link is TX,RX (names), got {item!r}")
        t, r = (p.strip() for p in pair)
        for name, known in ((t, tx_names), (r, rx_names)):
            if name not in known:
                raise HallrayError(f"link {item!r}: {name!r} is not a known name")
        out.append(list(tx_names).index(t) * len(rx_names) + list(rx_names).index(r))
    return out


def preview(
    scene: Scene,
    paths: Paths | None = None,
    links: Sequence[int | str | tuple[str, str]] | None = None,
    *,
    accuracy_map: Any = None,
    tx_names: Sequence[str] | None = None,
    rx_names: Sequence[str] | None = None,
    max_paths: int = DEFAULT_MAX_PATHS,
    max_triangles: int = DEFAULT_MAX_TRIANGLES,
    title: str | None = None,
) -> Any:
    """An interactive 3D view of a scene (see the module docstring for what is drawn).

    Parameters
    ----------
    scene : Scene
    paths : Paths, optional, traced paths (:func:`raytrace.trace`, ``Paths.load``)
    links : links of ``paths`` to draw: indices, ``"BS1,P07"`` or ``("BS1", "P07")``; default
        every link with a path
    accuracy_map : a loaded fingerprint map (``positioning.twin.fingerprint.read_map`` of
        ``accuracy-map``'s ``map.npz``); must be of this scene (its ``scene_sha256``)
    tx_names, rx_names : names of the paths' transmitters and receivers (default: the scene's
        base stations and points where the positions match within 1 mm, else ``tx0``, ``rx0``)
    max_paths : paths per link besides the first arrival, strongest first (negative: all)
    max_triangles : decimate the scene's meshes above this many triangles
    title : default the scene's name, its size and what is drawn

    Returns
    -------
    plotly.graph_objects.Figure; ``fig.layout.meta`` holds counts (``triangles``, ``paths``, ...)
    """
    import plotly.graph_objects as go

    from ..scene.metadata import SceneMetadata

    sites = SceneMetadata.from_scene(scene)
    traces, info = scene_traces(scene, max_triangles)
    lift = 0.03 * float(scene.bounds[1][2] - scene.bounds[0][2]) + 0.2
    traces += site_traces(list(zip(sites.bs_names, sites.bs_xyz)),
                          list(zip(sites.point_names, sites.point_xyz)), lift)  # fmt: skip
    n_links = n_paths = 0
    if paths is not None:
        tx_names = list(tx_names or site_names(paths.tx, sites.bs_names, sites.bs_xyz, "tx"))
        rx_names = list(rx_names or site_names(paths.rx, sites.point_names, sites.point_xyz, "rx"))
        chosen = choose_paths(paths, resolve_links(links, paths, tx_names, rx_names), max_paths)
        n_links, n_paths = len({int(paths.link[i]) for i, _ in chosen}), len(chosen)
        traces += path_traces(paths, chosen, tx_names, rx_names, scene.object_names)
    elif links:
        raise HallrayError("links need paths: trace them first (raytrace.trace)")
    n_map = 0
    map_idx: list[int] = []
    if accuracy_map is not None:
        fmap = check_accuracy_map(accuracy_map, scene)
        from ..halls.scan import floor_level

        first = len(traces)
        traces += map_traces(fmap, floor_level(scene))
        map_idx = list(range(first, len(traces)))
        n_map = int(fmap.n_cells)
    fig = go.Figure(traces)
    _layout(fig, scene, sites, title, n_links, n_paths, n_map, map_idx)
    fig.layout.meta = {**info, "objects": len(scene.objects), "links": n_links,
                       "paths": n_paths, "map_cells": n_map}  # fmt: skip
    return fig


def _layout(
    fig: Any, scene: Scene, sites: Any, title: str | None, n_links: int, n_paths: int,
    n_map: int, map_idx: list[int],
) -> None:  # fmt: skip
    """Title, axes in metres at true scale, a camera from the south-west, the legend and the
    accuracy map's menu."""
    lo, hi = scene.bounds
    name = sites.block.get("name") or Path(scene.source).stem or "scene"
    size = " x ".join(f"{v:.1f}" for v in hi - lo)
    parts = [f"{len(scene.objects)} objects, {len(scene.faces)} triangles, {size} m"]
    if n_links:
        parts.append(f"{n_paths} paths of {n_links} link(s), first arrivals bold")
    if n_map:
        parts.append(f"accuracy map of {n_map} cells")
    head = title or f"<b>{name}</b>"
    axis = {"showbackground": False, "gridcolor": "rgb(220,220,220)", "zeroline": False}
    fig.update_layout(
        title={"text": f"{head}<br><sup>{'; '.join(parts)}</sup>", "x": 0.01},
        scene={"aspectmode": "data", "xaxis": {**axis, "title": {"text": "x (m)"}},
               "yaxis": {**axis, "title": {"text": "y (m)"}},
               "zaxis": {**axis, "title": {"text": "z (m)"}},
               "camera": {"eye": {"x": -1.3, "y": -1.9, "z": 1.25}}},
        legend={"groupclick": "togglegroup", "itemsizing": "constant", "x": 0.0, "y": 0.92,
                "bgcolor": "rgba(255,255,255,0.7)"},
        margin={"l": 0, "r": 0, "t": 60, "b": 0}, paper_bgcolor="white",
        hoverlabel={"align": "left"},
    )  # fmt: skip
    if len(map_idx) > 1:
        labels = [fig.data[i].colorbar.title.text for i in map_idx]
        buttons = [
            {"label": lab, "method": "restyle",
             "args": [{"visible": [i == k for i in range(len(map_idx))]}, map_idx]}
            for k, lab in enumerate(labels)
        ]  # fmt: skip
        fig.update_layout(updatemenus=[{"buttons": buttons, "x": 0.99, "xanchor": "right",
                                        "y": 0.99, "yanchor": "top", "showactive": True}])  # fmt: skip


def view_html(fig: Any) -> str:
    """The figure as one self-contained HTML page (plotly's JavaScript embedded, no network)
    that fills the browser window."""
    return fig.to_html(
        include_plotlyjs=True,
        full_html=True,
        include_mathjax=False,
        default_width="100%",
        default_height="100vh",
        config={"displaylogo": False, "responsive": True, "scrollZoom": True},
    )
