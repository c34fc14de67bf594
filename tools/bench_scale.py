#!/usr/bin/env python3
"""Benchmark of scene scale: load, first and warm trace of the hall's 92 links, peak memory and
paths, for the bundled hall plus generated metal machines from 10^3 to 10^6 triangles
(:mod:`raytrace.halls.machines`), and the log-log slope of time against triangles.

Run from a checkout: ``python tools/bench_scale.py [--max-triangles 1e6] [--dir DIR] [--json]``
(``python tools/bench.py --scene-scale`` runs it). Each scene is measured in a fresh process (its
own peak memory, a cold load with the disk cache off, then the first trace: trees and candidates
built, then a warm trace; wall time and this process' CPU time, the steadier figure on a shared
machine: the trace's stage threads run in it). Generated scenes are kept in ``--dir`` for the next run.
``--scene FILE`` adds a scene of your own (a public city mesh: its links are
:func:`scene_links`'; not in the slope). ``--facet-reach R`` traces with the approximate
discovery of ``TraceConfig(facet_reach=R)``, and ``--recall`` adds an exact trace of each scene
and the approximate trace's recall against it. Not a test: it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError


def measure_one(path: str, f_hz: float, reach: float = 0.0, with_recall: bool = False) -> dict:
    """Load (no disk cache), first and warm trace of the scene's links (:func:`scene_links` when
    the scene carries none) in this process, with ``TraceConfig(facet_reach=reach)``; peak RSS.
    ``with_recall``: then an exact trace too, and the recall of the approximate one against it
    (:func:`raytrace.solver.near.recall`)."""
    from raytrace import TraceConfig, load_scene, trace
    from raytrace.scene.metadata import SceneMetadata
    from raytrace.solver.near import recall

    t0 = time.perf_counter()
    scene = load_scene(path, cache=False, default_material="metal")
    load_s = time.perf_counter() - t0
    inp = SceneMetadata.from_scene(scene)
    if len(inp.bs_xyz):
        tx, rx = inp.bs_xyz, inp.point_xyz
    else:
        tx, rx = scene_links(scene)
    cfg = TraceConfig(facet_reach=reach)
    t0, c0 = time.perf_counter(), time.process_time()
    paths = trace(scene, tx, rx, f_hz, cfg)
    first_s, first_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    trace(scene, tx, rx, f_hz, cfg)
    warm_s, warm_cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    found = {}
    if with_recall:
        r = recall(trace(scene, tx, rx, f_hz), paths)
        found = {"recall_paths": r.paths, "recall_first_arrivals": r.first_arrivals,
                 "exact_paths": r.n_exact}  # fmt: skip
    return {
        "scene": Path(path).name, "triangles": int(len(scene.faces)), "wedges": len(scene.wedges),
        "links": len(tx) * len(rx), "load_s": load_s, "first_trace_s": first_s,
        "warm_trace_s": warm_s, "first_trace_cpu_s": first_cpu, "warm_trace_cpu_s": warm_cpu,
        "paths": int(paths.n_paths), "facet_reach": reach, "peak_gb": peak, **found,
    }  # fmt: skip


def scene_links(scene, n_rx: int = 40, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Links of a scene that carries none (a city model): one transmitter 30 m above the lowest
    point at the middle of the footprint (5 m above the top where that is in a solid) and
    ``n_rx`` receivers 1.5 m above the lowest point, outside the solids, drawn (``seed``) from
    the middle 40 % of the footprint. (The hall's own links are not used for such a scene even
    where they fall inside its box: in a city they are points among its buildings.)"""
    lo, hi = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    rng = np.random.default_rng(seed)
    span = hi - lo
    cand = np.column_stack([rng.uniform(lo[0] + 0.3 * span[0], hi[0] - 0.3 * span[0], 50 * n_rx),
                            rng.uniform(lo[1] + 0.3 * span[1], hi[1] - 0.3 * span[1], 50 * n_rx),
                            np.full(50 * n_rx, lo[2] + 1.5)])  # fmt: skip
    rx = cand[scene.inside_solid(cand) < 0][:n_rx]
    tx = np.array([[0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2] + 30.0]])
    if scene.inside_solid(tx)[0] >= 0:
        tx[0, 2] = hi[2] + 5.0
    return tx, rx


