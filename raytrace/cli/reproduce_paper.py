"""``reproduce-paper``: from the bundled hall to the paper's comparison in one command.

Writes the paper's four ToA datasets (static and semi-dynamic, C-band and mmWave) under the
paper's model as written (``paper``), the realistic receiver and the ideal one (``first-path``),
from one trace, with :func:`raytrace.emulation.dataset.make_datasets`; positions every epoch with
every method (LS with the paper's random reference) and writes the paper's Table II and CDF plots
with ``accuracy-report`` (the positioning package) for each receiver; then ``paper.md``: Table II
beside the paper's and the findings (:mod:`raytrace.studies.paper`).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.errors import HallrayError
from .harness import OneLineParser, run_tool

#: Grid step of the twin's fingerprint maps, m (1 m: about 1700 cells in the hall).
DEFAULT_MAP_STEP_M = 1.0
#: Fixes timed per method for the cost table.
COST_FIXES = 2000
#: Methods of the main report beside the map-free ones: the twin and tracked rows.
EXTRA_METHODS = ("twin", "irls+track", "nlos-map+track", "twin+track")
#: Noise draws per map cell (the map's predicted errors; the twin uses its noiseless ToAs).
MAP_DRAWS = 20

#: The receivers whose reports are written beside the main one: the paper's model as written
#: (its Table II columns come first) and the ideal one (exact first detectable delay + eq. 3).
PAPER_RECEIVER = "paper"
IDEAL_RECEIVER = "first-path"
#: LS of every report: the paper's "random base station as a reference", drawn per epoch
#: (seeded with ``--seed``).
LS_REFERENCE = "random"

PAIRS = (
    ("static", "c-band"),
    ("static", "mmwave"),
    ("semi-dynamic", "c-band"),
    ("semi-dynamic", "mmwave"),
)


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="reproduce-paper",
        description=(
            "Trace the hall, write the paper's four ToA datasets (static / semi-dynamic x C-band / "
            "mmWave) and the positioning accuracy report (Table II, CDFs, top view of errors)."
        ),
    )
    p.add_argument("-o", "--output", default="hallray-out", help="output directory [hallray-out]")
    p.add_argument(
        "--scene", default="hall", help="scene with base stations, points and routes [hall]"
    )
    p.add_argument("--duration", type=float, default=60.0, help="emulated time, s [60]")
    p.add_argument("--rate", type=float, default=10.0, help="snapshots per second [10]")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--receiver",
        default=None,
        help="ToA receiver of the main report (default search-back); the reports of the paper's "
        "model (paper) and of the ideal receiver (first-path) are written beside it",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes for the snapshots [all cores this process may use]",
    )
    p.add_argument(
        "--map-step",
        type=float,
        default=DEFAULT_MAP_STEP_M,
        metavar="M",
        help="grid step of the fingerprint maps (one per band) of the twin estimator, m; 0: no "
        f"maps and no twin [{DEFAULT_MAP_STEP_M:g}]",
    )
    p.add_argument("--force", action="store_true", help="replace an existing output directory")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    return p


def reproduce_paper_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``reproduce-paper``."""
    return run_tool(_main, parser(), argv)


