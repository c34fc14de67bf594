"""Time and memory of scan-to-scene on a simulated scan of the bundled hall (needs open3d).

    python tools/bench_scan.py                 # about one million points (the default)
    python tools/bench_scan.py --points 300000 --json

A scan of the hall is simulated (``raytrace.halls.scan.simulate_scan``: 16 stations, 2 cm noise, 30
drop-out holes) until it holds the requested number of points, written as a .ply, and
reconstructed in a fresh process with the default options; the report has the wall time per
stage, the peak resident memory of that process (``resource.getrusage``: open3d's C++ memory
included) and the peak of Python's own allocations (``tracemalloc``: numpy arrays included,
open3d's not).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError

#: Fewest points asked for: fewer may leave the simulated scan empty. The reconstruction needs
#: far more (20000 are too few: scan-to-scene finds no plane and says so in one line).
MIN_POINTS = 1000

CHILD = """
import json, resource, sys, time, tracemalloc
from raytrace.core.errors import HallrayError
from raytrace.halls.scan import ScanOptions, scan_to_scene
tracemalloc.start()
t0 = time.perf_counter()
try:
    s = scan_to_scene({cloud!r}, {out!r}, ScanOptions())
except HallrayError as exc:  # a cloud it cannot reconstruct: one line, as the parent prints it
    sys.exit(f"error: {{exc}}")
wall = time.perf_counter() - t0
_, py_peak = tracemalloc.get_traced_memory()
rss_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
s.pop("elements", None)
print(json.dumps({{"summary": s, "wall_s": wall, "peak_rss_mib": rss_kib / 1024,
                  "peak_python_mib": py_peak / 2**20}}))
"""


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("--points", type=int, default=1_000_000, help="points in the cloud [1e6]")
    p.add_argument("--seed", type=int, default=11, help="seed of the simulated scan [11]")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    return p


def _main(args: argparse.Namespace) -> int:
    if args.points < MIN_POINTS:
        raise HallrayError(f"--points must be >= {MIN_POINTS}, got {args.points}")
    try:
        import open3d as o3d
    except ImportError:
        raise HallrayError("bench_scan.py needs open3d (pip install '.[scan]')") from None
    import numpy as np

    from raytrace.halls.scan import simulate_scan
    from raytrace.scene.io import load_scene

    hall = load_scene("hall")
    t0 = time.perf_counter()
    # about 42 % of the points drawn on the hall's triangles are seen from inside
    draw = int(args.points / 0.42)
    pts = simulate_scan(hall, draw, noise_m=0.02, n_gaps=30, seed=args.seed)
    while len(pts) < args.points:
        draw = int(draw * 1.1 * args.points / len(pts))
        pts = simulate_scan(hall, draw, noise_m=0.02, n_gaps=30, seed=args.seed)
    pts = pts[np.random.default_rng(args.seed).permutation(len(pts))[: args.points]]
    t_sim = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        cloud = str(Path(tmp) / "hall.ply")
        o3d.io.write_point_cloud(cloud, o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)))
        code = CHILD.format(cloud=cloud, out=str(Path(tmp) / "hall.glb"))
        res = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=False
        )
    if res.returncode:
        sys.stderr.write(res.stderr)  # the child's one-line error, or its traceback (a bug)
        return 2 if res.stderr.startswith("error: ") else res.returncode
    r = json.loads(res.stdout.strip().splitlines()[-1])
    r["points"] = len(pts)
    r["simulate_s"] = round(t_sim, 2)
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    s = r["summary"]
    print(f"cloud      {len(pts)} points (simulated in {t_sim:.1f} s)")
    print(
        f"wall time  {r['wall_s']:.1f} s (read + reconstruct + write), stages: "
        + ", ".join(f"{k[:-2]} {v:.1f} s" for k, v in s["time_s"].items())
    )
    print(
        f"memory     peak RSS {r['peak_rss_mib']:.0f} MiB, "
        f"peak Python allocations {r['peak_python_mib']:.0f} MiB"
    )
    print(
        f"result     {s['planes']} planes ({s['bounding_planes']} bounding), {s['objects']} objects, "
        f"{s['triangles']} triangles, residual mean {s['residual_mean_m'] * 100:.1f} cm, "
        f"p95 {s['residual_p95_m'] * 100:.1f} cm"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
