"""``accuracy-map``: the positioning-accuracy map of a hall from its digital twin.

    accuracy-map SCENE [--step 2] [--height H] [--band c-band] [--receiver first-lobe]
                 [--methods ls irls] [--draws 100] [--seed 1] [--paths-per-link 16]
                 [--workers N | --scheduler ADDR] [--clearance 0.25] [--max-cells 20000]
                 [--no-pictures] [--force] [-q] -o DIR

(``hallray map``.) Writes DIR/map.npz (schema ``hallray-accuracy-map``,
:mod:`positioning.twin.fingerprint`), DIR/map.csv with its schema in DIR/map.json, and PNG
heatmaps (docs/accuracy_map.md). Bad input gives a one-line ``error: ...``
on stderr and exit status 2 (:mod:`.harness`); DIR appears only when complete.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence

import numpy as np

from ..core.errors import HallrayError
from ..emulation.receivers.receiver import DEFAULT_TOA_METHOD, TOA_METHODS
from ..solver.config import add_trace_arguments
from .harness import OneLineParser, add_scene_arguments, run_tool, scene_options


def accuracy_map_parser() -> argparse.ArgumentParser:
    from ..studies import accuracy_map as am

    p = OneLineParser(
        prog="accuracy-map",
        description=(
            "Per grid cell over the floor: base stations in LoS, first arrivals, predicted ToA "
            "and its spread, GDOP and the predicted 2D error of positioning methods "
            "(DIR/map.npz, DIR/map.csv with DIR/map.json, PNG heatmaps; docs/accuracy_map.md)."
        ),
    )
    add_scene_arguments(p)
    p.add_argument("--step", type=float, default=am.DEFAULT_STEP_M, metavar="M",
                   help=f"grid step, m (default {am.DEFAULT_STEP_M:g})")  # fmt: skip
    p.add_argument("--height", type=float, default=None, metavar="H",
                   help="device height, m (default: the scene's test points' height)")  # fmt: skip
    p.add_argument("--band", default="c-band", help="band name (default c-band)")
    p.add_argument("--receiver", default=DEFAULT_TOA_METHOD,
                   help=f"ToA receiver: {', '.join(TOA_METHODS)} (default {DEFAULT_TOA_METHOD})")  # fmt: skip
    p.add_argument("--methods", nargs="+", default=list(am.DEFAULT_METHODS), metavar="METHOD",
                   help="positioning methods, by spaces or commas (default: ls irls)")  # fmt: skip
    p.add_argument("--draws", type=int, default=am.DEFAULT_DRAWS, metavar="K",
                   help=f"noise draws per cell (default {am.DEFAULT_DRAWS})")  # fmt: skip
    p.add_argument("--seed", type=int, default=am.DEFAULT_SEED, help="random seed (default 1)")
    p.add_argument("--paths-per-link", "--paths", dest="paths", type=int, default=None,
                   metavar="K",
                   help="strongest paths stored per cell and base station for the twin's "
                   f"re-synthesis (schema v2; default {am.DEFAULT_PATHS} with the first-lobe "
                   "receiver, which is the one the twin re-synthesises, else 0: a v1 map)")  # fmt: skip
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes (default: every core)")  # fmt: skip
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the chunks on this Dask scheduler (tcp://host:8786) instead")  # fmt: skip
    p.add_argument("--clearance", type=float, default=am.DEFAULT_CLEARANCE_M, metavar="M",
                   help="least distance of a cell centre from a test point, m (default 0.25)")  # fmt: skip
    p.add_argument("--max-cells", type=int, default=am.MAX_CELLS, metavar="N",
                   help=f"refuse grids with more cells (default {am.MAX_CELLS})")  # fmt: skip
    p.add_argument("--no-pictures", action="store_true", help="no PNG heatmaps")
    p.add_argument("--force", action="store_true", help="replace a non-empty output directory")
    add_trace_arguments(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    return p


def accuracy_map_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``accuracy-map``; returns the exit status."""
    return run_tool(
        _accuracy_map, accuracy_map_parser(), argv, interrupted="interrupted (nothing written)"
    )


def _accuracy_map(args: argparse.Namespace) -> int:
    from ..scene.bundled import resolve_scene
    from ..scene.io import load_scene
    from ..solver.config import config_from_args
    from ..solver.parallel import process_context, resolve_workers
    from ..studies.accuracy_map.compute import compute_map
    from ..studies.accuracy_map.files import check_output, write_outputs
    from ..studies.accuracy_map.settings import MapSettings

    t0 = time.perf_counter()
    if args.paths is None:
        from ..studies.accuracy_map.settings import DEFAULT_PATHS

        args.paths = DEFAULT_PATHS
    elif args.paths > 0 and args.receiver != "first-lobe":
        raise HallrayError(
            f"--paths-per-link {args.paths} needs --receiver first-lobe (the twin re-synthesises "
            "that receiver's ToA only); without it the map has no paths (schema v1)"
        )
    settings = MapSettings(
        step_m=args.step, height_m=args.height, band=args.band, receiver=args.receiver,
        methods=tuple(m for item in args.methods for m in item.split(",") if m), draws=args.draws, seed=args.seed, paths=args.paths,
        clearance_m=args.clearance, max_cells=args.max_cells, trace=config_from_args(args),
    )  # fmt: skip
    settings.check()
    resolve_workers(args.workers, 1)  # a bad --workers is refused before any work
    inputs = [resolve_scene(args.scene), args.materials, args.band]
    check_output(args.output, args.force, inputs)
    if args.scheduler is None and resolve_workers(args.workers, 2) > 1:
        # the workers' fork server imports its modules while this process loads the scene
        process_context(("raytrace.studies.accuracy_map",))
    scene = load_scene(args.scene, args.materials, **scene_options(args))
    amap = compute_map(scene, settings, scene_name=str(args.scene), workers=args.workers,
                       scheduler=args.scheduler, progress=not args.quiet)  # fmt: skip
    files = write_outputs(args.output, scene, amap, force=args.force,
                          pictures=not args.no_pictures, inputs=inputs)  # fmt: skip
    if not args.quiet:
        f = amap.fmap
        print(f"{f.n_cells} cells x {f.n_bs} base stations, {f.meta['n_paths']} paths, "
              f"{f.meta['workers']} workers; {len(files)} files in {args.output}")  # fmt: skip
        for k, m in enumerate(f.methods):
            print(f"  {m}: median cell p90 error {np.nanmedian(f.err_p90_m[k]):.2f} m, "
                  f"mean availability {np.nanmean(f.availability[k]):.3f}")  # fmt: skip
        print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(accuracy_map_main())
