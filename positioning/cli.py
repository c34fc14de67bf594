"""Command-line tools ``estimate-positions`` and ``accuracy-report``.

Both run through the one harness :func:`hallray.harness.run_command`: bad input gives a
one-line ``error: ...`` on stderr and exit status 2, never a traceback and never a half-written
output file (outputs go to a temporary file first and are renamed at the end). A run in which no
fix is trustworthy (every fix unsolved, not converged, ill-conditioned or outside the service
area) is an error as well.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hallray.harness import OneLineParser, run_command

from .api import METHODS, OUTSIDE_CHOICES, method_names, resolve_params
from .dataset import ToaDataset, load_dataset
from .errors import PositioningError
from .fixes import Fixes, Status, status_label
from .integrity import ALERT_LIMIT_M
from .metrics import error_2d, summarize
from .track import PARAMS as TRACK_PARAMS
from .track import check_params as check_track_params
from .track import split_method
from .twin import check_dataset as check_map

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
    "hpl_m",
    "chi2n",
    "flagged",
)
#: Extra trailing columns of a ``twin`` method's fixes.csv.
TWIN_COLUMNS = ("nlos_bs", "match_m")


def methods_help() -> str:
    """Text listing every registered method with its parameters and defaults."""
    lines = ["methods (use --param NAME=VALUE to change a parameter):"]
    for m in METHODS.values():
        lines.append(f"  {m.name:<12} {m.summary}")
        ps = ", ".join(f"{k}={v[0]}" for k, v in m.params.items())
        lines.append(f"  {'':<12} parameters: {ps}")
    lines.append("  METHOD+track: any method's fixes filtered over each point's epochs (Kalman)")
    ps = ", ".join(f"{k}={v[0]}" for k, v in TRACK_PARAMS.items())
    lines.append(f"  {'':<12} parameters (--param track:NAME=VALUE): {ps}")
    return "\n".join(lines)


def _parse_params(items: Sequence[str], methods: Sequence[str]) -> dict[str, dict[str, str]]:
    """``NAME=VALUE`` (applies to every method that has NAME) or ``METHOD:NAME=VALUE``
    (``track:NAME=VALUE`` for the tracker); keys: the base methods and ``"track"``."""
    methods = list(dict.fromkeys(split_method(m)[0] for m in methods))
    out: dict[str, dict[str, str]] = {m: {} for m in methods}
    out["track"] = {}
    for item in items:
        if "=" not in item:
            raise PositioningError(f"--param {item!r}: expected NAME=VALUE")
        key, value = item.split("=", 1)
        key = key.strip()
        if ":" in key:
            meth, name = key.split(":", 1)
            if meth == "track":
                out["track"][name] = value
                continue
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
        if m == "track":
            check_track_params(p)
            continue
        if m == "twin" and p.get("map"):
            check_map(p["map"], ds.bs_xyz, ds.bs_names, ds.band)
        q = dict(p)
        ref = q.get("reference")
        if isinstance(ref, str) and ref in ds.bs_names:
            q["reference"] = str(ds.bs_names.index(ref))
        resolve_params(m, q, len(ds.bs_names))


def fixes_csv(ds: ToaDataset, fixes: Fixes) -> str:
    """CSV text of one method's fixes (columns :data:`FIXES_COLUMNS`; a ``twin`` fix adds
    ``nlos_bs``, the base stations it judged NLoS joined by ``|``, and ``match_m``)."""
    err = error_2d(fixes.xyz, ds.true_xyz)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    twin_cols = "nlos" in fixes.extra and "match_m" in fixes.extra
    w.writerow(FIXES_COLUMNS + (TWIN_COLUMNS if twin_cols else ()))

    def num(v: float, fmt: str = ".6f") -> str:
        return "" if not np.isfinite(v) else format(v, fmt)

    for i in range(ds.n_fixes):
        x, y, z = fixes.xyz[i]
        tx, ty, tz = ds.true_xyz[i]
        extra = []
        if twin_cols:
            nlos = fixes.extra["nlos"][i]
            extra = ["|".join(n for n, f in zip(ds.bs_names, nlos, strict=True) if f)]
            extra.append(num(fixes.extra["match_m"][i], ".4f"))
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
                num(fixes.hpl_m[i], ".4f"),
                num(fixes.chi2n[i], ".4g"),
                int(fixes.flagged[i]),
                *extra,
            ]
        )
    return buf.getvalue()


def summary_line(method: str, fixes: Fixes, err: np.ndarray) -> str:
    """One line: fixes, availability, errors, and the counts of doubtful fixes."""
    s = summarize(err)
    line = (
        f"{method}: {fixes.n_epochs} fixes, availability {100.0 * fixes.availability:.1f} % "
        f"({fixes.n_unsolved} unsolved), mean {s['mean_m']:.3f} m, median {s['median_m']:.3f} m, "
        f"p90 {s['p90_m']:.3f} m; ill-conditioned {fixes.count(Status.ILL_CONDITIONED)}, "
        f"not converged {fixes.count(Status.NOT_CONVERGED)}, "
        f"out of area {fixes.count(Status.AREA_BOUND)}"
    )
    if np.isfinite(fixes.alert_limit_m):
        line += f", flagged {int(fixes.flagged.sum())} (HPL > {fixes.alert_limit_m:g} m)"
    return line


def _no_trusted(ds: ToaDataset, fixes: Fixes) -> PositioningError:
    return PositioningError(
        f"{ds.path}: no trustworthy fix ({fixes.n_unsolved} unsolved, "
        f"{fixes.count(Status.NOT_CONVERGED)} not converged, "
        f"{fixes.count(Status.ILL_CONDITIONED)} ill-conditioned, "
        f"{fixes.count(Status.AREA_BOUND)} outside the service area of {fixes.n_epochs}); "
        "check the base-station positions, the heights and the ToA units"
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
    p.add_argument(
        "--outside",
        choices=OUTSIDE_CHOICES,
        default="constrain",
        help="a fix outside the dataset's service area: solve again inside it (constrain, "
        "default) or leave it unsolved (reject); either way flagged area_bound",
    )
    p.add_argument(
        "--alert-limit",
        type=float,
        default=ALERT_LIMIT_M,
        metavar="M",
        help=f"flag fixes whose protection level exceeds M metres (default {ALERT_LIMIT_M:g})",
    )
    p.add_argument(
        "--map",
        metavar="MAP",
        action="append",
        help="fingerprint map (.npz) of the twin method; repeat it with one map per band, each "
        "dataset then uses the map of its band",
    )


def _base_method(name: str) -> str:
    """The registered method of ``name`` (``irls`` of ``irls+track``); unknown -> error."""
    base, _ = split_method(name)
    if base not in METHODS:
        raise PositioningError(
            f"unknown method {name!r}; choose one of: {', '.join(METHODS)} (or METHOD+track)"
        )
    return base


def _with_map(
    params: dict[str, dict[str, str]], maps: Sequence[str] | None, ds: ToaDataset
) -> dict[str, dict[str, str]]:
    """The parameters for ``ds``: ``--map`` becomes the twin's ``map`` parameter. With several
    maps (one per band, e.g. for a report over C-band and mmWave datasets), the one whose band is
    the dataset's; a one-line error when none is."""
    if not maps or "twin" not in params or params["twin"].get("map"):
        return params
    from .twin import load as load_map

    chosen = maps[0]
    if len(maps) > 1:
        bands = {m: str(load_map(m)[0].meta.get("band")) for m in maps}
        match = [m for m, b in bands.items() if b == str(ds.band)]
        if not match:
            raise PositioningError(
                f"{ds.path}: none of the maps is for band {ds.band!r} "
                f"({', '.join(f'{m}: {b}' for m, b in bands.items())})"
            )
        chosen = match[0]
    out = {m: dict(p) for m, p in params.items()}
    out["twin"]["map"] = chosen
    return out


