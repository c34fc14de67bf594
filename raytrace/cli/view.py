"""``hallray-view SCENE [--paths FILE] [--link TX,RX ...] [--map DIR] -o view.html``: an
interactive 3D view of a scene in one self-contained HTML page (:mod:`raytrace.viz.interactive`).

Without ``--paths`` and ``--link`` the hall, its base stations and points are drawn and nothing
is traced; ``--link`` traces the chosen links; ``--paths`` draws saved paths (its ``--link``
links, else every link). Bad input (a missing file, paths or a map of another scene, an unknown
link name): one line ``error: ...`` on stderr, exit status 2, no file.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import HallrayError
from ..solver.config import add_trace_arguments
from .harness import (
    OneLineParser,
    add_scene_arguments,
    parse_links,
    parse_xyz,
    run_tool,
    scene_options,
)


def parser() -> argparse.ArgumentParser:
    """The parser of ``hallray-view`` (also used by ``hallray view``)."""
    from ..viz.interactive import DEFAULT_MAX_PATHS, DEFAULT_MAX_TRIANGLES

    p = OneLineParser(
        prog="hallray-view",
        description=(
            "Write an interactive 3D view of a scene as one self-contained HTML file that works "
            "offline: turn the hall with the mouse, toggle materials and path kinds in the "
            "legend, hover a path for its delay, excess delay, power and interactions. Drawn: "
            "the objects coloured by material (outer walls and ceiling see-through), the base "
            "stations and points; with --link TX,RX those links traced here; with --paths FILE "
            "saved paths (its --link links, else all); with --map DIR an accuracy map on the "
            "floor. Without --paths or --link nothing is traced. SCENE is a mesh file, a "
            "Mitsuba/Sionna XML or 'hall'. See docs/view.md."
        ),
    )
    add_scene_arguments(p)
    p.add_argument("-o", "--output", required=True, help="output page (.html)")
    p.add_argument("--paths", metavar="FILE",
                   help="paths file (.npz) written by trace-scene -o for this scene")  # fmt: skip
    p.add_argument("--link", action="append", metavar="TX,RX",
                   help="a link to draw, by names (BS1,P07) or indices (repeatable); traced "
                   "here unless --paths is given")  # fmt: skip
    p.add_argument("--tx", type=parse_xyz, action="append", metavar="X,Y,Z",
                   help="a transmitter to trace from instead of the scene's base stations")  # fmt: skip
    p.add_argument("--rx", type=parse_xyz, action="append", metavar="X,Y,Z",
                   help="a receiver to trace to instead of the scene's points")  # fmt: skip
    p.add_argument("--map", metavar="DIR",
                   help="accuracy map of this scene: accuracy-map's output DIR (or its map.npz)")  # fmt: skip
    p.add_argument("--max-paths", type=int, default=DEFAULT_MAX_PATHS, metavar="N",
                   help="strongest paths drawn per link besides the first arrival (-1: all) "
                   f"[{DEFAULT_MAX_PATHS}]")  # fmt: skip
    p.add_argument("--max-triangles", type=int, default=DEFAULT_MAX_TRIANGLES, metavar="N",
                   help="decimate the scene's meshes above this many triangles "
                   f"[{DEFAULT_MAX_TRIANGLES}]")  # fmt: skip
    p.add_argument("--band", default="c-band", help="band when tracing with --link [c-band]")
    p.add_argument("--frequency-hz", type=float, help="carrier frequency, Hz (overrides --band)")
    p.add_argument("--title", help="title (default: the scene's name)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    add_trace_arguments(p)
    return p


def view_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``hallray-view``; returns the exit status."""
    return run_tool(main, parser(), argv, interrupted="interrupted (nothing written)")


