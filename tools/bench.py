#!/usr/bin/env python3
"""Benchmark: links traced per second on the bundled hall, and positions solved per second.

Run from a checkout: ``python tools/bench.py [--json] [--repeat N] [--scene hall] [--snapshots N]``.
Also times the incremental retrace of forklift snapshots against a full retrace.
Not a test: it prints figures to quote, it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from raytrace import TraceConfig, load_scene, trace  # noqa: E402


def _best_of(fn, repeat):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_trace(scene_name: str, repeat: int) -> dict:
    t0 = time.perf_counter()
    scene = load_scene(scene_name)
    load_s = time.perf_counter() - t0
    meta = scene.metadata.get("hallray", {})
    tx = np.array([b["xyz"] for b in meta["base_stations"]], float)
    rx = np.array([p["xyz"] for p in meta["points"]], float)
    n_links = len(tx) * len(rx)
    configs = {
        "los_only": TraceConfig(max_reflections=0, max_penetrations=0, max_diffractions=0),
        "los_r2_t2": TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=0),
        "los_r2_t2_d1_mixed": TraceConfig(
            max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=2
        ),
    }
    out = {
        "scene": scene_name,
        "triangles": int(len(scene.faces)),
        "facets": len(scene.facets),
        "wedges": len(scene.wedges),
        "links": n_links,
        "load_s": round(load_s, 4),
        "configs": {},
    }
    for name, cfg in configs.items():
        if cfg.max_diffractions and not len(scene.wedges):
            continue
        stats: dict[str, int] = {}
        best, paths = _best_of(lambda cfg=cfg: trace(scene, tx, rx, 3.775e9, cfg), repeat)
        trace(scene, tx, rx, 3.775e9, cfg, stats=stats)
        segs = int(stats.get("segments_tested", 0))
        out["configs"][name] = {
            "seconds": round(best, 4),
            "links_per_s": round(n_links / best, 1),
            "paths": paths.n_paths,
            "paths_by_kind": _kinds(paths),
            "segments_tested": segs,
            "segments_per_s": round(segs / best, 0),
            "stage_seconds": {
                k[len("time_us[") : -1]: round(v / 1e6, 4)
                for k, v in stats.items()
                if k.startswith("time_us[")
            },
        }
    return out


def _kinds(paths) -> dict[str, int]:
    """Number of paths by mechanism group: LoS, reflections only, with penetrations only, pure
    diffraction (D), diffraction mixed with reflections."""
    pure_d = (paths.n_diffractions > 0) & (paths.n_reflections == 0)
    mixed = (paths.n_diffractions > 0) & (paths.n_reflections > 0)
    refl = (paths.n_diffractions == 0) & (paths.n_reflections > 0)
    pen = (paths.n_diffractions == 0) & (paths.n_reflections == 0) & (paths.n_penetrations > 0)
    return {
        "los": int(paths.los.sum()),
        "reflection": int(refl.sum()),
        "penetration_only": int(pen.sum()),
        "diffraction_pure": int(pure_d.sum()),
        "diffraction_mixed": int(mixed.sum()),
    }


def bench_snapshots(scene_name: str, n: int) -> dict:
    """Incremental retrace of ``n`` snapshots with the hall's forklifts (both bands, one thread,
    as in a dataset worker) against a full retrace of the same snapshots."""
    from raytrace.emulation.bands import get_band
    from raytrace.scene.metadata import routes_from_metadata
    from raytrace.solver.incremental import SnapshotTracer

    scene = load_scene(scene_name)
    meta = scene.metadata.get("hallray", {})
    routes = routes_from_metadata(scene.metadata)
    if not routes or n <= 0:
        return {}
    tx = np.array([b["xyz"] for b in meta["base_stations"]], float)
    rx = np.array([p["xyz"] for p in meta["points"]], float)
    freqs = [get_band(b).center_frequency_hz for b in ("c-band", "mmwave")]
    st = SnapshotTracer(scene, tx, rx, routes, freqs, threads=1)
    times = np.linspace(0.0, 60.0, n, endpoint=False) + 0.37
    snaps = [st.scene_at(float(t)) for t in times]

    def timed(fn):
        w0, c0 = time.perf_counter(), time.process_time()
        for t, s in zip(times, snaps):
            fn(float(t), s)
        return (time.perf_counter() - w0) / n, (time.process_time() - c0) / n

    inc_wall, inc_cpu = timed(st.paths_at)
    stats = {k: round(v / n, 4) for k, v in st.stats.items() if k.endswith("_s")}
    st.threads = 1
    full_wall, full_cpu = timed(st.full_retrace)
    return {
        "snapshots": n,
        "incremental_s": {"wall": round(inc_wall, 4), "cpu": round(inc_cpu, 4)},
        "full_s": {"wall": round(full_wall, 4), "cpu": round(full_cpu, 4)},
        "speedup_cpu": round(full_cpu / inc_cpu, 1),
        "incremental_stages_s": stats,
    }


def bench_positioning(n_epochs: int) -> dict:
    try:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import bench_positioning

        return bench_positioning.run(n_epochs=n_epochs)
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--epochs", type=int, default=20000, help="epochs for the positioning benchmark"
    )
    ap.add_argument(
        "--snapshots",
        type=int,
        default=4,
        help="forklift snapshots for the incremental-retrace benchmark (0: skip)",
    )
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    res = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "trace": bench_trace(args.scene, args.repeat),
        "snapshots": bench_snapshots(args.scene, args.snapshots),
        "positioning": bench_positioning(args.epochs),
    }
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    tr = res["trace"]
    print(f"machine: {res['machine']['cpus']} cpus, Python {res['machine']['python']}")
    print(
        f"scene {tr['scene']}: {tr['triangles']} triangles, {tr['facets']} facets, {tr['wedges']} wedges; "
        f"{tr['links']} links; load {tr['load_s']:.3f} s"
    )
    for name, r in tr["configs"].items():
        print(
            f"  {name:<20} {r['seconds']:.3f} s  {r['links_per_s']:>9.1f} links/s  {r['paths']:>6} paths  "
            f"{r['segments_tested']:>8} segments ({r['segments_per_s']:.3g}/s)"
        )
        print("      paths: " + ", ".join(f"{k} {v}" for k, v in r["paths_by_kind"].items()))
        print(
            "      stages (s, overlapping on threads): "
            + ", ".join(f"{k} {v:.3f}" for k, v in r["stage_seconds"].items())
        )
    sn = res["snapshots"]
    if sn:
        print(
            f"snapshots with forklifts, both bands, 1 thread ({sn['snapshots']} snapshots): "
            f"incremental {sn['incremental_s']['cpu']:.3f} s CPU "
            f"({sn['incremental_s']['wall']:.3f} s wall), full retrace "
            f"{sn['full_s']['cpu']:.3f} s CPU ({sn['full_s']['wall']:.3f} s wall), "
            f"speed-up {sn['speedup_cpu']}x"
        )
        print(
            "      incremental stages (s): "
            + ", ".join(f"{k} {v:.3f}" for k, v in sn["incremental_stages_s"].items())
        )
    pos = res["positioning"]
    if "error" in pos:
        print(f"positioning: {pos['error']}")
    else:
        print("positioning (fixes per second, batched):")
        for k, v in pos.items():
            print(f"  {k}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
