"""Speed and accuracy of the ``twin`` estimator on the hall's datasets, per ToA raster spacing.

For each dataset ``DATA/<setup>`` and the map ``MAPS/<band>/map.npz`` (the layout
``reproduce-paper`` writes: ``hallray-out/datasets`` and ``hallray-out/maps``): p90 / mean of the
2D error and fixes per CPU second of the twin alone (with its map-free prior), first on an empty
ToA raster ("cold") and then again ("warm"), for each ``--steps`` value (0: the exact
re-synthesis, the receiver re-run at every iterate; slow). Run with ``OPENBLAS_NUM_THREADS=1``
for single-threaded figures.

Usage::

    OPENBLAS_NUM_THREADS=1 python tools/bench_twin.py --data hallray-out/datasets \\
        --maps hallray-out/maps --steps 0.05,0
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from hallray.harness import OneLineParser, run_command
from positioning.errors import PositioningError
from positioning.evaluation.metrics import error_2d
from positioning.io.dataset import load_dataset
from positioning.io.prepare import dataset_problem
from positioning.methods.registry import METHODS, resolve_params
from positioning.twin.lattice import load

SETUPS = "static-c-band,static-mmwave,semi-dynamic-c-band,semi-dynamic-mmwave"


def _steps(text: str) -> list[float]:
    """``--steps``: comma-separated raster spacings, m, each finite and >= 0 (argparse type)."""
    try:
        steps = [float(x) for x in text.split(",")]
    except ValueError:
        steps = []
    if not steps or not all(np.isfinite(steps)) or min(steps) < 0:
        raise argparse.ArgumentTypeError(
            f"expected raster spacings >= 0 m, comma-separated (e.g. 0.05,0), got {text!r}"
        )
    return steps


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="folder of the datasets (one per setup)")
    ap.add_argument("--maps", required=True, help="folder with <band>/map.npz")
    ap.add_argument("--setups", default=SETUPS, help=f"comma-separated datasets of DATA [{SETUPS}]")
    ap.add_argument("--steps", type=_steps, default="0.05",
                    help="raster spacings, m, comma-separated")  # fmt: skip
    return ap


def _band(setup: str) -> str:
    return "c-band" if setup.endswith("c-band") else "mmwave"


def _main(a: argparse.Namespace) -> int:
    setups = a.setups.split(",")
    for setup in setups:  # every input there before any work
        if not (Path(a.data) / setup).is_dir():
            raise PositioningError(f"{Path(a.data) / setup}: dataset directory not found")
        if not (Path(a.maps) / _band(setup) / "map.npz").is_file():
            raise PositioningError(f"{Path(a.maps) / _band(setup) / 'map.npz'}: no such map file")
    print("| setup | resynth_step | p90 / mean, m | cold, fixes per CPU s | warm |")
    print("|---|---|---|---|---|")
    for setup in setups:
        band = _band(setup)
        ds = load_dataset(Path(a.data) / setup)
        prob = dataset_problem(ds)
        mp = str(Path(a.maps) / band / "map.npz")
        for step in a.steps:
            p = resolve_params("twin", {"map": mp, "resynth_step": step}, prob.n_bs)
            load(mp)[1].rasters.clear()
            rate = []
            for _ in range(2):
                t0 = time.process_time()
                out = METHODS["twin"].run(prob, p)
                rate.append(prob.n_epochs / (time.process_time() - t0))
                if step == 0:
                    break  # nothing is kept between passes
            e = error_2d(out.xyz, ds.true_xyz)
            warm = f"{rate[1]:.0f}" if len(rate) > 1 else "(as cold)"
            print(f"| {setup} | {step:g} | {np.percentile(e, 90):.2f} / {e.mean():.3f} | "
                  f"{rate[0]:.0f} | {warm} |", flush=True)  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
