"""``run-sweep CONFIG.yaml [-o OUT_DIR] [--workers N] [--scheduler ADDRESS]``.

Exit status: 0 when every cell is done, 1 when some cells failed (their errors are printed; a
rerun retries them), 2 on bad input (one line ``error: ...``), 130 when interrupted (finished
cells are kept; a rerun resumes).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..core.errors import HallrayError
from .harness import OneLineParser, run_tool

EXIT_CELLS_FAILED = 1


def run_sweep_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="run-sweep",
        description=(
            "Run the pipeline (InF hall -> trace -> ToA -> positioning) over a grid of "
            "profiles, seeds, bands and estimator settings and collect one results table "
            "(OUT/results.csv and OUT/results.md). One result file per cell (OUT/cells/<key>.json): "
            "a rerun skips finished cells. See docs/sweep.md."
        ),
    )
    p.add_argument("config", help="sweep config (YAML)")
    p.add_argument("-o", "--output", metavar="OUT_DIR", help="output directory [CONFIG-sweep]")
    p.add_argument(
        "--workers", type=int, help="local worker processes [all cores]; 1 = in this process"
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask distributed cluster (e.g. tcp://10.0.0.5:8786); needs dask[distributed]",
    )
    p.add_argument(
        "--limit", type=int, metavar="N", help="compute at most N missing cells, then stop"
    )
    p.add_argument(
        "--list", action="store_true", help="list the cells and their state, run nothing"
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def run_sweep_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``run-sweep``."""
    return run_tool(
        _run_sweep, run_sweep_parser(), argv,
        interrupted="interrupted; finished cells are kept, rerun to resume",
    )  # fmt: skip


def _run_sweep(args: argparse.Namespace) -> int:
    from ..studies.sweep.config import load_sweep_config
    from ..studies.sweep.files import read_cell_result
    from ..studies.sweep.run import default_output, run_sweep

    cfg = load_sweep_config(args.config)
    if args.list:
        out = default_output(cfg) if args.output is None else args.output
        for cell in cfg.cells():
            done = read_cell_result(out, cell) is not None
            desc = ", ".join(
                f"{k}={cell.params[k] if '.' not in k else cell.methods[k.split('.')[0]][k.split('.', 1)[1]]}"
                for k in cfg.varying
            )
            print(f"{cell.index:4d} {cell.key} {'done' if done else 'todo'}  {desc}")
        return 0
    if args.limit is not None and args.limit < 0:
        raise HallrayError(f"--limit must be >= 0, got {args.limit}")
    progress = not args.quiet and sys.stderr.isatty()
    report = run_sweep(
        cfg, args.output, workers=args.workers, scheduler=args.scheduler, progress=progress,
        limit=args.limit,
    )  # fmt: skip
    done = len(report.results)
    rate = f", {report.cells_per_minute:.1f} cells/min" if report.computed else ""
    print(
        f"sweep {cfg.name}: {report.n_cells} cells, {len(report.computed)} computed, "
        f"{len(report.skipped)} already done, {len(report.failed)} failed "
        f"in {report.wall_s:.1f} s ({report.mode}{rate})"
    )
    print(
        f"results ({done} cells): {report.out_dir / 'results.csv'}, {report.out_dir / 'results.md'}"
    )
    for key, msg in report.failed.items():
        print(f"cell {key} failed: {msg}", file=sys.stderr)
    if report.failed:
        return EXIT_CELLS_FAILED
    return 0
