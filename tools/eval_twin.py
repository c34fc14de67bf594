"""Honest evaluation of the twin estimator and the tracker on the bundled hall's datasets.

For each dataset ``DATA/<scenario>-<band>`` and the map ``MAPS/<prefix>-<band>.npz`` (the static
scene's map for both scenarios: stale in the semi-dynamic ones): p90 and mean 2D error of
``irls``, ``nlos-aware`` and ``twin`` (single epoch) and their ``+track`` forms (separate
table), the twin's share of ``MAP_MISMATCH`` fixes, fixes outside the dataset's service area,
and per test point the distance to the nearest map cell.

Usage::

    python tools/eval_twin.py --data /work/data/first-lobe --maps /tmp/maps --prefix hall
    python tools/eval_twin.py ... --twin-param bias=cell      # the v1 refinement on a v2 map
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hallray.harness import OneLineParser, run_command  # noqa: E402
from positioning.errors import PositioningError  # noqa: E402
from positioning.estimators.fixes import Status  # noqa: E402
from positioning.evaluation.metrics import error_2d  # noqa: E402
from positioning.io.dataset import load_dataset  # noqa: E402
from positioning.report.runs import evaluate  # noqa: E402
from positioning.twin.estimator import clamp_to_polygon  # noqa: E402
from positioning.twin.fingerprint import read_map, write_map  # noqa: E402

SINGLE = ("irls", "nlos-aware", "twin")
TRACKED = tuple(f"{m}+track" for m in SINGLE)


def outside(xy: np.ndarray, meta: dict) -> int:
    """Fixes outside the dataset's service area (its polygon, else hall_xy)."""
    sa = meta.get("service_area") or {}
    poly = sa.get("polygon") if isinstance(sa, dict) else sa
    if poly is None:
        (x0, y0), (x1, y1) = meta["hall_xy"]
        poly = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    fin = np.isfinite(xy).all(axis=1)
    _, moved = clamp_to_polygon(xy[fin], np.asarray(poly, dtype=float))
    return int(moved.sum())


def near_points(fmap, radius: float, data: Path, band: str, folder: Path):
    """The map reduced to the cells within ``radius`` of a test point, written to ``folder``."""
    ds = load_dataset(data / f"static-{band}")
    pts = np.unique(ds.true_xyz[:, :2], axis=0)
    d = np.linalg.norm(fmap.cell_xyz[:, None, :2] - pts[None], axis=2).min(axis=1)
    sub = fmap.select(d <= radius)
    return sub, write_map(folder / f"near-{band}.npz", sub)


def _key_value(text: str) -> tuple[str, str]:
    """``--twin-param KEY=VALUE`` -> (KEY, VALUE) (argparse type)."""
    key, sep, value = text.partition("=")
    if not (sep and key):
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="/work/data/first-lobe")
    ap.add_argument("--maps", required=True)
    ap.add_argument("--prefix", default="hall", help="map file prefix (hall, shift, wall)")
    ap.add_argument("--bands", default="c-band,mmwave")
    ap.add_argument("--scenarios", default="static,semi-dynamic")
    ap.add_argument(
        "--near-points",
        type=float,
        default=0.0,
        metavar="R",
        help="use only the map's cells within R m of a test point (to compare with maps built "
        "by build_twin_map.py --near-points R)",
    )
    ap.add_argument(
        "--twin-param",
        type=_key_value,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="twin parameter, e.g. bias=cell (the v1 refinement on a v2 map) or paths=16",
    )
    return ap


def check_inputs(a: argparse.Namespace) -> None:
    """Refuse a meaningless setting or a missing map or dataset before any work."""
    if not (np.isfinite(a.near_points) and a.near_points >= 0):
        raise PositioningError(
            f"--near-points must be >= 0 m (0: every cell), got {a.near_points:g}"
        )
    scenarios = a.scenarios.split(",") + (["static"] if a.near_points > 0 else [])
    for band in a.bands.split(","):
        mp = Path(a.maps) / f"{a.prefix}-{band}.npz"
        if not mp.is_file():
            raise PositioningError(f"{mp}: no such map file")
        for sc in scenarios:
            if not (Path(a.data) / f"{sc}-{band}").is_dir():
                raise PositioningError(
                    f"{Path(a.data) / f'{sc}-{band}'}: dataset directory not found"
                )


def _main(a: argparse.Namespace) -> int:
    check_inputs(a)
    twin_params = dict(a.twin_param)
    tmp = tempfile.TemporaryDirectory()
    single, tracked, points = [], [], []
    for band in a.bands.split(","):
        mp = Path(a.maps) / f"{a.prefix}-{band}.npz"
        fmap = read_map(mp)
        if a.near_points > 0:
            fmap, mp = near_points(fmap, a.near_points, Path(a.data), band, Path(tmp.name))
        for sc in a.scenarios.split(","):
            ds = load_dataset(Path(a.data) / f"{sc}-{band}")
            t0 = time.perf_counter()
            r = evaluate(ds, SINGLE + TRACKED, {"twin": {"map": str(mp), **twin_params}})
            dt = time.perf_counter() - t0
            s = {m: r.summaries[m] for m in r.summaries}
            tw = r.fixes["twin"]
            mm = tw.count(Status.MAP_MISMATCH) / tw.n_epochs
            out = {m: outside(r.fixes[m].xyz[:, :2], ds.meta) for m in r.fixes}
            ratio = s["twin"]["p90_m"] / s["irls"]["p90_m"]
            best_free = min(s["irls"]["p90_m"], s["nlos-aware"]["p90_m"])
            single.append(
                f"| {sc} | {band} | " + " | ".join(f"{s[m]['p90_m']:.2f} / {s[m]['mean_m']:.2f}" for m in SINGLE)
                + f" | {ratio:.2f} | {s['twin']['p90_m'] / best_free:.2f} | {mm:.1%} | "
                + f"{out['twin']} (irls {out['irls']}) | {dt:.0f} s |"
            )  # fmt: skip
            tracked.append(
                f"| {sc} | {band} | "
                + " | ".join(f"{s[m]['p90_m']:.2f} / {s[m]['mean_m']:.2f}" for m in TRACKED)
                + " |"
            )
            if sc == a.scenarios.split(",")[0]:
                names = list(dict.fromkeys(ds.point.tolist()))
                xy = np.array([ds.true_xyz[ds.point == n][0, :2] for n in names])
                d = np.linalg.norm(xy[:, None, :] - fmap.cell_xyz[None, :, :2], axis=2).min(1)
                e = error_2d(tw.xyz, ds.true_xyz)
                med = [np.median(e[ds.point == n]) for n in names]
                points.append((band, names, d, med))
    tmp.cleanup()  # the reduced maps of --near-points, all read by now
    print(f"map prefix {a.prefix!r}: p90 / mean of the 2D error, metres\n")
    print("| setup | band | irls | nlos-aware | twin | twin/irls p90 | twin/best map-free p90 |"
          " twin map mismatch | fixes outside hall | time (all 6 methods) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(single))
    print("\nTracked (METHOD+track), p90 / mean, metres\n")
    print("| setup | band | " + " | ".join(TRACKED) + " |\n|---|---|---|---|---|")
    print("\n".join(tracked))
    for band, names, d, med in points:
        print(f"\nper test point ({band}): distance to the nearest map cell (m) / twin median error"
              " (m, static)")  # fmt: skip
        print(" ".join(f"{n} {x:.2f}/{m:.2f}" for n, x, m in zip(names, d, med, strict=True)))
        print(f"nearest-cell distance: min {d.min():.3f} m, max {d.max():.3f} m")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
