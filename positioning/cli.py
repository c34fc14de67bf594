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

from .api import METHODS, method_names, resolve_params
from .dataset import ToaDataset, load_dataset
from .errors import PositioningError
from .fixes import Fixes, status_label
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
)
#: Extra trailing columns of a ``twin`` method's fixes.csv.
TWIN_COLUMNS = ("nlos_bs", "match_m")


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
                *extra,
            ]
        )
    return buf.getvalue()


def _summary_line(method: str, fixes: Fixes, err: np.ndarray) -> str:
    s = summarize(err)
    return (
        f"{method}: {fixes.n_epochs} fixes, {fixes.n_unsolved} unsolved, "
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
    p.add_argument("--map", metavar="MAP", help="fingerprint map (.npz) of the twin method")


def _base_method(name: str) -> str:
    """The registered method of ``name`` (``irls`` of ``irls+track``); unknown -> error."""
    base, _ = split_method(name)
    if base not in METHODS:
        raise PositioningError(
            f"unknown method {name!r}; choose one of: {', '.join(METHODS)} (or METHOD+track)"
        )
    return base


def _with_map(params: dict[str, dict[str, str]], map_path: str | None) -> None:
    """``--map`` becomes the twin's ``map`` parameter."""
    if map_path is not None and "twin" in params:
        params["twin"].setdefault("map", map_path)


def _run(main: Any, argv: Sequence[str] | None) -> int:
    try:
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
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


def _estimate(argv: Sequence[str] | None) -> int:
    from .report import atomic_write_text, solve_dataset

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
    p.add_argument("-o", "--output", metavar="FIXES_CSV", help="output CSV file")
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
    base = _base_method(args.method)
    out = Path(args.output)
    if out.is_dir():
        raise PositioningError(f"{out}: is a directory")
    if not out.parent.exists():
        raise PositioningError(f"{out.parent}: output directory not found")
    height = _height_mode(args)
    params = _parse_params(args.param, [args.method])
    _with_map(params, args.map)
    ds = load_dataset(args.dataset)
    _check_params(params, ds)
    fixes = solve_dataset(ds, args.method, params[base], height, track=params["track"])
    if fixes.n_unsolved == fixes.n_epochs:
        raise _all_unsolved(ds)
    atomic_write_text(out, fixes_csv(ds, fixes))
    err = error_2d(fixes.xyz, ds.true_xyz)
    print(f"{_summary_line(args.method, fixes, err)} -> {out}")
    return 0


def _report(argv: Sequence[str] | None) -> int:
    from .report import evaluate, write_report

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
    args = p.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise PositioningError("--methods is empty")
    for m in methods:
        _base_method(m)
    methods = list(dict.fromkeys(methods))
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise PositioningError(f"{out}: exists and is not a directory")
    height = _height_mode(args)
    params = _parse_params(args.param, methods)
    _with_map(params, args.map)
    datasets = [load_dataset(d) for d in args.datasets]
    results = []
    for ds in datasets:
        _check_params(params, ds)
    for ds in datasets:
        r = evaluate(ds, methods, params, height)
        if all(f.n_unsolved == f.n_epochs for f in r.fixes.values()):
            raise _all_unsolved(ds)
        results.append(r)
    md, written = write_report(results, methods, out)
    print(md, end="")
    print(f"wrote {len(written)} files to {out}")
    return 0


def estimate_positions_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``estimate-positions``: positions of every fix of a dataset to a CSV."""
    return _run(_estimate, argv)


def accuracy_report_main(argv: Sequence[str] | None = None) -> int:
    """Console script ``accuracy-report``: Table II, CDF and top-view plots for datasets."""
    return _run(_report, argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(estimate_positions_main())
