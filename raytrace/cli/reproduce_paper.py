"""``reproduce-paper``: from the bundled hall to the paper's comparison in one command.

Writes the paper's four ToA datasets (static and semi-dynamic, C-band and mmWave) under the
realistic receiver and under the ideal one (``first-path``), from one trace, with
:func:`raytrace.emulation.dataset.make_datasets`; positions every epoch with every method and
writes the paper's Table II and CDF plots with ``accuracy-report`` (the positioning package) for
each receiver; then ``paper.md``: Table II beside the paper's and the findings
(:mod:`raytrace.studies.paper`).
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

#: The receiver whose report is written beside the main one: the paper's ideal eq. 3 model.
IDEAL_RECEIVER = "first-path"

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
        help="ToA receiver of the main report (default first-lobe); the ideal first-path "
        "receiver's report is written beside it",
    )
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

    from ..emulation.receivers import DEFAULT_TOA_METHOD, TOA_METHODS

    receiver = args.receiver or DEFAULT_TOA_METHOD
    if receiver not in TOA_METHODS:
        raise HallrayError(f"unknown receiver {receiver!r}; use one of {', '.join(TOA_METHODS)}")
    receivers = list(dict.fromkeys([receiver, IDEAL_RECEIVER]))
    out = Path(args.output)
    scene = None if args.scene == "hall" else args.scene
    t0 = time.perf_counter()
    # the whole output (datasets, reports, paper.md) is built in a temporary directory beside OUT
    # and renamed when complete: an error, Ctrl-C or SIGTERM leaves nothing, and a rerun starts
    # clean
    with output_dir(out, force=args.force, inputs=[scene]) as tmp:
        text = _build(args, receivers, tmp, out, t0)
    print("\n" + text.split("## Why, by mechanism")[0].rstrip())
    reports = ", ".join(str(out / _report_name(r, receivers)) for r in receivers)
    print(f"\nreports in {reports}; comparison and findings in {out / 'paper.md'} "
          f"(total {time.perf_counter() - t0:.1f} s)")  # fmt: skip
    return 0


def _report_name(receiver: str, receivers: Sequence[str]) -> str:
    return "report" if receiver == receivers[0] else f"report-{receiver}"


def _build(
    args: argparse.Namespace, receivers: Sequence[str], tmp: Path, out: Path, t0: float
) -> str:
    """Datasets of every receiver into ``tmp/datasets`` (one trace), a report per receiver, and
    ``tmp/paper.md``; returns the text of ``paper.md``."""
    from positioning.cli import accuracy_report_main

    from ..emulation.dataset import make_datasets
    from ..studies.paper import write_comparison

    summaries = make_datasets(
        tmp / "datasets",
        PAIRS,
        scene=args.scene,
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
    reports, datasets = {}, {}
    for r in receivers:
        datasets[r] = [s["directory"] for s in summaries if s["toa_method"] == r]
        reports[r] = tmp / _report_name(r, receivers)
        print(f"\n== receiver {r} ==")
        sys.stdout.flush()
        code = accuracy_report_main([*datasets[r], "-o", str(reports[r])])
        if code != 0:
            raise HallrayError(f"the accuracy report failed (exit status {code}); nothing written")
    return write_comparison(tmp / "paper.md", reports, datasets)
