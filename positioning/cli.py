"""Command-line tools ``estimate-positions`` and ``accuracy-report``.

Bad input gives a one-line ``error: ...`` on stderr and exit status 2, never a traceback and never
a half-written output file (outputs go to a temporary file first and are renamed at the end).
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from .api import METHODS, resolve_params
from .dataset import ToaDataset, load_dataset
from .errors import PositioningError
from .fixes import Fixes, status_label
from .metrics import error_2d, summarize

FIXES_COLUMNS = (
    "epoch",
    "time_s",
    "point",
    "method",
    "x",
    "y",
    "z",
    "x_true",
    "y_true",
    "z_true",
    "error_m",
    "status",
    "iterations",
    "n_bs",
)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``error: ...``, exit 2) instead of usage + message."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {message}\n")


def methods_help() -> str:
    """Text listing every registered method with its parameters and defaults."""
    lines = ["methods (use --param NAME=VALUE to change a parameter):"]
    for m in METHODS.values():
        lines.append(f"  {m.name:<12} {m.summary}")
        ps = ", ".join(f"{k}={v[0]}" for k, v in m.params.items())
        lines.append(f"  {'':<12} parameters: {ps}")
    return "\n".join(lines)


def _parse_params(items: Sequence[str], methods: Sequence[str]) -> dict[str, dict[str, str]]:
    """``NAME=VALUE`` (applies to every method that has NAME) or ``METHOD:NAME=VALUE``."""
    out: dict[str, dict[str, str]] = {m: {} for m in methods}
    for item in items:
        if "=" not in item:
            raise PositioningError(f"--param {item!r}: expected NAME=VALUE")
        key, value = item.split("=", 1)
        key = key.strip()
        if ":" in key:
            meth, name = key.split(":", 1)
            if meth not in METHODS:
                raise PositioningError(
                    f"--param {item!r}: unknown method {meth!r}; choose one of: "
                    f"{', '.join(METHODS)}"
                )
            if meth in out:
                out[meth][name] = value
            continue
        targets = [m for m in methods if key in METHODS[m].params]
        if not targets:
            raise PositioningError(
                f"--param {item!r}: no parameter {key!r} in method(s) {', '.join(methods)}"
            )
        for m in targets:
            out[m][key] = value
    return out


def _height_mode(args: argparse.Namespace) -> str | float:
    if args.three_d:
        return "3d"
    if args.height is not None:
        if not np.isfinite(args.height):
            raise PositioningError("--height must be a finite number of metres")
        return float(args.height)
    return "true"


def _check_params(params: dict[str, dict[str, str]], ds: ToaDataset) -> None:
    """Validate parameters early (before any solve); a reference may be a base-station name."""
    for m, p in params.items():
        q = dict(p)
        ref = q.get("reference")
        if isinstance(ref, str) and ref in ds.bs_names:
            q["reference"] = str(ds.bs_names.index(ref))
        resolve_params(m, q, len(ds.bs_names))


def fixes_csv(ds: ToaDataset, fixes: Fixes) -> str:
    """CSV text of one method's fixes (columns :data:`FIXES_COLUMNS`)."""
    err = error_2d(fixes.xyz, ds.true_xyz)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(FIXES_COLUMNS)

    def num(v: float, fmt: str = ".6f") -> str:
        return "" if not np.isfinite(v) else format(v, fmt)

    for i in range(ds.n_fixes):
        x, y, z = fixes.xyz[i]
        tx, ty, tz = ds.true_xyz[i]
        w.writerow(
            [
                int(ds.epoch[i]),
                num(ds.time_s[i], ".6g"),
                ds.point[i],
                fixes.method,
                num(x),
                num(y),
                num(z),
                num(tx),
                num(ty),
                num(tz),
                num(err[i]),
                status_label(fixes.status[i]),
                int(fixes.iterations[i]),
                int(fixes.n_used[i]),
            ]
        )
    return buf.getvalue()


def _summary_line(method: str, fixes: Fixes, err: np.ndarray, counts: dict | None = None) -> str:
    s = summarize(err)
    extra = ""
    if counts:
        extra = f"{counts['not_converged']} not converged, {counts['ill_conditioned']} ill-conditioned, "
    return (
        f"{method}: {fixes.n_epochs} fixes, {fixes.n_unsolved} unsolved, {extra}"
        f"mean {s['mean_m']:.3f} m, median {s['median_m']:.3f} m, p90 {s['p90_m']:.3f} m"
    )


def _all_unsolved(ds: ToaDataset) -> PositioningError:
    return PositioningError(
        f"{ds.path}: no fix could be solved (every epoch has too few base stations with a ToA: "
        "at least 3 are needed in 2D, 4 in 3D)"
    )


def _common_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--height",
        type=float,
        default=None,
        metavar="M",
        help="known device height in metres for the 2D solve (default: each point's true z)",
    )
    g.add_argument(
        "--3d", dest="three_d", action="store_true", help="solve for x, y, z (no known height)"
    )


