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
    from positioning.cli import accuracy_report_main

    from ..core.errors import HallrayError
    from ..emulation.dataset import make_datasets
    from ..emulation.receivers import DEFAULT_TOA_METHOD, TOA_METHODS
    from ..studies.paper import write_comparison

    receiver = args.receiver or DEFAULT_TOA_METHOD
    if receiver not in TOA_METHODS:
        raise HallrayError(f"unknown receiver {receiver!r}; use one of {', '.join(TOA_METHODS)}")
    receivers = list(dict.fromkeys([receiver, IDEAL_RECEIVER]))
    out = Path(args.output)
    data_dir = out / "datasets"
    if out.exists() and any(out.iterdir()) and not args.force:
        raise HallrayError(f"output directory {out} is not empty (use --force to replace it)")
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        summaries = make_datasets(
            data_dir,
            PAIRS,
            scene=args.scene,
            duration_s=args.duration,
            rate_hz=args.rate,
            seed=args.seed,
            workers=args.workers,
            force=args.force,
            progress=not args.quiet,
            toa_method=receivers,
        )
    except BaseException:
        # leave nothing behind that this run created
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise
    print(f"datasets written to {data_dir} in {time.perf_counter() - t0:.1f} s:")
    for s in summaries:
        print(f"  {Path(s['directory']).name:<33} {s['epochs']} epochs, receiver {s['toa_method']}")
    reports, datasets = {}, {}
    for r in receivers:
        datasets[r] = [s["directory"] for s in summaries if s["toa_method"] == r]
        reports[r] = out / ("report" if r == receiver else f"report-{r}")
        print(f"\n== receiver {r} ==")
        sys.stdout.flush()
        code = accuracy_report_main([*datasets[r], "-o", str(reports[r])])
        if code != 0:
            return code
    text = write_comparison(out / "paper.md", reports, datasets)
    print("\n" + text.split("## Why, by mechanism")[0].rstrip())
    print(f"\nreports in {', '.join(str(p) for p in reports.values())}; comparison and findings "
          f"in {out / 'paper.md'} (total {time.perf_counter() - t0:.1f} s)")  # fmt: skip
    return 0
