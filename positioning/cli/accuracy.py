"""``accuracy-report``: Table II of the paper, the integrity table, CDF and top-view plots for
ToA datasets (:mod:`positioning.report`)."""

from __future__ import annotations

import argparse
import contextlib
import io
import warnings
from collections.abc import Sequence
from pathlib import Path

from hallray.harness import OneLineParser, run_command

from ..errors import PositioningError
from ..estimators.fixes import Status
from ..io.dataset import load_dataset
from ..methods.registry import method_names
from .options import (
    add_common_args,
    alert_limit,
    all_unsolved,
    base_method,
    check_distinct_datasets,
    check_method_params,
    height_mode,
    methods_help,
    no_trusted,
    parse_params,
    run_inputs,
    summary_line,
    with_map,
)

#: The name an accuracy report's marker records (:func:`hallray.safe_output.write_marker`).
REPORT_COMMAND = "accuracy-report"


def _report_parser() -> OneLineParser:
    p = OneLineParser(
        prog="accuracy-report",
        description=(
            "Table II of the paper (mean and 90th percentile of the 2D error) for every dataset "
            "and method, CDF plots and a top view of the hall."
        ),
        epilog=methods_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("datasets", nargs="+", metavar="DATASET_DIR")
    p.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output directory")
    p.add_argument(
        "--methods",
        default=",".join(method_names(include_map=False)),
        help=f"comma-separated methods, METHOD+track for tracked rows "
        f"(default: {','.join(method_names(include_map=False))})",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="[METHOD:]NAME=VALUE",
        help="method parameter, repeatable; without METHOD: it applies to every method having it",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        metavar="N",
        help="processes for the datasets, datasets with the same map together (default 1; the "
        "report does not depend on it)",
    )
    add_common_args(p)
    return p


def _report(args: argparse.Namespace) -> int:
    from hallray.safe_output import check_output_dir, output_dir

    from ..evaluation.trust import check_trustworthy, trust_counts
    from ..io.scale import check_height
    from ..report.pool import evaluate_all
    from ..report.write import write_report

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise PositioningError("--methods is empty")
    for m in methods:
        base_method(m)
    methods = list(dict.fromkeys(methods))
    if args.workers < 1:
        raise PositioningError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.output)
    height = height_mode(args)
    limit = alert_limit(args)
    params = parse_params(args.param, methods)
    inputs = run_inputs(args.datasets, args.map, params)
    # before any work: the output may not touch an input, and replaces only an earlier report
    check_output_dir(out, command=REPORT_COMMAND, inputs=inputs, replace_previous=True)
    check_distinct_datasets(args.datasets)
    datasets = [load_dataset(d) for d in args.datasets]
    per_ds = [with_map(params, args.map, ds) for ds in datasets]
    results = []
    for ds, p in zip(datasets, per_ds, strict=True):
        check_height(height, ds.bs_xyz)
        check_method_params(p, ds)
    evaluated = evaluate_all(datasets, methods, per_ds, height, outside=args.outside,
                             alert_limit_m=limit, workers=args.workers)  # fmt: skip
    for ds, r in zip(datasets, evaluated, strict=True):
        fx = list(r.fixes.values())
        if all(f.n_unsolved == f.n_epochs and not f.count(Status.AREA_BOUND) for f in fx):
            raise all_unsolved(ds)
        counts = [trust_counts(ds, f, height) for f in fx]  # station geometry: names the cause
        check_trustworthy(max(counts, key=lambda c: c["trustworthy"]), str(ds.path), height)
        if not any(f.trusted.any() for f in fx):
            raise no_trusted(ds, fx[0])
        results.append(r)
    # the report appears whole or not at all; a previous report there is replaced
    with output_dir(out, command=REPORT_COMMAND, inputs=inputs, replace_previous=True) as tmp:
        md, written = write_report(results, methods, tmp)
    print(md, end="")
    print()
    for r in results:
        for m in methods:
            print(f"{r.dataset.name} {summary_line(m, r.fixes[m], r.errors[m])}")
    print(f"wrote {len(written)} files to {out}")
    return 0


def accuracy_report_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``accuracy-report``: Table II, CDF and top-view plots for datasets."""
    return run_command(_report, _report_parser(), argv)


def accuracy_report(argv: Sequence[str]) -> int:
    """``accuracy-report`` without the command harness, for a command that runs it inside its
    own (``reproduce-paper``): bad input and interruptions (Ctrl-C, SIGTERM) propagate to the
    caller's harness as exceptions instead of becoming an exit status here."""
    return int(_report(_report_parser().parse_args(list(argv))))


def _captured_report(argv: Sequence[str]) -> tuple[int, str, list[tuple[str, type[Warning]]]]:
    """:func:`accuracy_report` with what it prints and the warnings it gives (message, category)
    kept, for the caller to print and give in its own order."""
    out = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(out):
        warnings.simplefilter("always")
        code = accuracy_report(argv)
    return code, out.getvalue(), [(str(w.message), w.category) for w in caught]


def accuracy_reports(
    argvs: Sequence[Sequence[str]], processes: int
) -> list[tuple[int, str, list[tuple[str, type[Warning]]]]]:
    """Several :func:`accuracy_report` runs side by side on ``processes`` spawned processes
    (:func:`positioning.report.pool.spawn_pool`): per report, in the order of ``argvs``, its
    exit status, the text it printed and the warnings it gave (message, category).

    Each report is the one :func:`accuracy_report` writes in this process (its own output
    directory, the same numbers; give each ``--workers 1`` where the reports are the
    parallelism). An error in a report is raised here as it was raised there; an error or an
    interruption ends the other reports at once (a report ended so leaves its staged directory
    and lock file beside its output, as a killed one does: write the reports inside a staging
    directory of the caller's, as ``reproduce-paper`` does).
    """
    from ..report.pool import spawn_pool

    pool = spawn_pool(max(1, min(processes, len(argvs))))
    done = False
    try:
        pending = [pool.apply_async(_captured_report, ([str(a) for a in argv],)) for argv in argvs]
        results = [p.get() for p in pending]
        done = True
    finally:
        if done:
            pool.close()
        else:
            pool.terminate()
        pool.join()
    return results
