#!/usr/bin/env python3
"""Reciprocity of the tracer: trace a scene's links both ways and compare each path with its
reverse, per kind of path.

Run from a checkout: ``python tools/check_reciprocity.py [--scene hall] [--band c-band]
[--max-reflections 2] [--max-penetrations 2] [--max-diffractions 1] [--tol-db 1e-6]``.

A path from A to B and the same path from B to A (the interactions in reverse order, on the same
facets, wedges and objects, through the same reflection and diffraction points) must have the
same delay and the same complex gain in a reciprocal medium with the same antenna at both ends.
Prints, per kind (``RD``, ``TRR``, ...), how many paths were found one way only, and the largest
differences of delay (m) and gain (dB, and relative) between a path and its reverse
(``raytrace.studies.reciprocity``; the hall's figures are held by a slow test). A diagnostic for
the physics (docs/tracing.md, "Penetration"; docs/diffraction.md, (D8a)).
"""

from __future__ import annotations

import argparse
import math

from raytrace import TraceConfig, load_scene, trace
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.emulation.bands import get_band
from raytrace.scene.metadata import SceneMetadata
from raytrace.studies.reciprocity import compare_reverse, format_table


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall", help="scene file or 'hall' [hall]")
    ap.add_argument("--band", default="c-band", help="band name [c-band]")
    ap.add_argument("--max-reflections", type=int, default=2, help="reflections per path [2]")
    ap.add_argument("--max-penetrations", type=int, default=2, help="penetrations per path [2]")
    ap.add_argument("--max-diffractions", type=int, default=1, help="diffractions per path [1]")
    ap.add_argument("--tol-db", type=float, default=1e-6, help="gain difference counted, dB")
    return ap


def _main(args: argparse.Namespace) -> int:
    # a bad band, limit or tolerance before the scene is read: one line, no traceback
    if not (math.isfinite(args.tol_db) and args.tol_db >= 0):
        raise HallrayError(f"--tol-db must be a number of dB >= 0, got {args.tol_db:g}")
    f = get_band(args.band).center_frequency_hz
    cfg = TraceConfig(max_reflections=args.max_reflections,
                      max_penetrations=args.max_penetrations,
                      max_diffractions=args.max_diffractions)  # fmt: skip
    scene = load_scene(args.scene)
    inp = SceneMetadata.from_scene(scene, require=True)
    fwd = trace(scene, inp.bs_xyz, inp.point_xyz, f, cfg)
    rev = trace(scene, inp.point_xyz, inp.bs_xyz, f, cfg)
    rows = compare_reverse(fwd, rev, args.tol_db)
    print(f"{args.scene}, {args.band}: {fwd.n_paths} paths one way, {rev.n_paths} the other")
    print(format_table(rows))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