def _run(main: Any, argv: Sequence[str] | None) -> int:
    from .command import _sigterm_as_interrupt

    try:
        with _sigterm_as_interrupt():
            return main(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2, already printed)
        return exc.code if isinstance(exc.code, int) else 2
    except PositioningError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        name = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"error: {name}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the output layer removed its temporary files
        print("error: interrupted", file=sys.stderr)
        return 130


def _estimate(argv: Sequence[str] | None) -> int:
    from .output import STDOUT, check_output, write_file
    from .report import solve_dataset
    from .sanity import check_height, check_trustworthy, trust_counts

    p = _Parser(
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
    _common_args(p)
    args = p.parse_args(argv)
    if args.list_methods:
        print(methods_help())
        return 0
    if args.dataset is None:
        p.error("the following arguments are required: DATASET_DIR")
    if args.output is None:
        p.error("the following arguments are required: -o/--output")
    if args.method not in METHODS:
        raise PositioningError(
            f"unknown method {args.method!r}; choose one of: {', '.join(METHODS)}"
        )
    inputs = [Path(args.dataset) / n for n in ("toa.csv", "meta.json")]
    out = args.output
    if out != STDOUT:
        check_output(out, inputs=inputs)  # before any work
    height = _height_mode(args)
    params = _parse_params(args.param, [args.method])
    ds = load_dataset(args.dataset)
    check_height(height, ds.bs_xyz)
    _check_params(params, ds)
    fixes = solve_dataset(ds, args.method, params[args.method], height)
    if fixes.n_unsolved == fixes.n_epochs:
        raise _all_unsolved(ds)
    counts = trust_counts(ds, fixes, height)
    check_trustworthy(counts, str(ds.path), height)
    write_file(out, fixes_csv(ds, fixes), inputs=inputs, stdout_ok=True)
    err = error_2d(fixes.xyz, ds.true_xyz)
    summary = sys.stderr if out == STDOUT else sys.stdout  # stdout holds the CSV
    print(f"{_summary_line(args.method, fixes, err, counts)} -> {out}", file=summary)
    return 0


def _report(argv: Sequence[str] | None) -> int:
    from .output import check_output, output_dir
    from .report import evaluate, is_report_dir, write_report
    from .sanity import check_height

    p = _Parser(
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
        default=",".join(METHODS),
        help=f"comma-separated methods (default: {','.join(METHODS)})",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="[METHOD:]NAME=VALUE",
        help="method parameter, repeatable; without METHOD: it applies to every method having it",
    )
    _common_args(p)
    args = p.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise PositioningError("--methods is empty")
    for m in methods:
        if m not in METHODS:
            raise PositioningError(f"unknown method {m!r}; choose one of: {', '.join(METHODS)}")
    methods = list(dict.fromkeys(methods))
    out = Path(args.output)
    check_output(out, inputs=args.datasets, directory=True)  # before any work
    height = _height_mode(args)
    params = _parse_params(args.param, methods)
    datasets = [load_dataset(d) for d in args.datasets]
    results = []
    for ds in datasets:
        check_height(height, ds.bs_xyz)
        _check_params(params, ds)
    for ds in datasets:
        r = evaluate(ds, methods, params, height)
        if all(f.n_unsolved == f.n_epochs for f in r.fixes.values()):
            raise _all_unsolved(ds)
        _trust_lines(ds, r.fixes, height)
        results.append(r)
    # the report appears whole or not at all; a previous report there is replaced
    with output_dir(out, inputs=args.datasets, replaceable=is_report_dir) as tmp:
        md, written = write_report(results, methods, tmp)
    print(md, end="")
    print(f"wrote {len(written)} files to {out}")
    return 0


def _trust_lines(ds: ToaDataset, fixes: dict[str, Fixes], height: str | float) -> None:
    """accuracy-report: refuse a dataset no method has a trustworthy fix of; count the doubtful
    fixes on stderr (stdout holds the table)."""
    from .sanity import check_trustworthy, trust_counts

    counts = {m: trust_counts(ds, f, height) for m, f in fixes.items()}
    best = max(counts.values(), key=lambda c: c["trustworthy"])
    check_trustworthy(best, str(ds.path), height)
    for m, c in counts.items():
        if c["trustworthy"] < fixes[m].n_epochs:
            print(
                f"{ds.name} {m}: {c['unsolved']} unsolved, {c['not_converged']} not converged, "
                f"{c['ill_conditioned']} ill-conditioned of {fixes[m].n_epochs} fixes",
                file=sys.stderr,
            )


def estimate_positions_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``estimate-positions``: positions of every fix of a dataset to a CSV."""
    return _run(_estimate, argv)


def accuracy_report_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``accuracy-report``: Table II, CDF and top-view plots for datasets."""
    return _run(_report, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(estimate_positions_main())
