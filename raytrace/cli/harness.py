"""What every ray-tracer command shares: the harness (one-line errors, exit codes, signals) and the
common option types.

The harness itself is :mod:`hallray.harness` (one for both packages); :func:`run_tool` runs a
raytrace tool with :class:`~raytrace.core.errors.HallrayError` as bad input. The command modules
beside this one are thin: they parse, call the library, print or write.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from hallray.harness import EXIT_BAD_INPUT, OneLineParser, run_command

from ..core.errors import HallrayError

__all__ = [
    "EXIT_BAD_INPUT",
    "OneLineParser",
    "add_scene_arguments",
    "parse_links",
    "parse_xyz",
    "run_tool",
]


def run_tool(
    main: Callable[[argparse.Namespace], int],
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    *,
    interrupted: str = "interrupted",
) -> int:
    """Run a raytrace command (:func:`hallray.harness.run_command`); returns the exit status."""
    return run_command(main, parser, argv, user_errors=(HallrayError,), interrupted=interrupted)


def parse_xyz(text: str) -> list[float]:
    """``"x,y,z"`` in metres -> three floats (argparse type; negative values work)."""
    parts = text.replace(" ", "").split(",")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in metres, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in metres, got {text!r}")
    if not all(np.isfinite(vals)):
        raise argparse.ArgumentTypeError(f"coordinates must be finite numbers, got {text!r}")
    return vals


def add_scene_arguments(p: argparse.ArgumentParser) -> None:
    """The options of every command that loads a scene: SCENE, --materials, --default-material."""
    p.add_argument("scene",
                   help="scene file (.glb .gltf .obj .ply .stl .dae, IFC, Mitsuba XML) or 'hall'")
    p.add_argument("--materials", help="materials YAML (user materials, bind patterns, default)")
    p.add_argument("--default-material", help="material for objects no name or pattern binds")
    p.add_argument(
        "--smooth-angle",
        type=float,
        metavar="DEG",
        help="edges bending less than this are smooth (a tessellated curve), not diffracting "
        "wedges [1]",
    )
    model = p.add_mutually_exclusive_group()
    model.add_argument(
        "--surfaces",
        dest="surfaces",
        action="store_const",
        const=True,
        help="every mesh is surfaces, each face a slab of its material's thickness, a closed "
        "mesh a hollow shell (Sionna RT's model; the default for a Mitsuba XML hallray did not "
        "write)",
    )
    model.add_argument(
        "--solids",
        dest="surfaces",
        action="store_const",
        const=False,
        help="a closed (watertight) mesh is a solid crossed along its chord (the default for "
        "mesh files and hallray's own XML)",
    )
    p.add_argument(
        "--up",
        choices=("z", "y"),
        help="the file's axis that points up; y turns it to z up, (x, y, z) -> (x, -z, y) "
        "[the format's convention: y for glTF not written by trimesh and Blender's OBJ, else z]",
    )
    p.add_argument(
        "--unit",
        choices=("m", "mm", "cm", "km", "in", "ft"),
        help="unit of the file's numbers, scaled to metres as it is read (a CAD export in "
        "millimetres: mm) [the unit a Collada file states, else m]",
    )
    p.add_argument(
        "--no-scene-cache",
        action="store_true",
        help="neither read nor write the preprocessing cache beside a large scene "
        "(.hallray-cache/)",
    )


def scene_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`~raytrace.scene.io.load_scene` from
    :func:`add_scene_arguments`'s options (beyond SCENE and --materials)."""
    return {
        "default_material": args.default_material,
        "smooth_angle_deg": args.smooth_angle,
        "surfaces": args.surfaces,
        "up": args.up,
        "unit": args.unit,
        "cache": False if args.no_scene_cache else None,
    }


def parse_links(items: list[str], tx_names: list[str], rx_names: list[str]) -> list[int]:
    """``--link TX,RX`` values (names or indices) -> link indices ``tx * R + rx``."""
    out = []
    for item in items:
        parts = item.split(",")
        if len(parts) != 2:
            raise HallrayError(f"--link expects TX,RX (indices or names), got {item!r}")
        idx = []
        for part, names in zip(parts, (tx_names, rx_names)):
            part = part.strip()
            if part in names:
                idx.append(names.index(part))
            elif part.isdigit() and int(part) < len(names):
                idx.append(int(part))
            else:
                raise HallrayError(f"--link {item!r}: {part!r} is not a known name or index")
        out.append(idx[0] * len(rx_names) + idx[1])
    return out
