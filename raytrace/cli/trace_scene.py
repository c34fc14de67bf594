"""``trace-scene``: summarise a scene and trace all paths between transmitters and receivers;
``build-hall``: build a hall mesh from its YAML description."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
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


# -- trace-scene ------------------------------------------------------------------------------
def trace_scene_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="trace-scene",
        description=(
            "Summarise a scene and trace all paths between transmitters and receivers. SCENE is a "
            "mesh (.glb .gltf .obj .ply .stl), a Mitsuba/Sionna XML, or 'hall' for the bundled "
            "reference hall, whose base stations and points are traced by default."
        ),
    )
    add_scene_arguments(p)
    p.add_argument(
        "--tx", type=parse_xyz, action="append", metavar="X,Y,Z", help="transmitter (repeatable), m"
    )
    p.add_argument(
        "--rx", type=parse_xyz, action="append", metavar="X,Y,Z", help="receiver (repeatable), m"
    )
    p.add_argument(
        "--band", default="c-band", help="band name (c-band, mmwave) or a bands YAML [c-band]"
    )
    p.add_argument("--frequency-hz", type=float, help="carrier frequency in Hz (overrides --band)")
    p.add_argument("-o", "--output", help="write the paths (.npz, .json or .csv)")
    p.add_argument(
        "--export-glb", metavar="FILE", help="write the scene with the paths of --link links"
    )
    p.add_argument(
        "--link",
        action="append",
        metavar="TX,RX",
        help="links to export with --export-glb, as indices or names (default: the first link)",
    )
    p.add_argument(
        "--summary-only", action="store_true", help="print the scene summary, trace nothing"
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_trace_arguments(p)
    return p


def trace_scene_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``trace-scene``."""
    return run_tool(_trace_scene, trace_scene_parser(), argv)


