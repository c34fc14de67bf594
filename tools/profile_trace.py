#!/usr/bin/env python3
"""Where the time of a trace goes: cProfile of the hall's links on one thread, by stage and by
function.

Run from a checkout: ``python tools/profile_trace.py [--scene hall] [--grid-step M] [--top 25]``.
``--grid-step`` traces a grid of receivers over the floor (as ``accuracy-map``) instead of the
scene's points, in this process on one thread, chunk by chunk as a worker would (``trace`` would
send a large grid to worker processes, where cProfile does not see it). Prints each stage's time (the tracer's own ``time_us`` counters), then the
functions with the most time of their own, grouped by module (CPU time of this process, so that
other jobs on a shared machine do not inflate it; the stage counters are wall time). Not a test.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import time
from collections import defaultdict
from pathlib import Path

from raytrace import TraceConfig, load_scene, trace
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.scene.metadata import SceneMetadata
from raytrace.solver.parallel import receiver_chunks


def _module(file: str) -> str:
    """A short name for the module of a profiled function."""
    if "raytrace" in file:
        return Path(file).name
    if file == "~":
        return "C built-ins (numpy ufuncs, einsum, Embree calls)"
    for lib in ("numpy", "embree", "scipy"):
        if lib in file:
            return f"{lib} (Python)"
    return file


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall", help="scene file or 'hall' [hall]")
    ap.add_argument("--grid-step", type=float, default=None,
                    help="trace a grid of this step (m) over the floor instead of the points")  # fmt: skip
    ap.add_argument("--top", type=int, default=25, help="functions listed [25]")
    return ap


def _main(args: argparse.Namespace) -> int:
    if args.grid_step is not None and not (math.isfinite(args.grid_step) and args.grid_step > 0):
        raise HallrayError(
            f"--grid-step must be a positive number of metres, got {args.grid_step:g}"
        )
    if args.top < 1:
        raise HallrayError(f"--top must be >= 1, got {args.top}")
    scene = load_scene(args.scene)
    inp = SceneMetadata.from_scene(scene, require=True)
    rx = inp.point_xyz
    if args.grid_step:
        from raytrace.studies.accuracy_map import MapSettings, make_grid

        rx = make_grid(scene, MapSettings(step_m=args.grid_step), inp.point_names, rx).cell_xyz
    f, cfg = 3.775e9, TraceConfig()
    trace(scene, inp.bs_xyz, rx[:2], f, cfg, threads=1)  # warm caches (facets, wedges, Embree)
    stats: dict[str, int] = {}
    # CPU time, not wall time: on a shared machine the wall clock also counts other jobs' turns
    prof = cProfile.Profile(time.process_time)
    t0, c0 = time.perf_counter(), time.process_time()
    prof.enable()
    n_paths = 0
    for c in receiver_chunks(len(inp.bs_xyz), len(rx)):  # as a worker: chunks, one thread
        part = trace(scene, inp.bs_xyz, rx[c.start : c.stop], f, cfg, threads=1, stats=stats)
        n_paths += part.n_paths
    prof.disable()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n_links = len(inp.bs_xyz) * len(rx)
    print(f"{n_links} links, {n_paths} paths: {wall:.3f} s wall, {cpu:.3f} s CPU, one "
          "thread, under cProfile")  # fmt: skip
    print("stages (tracer counters, wall s):")
    stage_s = {k[8:-1]: v / 1e6 for k, v in stats.items() if k.startswith("time_us[")}
    for k, v in sorted(stage_s.items(), key=lambda kv: -kv[1]):
        print(f"  {k:<36} {v:7.3f}  {100 * v / wall:5.1f} %")
    ps = pstats.Stats(prof)
    print(f"{ps.total_calls} Python function calls ({ps.total_calls / n_links:.0f} per link)")  # type: ignore[attr-defined]
    by_module: dict[str, float] = defaultdict(float)
    rows = []
    for (file, line, func), (_, _, tottime, _, _) in ps.stats.items():  # type: ignore[attr-defined]
        mod = _module(file)
        by_module[mod] += tottime
        rows.append((tottime, f"{Path(file).name}:{line}({func})"))
    print("own CPU time by module (s):")
    for mod, v in sorted(by_module.items(), key=lambda kv: -kv[1])[:12]:
        print(f"  {mod:<44} {v:7.3f}  {100 * v / cpu:5.1f} %")
    print(f"top {args.top} functions by own CPU time (s):")
    for v, name in sorted(rows, reverse=True)[: args.top]:
        print(f"  {v:7.3f}  {name}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
