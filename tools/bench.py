#!/usr/bin/env python3
"""Benchmark: links traced per second on the bundled hall, and positions solved per second.

Run from a checkout: ``python tools/bench.py [--json] [--repeat N] [--scene hall] [--snapshots N]
[--grid-step 2] [--no-scaling | --only-scaling]``; ``--scene-scale 1e5`` runs the scene-scale
section instead (``tools/bench_scale.py``: load, trace and memory from 10^3 triangles up).
Also times the incremental retrace of forklift snapshots against a full retrace, and the scaling
over cores: links/s and paths/s at 1, 2 and all cores (CPU affinity) on the hall's links and on a
grid of receivers over its floor, the parallel efficiency, the serial part of a trace over worker
processes (checks, pool start-up for the first pool of an interpreter and for a kept one, joining
the chunks) and the Amdahl bound it implies for 16 cores.
Not a test: it prints figures to quote, it asserts nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from raytrace import TraceConfig, load_scene, trace
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.scene.metadata import SceneMetadata


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
    inp = SceneMetadata.from_scene(scene, require=True)  # one-line SceneError if it has none
    tx, rx = inp.bs_xyz, inp.point_xyz
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
    routes = routes_from_metadata(scene.metadata)
    if not routes or n <= 0:
        return {}
    inp = SceneMetadata.from_scene(scene, require=True)
    tx, rx = inp.bs_xyz, inp.point_xyz
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


#: Cores of the Amdahl extrapolation.
AMDAHL_CORES = 16


@contextlib.contextmanager
def _cores(n: int):
    """Run the block on the first ``n`` cores of this process's affinity (Linux), then restore."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, sorted(before)[:n])
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


# A pool's start-up (scene sent, Embree rebuilt) is timed with the job ``operator.is_(scene,
# item)``: it does nothing, and the workers have it without importing this script (a job is sent
# by reference, and the workers do not import ``__main__``).
_COLD_START = """
import operator, time
def main():
    from raytrace import load_scene
    from raytrace.solver.parallel import ScenePool, close_pools
    scene = load_scene({scene!r})
    t0 = time.perf_counter()
    # the kept pool of lanes - 1 workers; with as many items as lanes this process takes the
    # last one and the workers the others: done when each worker has answered
    list(ScenePool(scene, {lanes}).map(operator.is_, range({lanes})))
    print(time.perf_counter() - t0)
    close_pools()
if __name__ == "__main__":
    main()
"""


def _pool_start(scene_name: str, lanes: int, repeat: int) -> dict:
    """Seconds until the ``lanes - 1`` workers of a pool answer: the first pool of a fresh
    interpreter (fork server started, its imports; best of ``repeat`` interpreters), and a kept
    pool taken again for the same scene (the scene pickled and compared)."""
    import operator
    import subprocess

    from raytrace.solver.parallel import ScenePool

    code = _COLD_START.format(scene=scene_name, lanes=lanes)
    cold = min(
        float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True).stdout.split()[-1])  # fmt: skip
        for _ in range(repeat)
    )
    scene = load_scene(scene_name)
    kept = np.inf
    for _ in range(repeat + 1):  # the first one starts the pool
        t0 = time.perf_counter()
        list(ScenePool(scene, lanes).map(operator.is_, range(lanes)))
        kept = min(kept, time.perf_counter() - t0) if _ else np.inf
    return {"pool_start_first_s": cold, "pool_start_kept_s": kept}


def _serial_parts(scene, tx, rx, f, cfg) -> dict:
    """Seconds spent outside the chunks' tracing: the input checks, joining the chunks' paths."""
    from raytrace.solver.tracer import check_distinct, check_positions, join_chunks, trace_chunks

    t0 = time.perf_counter()
    # what trace() checks before it traces (tracer._checked: the positions, then their distance)
    check_distinct(
        check_positions(scene, tx, "transmitter"), check_positions(scene, rx, "receiver")
    )
    t1 = time.perf_counter()
    parts = [p for _, p in trace_chunks(scene, tx, rx, f, cfg, workers=1)]
    t2 = time.perf_counter()
    joined = join_chunks(parts, len(tx))  # what trace() does with the chunks
    t3 = time.perf_counter()
    del joined
    # the same join again: what it costs without first touches of fresh memory (which a virtual
    # machine can make dear); the serial fraction keeps the first, as trace() meets it
    t4 = time.perf_counter()
    join_chunks(parts, len(tx))
    t5 = time.perf_counter()
    return {"check_s": t1 - t0, "join_s": t3 - t2, "join_repeat_s": t5 - t4}


