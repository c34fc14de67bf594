"""``reproduce-paper``: from the bundled hall to the paper's comparison in one command.

Writes the paper's four ToA datasets (static and semi-dynamic, C-band and mmWave) with
:func:`raytrace.emulation.dataset.make_datasets`, then positions every epoch with every method and writes
the paper's Table II and CDF plots with ``accuracy-report`` (the positioning package), printing
the table.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from ..core.errors import HallrayError
from .harness import OneLineParser, run_tool

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
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="processes for the snapshots [all cores]",
    )
    p.add_argument("--force", action="store_true", help="replace an existing output directory")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    return p


def reproduce_paper_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``reproduce-paper``."""
    return run_tool(_main, parser(), argv)


def _main(args: argparse.Namespace) -> int:
    from positioning.output import output_dir

    out = Path(args.output)
    scene = None if args.scene == "hall" else args.scene
    t0 = time.perf_counter()
    # the whole output (datasets and report) is built in a temporary directory beside OUT and
    # renamed when complete: an error, Ctrl-C or SIGTERM leaves nothing, and a rerun starts clean
    with output_dir(out, force=args.force, inputs=[scene]) as tmp:
        code = _build(args, tmp, out, t0)
        if code != 0:
            raise HallrayError(f"the accuracy report failed (exit status {code}); nothing written")
    print(f"\nreport written to {out / 'report'} (total {time.perf_counter() - t0:.1f} s)")
    return 0


def _build(args: argparse.Namespace, tmp: Path, out: Path, t0: float) -> int:
    """Datasets into ``tmp/datasets``, the report into ``tmp/report``; the report's exit status."""
    from positioning.cli import accuracy_report_main

    from ..emulation.dataset import make_datasets

    summaries = make_datasets(
        tmp / "datasets",
        PAIRS,
        scene=args.scene,
        duration_s=args.duration,
        rate_hz=args.rate,
        seed=args.seed,
        workers=args.workers,
        progress=not args.quiet,
    )
    print(f"datasets written to {out / 'datasets'} in {time.perf_counter() - t0:.1f} s:")
    for s in summaries:
        print(f"  {Path(s['directory']).name:<22} {s['epochs']} epochs")
    sys.stdout.flush()
    return accuracy_report_main([s["directory"] for s in summaries] + ["-o", str(tmp / "report")])