def _main(args: argparse.Namespace) -> int:
    from hallray.safe_output import output_dir

    from ..emulation.receivers.receiver import DEFAULT_TOA_METHOD, TOA_METHODS
    from ..scene.bundled import resolve_scene

    receiver = args.receiver or DEFAULT_TOA_METHOD
    if receiver not in TOA_METHODS:
        raise HallrayError(f"unknown receiver {receiver!r}; use one of {', '.join(TOA_METHODS)}")
    receivers = list(dict.fromkeys([receiver, PAPER_RECEIVER, IDEAL_RECEIVER]))
    if args.workers is None:
        from ..solver.parallel import cpu_count

        args.workers = cpu_count()
    if args.workers < 1:
        raise HallrayError(f"--workers must be at least 1, got {args.workers}")
    if not (math.isfinite(args.map_step) and args.map_step >= 0):
        raise HallrayError(f"--map-step must be a number of metres >= 0, got {args.map_step!r}")
    from ..scene.io import load_scene

    # the scene is read and built once, for the grid check, the datasets and the maps
    args.scene_obj = load_scene(args.scene)
    if args.map_step > 0:  # a grid step it refuses is refused before any work
        _check_map_grid(args, receiver)
    out = Path(args.output)
    scene = resolve_scene(args.scene)
    t0 = time.perf_counter()
    # the whole output (datasets, reports, paper.md) is built in a temporary directory beside OUT
    # and renamed when complete: an error, Ctrl-C or SIGTERM leaves nothing, and a rerun starts
    # clean
    with output_dir(out, command="reproduce-paper", force=args.force, inputs=[scene]) as tmp:
        text = _build(args, receivers, tmp, out, t0)
    print("\n" + text.split("## Why, by mechanism")[0].rstrip())
    reports = ", ".join(str(out / _report_name(r, receivers)) for r in receivers)
    print(f"\nreports in {reports}; comparison and findings in {out / 'paper.md'} "
          f"(total {time.perf_counter() - t0:.1f} s)")  # fmt: skip
    return 0


def _check_map_grid(args: argparse.Namespace, receiver: str) -> None:
    """The maps' settings and grid size (cells, the size limits), before any dataset is built:
    a ``--map-step`` the maps would refuse is refused in seconds, not after the datasets."""
    from ..scene.metadata import SceneMetadata
    from ..studies.accuracy_map.grid import make_grid
    from ..studies.accuracy_map.settings import MapSettings

    settings = MapSettings(step_m=args.map_step, receiver=receiver, draws=MAP_DRAWS)
    settings.check()
    scene = args.scene_obj
    sites = SceneMetadata.from_scene(scene)
    grid = make_grid(scene, settings, sites.point_names, sites.point_xyz)
    settings.check_grid(len(grid.cell_xyz), len(sites.bs_xyz))


def _report_name(receiver: str, receivers: Sequence[str]) -> str:
    return "report" if receiver == receivers[0] else f"report-{receiver}"