def main(args: argparse.Namespace) -> int:
    """``hallray-view``: check -> load -> paths (read or traced) -> figure -> one HTML file."""
    from hallray.safe_output import check_output, write_file

    from ..scene.bundled import resolve_scene
    from ..scene.io import load_scene
    from ..viz.interactive import preview, view_html

    t0 = time.perf_counter()
    if not args.output.lower().endswith((".html", ".htm")):
        raise HallrayError(f"output {args.output} must end in .html")
    if args.max_triangles < 100:
        raise HallrayError(f"--max-triangles must be at least 100, got {args.max_triangles}")
    inputs = [resolve_scene(args.scene), args.materials, args.paths]
    map_file = _map_file(args.map)
    check_output(args.output, inputs=[*inputs, map_file])
    if args.paths and (args.tx or args.rx):
        raise HallrayError("give either --paths or --tx/--rx, not both")
    if (args.tx or args.rx) and not args.link:
        raise HallrayError("--tx/--rx are for tracing links: add --link TX,RX")
    _say(args, f"loading {args.scene}")
    scene = load_scene(args.scene, args.materials, **scene_options(args))
    paths, links, names = _paths(args, scene)
    _say(args, "building the view")
    fmap = None
    if map_file is not None:
        from positioning.twin.fingerprint import read_map

        fmap = read_map(map_file)
    fig = preview(scene, paths, links, accuracy_map=fmap, max_paths=args.max_paths,
                  max_triangles=args.max_triangles, title=args.title,
                  tx_names=names[0], rx_names=names[1])  # fmt: skip
    html = view_html(fig).encode("utf-8")
    write_file(args.output, html, inputs=[*inputs, map_file])
    if not args.quiet:
        m = fig.layout.meta
        dec = f" (decimated from {m['triangles_in_scene']})" if m["decimation_m"] else ""
        print(
            f"wrote {args.output}: {len(html) / 1e6:.1f} MB, {m['objects']} objects, "
            f"{m['triangles']} triangles{dec}, {m['links']} link(s), {m['paths']} paths"
            + (f", accuracy map of {m['map_cells']} cells" if m["map_cells"] else "")
            + f" in {time.perf_counter() - t0:.1f} s"
        )
    return 0


def _say(args: argparse.Namespace, what: str) -> None:
    """A progress line on a terminal's stderr (not with -q, not into a pipe or file), for the
    steps that may take seconds."""
    if not args.quiet and sys.stderr.isatty():
        print(f"{what}...", file=sys.stderr, flush=True)


def _map_file(arg: str | None) -> Path | None:
    """accuracy-map's map.npz from --map DIR (or the file itself); a one-line error if absent."""
    if arg is None:
        return None
    p = Path(arg)
    if p.is_dir():
        p = p / "map.npz"
    if not p.is_file():
        raise HallrayError(f"--map {arg}: no accuracy map there (give accuracy-map's DIR)")
    return p


def _paths(args: argparse.Namespace, scene: Any) -> tuple[Any, list[int] | None, tuple]:
    """(paths or None, the link indices to draw or None for all, (tx names, rx names))."""
    from ..scene.metadata import SceneMetadata
    from ..solver.paths import Paths, check_paths_scene
    from ..viz.interactive import site_names

    sites = SceneMetadata.from_scene(scene)
    if args.paths:
        paths = Paths.load(args.paths)
        check_paths_scene(args.paths, paths, scene)
        tx_names = site_names(paths.tx, sites.bs_names, sites.bs_xyz, "tx")
        rx_names = site_names(paths.rx, sites.point_names, sites.point_xyz, "rx")
        links = parse_links(args.link, tx_names, rx_names) if args.link else None
        return paths, links, (tx_names, rx_names)
    if not args.link:
        return None, None, (None, None)
    tx = np.array(args.tx, dtype=float) if args.tx else sites.bs_xyz
    rx = np.array(args.rx, dtype=float) if args.rx else sites.point_xyz
    tx_names = [f"tx{i}" for i in range(len(tx))] if args.tx else sites.bs_names
    rx_names = [f"rx{i}" for i in range(len(rx))] if args.rx else sites.point_names
    if len(tx) == 0 or len(rx) == 0:
        raise HallrayError(
            "the scene stores no base stations or points: give --tx and --rx, or --paths"
        )
    chosen = parse_links(args.link, tx_names, rx_names)
    return _trace_links(args, scene, tx, rx, tx_names, rx_names, chosen)


def _trace_links(
    args: argparse.Namespace, scene: Any, tx: np.ndarray, rx: np.ndarray,
    tx_names: list[str], rx_names: list[str], chosen: list[int],
) -> tuple[Any, list[int], tuple]:  # fmt: skip
    """Trace the transmitters and receivers of the chosen links (all pairs of them, at once) and
    return the links among them to draw."""
    from ..emulation.bands import get_band
    from ..solver.config import config_from_args
    from ..solver.tracer import check_positions, trace

    ts = sorted({c // len(rx) for c in chosen})
    rs = sorted({c % len(rx) for c in chosen})
    check_positions(scene, tx[ts], "transmitter", strict=True)
    check_positions(scene, rx[rs], "receiver", strict=True)
    freq = args.frequency_hz or get_band(args.band).center_frequency_hz
    if not (np.isfinite(freq) and freq > 0):
        raise HallrayError(f"--frequency-hz must be a positive number, got {freq:g}")
    _say(args, f"tracing {len(chosen)} link(s) at {freq / 1e9:.6g} GHz")
    paths = trace(scene, tx[ts], rx[rs], float(freq), config_from_args(args))
    sub = [ts.index(c // len(rx)) * len(rs) + rs.index(c % len(rx)) for c in chosen]
    return paths, sub, ([tx_names[t] for t in ts], [rx_names[r] for r in rs])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(view_main())
