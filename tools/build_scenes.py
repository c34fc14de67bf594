#!/usr/bin/env python
"""Build the bundled scenes: ``scenes/hall.glb`` from ``scenes/hall.yaml`` and the canonical test
scenes ``scenes/canonical/*.glb``.

    python tools/build_scenes.py                 # (re)build every GLB
    python tools/build_scenes.py --check         # exit 1 if a committed GLB or LoS note is stale
    python tools/build_scenes.py --update-notes  # rewrite the LoS part of the points' notes in
                                                 # scenes/hall.yaml from a fresh segment test
    python tools/build_scenes.py --los-table     # print the LoS table (markdown, for docs/hall.md)

Every GLB is reproducible byte for byte (same input -> same bytes) and written atomically.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import SceneError
from raytrace.core.fileio import write_atomic
from raytrace.halls.spec import (
    SCHEMA_VERSION,
    Box,
    Primitive,
    Sheet,
    build_scene,
    glb_bytes,
    line_of_sight,
    load_hall_spec,
    los_markdown,
    los_note,
    scene_from_primitives,
)

ROOT = Path(__file__).resolve().parent.parent

SCENES = ROOT / "scenes"
HALL_YAML = SCENES / "hall.yaml"
HALL_GLB = SCENES / "hall.glb"
CANONICAL = SCENES / "canonical"


def _box(name: str, material: str, lo: tuple, hi: tuple) -> Box:
    """Axis-aligned closed box from its min and max corners (m)."""
    center = tuple(0.5 * (a + b) for a, b in zip(lo, hi, strict=True))
    size = tuple(b - a for a, b in zip(lo, hi, strict=True))
    return Box(name, material, center, size)


def _sheet(name: str, material: str, origin: tuple, u: tuple, v: tuple) -> Sheet:
    return Sheet(name, material, origin, u, v)


def _sites(prefix: str, xyz: list[tuple[float, float, float]]) -> list[dict]:
    return [{"name": f"{prefix}{k + 1}", "xyz": [float(c) for c in p]} for k, p in enumerate(xyz)]


def _floor(half: float = 10.0) -> Sheet:
    return _sheet(
        "floor", "concrete", (-half, -half, 0.0), (2 * half, 0.0, 0.0), (0.0, 2 * half, 0.0)
    )


def canonical_scenes() -> dict[str, tuple[list[Primitive], str, list, list]]:
    """name -> (primitives, description, suggested tx positions, suggested rx positions), in m."""
    scenes: dict[str, tuple[list[Primitive], str, list, list]] = {}
    scenes["one_wall"] = (
        [_box("wall", "concrete", (-5.0, -0.1, 0.0), (5.0, 0.1, 3.0))],
        "one closed concrete wall, 10 x 0.2 x 3 m, centred on the y = 0 plane: x in [-5, 5], "
        "y in [-0.1, 0.1], z in [0, 3]; rx1 behind it (penetration), rx2 on the tx side (reflection)",
        [(0.0, -5.0, 1.5)],
        [(0.0, 5.0, 1.5), (3.0, -4.0, 1.5)],
    )
    scenes["one_sheet"] = (
        [_sheet("sheet", "metal", (-5.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 0.0, 3.0))],
        "one open metal rectangle in the plane y = 0: x in [-5, 5], z in [0, 3]; rx1 behind it, "
        "rx2 on the tx side (reflection)",
        [(0.0, -5.0, 1.5)],
        [(0.0, 5.0, 1.5), (3.0, -4.0, 1.5)],
    )
    scenes["floor"] = (
        [_floor()],
        "a 20 x 20 m concrete floor as an open sheet at z = 0 (x, y in [-10, 10]): two-ray model",
        [(-5.0, 0.0, 2.0)],
        [(5.0, 0.0, 1.5)],
    )
    scenes["shoebox"] = (
        [
            _sheet("floor", "concrete", (0, 0, 0), (10, 0, 0), (0, 8, 0)),
            _sheet("ceiling", "concrete", (0, 0, 3), (10, 0, 0), (0, 8, 0)),
            _sheet("wall_south", "concrete", (0, 0, 0), (10, 0, 0), (0, 0, 3)),
            _sheet("wall_north", "concrete", (0, 8, 0), (10, 0, 0), (0, 0, 3)),
            _sheet("wall_west", "concrete", (0, 0, 0), (0, 8, 0), (0, 0, 3)),
            _sheet("wall_east", "concrete", (10, 0, 0), (0, 8, 0), (0, 0, 3)),
        ],
        "a 10 x 8 x 3 m room ([0, 10] x [0, 8] x [0, 3]) made of six separate open concrete "
        "sheets (two-sided): image-source reference",
        [(2.0, 3.0, 1.5)],
        [(7.0, 5.0, 1.2)],
    )
    for material in ("metal", "concrete"):
        name = "box_on_floor" if material == "metal" else "box_on_floor_concrete"
        scenes[name] = (
            [_box("box", material, (-1.0, -1.0, 0.0), (1.0, 1.0, 2.0)), _floor()],
            f"a closed {material} box 2 x 2 x 2 m ([-1, 1]^2 x [0, 2]) on a 20 x 20 m concrete "
            "floor sheet at z = 0; rx1 hidden behind the box, rx2 beside it",
            [(-5.0, 0.0, 1.5)],
            [(5.0, 0.0, 1.5), (0.0, 5.0, 1.0)],
        )
    scenes["half_plane"] = (
        [_sheet("screen", "metal", (0.0, -50.0, -50.0), (0.0, 100.0, 0.0), (0.0, 0.0, 50.0))],
        "knife edge: a metal screen in the plane x = 0, y in [-50, 50], z in [-50, 0]; its straight "
        "edge runs along y at z = 0. tx at 20 m before it, rx 20 m behind it from deep shadow "
        "(z = -4) to lit (z = +4)",
        [(-20.0, 0.0, 0.0)],
        [(20.0, 0.0, z) for z in (-4.0, -1.0, 0.0, 1.0, 4.0)],
    )
    scenes["two_boxes"] = (
        [
            _box("box_a", "metal", (-4.0, -1.0, 0.0), (-2.0, 1.0, 3.0)),
            _box("box_b", "metal", (2.0, -1.0, 0.0), (4.0, 1.0, 3.0)),
        ],
        "two closed metal boxes 2 x 2 x 3 m, x in [-4, -2] and [2, 4], y in [-1, 1], z in [0, 3], "
        "a 4 m gap between them; tx1 -> rx1 blocked by both, tx2 -> rx2 through the gap",
        [(-8.0, 0.0, 1.5), (0.0, -6.0, 1.5)],
        [(8.0, 0.0, 1.5), (0.0, 6.0, 1.5)],
    )
    return scenes


def canonical_glbs() -> dict[Path, bytes]:
    """Output path -> GLB bytes of every canonical scene."""
    out: dict[Path, bytes] = {}
    for name, (prims, description, tx, rx) in canonical_scenes().items():
        meta = {
            "schema_version": SCHEMA_VERSION,
            "name": name,
            "description": description,
            "materials": {},
            "tx": _sites("tx", tx),
            "rx": _sites("rx", rx),
        }
        out[CANONICAL / f"{name}.glb"] = glb_bytes(scene_from_primitives(prims, meta))
    return out


def hall_glb() -> bytes:
    return glb_bytes(build_scene(load_hall_spec(HALL_YAML)))


_POINT_LINE = re.compile(r'^(\s*- \{name: (\w+), xyz: \[[^\]]*\], note: ")([^"]*)("\}\s*)$')


def updated_hall_yaml() -> str:
    """hall.yaml with the LoS part of every point's note recomputed (the description kept)."""
    table = line_of_sight(load_hall_spec(HALL_YAML))
    lines = HALL_YAML.read_text(encoding="utf-8").splitlines(keepends=True)
    done = set()
    for k, line in enumerate(lines):
        m = _POINT_LINE.match(line)
        if m is None or m.group(2) not in table:
            continue
        description = m.group(3).split("; LoS to ")[0].split("LoS to ")[0].rstrip("; ")
        status = los_note(table[m.group(2)])
        note = f"{description}; {status}" if description else status
        lines[k] = f"{m.group(1)}{note}{m.group(4)}"
        done.add(m.group(2))
    missing = sorted(set(table) - done)
    if missing:
        raise SceneError(f"{HALL_YAML}: points not written as one-line flow mappings: {missing}")
    return "".join(lines)


