"""``estimate-positions``: the positions of every fix of a ToA dataset, as a CSV file
(:mod:`positioning.report.fixes_file`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from hallray.harness import OneLineParser, run_command

from ..errors import PositioningError
from ..estimators.fixes import Status
from ..evaluation.metrics import error_2d
from ..io.dataset import load_dataset
from ..report.fixes_file import fixes_csv
from .options import (
    add_common_args,
    alert_limit,
    all_unsolved,
    base_method,
    check_method_params,
    height_mode,
    methods_help,
    no_trusted,
    parse_params,
    run_inputs,
    summary_line,
    with_map,
)


def _estimate_parser() -> OneLineParser:
    p = OneLineParser(
        prog="estimate-positions",
        description="Estimate device positions from a ToA dataset (toa.csv + meta.json).",
        epilog=methods_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dataset", nargs="?", metavar="DATASET_DIR")
    p.add_argument("--method", default="irls", help="positioning method (default irls)")
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="method parameter, repeatable (e.g. u_max=2.5)",
    )
    p.add_argument("-o", "--output", metavar="FIXES_CSV", help="output CSV file ('-': stdout)")
    p.add_argument("--list-methods", action="store_true", help="list the methods and exit")
    add_common_args(p)
    return p


def _estimate(args: argparse.Namespace) -> int:
    from hallray.safe_output import STDOUT, check_output, write_file

    from ..evaluation.trust import check_trustworthy, trust_counts
    from ..io.scale import check_height
    from ..report.runs import solve_dataset

    if args.list_methods:
        print(methods_help())
        return 0
    if args.dataset is None:
        raise PositioningError("the following arguments are required: DATASET_DIR")
    if args.output is None:
        raise PositioningError("the following arguments are required: -o/--output")
    base = base_method(args.method)
    height = height_mode(args)
    limit = alert_limit(args)
    params = parse_params(args.param, [args.method])
    inputs = run_inputs([args.dataset], args.map, params)
    out = args.output
    if out != STDOUT:
        check_output(out, inputs=inputs)  # before any work
    ds = load_dataset(args.dataset)
    params = with_map(params, args.map, ds)
    check_height(height, ds.bs_xyz)
    check_method_params(params, ds)
    fixes = solve_dataset(
        ds, args.method, params[base], height, outside=args.outside, alert_limit_m=limit,
        track=params["track"],
    )  # fmt: skip
    if fixes.n_unsolved == fixes.n_epochs and not fixes.count(Status.AREA_BOUND):
        raise all_unsolved(ds)
    # station geometry first: its message names the cause (collinear, one plane)
    check_trustworthy(trust_counts(ds, fixes, height), str(ds.path), height)
    if not fixes.trusted.any():
        raise no_trusted(ds, fixes)
    write_file(out, fixes_csv(ds, fixes), inputs=inputs, stdout_ok=True)
    err = error_2d(fixes.xyz, ds.true_xyz)
    summary = sys.stderr if out == STDOUT else sys.stdout  # stdout holds the CSV
    print(f"{summary_line(args.method, fixes, err)} -> {out}", file=summary)
    return 0


def estimate_positions_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``estimate-positions``: positions of every fix of a dataset to a CSV."""
    return run_command(_estimate, _estimate_parser(), argv)