def _lane_busy(scene, tx, rx, f, cfg) -> dict:
    """One trace on 2 lanes (a kept pool): its wall time, and the time each lane spent on its
    chunks (the tracer's ``busy_us`` counters); the rest of a lane's wall time is idle (the
    worker: waiting for its next chunk while its last result crosses to this process) or, in
    this process, the join."""
    st: dict = {}
    t0 = time.perf_counter()
    trace(scene, tx, rx, f, cfg, workers=2, stats=st)
    wall = time.perf_counter() - t0
    caller, workers = st.get("busy_us[caller]", 0) / 1e6, st.get("busy_us[workers]", 0) / 1e6
    return {"wall_s": round(wall, 4), "caller_busy_s": round(caller, 4),
            "worker_busy_s": round(workers, 4), "worker_idle_s": round(max(wall - workers, 0.0), 4)}  # fmt: skip


def _amdahl(serial_fraction: float, n: int = AMDAHL_CORES) -> float:
    """Parallel efficiency on ``n`` cores by Amdahl's law: ``1 / (n s + 1 - s)``."""
    s = min(max(serial_fraction, 0.0), 1.0)
    return 1.0 / (n * s + 1.0 - s)


def bench_scaling(scene_name: str, repeat: int, grid_step: float) -> dict:
    """Links/s and paths/s at 1, 2 and all cores on the hall's links and on a grid over its
    floor (all mechanisms, depth 2), the parallel efficiency, and the serial fraction."""
    from raytrace.solver.parallel import cpu_count
    from raytrace.studies.accuracy_map import MapSettings, make_grid

    scene = load_scene(scene_name)
    inp = SceneMetadata.from_scene(scene, require=True)
    grid = make_grid(scene, MapSettings(step_m=grid_step), inp.point_names, inp.point_xyz)
    cfg, f = TraceConfig(), 3.775e9
    n_all = cpu_count()
    counts = sorted({1, min(2, n_all), n_all})
    out = {"cores_available": n_all, "load_average": list(os.getloadavg()), "workloads": {}}
    starts = _pool_start(scene_name, 2, repeat) if n_all >= 2 else {}
    for name, rx in (("hall", inp.point_xyz), (f"grid_{grid_step:g}m", grid.cell_xyz)):
        links = len(inp.bs_xyz) * len(rx)
        rows = {}
        for n in counts:
            with _cores(n):
                for mode, kw in (("processes", {"workers": n}), ("default", {})):
                    best, paths = _best_of(
                        lambda kw=kw, rx=rx: trace(scene, inp.bs_xyz, rx, f, cfg, **kw), repeat
                    )
                    rows[f"{mode}@{n}"] = {
                        "cores": n,
                        "seconds": round(best, 4),
                        "links_per_s": round(links / best, 1),
                        "paths_per_s": round(paths.n_paths / best, 0),
                    }
        t1 = rows["processes@1"]["seconds"]
        for r in rows.values():
            r["speedup"] = round(t1 / r["seconds"], 3)
            r["efficiency"] = round(t1 / r["seconds"] / r["cores"], 3)
        entry = {"links": links, "paths": paths.n_paths, "runs": rows}
        if n_all >= 2:
            entry["lanes"] = _lane_busy(scene, inp.bs_xyz, rx, f, cfg)
            ser = {**_serial_parts(scene, inp.bs_xyz, rx, f, cfg), **starts}
            s_fit = 2.0 * rows["processes@2"]["seconds"] / t1 - 1.0  # t2 = t1 (s + (1 - s) / 2)
            entry["serial"] = {k: round(v, 4) for k, v in ser.items()}
            entry["serial"]["serial_fraction_from_1_vs_2"] = round(s_fit, 4)
            entry["serial"][f"amdahl_efficiency_{AMDAHL_CORES}_from_1_vs_2"] = round(_amdahl(s_fit), 3)
            for when in ("first", "kept"):
                start = ser[f"pool_start_{when}_s"]
                s_meas = (ser["check_s"] + ser["join_s"] + start) / (t1 + start)
                entry["serial"][f"serial_fraction_{when}"] = round(s_meas, 4)
                entry["serial"][f"amdahl_efficiency_{AMDAHL_CORES}_{when}"] = round(_amdahl(s_meas), 3)
        out["workloads"][name] = entry
    return out


