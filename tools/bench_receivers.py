"""Receiver study: every ToA receiver on the bundled hall, per band and first-arrival class.

Run from a checkout::

    python tools/bench_receivers.py -o DIR [--duration 3] [--receivers a,b,...] [--no-table]

It writes the datasets of every receiver from one trace per snapshot (``DIR/datasets``: static and
semi-dynamic, C-band and mmWave, seed 1; the receivers of :data:`RECEIVERS` unless
``--receivers``), then ``DIR/receivers.md`` and ``DIR/receivers.json``:

* per receiver, band and first-arrival class of the link (``first_kind``: ``LoS``;
  ``diffraction``, a first path with diffractions only; ``reflection``, one with a reflection;
  and, overlapping these, ``diffraction-first``, a first path with a diffraction, ``D``, ``DR``,
  ``RD``, ..., issue 38's target class): the share of links, detection rate, range error
  ``c (toa_s - tx_offset_s - clock_offset_s) - distance_m`` median / p90 / p99 and the p90 of
  its magnitude (detected links; both scenarios, and per scenario in the JSON), and false early
  detections,
  the share of links whose range error is below ``-c 1.25 / (4 B)`` (a quarter pulse before the
  line-of-sight distance);
* cost per link: the receiver's path-only work (prepare) on the static hall's links and one
  epoch's measurement, best of three (microseconds per link; the ratio to ``first-lobe``);
* the early links: per receiver and band, every link (point, base station) reported early in at
  least one epoch, with its share of epochs and its median range error;
* Table II (``--no-table`` skips it): ``accuracy-report --methods ls,irls`` on each receiver's
  four datasets, mean and p90 of the 2D error.

Figures depend on the seed and duration only (the files do not depend on the machine); the cost
does.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from hallray.harness import OneLineParser, run_command
from hallray.safe_output import write_file
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError

# the tracer, the datasets and positioning are imported where used: --help and bad input answer
# without compiling the kernels

#: The receivers compared by default (the realistic ones and the ideal reference).
RECEIVERS = ("first-lobe", "first-lobe-cfr", "search-back", "super-res", "first-path")
BANDS = ("c-band", "mmwave")
SCENARIOS = ("static", "semi-dynamic")
CLASSES = ("LoS", "diffraction", "reflection", "diffraction-first", "all")
#: Pulse period over 1/B (eq. 2, beta = 0.25): an early ToA is a quarter of c T before the LoS.
PERIOD_B = 1.25


def first_class(kind: str) -> str:
    """``LoS``, ``reflection`` (the first path has a reflection) or ``diffraction`` (only
    diffractions; the hall's first paths are ``D``, ``DD``, ``RD``, ...)."""
    if kind == "LoS":
        return "LoS"
    return "reflection" if "R" in kind else "diffraction"


def read_errors(directory: Path) -> dict[str, Any]:
    """Range errors (m, NaN: not detected), classes and the early limit of one dataset."""
    meta = json.loads((directory / "meta.json").read_text())
    with open(directory / "toa.csv", newline="") as f:
        rows = list(csv.DictReader(f))

    def col(name: str) -> np.ndarray:
        return np.array([float(r[name]) if r[name] != "" else np.nan for r in rows])

    err = C0 * (col("toa_s") - col("tx_offset_s") - col("clock_offset_s")) - col("distance_m")
    bandwidth = float(meta["band_parameters"]["bandwidth_hz"])
    return {
        "method": meta["toa_method"],
        "band": meta["band"],
        "scenario": meta["scenario"],
        "link": np.array([f"{r['point']}-{r['bs']}" for r in rows]),
        "error": err,
        "cls": np.array([first_class(r["first_kind"]) for r in rows]),
        "dfirst": np.array(["D" in r["first_kind"] for r in rows], dtype=bool),
        "early_m": C0 * PERIOD_B / bandwidth / 4,
    }


def class_stats(err: np.ndarray, early_m: float) -> dict[str, float]:
    """Links, detection rate, error median / p90 / p99 and |error| p90 (m, detected) and early
    share."""
    n = int(err.size)
    det = err[np.isfinite(err)]
    q = np.quantile(det, [0.5, 0.9, 0.99]) if det.size else np.full(3, np.nan)
    abs_p90 = float(np.quantile(np.abs(det), 0.9)) if det.size else float("nan")
    return {
        "links": n,
        "detected": float(det.size / n) if n else float("nan"),
        "median_m": float(q[0]),
        "p90_m": float(q[1]),
        "p99_m": float(q[2]),
        "abs_p90_m": abs_p90,
        "early": float(np.sum(det < -early_m) / n) if n else float("nan"),
    }


def accuracy(datasets: list[dict[str, Any]], by_scenario: bool) -> list[dict[str, Any]]:
    """Statistics per receiver, band, class (and scenario if ``by_scenario``)."""
    keys = sorted({(d["method"], d["band"], d["scenario"] if by_scenario else "both")
                   for d in datasets})  # fmt: skip
    out = []
    for method, band, scen in keys:
        parts = [d for d in datasets if d["method"] == method and d["band"] == band
                 and scen in ("both", d["scenario"])]  # fmt: skip
        err = np.concatenate([d["error"] for d in parts])
        cls = np.concatenate([d["cls"] for d in parts])
        dfirst = np.concatenate([d["dfirst"] for d in parts])
        for c in CLASSES:
            sel = err if c == "all" else err[dfirst] if c == "diffraction-first" else err[cls == c]
            if sel.size:
                row = {"receiver": method, "band": band, "scenario": scen, "class": c}
                row |= class_stats(sel, parts[0]["early_m"])
                row["share"] = float(sel.size / err.size)
                out.append(row)
    return out


def early_links(datasets: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per receiver, band and scenario, the links reported early in at least one epoch: their
    share of epochs early and median range error (m), most often early first."""
    out = []
    for d in datasets:
        early = d["error"] < -d["early_m"]
        for name in sorted(set(d["link"][early])):
            sel = d["link"] == name
            out.append({"receiver": d["method"], "band": d["band"], "scenario": d["scenario"],
                        "link": str(name), "early_share": float(np.mean(early[sel])),
                        "median_m": float(np.median(d["error"][sel]))})  # fmt: skip
    out.sort(key=lambda r: (r["receiver"], r["band"], r["scenario"], -r["early_share"], r["link"]))
    return out


def receiver_cost(receivers: list[str], repeats: int = 3) -> list[dict[str, Any]]:
    """Microseconds per link of each receiver on the static hall: prepare, one epoch's measure."""
    from raytrace.emulation.dataset.config import DatasetConfig
    from raytrace.emulation.dataset.epochs import scenario_group
    from raytrace.scene.io import load_scene
    from raytrace.scene.metadata import SceneMetadata

    sc = load_scene("hall")
    inputs = SceneMetadata.from_scene(sc, require=True)
    out = []
    for band in BANDS:
        configs = [DatasetConfig("static", band, toa_method=m, duration_s=1.0) for m in receivers]
        g = scenario_group("static", configs, sc, inputs, {})
        for k, model in enumerate(g.models):
            paths = g.paths_of(g.tracer.static_paths, k)
            prep_s, meas_s = [], []
            for _ in range(repeats):
                t = time.perf_counter()
                prep = model.prepare(paths)
                prep_s.append(time.perf_counter() - t)
                t = time.perf_counter()
                model.measure(paths, [0], prep)
                meas_s.append(time.perf_counter() - t)
            n = paths.n_links
            out.append({"receiver": receivers[k], "band": band, "links": n,
                        "prepare_us": 1e6 * min(prep_s) / n, "measure_us": 1e6 * min(meas_s) / n})  # fmt: skip
    for row in out:
        ref = [r for r in out if r["band"] == row["band"] and r["receiver"] == "first-lobe"]
        total = row["prepare_us"] + row["measure_us"]
        row["total_us"] = total
        row["vs_first_lobe"] = total / ref[0]["total_us"] if ref else float("nan")
    return out


def table_two(ds_dir: Path, out_dir: Path, receivers: list[str]) -> list[dict[str, Any]]:
    """Mean and p90 2D error of ``ls`` and ``irls`` on each receiver's four datasets."""
    from positioning.cli.accuracy import accuracy_report_main

    rows = []
    for method in receivers:
        suffix = "" if method == receivers[0] else f"-{method}"
        dirs = [str(ds_dir / f"{s}-{b}{suffix}") for s in SCENARIOS for b in BANDS]
        rep = out_dir / f"table-{method}"
        shutil.rmtree(rep, ignore_errors=True)
        with contextlib.redirect_stdout(io.StringIO()):
            code = accuracy_report_main(["--methods", "ls,irls", "-o", str(rep), *dirs])
        if code:
            raise HallrayError(f"accuracy-report failed on {method} (exit {code})")
        with open(rep / "table.csv", newline="") as f:
            for r in csv.DictReader(f):
                rows.append({"receiver": method, **r})
    return rows


def _fmt(v: float, nd: int = 2) -> str:
    return "-" if not np.isfinite(v) else f"{v:.{nd}f}"


def markdown(
    acc: list[dict], cost: list[dict], table: list[dict], early: list[dict] = (),
    by_scenario: list[dict] = (),
) -> str:
    """The study as markdown tables (``by_scenario``: the issue's targets per scenario)."""
    lines = ["## Range error per receiver, band and first-arrival class (both scenarios)", "",
             "| receiver | band | class | share | detected | median [m] | p90 [m] | p99 [m] | "
             "abs p90 [m] | early [%] |", "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in acc:
        lines.append(f"| {r['receiver']} | {r['band']} | {r['class']} | {_fmt(r['share'])} | "
                     f"{_fmt(r['detected'], 3)} | {_fmt(r['median_m'])} | {_fmt(r['p90_m'])} | "
                     f"{_fmt(r['p99_m'])} | {_fmt(r['abs_p90_m'])} | {_fmt(100 * r['early'])} |")  # fmt: skip
    if by_scenario:
        lines += ["", "## Per scenario: LoS and diffraction-first links, all links' early share", "",
                  "| receiver | band | scenario | LoS abs p90 [m] | diffraction-first abs p90 [m] | "
                  "early, all links [%] |", "|---|---|---|---|---|---|"]  # fmt: skip
        keys = sorted({(r["receiver"], r["band"], r["scenario"]) for r in by_scenario})
        for key in keys:
            got = {r["class"]: r for r in by_scenario if (r["receiver"], r["band"], r["scenario"]) == key}
            los, dif, all_ = (got.get(c, {}) for c in ("LoS", "diffraction-first", "all"))
            lines.append(f"| {key[0]} | {key[1]} | {key[2]} | {_fmt(los.get('abs_p90_m', np.nan))} | "
                         f"{_fmt(dif.get('abs_p90_m', np.nan))} | "
                         f"{_fmt(100 * all_.get('early', np.nan))} |")  # fmt: skip
    if early:
        lines += ["", "## Early links (reported early in at least one epoch)", "",
                  "| receiver | band | scenario | link | epochs early | median error [m] |",
                  "|---|---|---|---|---|---|"]  # fmt: skip
        for r in early:
            lines.append(f"| {r['receiver']} | {r['band']} | {r['scenario']} | {r['link']} | "
                         f"{100 * r['early_share']:.0f} % | {r['median_m']:.2f} |")  # fmt: skip
    lines += ["", "## Cost per link (static hall, best of 3)", "",
              "| receiver | band | links | prepare [us] | measure [us] | total [us] | "
              "x first-lobe |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in cost:
        lines.append(f"| {r['receiver']} | {r['band']} | {r['links']} | {_fmt(r['prepare_us'], 1)} "
                     f"| {_fmt(r['measure_us'], 1)} | {_fmt(r['total_us'], 1)} | "
                     f"{_fmt(r['vs_first_lobe'])} |")  # fmt: skip
    if table:
        lines += ["", "## Table II (2D error, m)", "",
                  "| receiver | metric | scenario | band | LS | IRLS |", "|---|---|---|---|---|---|"]
        for r in table:
            if r["metric"] in ("mean", "p90"):
                lines.append(f"| {r['receiver']} | {r['metric']} | {r['scenario']} | {r['band']} | "
                             f"{float(r['ls']):.2f} | {float(r['irls']):.2f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def parser() -> OneLineParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("-o", "--output", required=True, help="output directory")
    p.add_argument("--duration", type=float, default=3.0, help="seconds of each dataset [3]")
    p.add_argument("--receivers", default=",".join(RECEIVERS),
                   help=f"comma-separated receivers [{','.join(RECEIVERS)}]")  # fmt: skip
    p.add_argument("--no-table", action="store_true", help="skip Table II")
    p.add_argument("--no-cost", action="store_true", help="skip the cost per link")
    p.add_argument("--reuse", action="store_true",
                   help="use the datasets already in OUTPUT/datasets")  # fmt: skip
    return p


def _main(args: Any) -> int:
    from raytrace.emulation.dataset import make_datasets
    from raytrace.emulation.receivers import TOA_METHODS

    receivers = [r.strip() for r in args.receivers.split(",") if r.strip()]
    bad = [r for r in receivers if r not in TOA_METHODS]
    if bad or not receivers:
        raise HallrayError(f"unknown receiver {bad[0] if bad else ''!r}; known: {', '.join(TOA_METHODS)}")
    if not args.duration > 0:
        raise HallrayError(f"--duration must be positive, got {args.duration!r}")
    out = Path(args.output)
    ds_dir = out / "datasets"
    if args.reuse and not ds_dir.is_dir():
        raise HallrayError(f"--reuse: no datasets in {ds_dir}")
    out.mkdir(parents=True, exist_ok=True)
    if not args.reuse:
        pairs = [(s, b) for s in SCENARIOS for b in BANDS]
        make_datasets(ds_dir, pairs, duration_s=args.duration, toa_method=receivers, force=True)
    datasets = [read_errors(d) for d in sorted(ds_dir.iterdir()) if (d / "toa.csv").is_file()]
    datasets = [d for d in datasets if d["method"] in receivers]
    acc = accuracy(datasets, by_scenario=False)
    acc_s = accuracy(datasets, by_scenario=True)
    early = early_links(datasets)
    cost = [] if args.no_cost else receiver_cost(receivers)
    table = [] if args.no_table else table_two(ds_dir, out, receivers)
    text = markdown(acc, cost, table, early, acc_s)
    blob = {"duration_s": args.duration, "receivers": receivers, "accuracy": acc,
            "accuracy_by_scenario": acc_s, "early_links": early, "cost": cost,
            "table_ii": table}  # fmt: skip
    write_file(out / "receivers.json", json.dumps(blob, indent=1) + "\n")
    write_file(out / "receivers.md", text)
    print(text)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv, user_errors=(HallrayError,))


if __name__ == "__main__":
    raise SystemExit(main())
