"""What the positioning commands share (``estimate-positions``, :mod:`positioning.cli.estimate`;
``accuracy-report``, :mod:`positioning.cli.accuracy`): their common options, the parsing and early
checks of method parameters, the one-line summary and the errors of a run without a trustworthy
fix.

Both commands run through the one harness :func:`hallray.harness.run_command`: bad input gives a
one-line ``error: ...`` on stderr and exit status 2, never a traceback and never a half-written
output file (outputs go to a temporary file first and are renamed at the end). A run in which no
fix is trustworthy (every fix unsolved, not converged, ill-conditioned or outside the service
area) is an error as well.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from ..errors import PositioningError
from ..estimators.eq7 import reference_by_name
from ..estimators.fixes import Fixes, Status
from ..estimators.track import PARAMS as TRACK_PARAMS
from ..estimators.track import check_params as check_track_params
from ..estimators.track import split_method
from ..evaluation.integrity import ALERT_LIMIT_M
from ..evaluation.metrics import summarize
from ..io.dataset import ToaDataset
from ..methods.registry import METHODS, resolve_params
from ..methods.run import OUTSIDE_CHOICES
from ..twin.lattice import check_dataset as check_map


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


def parse_params(items: Sequence[str], methods: Sequence[str]) -> dict[str, dict[str, str]]:
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
            if meth not in out:  # validated all the same, then refused: it would be ignored
                resolve_params(meth, {name: value})
                raise PositioningError(
                    f"--param {item!r}: method {meth!r} is not run here (methods: "
                    f"{', '.join(m for m in out if m != 'track')}): drop it or run that method"
                )
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


def run_inputs(
    datasets: Sequence[str], maps: Sequence[str] | None, params: dict[str, dict[str, str]]
) -> list[str]:
    """Everything a run reads, which no output may be, contain or lie inside: each dataset's
    files and directory, and every map (``--map``, ``--param twin:map=FILE``)."""
    import os

    files = [os.path.join(d, n) for d in datasets for n in ("toa.csv", "meta.json")]
    maps = [*(maps or []), *(p["map"] for p in params.values() if p.get("map"))]
    return [*files, *datasets, *maps]


def check_distinct_datasets(paths: Sequence[str]) -> None:
    """Refuse a dataset given twice (every table row would be doubled) and two datasets of one
    name (the report names rows and files after the dataset's directory)."""
    import os

    seen: dict[str, str] = {}
    names: dict[str, str] = {}
    for p in paths:
        key = os.path.realpath(p)
        if key in seen:
            raise PositioningError(
                f"dataset {p} is given twice (also as {seen[key]}): give each dataset once"
            )
        seen[key] = p
        name = os.path.basename(key)
        if name in names:
            raise PositioningError(
                f"datasets {names[name]} and {p} have the same name {name!r}, which the report's "
                "rows and files are named after: copy one under another name"
            )
        names[name] = p


def height_mode(args: argparse.Namespace) -> str | float:
    """The solve's heights from ``--3d`` / ``--height``: ``"3d"``, a known height in metres, or
    ``"true"`` (each point's true z; :func:`positioning.io.prepare.heights_for`)."""
    if args.three_d:
        return "3d"
    if args.height is not None:
        if not np.isfinite(args.height):
            raise PositioningError("--height must be a finite number of metres")
        return float(args.height)
    return "true"


def check_method_params(params: dict[str, dict[str, str]], ds: ToaDataset) -> None:
    """Validate parameters early (before any solve); a reference may be a base-station name."""
    for m, p in params.items():
        if m == "track":
            check_track_params(p)
            continue
        if m == "twin" and p.get("map"):
            check_map(p["map"], ds.bs_xyz, ds.bs_names, ds.band)
        q = dict(p)
        if "reference" in q:
            q["reference"] = reference_by_name(q["reference"], list(ds.bs_names))
        resolve_params(m, q, len(ds.bs_names))


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


def no_trusted(ds: ToaDataset, fixes: Fixes) -> PositioningError:
    """The one-line error of a run without a trustworthy fix, with the counts of why."""
    return PositioningError(
        f"{ds.path}: no trustworthy fix ({fixes.n_unsolved} unsolved, "
        f"{fixes.count(Status.NOT_CONVERGED)} not converged, "
        f"{fixes.count(Status.ILL_CONDITIONED)} ill-conditioned, "
        f"{fixes.count(Status.AREA_BOUND)} outside the service area of {fixes.n_epochs}); "
        "check the base-station positions, the heights and the ToA units"
    )


def all_unsolved(ds: ToaDataset) -> PositioningError:
    """The one-line error of a run in which no epoch had enough base stations."""
    return PositioningError(
        f"{ds.path}: no fix could be solved (every epoch has too few base stations with a ToA: "
        "at least 3 are needed in 2D, 4 in 3D)"
    )


def add_common_args(p: argparse.ArgumentParser) -> None:
    """The options both commands take: ``--height`` or ``--3d``, ``--outside``,
    ``--alert-limit`` and ``--map``."""
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


def base_method(name: str) -> str:
    """The registered method of ``name`` (``irls`` of ``irls+track``); unknown -> error."""
    base, _ = split_method(name)
    if base not in METHODS:
        raise PositioningError(
            f"unknown method {name!r}; choose one of: {', '.join(METHODS)} (or METHOD+track)"
        )
    return base


def with_map(
    params: dict[str, dict[str, str]], maps: Sequence[str] | None, ds: ToaDataset
) -> dict[str, dict[str, str]]:
    """The parameters for ``ds``: ``--map`` becomes the twin's ``map`` parameter. With several
    maps (one per band, e.g. for a report over C-band and mmWave datasets), the one whose band is
    the dataset's; a one-line error when none is."""
    if not maps or "twin" not in params or params["twin"].get("map"):
        return params
    from ..twin.lattice import load as load_map

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


def alert_limit(args: argparse.Namespace) -> float:
    """``--alert-limit`` in metres, checked: a positive finite number."""
    a = args.alert_limit
    if not (np.isfinite(a) and a > 0):
        raise PositioningError(f"--alert-limit must be a positive number of metres, got {a!r}")
    return float(a)