def _write_all(outputs: dict[Path, Callable[[], bytes]]) -> None:
    for path, make in outputs.items():
        data = make()
        old = path.read_bytes() if path.exists() else None
        if old != data:
            write_atomic(path, data)
            print(f"wrote {path.relative_to(ROOT)} ({len(data)} bytes)")
        else:
            print(f"unchanged {path.relative_to(ROOT)}")


def parser() -> argparse.ArgumentParser:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--check", action="store_true", help="fail if a committed file is stale")
    group.add_argument("--update-notes", action="store_true", help="rewrite LoS notes in hall.yaml")
    group.add_argument("--los-table", action="store_true", help="print the LoS table (markdown)")
    return parser


def _main(args: argparse.Namespace) -> int:
    if args.los_table:
        print(los_markdown(load_hall_spec(HALL_YAML)), end="")
        return 0
    if args.update_notes:
        text = updated_hall_yaml()
        write_atomic(HALL_YAML, text.encode("utf-8"))
        print(f"updated notes in {HALL_YAML.relative_to(ROOT)}")
        return 0
    outputs: dict[Path, Callable[[], bytes]] = {HALL_GLB: hall_glb}
    for path, data in canonical_glbs().items():
        outputs[path] = lambda data=data: data
    if args.check:
        stale = [p for p, make in outputs.items() if not p.exists() or p.read_bytes() != make()]
        if updated_hall_yaml() != HALL_YAML.read_text(encoding="utf-8"):
            stale.append(HALL_YAML)
        for p in stale:
            print(f"stale: {p.relative_to(ROOT)}", file=sys.stderr)
        return 1 if stale else 0
    _write_all(outputs)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