def _alert_limit(args: argparse.Namespace) -> float:
    a = args.alert_limit
    if not (np.isfinite(a) and a > 0):
        raise PositioningError(f"--alert-limit must be a positive number of metres, got {a!r}")
    return float(a)


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
    _common_args(p)
    return p


def _estimate(args: argparse.Namespace) -> int:
    from hallray.safe_output import STDOUT, check_output, write_file

    from .report import solve_dataset
    from .sanity import check_height, check_trustworthy, trust_counts

    if args.list_methods:
        print(methods_help())
        return 0
    if args.dataset is None:
        raise PositioningError("the following arguments are required: DATASET_DIR")
    if args.output is None:
        raise PositioningError("the following arguments are required: -o/--output")
    base = _base_method(args.method)
    inputs = [Path(args.dataset) / n for n in ("toa.csv", "meta.json")]
    out = args.output
    if out != STDOUT:
        check_output(out, inputs=inputs)  # before any work
    height = _height_mode(args)
    limit = _alert_limit(args)
    params = _parse_params(args.param, [args.method])
    ds = load_dataset(args.dataset)
    params = _with_map(params, args.map, ds)
    check_height(height, ds.bs_xyz)
    _check_params(params, ds)
    fixes = solve_dataset(
        ds, args.method, params[base], height, outside=args.outside, alert_limit_m=limit,
        track=params["track"],
    )  # fmt: skip
    if fixes.n_unsolved == fixes.n_epochs and not fixes.count(Status.AREA_BOUND):
        raise _all_unsolved(ds)
    # station geometry first: its message names the cause (collinear, one plane)
    check_trustworthy(trust_counts(ds, fixes, height), str(ds.path), height)
    if not fixes.trusted.any():
        raise _no_trusted(ds, fixes)
    write_file(out, fixes_csv(ds, fixes), inputs=inputs, stdout_ok=True)
    err = error_2d(fixes.xyz, ds.true_xyz)
    summary = sys.stderr if out == STDOUT else sys.stdout  # stdout holds the CSV
    print(f"{summary_line(args.method, fixes, err)} -> {out}", file=summary)
    return 0


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
    _common_args(p)
    return p


