"""``make-dataset``: write the paper's ToA datasets (static / semi-dynamic, C-band / mmWave).

    make-dataset --scenario static|semi-dynamic --band c-band|mmwave [--scene hall]
                 [--duration 60] [--rate 10] [--seed 1]
                 [--receiver first-lobe|first-path|peak|leading-edge|paper|first-lobe-cfr|
                             search-back|super-res]
                 [--no-first-path-threshold]
                 [--relative-threshold-db -12] [--cfar-cells 64|none] [--comb 1|2|4|6|12]
                 [--workers N] [--no-noise] [--force] [-q] -o DIR
    make-dataset --all [...] -o DIR      # DIR/static-c-band, DIR/static-mmwave,
                                         # DIR/semi-dynamic-c-band, DIR/semi-dynamic-mmwave

Bad input gives a one-line ``error: ...`` on stderr and exit status 2 (:mod:`.harness`); the
output directory appears only when complete.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from ..core.errors import HallrayError
from ..emulation.channel.cfr import PrsSettings
from ..emulation.receivers.first_lobe import FirstLobeSettings
from ..emulation.receivers.receiver import DEFAULT_TOA_METHOD, TOA_METHODS
from ..solver.config import add_trace_arguments
from .harness import OneLineParser, run_tool


def make_dataset_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="make-dataset",
        description=(
            "Emulate the ToA measurements of the paper's scenarios: trace the scene (and, for "
            "semi-dynamic, its moving forklifts), apply the link budget and the ToA estimator, "
            "and write DIR/toa.csv and DIR/meta.json (schema: docs/dataset.md)."
        ),
    )
    p.add_argument("--scenario", help="static or semi-dynamic")
    p.add_argument("--band", help="c-band or mmwave (or a band defined in a YAML file)")
    p.add_argument(
        "--all",
        action="store_true",
        help="write the four datasets (both scenarios x both bands) into DIR/<scenario>-<band>",
    )
    p.add_argument("--scene", default="hall", help="scene file or bundled name (default: hall)")
    p.add_argument("--duration", type=float, default=60.0, help="emulated seconds (default 60)")
    p.add_argument("--rate", type=float, default=10.0, help="epochs per second (default 10)")
    p.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    p.add_argument(
        "--receiver",
        "--toa-method",  # its name before the hallray command: still accepted
        dest="toa_method",
        default=DEFAULT_TOA_METHOD,
        help=(
            f"ToA receiver: {', '.join(TOA_METHODS)} (default {DEFAULT_TOA_METHOD}: the "
            "realistic receiver; first-path: the ideal one, exact first detectable delay plus "
            "eq. 3 noise; paper: the paper's model as written)"
        ),
    )
    p.add_argument(
        "--relative-threshold-db",
        type=float,
        default=FirstLobeSettings.relative_threshold_db,
        metavar="DB",
        help="first-lobe: detection threshold relative to the strongest peak (default -12 dB)",
    )
    p.add_argument(
        "--cfar-cells",
        default=str(FirstLobeSettings.cfar_cells),
        metavar="M",
        help="first-lobe: CA-CFAR reference cells, or 'none' for a known noise power (default 64)",
    )
    p.add_argument(
        "--comb",
        type=int,
        default=1,
        metavar="N",
        help="receivers on the PRS CFR: the PRS comb, 1 (every subcarrier), 2, 4, 6 or 12 "
        "(default 1)",
    )
    p.add_argument(
        "--no-first-path-threshold",
        action="store_true",
        help="first-path: the first traced path above the tracer's power floor, not the first "
        "one the link budget detects",
    )
    p.add_argument("--workers", type=int, default=1, help="processes for the snapshots (default 1)")
    p.add_argument(
        "--no-noise", action="store_true", help="no estimation noise (first-path: exact delays)"
    )
    p.add_argument("--force", action="store_true", help="replace a non-empty output directory")
    add_trace_arguments(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars or summary")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    return p


def _cells(text: str) -> int | None:
    """``--cfar-cells`` value: a positive integer or 'none'."""
    if text.strip().lower() == "none":
        return None
    try:
        return int(text)
    except ValueError:
        raise HallrayError(
            f"--cfar-cells must be a positive integer or 'none', got {text!r}"
        ) from None


def make_dataset_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``make-dataset``; returns the exit status."""
    return run_tool(
        _make_dataset, make_dataset_parser(), argv, interrupted="interrupted (nothing written)"
    )


def _make_dataset(args: argparse.Namespace) -> int:
    from hallray.safe_output import output_dir

    from ..emulation.dataset.config import ALL_DATASETS
    from ..scene.bundled import resolve_scene

    if args.all:
        if args.scenario or args.band:
            raise HallrayError("--all writes every scenario and band: drop --scenario/--band")
        pairs, subdirs = list(ALL_DATASETS), True
    else:
        if not args.scenario or not args.band:
            raise HallrayError("give --scenario and --band, or --all")
        pairs, subdirs = [(args.scenario, args.band)], False
    PrsSettings(comb=args.comb)  # an unknown comb is refused before any work
    scene = resolve_scene(args.scene)
    # built in a temporary directory beside the output, renamed when whole; locked against a
    # second writer; only an earlier make-dataset output is replaced (--force)
    with output_dir(args.output, command="make-dataset", force=args.force,
                    inputs=[scene, args.band]) as tmp:  # fmt: skip
        summaries = _make(args, tmp, pairs, subdirs)
    for s in summaries:  # name the final directory, not the staging one
        s["directory"] = str(Path(args.output) / Path(s["directory"]).relative_to(tmp))
    if not args.quiet:
        for s in summaries:
            print(
                f"{s['directory']}: {s['scenario']} {s['band']}, {s['epochs']} epochs, "
                f"{s['rows']} rows, detected {100 * s['detected_fraction']:.1f} %, "
                f"LoS {100 * s['los_fraction']:.1f} %, first path LoS "
                f"{100 * s['first_path_los_fraction']:.1f} %"
            )
        print(f"done in {summaries[-1]['total_seconds']:.1f} s")
    return 0


def _make(args: argparse.Namespace, tmp: Path, pairs: list, subdirs: bool) -> list[dict]:
    """Write the datasets into the empty staging directory ``tmp``."""
    from ..emulation.dataset.make import make_datasets
    from ..solver.config import config_from_args

    return make_datasets(
        tmp,
        pairs,
        scene=args.scene,
        duration_s=args.duration,
        rate_hz=args.rate,
        seed=args.seed,
        toa_method=args.toa_method,
        first_lobe=FirstLobeSettings(args.relative_threshold_db, _cells(args.cfar_cells)),
        prs=PrsSettings(comb=args.comb),
        first_path_threshold=not args.no_first_path_threshold,
        trace_settings=config_from_args(args),
        noise=not args.no_noise,
        workers=args.workers,
        progress=not args.quiet,
        subdirectories=subdirs,
        staging=False,
    )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(make_dataset_main())