def _print_scaling(sc: dict) -> None:
    print(
        f"scaling over cores ({sc['cores_available']} available, load average "
        f"{', '.join(f'{v:.1f}' for v in sc['load_average'])} at the start):"
    )
    for name, w in sc["workloads"].items():
        print(f"  {name}: {w['links']} links, {w['paths']} paths")
        for key, r in w["runs"].items():
            print(
                f"    {key:<12} {r['seconds']:8.3f} s {r['links_per_s']:9.1f} links/s "
                f"{r['paths_per_s']:10.0f} paths/s  speed-up {r['speedup']:.2f} "
                f"efficiency {r['efficiency']:.2f}"
            )
        la = w.get("lanes")
        if la:
            print(
                f"    one trace on 2 lanes: {la['wall_s']:.3f} s; busy on their chunks: this "
                f"process {la['caller_busy_s']:.3f} s, the worker {la['worker_busy_s']:.3f} s "
                f"(idle {la['worker_idle_s']:.3f} s)"
            )
        s = w.get("serial")
        if s:
            print(
                f"    serial part with 2 workers: checks {s['check_s']:.3f} s, join "
                f"{s['join_s']:.3f} s ({s['join_repeat_s']:.3f} s repeated), pool start {s['pool_start_first_s']:.3f} s (first pool of "
                f"the interpreter) / {s['pool_start_kept_s']:.3f} s (kept pool) -> serial "
                f"fraction {s['serial_fraction_first']:.3f} / {s['serial_fraction_kept']:.3f}, "
                f"{s['serial_fraction_from_1_vs_2']:.3f} from 1 vs 2 workers; Amdahl efficiency "
                f"on {AMDAHL_CORES} cores {s[f'amdahl_efficiency_{AMDAHL_CORES}_first']:.2f} / "
                f"{s[f'amdahl_efficiency_{AMDAHL_CORES}_kept']:.2f} / "
                f"{s[f'amdahl_efficiency_{AMDAHL_CORES}_from_1_vs_2']:.2f}"
            )


def bench_positioning(n_epochs: int) -> dict:
    """Fixes per second of every positioning method: ``tools/bench_positioning.py N --json``'s
    speed figures (run as a maintainer runs it), or ``{"error": ...}``."""
    import subprocess

    script = Path(__file__).resolve().parent / "bench_positioning.py"
    proc = subprocess.run([sys.executable, str(script), str(n_epochs), "--json", "--speed-only"],
                          capture_output=True, text=True)  # fmt: skip
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"]
        return {"error": lines[-1]}
    return json.loads(proc.stdout)["speed"]


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall", help="scene file or 'hall' [hall]")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing, best kept [3]")
    ap.add_argument(
        "--epochs", type=int, default=20000, help="epochs for the positioning benchmark"
    )
    ap.add_argument(
        "--snapshots",
        type=int,
        default=4,
        help="forklift snapshots for the incremental-retrace benchmark (0: skip)",
    )
    ap.add_argument("--grid-step", type=float, default=2.0, help="grid of the scaling runs, m")
    scaling = ap.add_mutually_exclusive_group()
    scaling.add_argument("--no-scaling", action="store_true", help="skip the scaling over cores")
    scaling.add_argument("--only-scaling", action="store_true", help="only the scaling over cores")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    ap.add_argument(
        "--scene-scale",
        metavar="MAX_TRIANGLES",
        type=float,
        help="only the scene-scale section (tools/bench_scale.py): the hall plus generated "
        "machines up to this many triangles",
    )
    return ap


def check_args(args: argparse.Namespace) -> None:
    """Refuse meaningless settings before any work (a one-line :class:`HallrayError`)."""
    if args.repeat < 1:
        raise HallrayError(f"--repeat must be >= 1, got {args.repeat}")
    if args.epochs < 1:
        raise HallrayError(f"--epochs must be >= 1, got {args.epochs}")
    if args.snapshots < 0:
        raise HallrayError(f"--snapshots must be >= 0 (0: skip), got {args.snapshots}")
    if not (np.isfinite(args.grid_step) and args.grid_step > 0):
        raise HallrayError(
            f"--grid-step must be a positive number of metres, got {args.grid_step:g}"
        )


def _main(args: argparse.Namespace) -> int:
    check_args(args)
    if args.scene_scale is not None:  # its own tool, one fresh process per scene
        cmd = [sys.executable, str(Path(__file__).with_name("bench_scale.py")),
               "--max-triangles", repr(args.scene_scale)] + (["--json"] if args.json else [])  # fmt: skip
        return subprocess.call(cmd)
    if args.only_scaling:
        sc = bench_scaling(args.scene, args.repeat, args.grid_step)
        if args.json:
            print(json.dumps(sc, indent=1))
        else:
            _print_scaling(sc)
        return 0
    res = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "trace": bench_trace(args.scene, args.repeat),
        "snapshots": bench_snapshots(args.scene, args.snapshots),
        "positioning": bench_positioning(args.epochs),
        "scaling": {}
        if args.no_scaling
        else bench_scaling(args.scene, args.repeat, args.grid_step),
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
    if res["scaling"]:
        _print_scaling(res["scaling"])
    pos = res["positioning"]
    if "error" in pos:
        print(f"positioning: {pos['error']}")
    else:
        print("positioning (fixes per second, batched):")
        for k, v in pos.items():
            print(f"  {k}: {v:.1f}" if v < 100 else f"  {k}: {v:.0f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