def _trace_scene(args: argparse.Namespace) -> int:
    from ..emulation.bands import get_band
    from ..scene.io import load_scene
    from ..scene.metadata import SceneMetadata
    from ..solver.config import config_from_args
    from ..solver.tracer import check_positions, trace

    _check_outputs(args)
    scene = load_scene(args.scene, args.materials, **scene_options(args))
    summary = scene.summary()
    sites = SceneMetadata.from_scene(scene)
    tx_names, tx = sites.bs_names, sites.bs_xyz
    rx_names, rx = sites.point_names, sites.point_xyz
    if args.tx:
        tx_names, tx = [f"tx{i}" for i in range(len(args.tx))], np.array(args.tx, dtype=float)
    if args.rx:
        rx_names, rx = [f"rx{i}" for i in range(len(args.rx))], np.array(args.rx, dtype=float)

    if args.summary_only or len(tx) == 0 or len(rx) == 0:
        if not args.summary_only and (len(tx) == 0) != (len(rx) == 0):
            raise HallrayError(
                "give both --tx and --rx (the scene has no stored positions for the other)"
            )
        if args.output or args.export_glb:
            raise HallrayError("nothing traced: give --tx and --rx to write paths")
        if args.json:
            print(json.dumps(summary, indent=1))
        else:
            _print_summary(summary)
        return 0

    check_positions(scene, tx, "transmitter", strict=True)
    check_positions(scene, rx, "receiver", strict=True)
    band = get_band(args.band)
    freq = float(args.frequency_hz) if args.frequency_hz is not None else band.center_frequency_hz
    t0 = time.perf_counter()
    show = not args.quiet and not args.json and sys.stderr.isatty()
    paths = trace(scene, tx, rx, freq, config_from_args(args), progress=show)
    elapsed = time.perf_counter() - t0
    table = link_table(paths, tx_names, rx_names)
    if args.output:
        paths.save(args.output, scene_sha256=scene.content_hash())
    if args.export_glb:
        from ..viz.export import export_paths_glb

        links = parse_links(args.link, tx_names, rx_names) if args.link else [0]
        export_paths_glb(scene, paths, links, args.export_glb)
    if args.json:
        print(
            json.dumps(
                {
                    "scene": summary,
                    "frequency_hz": freq,
                    "n_paths": paths.n_paths,
                    "elapsed_s": round(elapsed, 4),
                    "links": table,
                },
                indent=1,
            )
        )
        return 0
    _print_summary(summary)
    print(
        f"\ntraced {paths.n_links} links ({len(tx)} tx x {len(rx)} rx) at {freq / 1e9:.4g} GHz: "
        f"{paths.n_paths} paths in {elapsed:.2f} s "
        f"(reflections <= {args.max_reflections}, penetrations <= {args.max_penetrations}, "
        f"diffractions <= {args.max_diffractions}, interactions <= {args.max_interactions})\n"
    )
    _print_links(table)
    if args.output:
        print(f"\npaths written to {args.output}")
    if args.export_glb:
        print(f"scene with paths written to {args.export_glb}")
    return 0


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, an output that is special, an input, or both outputs at once."""
    from hallray.safe_output import check_output

    from ..scene.bundled import resolve_scene

    inputs = [resolve_scene(args.scene), args.materials, args.band]
    if args.output:
        check_output(args.output, inputs=inputs, what="-o")
    if args.export_glb:
        if not args.export_glb.lower().endswith(".glb"):
            raise HallrayError(
                f"--export-glb {args.export_glb}: the export is binary glTF: name it .glb"
            )
        check_output(args.export_glb, inputs=[*inputs, args.output], what="--export-glb")


def link_table(paths: Any, tx_names: list[str], rx_names: list[str]) -> list[dict[str, Any]]:
    """Per-link summary rows: first arrival, LoS, path counts by kind, strongest path."""
    from ..core.constants import C0

    first = paths.first_arrival()
    strong = paths.strongest()
    counts = paths.counts_by_kind()
    kinds = paths.kind_label
    power = paths.power_db
    n_rx = len(paths.rx)
    rows = []
    for link in range(paths.n_links):
        t, r = divmod(link, n_rx)
        d = float(np.linalg.norm(paths.tx[t] - paths.rx[r]))
        i, s = first[link], strong[link]
        rows.append(
            {
                "tx": tx_names[t] if t < len(tx_names) else f"tx{t}",
                "rx": rx_names[r] if r < len(rx_names) else f"rx{r}",
                "distance_m": round(d, 4),
                "los": bool(counts["los"][link] > 0),
                "first_delay_ns": None if i < 0 else round(paths.delay_s[i] * 1e9, 4),
                "first_excess_m": None if i < 0 else round(paths.delay_s[i] * C0 - d, 4),
                "first_kind": None if i < 0 else str(kinds[i]),
                "n_los": int(counts["los"][link]),
                "n_reflection": int(counts["reflection"][link]),
                "n_penetration": int(counts["penetration"][link]),
                "n_diffraction": int(counts["diffraction"][link]),
                "strongest_kind": None if s < 0 else str(kinds[s]),
                "strongest_power_db": None if s < 0 else round(float(power[s]), 2),
            }
        )
    return rows


_UNIT_WORDS = {"mm": "millimetres", "cm": "centimetres", "km": "kilometres", "in": "inches",
               "ft": "feet"}  # fmt: skip


def _print_summary(s: dict[str, Any]) -> None:
    size = " x ".join(f"{v:.2f}" for v in s["size_m"])
    mats = ", ".join(f"{k} ({v})" for k, v in s["materials"].items())
    print(f"scene      {s['source']}")
    print(f"extent     {size} m  (min {s['bounds_min_m']}, max {s['bounds_max_m']})")
    print(
        f"objects    {s['objects']} ({s['closed_solids']} closed solids, {s['open_sheets']} open sheets)"
    )
    if s.get("surfaces"):
        print("model      surfaces: every face a slab of its material's thickness, closed meshes "
              "hollow (Sionna RT's; --solids for solids)")  # fmt: skip
    if s.get("up") == "y":
        print("up         the file's +y, turned to z up: (x, y, z) -> (x, -z, y); --up z keeps "
              "the file's axes")  # fmt: skip
    if s.get("unit", "m") != "m":
        print(f"unit       the file's numbers are {_UNIT_WORDS.get(s['unit'], s['unit'])}, "
              "scaled to metres")  # fmt: skip
    print(f"materials  {mats}")
    print(f"triangles  {s['triangles']}   facets {s['facets']}   wedges {s['wedges']}")


def _print_links(rows: list[dict[str, Any]]) -> None:
    head = (
        f"{'tx':<6} {'rx':<6} {'dist m':>7} {'LoS':>3} {'first ns':>9} {'excess m':>8} {'first':>6} "
        f"{'#LoS':>4} {'#R':>4} {'#T':>4} {'#D':>4} {'strongest':>9} {'dB':>8}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        fd = "-" if r["first_delay_ns"] is None else f"{r['first_delay_ns']:.3f}"
        ex = "-" if r["first_excess_m"] is None else f"{r['first_excess_m']:.3f}"
        sp = "-" if r["strongest_power_db"] is None else f"{r['strongest_power_db']:.2f}"
        print(
            f"{r['tx']:<6} {r['rx']:<6} {r['distance_m']:>7.2f} {'yes' if r['los'] else 'no':>3} {fd:>9} "
            f"{ex:>8} {r['first_kind'] or '-':>6} {r['n_los']:>4} {r['n_reflection']:>4} "
            f"{r['n_penetration']:>4} {r['n_diffraction']:>4} {r['strongest_kind'] or '-':>9} {sp:>8}"
        )