def _build(
    args: argparse.Namespace, receivers: Sequence[str], tmp: Path, out: Path, t0: float
) -> str:
    """Datasets of every receiver into ``tmp/datasets`` (one trace), a report per receiver, and
    ``tmp/paper.md``; returns the text of ``paper.md``."""
    from positioning import method_names
    from positioning.cli.accuracy import accuracy_report

    from ..emulation.dataset.make import make_datasets
    from ..studies.paper import costs_markdown, method_costs, write_comparison

    summaries = make_datasets(
        tmp / "datasets",
        PAIRS,
        scene=args.scene_obj,
        duration_s=args.duration,
        rate_hz=args.rate,
        seed=args.seed,
        workers=args.workers,
        progress=not args.quiet,
        toa_method=receivers,
    )
    print(f"datasets written to {out / 'datasets'} in {time.perf_counter() - t0:.1f} s:")
    for s in summaries:
        print(f"  {Path(s['directory']).name:<33} {s['epochs']} epochs, receiver {s['toa_method']}")
    maps = _build_maps(args, receivers[0], tmp / "maps") if args.map_step > 0 else []
    reports, datasets, argvs = {}, {}, []
    # with several cores, the reports side by side, one process each (three on two cores too:
    # the system shares the cores, and a report waiting for a free process would be a third of
    # the stage on one core): a report's figures and its twin are serial, so one report's
    # datasets on two workers left a core idle (the files do not depend on it)
    side_by_side = args.workers > 1 and len(receivers) > 1
    per_report = max(1, args.workers // len(receivers)) if side_by_side else args.workers
    for r in receivers:
        datasets[r] = [s["directory"] for s in summaries if s["toa_method"] == r]
        reports[r] = tmp / _report_name(r, receivers)
        argv = [*datasets[r], "-o", str(reports[r]), "--workers", str(per_report)]
        argv += ["--param", f"ls:reference={LS_REFERENCE}", "--param", f"ls:seed={args.seed}"]
        methods = method_names(include_map=False) + [
            m for m in EXTRA_METHODS if maps or "twin" not in m
        ]
        if r == receivers[0]:  # the maps are of this receiver
            argv += ["--methods", ",".join(methods)]
            argv += [a for m in maps for a in ("--map", str(m["path"]))]
        else:
            argv += ["--methods", ",".join(m for m in methods if "twin" not in m)]
        argvs.append(argv)
    if side_by_side:
        _reports_side_by_side(receivers, argvs, max(args.workers, len(receivers)))
    else:
        for r, argv in zip(receivers, argvs):
            print(f"\n== receiver {r} ==")
            sys.stdout.flush()
            # inside this command's harness: an interruption or an error is reported once, by it
            _check_report(accuracy_report(argv))
    main_static = next(d for d in datasets[receivers[0]] if Path(d).name == "static-c-band")
    params: dict[str, dict[str, Any]] = {"ls": {"reference": LS_REFERENCE, "seed": args.seed}}
    if maps:
        params["twin"] = {"map": str(maps[0]["path"])}
    timed = [m for m in methods if maps or "twin" not in m]
    rates, n_timed = method_costs(main_static, timed, params, n_fixes=COST_FIXES)
    costs = costs_markdown(maps, rates, n_timed)
    # Table II's columns: the paper's model first, then the main receiver, then the ideal one
    order = list(dict.fromkeys([PAPER_RECEIVER, *receivers]))
    return write_comparison(tmp / "paper.md", {r: reports[r] for r in order}, datasets,
                            costs=costs, main=receivers[0])  # fmt: skip


def _check_report(code: int) -> None:
    if code != 0:
        raise HallrayError(f"the accuracy report failed (exit status {code}); nothing written")


def _reports_side_by_side(receivers: Sequence[str], argvs: Sequence[list[str]], workers: int):
    """The reports on ``workers`` spawned processes (at most one per report) at once; what each printed, and its
    warnings, given here in the receivers' order, as the reports one after the other give them.
    An error or an interruption ends them all and reaches this command's harness."""
    import warnings

    from positioning.cli.accuracy import accuracy_reports

    said = []
    for r, (code, text, caught) in zip(receivers, accuracy_reports(argvs, workers)):
        print(f"\n== receiver {r} ==")
        print(text, end="")
        sys.stdout.flush()
        _check_report(code)
        said += caught
    for message, category in dict.fromkeys(said):  # each once, as the "default" filter does
        warnings.warn(message, category, stacklevel=2)


def _build_maps(args: argparse.Namespace, receiver: str, folder: Path) -> list[dict[str, Any]]:
    """The static scene's fingerprint map per band (``accuracy-map``), timed and sized."""
    from ..studies.accuracy_map.compute import compute_map
    from ..studies.accuracy_map.files import write_outputs
    from ..studies.accuracy_map.settings import MapSettings

    scene = args.scene_obj
    out = []
    for band in ("c-band", "mmwave"):
        t0 = time.perf_counter()
        settings = MapSettings(step_m=args.map_step, band=band, receiver=receiver, draws=MAP_DRAWS)
        settings.check()
        amap = compute_map(scene, settings, scene_name=str(args.scene), workers=args.workers,
                           progress=not args.quiet)  # fmt: skip
        folder.mkdir(parents=True, exist_ok=True)
        write_outputs(folder / band, scene, amap, pictures=False)
        path = folder / band / "map.npz"
        out.append({"band": band, "path": path, "cells": amap.fmap.n_cells,
                    "step_m": args.map_step, "seconds": time.perf_counter() - t0,
                    "bytes": path.stat().st_size})  # fmt: skip
        print(f"fingerprint map {band}: {amap.fmap.n_cells} cells in {out[-1]['seconds']:.1f} s")
    return out
