"""``render-scene SCENE [--paths FILE] [--link TX,RX ...] -o FILE.png``: a picture of a scene.

A top view and a perspective view, coloured by material, with the base stations, the points and
the chosen links' paths coloured by kind (read from a paths file written by ``trace-scene -o``,
or traced on the fly). Bad input: one line ``error: ...`` on stderr, exit status 2, no file.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from ..core.errors import HallrayError
from ..solver.config import add_trace_arguments, config_from_args
from .harness import (
    OneLineParser,
    add_scene_arguments,
    parse_links,
    parse_xyz,
    run_tool,
    scene_options,
)


def _size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, got {text!r}") from None
    return w, h


def render_scene_parser() -> argparse.ArgumentParser:
    from ..viz.render import DEFAULT_DPI, DEFAULT_SIZE_PX

    p = OneLineParser(
        prog="render-scene",
        description=(
            "Draw a scene (top view and perspective view, coloured by material) with its base "
            "stations, points and the paths of chosen links, coloured by kind, into a PNG. "
            "SCENE is a mesh file, a Mitsuba/Sionna XML or 'hall'. See docs/render.md."
        ),
    )
    add_scene_arguments(p)
    p.add_argument("-o", "--output", required=True, help="output picture (.png)")
    p.add_argument(
        "--paths", metavar="FILE", help="paths file (.npz) written by trace-scene -o for this scene"
    )
    p.add_argument(
        "--link",
        action="append",
        metavar="TX,RX",
        help="a link to draw, by names (BS1,P07) or indices (repeatable)",
    )
    p.add_argument("--tx", type=parse_xyz, action="append", metavar="X,Y,Z", help="transmitter")
    p.add_argument("--rx", type=parse_xyz, action="append", metavar="X,Y,Z", help="receiver")
    p.add_argument(
        "--max-paths",
        type=int,
        default=8,
        help="strongest paths drawn per link besides the first arrival (-1: all) [8]",
    )
    p.add_argument("--band", default="c-band", help="band when tracing on the fly [c-band]")
    p.add_argument("--frequency-hz", type=float, help="carrier frequency, Hz (overrides --band)")
    p.add_argument(
        "--size",
        type=_size,
        default=DEFAULT_SIZE_PX,
        metavar="WxH",
        help=f"picture size in pixels [{DEFAULT_SIZE_PX[0]}x{DEFAULT_SIZE_PX[1]}]",
    )
    p.add_argument("--dpi", type=int, default=DEFAULT_DPI, help=f"[{DEFAULT_DPI}]")
    p.add_argument("--title", help="title (default: the scene's name)")
    p.add_argument(
        "--cut-height", type=float, help="top view: leave out objects wholly above this, m"
    )
    p.add_argument("--elev", type=float, default=32.0, help="perspective elevation, deg [32]")
    p.add_argument("--azim", type=float, default=-125.0, help="perspective azimuth, deg [-125]")
    add_trace_arguments(p)
    return p


def render_scene_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``render-scene``."""
    return run_tool(_render_scene, render_scene_parser(), argv)


def _render_scene(args: argparse.Namespace) -> int:
    from ..scene.io import load_scene
    from ..scene.metadata import SceneMetadata
    from ..solver.paths import Paths, check_paths_scene
    from ..viz.render import link_paths, render_scene

    if not args.output.lower().endswith(".png"):
        raise HallrayError(f"output {args.output} must end in .png")
    if args.dpi < 20 or args.dpi > 1200:
        raise HallrayError(f"--dpi must be 20..1200, got {args.dpi}")
    for flag, value in (("--elev", args.elev), ("--azim", args.azim),
                        ("--cut-height", args.cut_height)):  # fmt: skip
        if value is not None and not np.isfinite(value):
            raise HallrayError(f"{flag} must be a finite number, got {value}")
    w, h = args.size
    if min(w, h) < 16:
        raise HallrayError(f"--size must be at least 16x16 pixels, got {w}x{h}")
    from hallray.limits import check_size

    check_size("pixels", float(w) * float(h), f"--size {w}x{h}")
    from hallray.safe_output import check_output

    from ..scene.bundled import resolve_scene

    check_output(args.output, inputs=[resolve_scene(args.scene), args.materials, args.paths])
    scene = load_scene(args.scene, args.materials, **scene_options(args))
    sites = SceneMetadata.from_scene(scene)
    bs_names, bs_xyz, pt_names, pt_xyz = (
        sites.bs_names,
        sites.bs_xyz,
        sites.point_names,
        sites.point_xyz,
    )
    links = []
    freq = None
    if args.paths:
        if args.tx or args.rx:
            raise HallrayError("give either --paths or --tx/--rx, not both")
        paths = Paths.load(args.paths)
        check_paths_scene(args.paths, paths, scene)
        tx_names = _names_for(paths.tx, bs_names, bs_xyz, "tx")
        rx_names = _names_for(paths.rx, pt_names, pt_xyz, "rx")
        chosen = parse_links(args.link, tx_names, rx_names) if args.link else []
        links = link_paths(paths, chosen, tx_names, rx_names, max_paths=args.max_paths)
        freq = paths.frequency_hz
    elif args.link:
        from ..emulation.bands import get_band
        from ..solver.tracer import check_positions, trace

        tx = np.array(args.tx, dtype=float) if args.tx else bs_xyz
        rx = np.array(args.rx, dtype=float) if args.rx else pt_xyz
        tx_names = [f"tx{i}" for i in range(len(tx))] if args.tx else bs_names
        rx_names = [f"rx{i}" for i in range(len(rx))] if args.rx else pt_names
        if len(tx) == 0 or len(rx) == 0:
            raise HallrayError(
                "the scene stores no base stations or points: give --tx and --rx, or --paths"
            )
        chosen = parse_links(args.link, tx_names, rx_names)
        check_positions(scene, tx, "transmitter", strict=True)
        check_positions(scene, rx, "receiver", strict=True)
        band = get_band(args.band)
        freq = float(args.frequency_hz) if args.frequency_hz else band.center_frequency_hz
        for link in chosen:
            t, r = divmod(link, len(rx))
            one = trace(scene, tx[t : t + 1], rx[r : r + 1], freq, config_from_args(args))
            links += link_paths(one, [0], [tx_names[t]], [rx_names[r]], max_paths=args.max_paths)
    elif args.tx or args.rx:
        raise HallrayError("--tx/--rx are for tracing links: add --link TX,RX")
    info = render_scene(
        scene,
        args.output,
        links=links,
        size_px=args.size,
        dpi=args.dpi,
        title=args.title,
        cut_height_m=args.cut_height,
        elev=args.elev,
        azim=args.azim,
        frequency_hz=freq,
    )
    w, h = info["size_px"]
    print(
        f"wrote {args.output}: {w}x{h} px, {info['objects_drawn']} objects, "
        f"{len(links)} link(s), {info['paths_drawn']} paths"
    )
    for lk in links:
        print(f"  {lk.tx_name} -> {lk.rx_name}: first arrival {lk.first_kind}")
    return 0


def _names_for(xyz: np.ndarray, names: list[str], stored: np.ndarray, prefix: str) -> list[str]:
    """The scene's names for the positions of a paths file when they match (1 mm), else
    ``tx0, tx1, ...``."""
    if len(names) == len(xyz) and np.allclose(stored, xyz, atol=1e-3):
        return list(names)
    return [f"{prefix}{i}" for i in range(len(xyz))]