def slope(rows: list[dict], key: str, from_triangles: float = 1e4) -> float | None:
    """Least-squares slope of log(time) against log(triangles) over scenes from 10^4 up."""
    pts = [(r["triangles"], r[key]) for r in rows if r["triangles"] >= from_triangles and r[key] > 0]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-triangles", type=float, default=1e5,
                    help="largest generated scene, triangles (1e6 runs the million) [1e5]")  # fmt: skip
    ap.add_argument("--dir", help="where generated scenes are kept [a temporary folder]")
    ap.add_argument("--scene", action="append", default=[], help="another scene (repeatable)")
    ap.add_argument("--frequency-hz", type=float, default=3.775e9, help="carrier [3.775e9]")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per scene [3600]")
    ap.add_argument("--facet-reach", type=float, default=0.0,
                    help="trace with TraceConfig(facet_reach=...), metres (0: exact) [0]")  # fmt: skip
    ap.add_argument("--recall", action="store_true",
                    help="with --facet-reach: also trace exactly and report the recall")  # fmt: skip
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # the child process: measure this scene
    return ap


def _child(path: str, args: argparse.Namespace) -> dict:
    cmd = [sys.executable, __file__, "--one", path, "--frequency-hz", repr(args.frequency_hz),
           "--facet-reach", repr(args.facet_reach)] + (["--recall"] if args.recall else [])
    timeout = args.timeout
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"scene": Path(path).name, "error": f"over {timeout:g} s"}
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines() or ["no output"]
        return {"scene": Path(path).name, "error": lines[-1]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _main(args: argparse.Namespace) -> int:
    from raytrace.halls.machines import SCALE_STEPS, write_hall_with_machines
    from raytrace.scene.bundled import resolve_scene

    if args.one:
        print(json.dumps(measure_one(args.one, args.frequency_hz, args.facet_reach, args.recall)))
        return 0
    if not 0.0 <= args.facet_reach < float("inf"):
        raise HallrayError(f"--facet-reach must be a distance >= 0 m, got {args.facet_reach:g}")
    if args.recall and not args.facet_reach:
        raise HallrayError("--recall compares a trace with --facet-reach against the exact one: "
                           "give --facet-reach")
    if not args.max_triangles >= 1e3:
        raise HallrayError(f"--max-triangles must be at least 1e3, got {args.max_triangles:g}")
    work = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="hallray-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    files = []
    for n, sub in SCALE_STEPS:
        if 1280 + n * 20 * 4**sub > args.max_triangles:
            break
        f = work / f"hall_{n}x{sub}.glb"
        if not f.exists():
            if n:
                write_hall_with_machines(f, n, sub)
            else:  # the bundled hall itself
                f.write_bytes(Path(resolve_scene("hall")).read_bytes())
        files.append(str(f))
    rows = []
    for f in files + list(args.scene):
        r = _child(f, args)
        rows.append(r)
        if not args.json:
            _print_row(r)
    ok = [r for r in rows[:len(files)] if "error" not in r]  # the generated halls only
    out = {"rows": rows, "slope_load": slope(ok, "load_s"), "slope_first_trace": slope(ok, "first_trace_s"),
           "slope_warm_trace": slope(ok, "warm_trace_s"),
           "slope_first_trace_cpu": slope(ok, "first_trace_cpu_s")}  # fmt: skip
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print("log-log slope from 10^4 triangles: " + ", ".join(
            f"{k[6:]} {v:.2f}" for k, v in out.items() if k.startswith("slope") and v is not None))  # fmt: skip
    return 0


def _print_row(r: dict) -> None:
    if "error" in r:
        print(f"{r['scene']:>22}: {r['error']}")
        return
    print(f"{r['scene']:>22} {r['triangles']:>9,} tri {r['wedges']:>8,} wedges  load {r['load_s']:6.1f} s  "
          f"first {r['first_trace_s']:6.1f} s ({r['first_trace_cpu_s']:.1f} s CPU)  "
          f"warm {r['warm_trace_s']:6.1f} s ({r['warm_trace_cpu_s']:.1f} s CPU)  {r['paths']:>7,} paths  "
          f"peak {r['peak_gb']:.2f} GB" + (f"  recall {r['recall_paths']:.2%} of paths, "
          f"{r['recall_first_arrivals']:.0%} of first arrivals" if "recall_paths" in r else ""),
          flush=True)  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
