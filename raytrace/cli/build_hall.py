"""``build-hall HALL.yaml [-o HALL.glb] [--los]``: validate a hall YAML and write its GLB.

Bad input (invalid YAML, an output that is not ``.glb``): one line ``error: ...`` on stderr, exit
status 2, no output file.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from ..core.errors import SceneError
from ..halls.spec.build import build_scene, write_glb
from ..halls.spec.los import line_of_sight, los_note
from ..halls.spec.parse import load_hall_spec
from .harness import OneLineParser, run_tool


def build_hall_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="build-hall",
        description="Build a hall GLB (one node per object, material in the node name) from YAML.",
    )
    p.add_argument("hall", help="hall description (YAML, see docs/hall.md)")
    p.add_argument("-o", "--output", help="output GLB (default: HALL with suffix .glb)")
    p.add_argument(
        "--los", action="store_true", help="print the line-of-sight table (points x base stations)"
    )
    return p


def _build_hall(args: argparse.Namespace) -> int:
    from hallray.safe_output import check_output

    out = Path(args.output) if args.output else Path(args.hall).with_suffix(".glb")
    if out.suffix.lower() != ".glb":
        raise SceneError(f"output {out} must end in .glb")
    check_output(out, inputs=[args.hall])  # before any work: never the YAML, never the package
    spec = load_hall_spec(args.hall)
    scene = build_scene(spec)
    data = write_glb(scene, out)
    n_faces = sum(len(g.faces) for g in scene.geometry.values())
    print(f"wrote {out}: {len(scene.geometry)} objects, {n_faces} triangles, {len(data)} bytes")
    if args.los:
        for point, status in line_of_sight(spec).items():
            print(f"{point}: {los_note(status)}")
    return 0


def build_hall_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``build-hall``; returns the exit status (0, or 2 on bad input)."""
    return run_tool(_build_hall, build_hall_parser(), argv)