def _report(args: argparse.Namespace) -> int:
    from hallray.safe_output import check_output, output_dir

    from .report import evaluate, is_report_dir, write_report
    from .sanity import check_height, check_trustworthy, trust_counts

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise PositioningError("--methods is empty")
    for m in methods:
        _base_method(m)
    methods = list(dict.fromkeys(methods))
    out = Path(args.output)
    check_output(out, inputs=args.datasets, directory=True)  # before any work
    height = _height_mode(args)
    limit = _alert_limit(args)
    params = _parse_params(args.param, methods)
    datasets = [load_dataset(d) for d in args.datasets]
    per_ds = [_with_map(params, args.map, ds) for ds in datasets]
    results = []
    for ds, p in zip(datasets, per_ds, strict=True):
        check_height(height, ds.bs_xyz)
        _check_params(p, ds)
    for ds, p in zip(datasets, per_ds, strict=True):
        r = evaluate(ds, methods, p, height, outside=args.outside, alert_limit_m=limit)
        fx = list(r.fixes.values())
        if all(f.n_unsolved == f.n_epochs and not f.count(Status.AREA_BOUND) for f in fx):
            raise _all_unsolved(ds)
        counts = [trust_counts(ds, f, height) for f in fx]  # station geometry: names the cause
        check_trustworthy(max(counts, key=lambda c: c["trustworthy"]), str(ds.path), height)
        if not any(f.trusted.any() for f in fx):
            raise _no_trusted(ds, fx[0])
        results.append(r)
    # the report appears whole or not at all; a previous report there is replaced
    with output_dir(out, inputs=args.datasets, replaceable=is_report_dir) as tmp:
        md, written = write_report(results, methods, tmp)
    print(md, end="")
    print()
    for r in results:
        for m in methods:
            print(f"{r.dataset.name} {summary_line(m, r.fixes[m], r.errors[m])}")
    print(f"wrote {len(written)} files to {out}")
    return 0


def estimate_positions_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``estimate-positions``: positions of every fix of a dataset to a CSV."""
    return run_command(_estimate, _estimate_parser(), argv)


def accuracy_report_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``accuracy-report``: Table II, CDF and top-view plots for datasets."""
    return run_command(_report, _report_parser(), argv)


def accuracy_report(argv: Sequence[str]) -> int:
    """``accuracy-report`` without the command harness, for a command that runs it inside its
    own (``reproduce-paper``): bad input and interruptions (Ctrl-C, SIGTERM) propagate to the
    caller's harness as exceptions instead of becoming an exit status here."""
    return int(_report(_report_parser().parse_args(list(argv))))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(estimate_positions_main())
