"""``scan-to-scene CLOUD -o SCENE.glb``: a laser scan (point cloud) to a traceable scene.

Thin: parse, call :func:`raytrace.halls.scan.scan_to_scene`, print the summary. Bad input of any kind
is a one-line ``error: ...`` on stderr and exit status 2, and no output file.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

from .harness import OneLineParser, run_tool

#: The reconstruction options: flag, ScanOptions field, type, help (the default is appended).
_OPTIONS: tuple[tuple[str, str, type, str], ...] = (
    ("--voxel", "voxel_size_m", float, "voxel size, m"),
    (
        "--plane-distance",
        "plane_distance_m",
        float,
        "RANSAC inlier distance, m (about 2.5 x the scan noise)",
    ),
    ("--plane-min-points", "plane_min_points", int, "smallest plane, points after downsampling"),
    ("--plane-min-area", "plane_min_area_m2", float, "smallest plane piece kept as a polygon, m^2"),
    ("--max-planes", "max_planes", int, "most planes extracted"),
    (
        "--simplify",
        "simplify_m",
        float,
        "outline simplification tolerance, m (default 1.5 voxels); larger: fewer triangles",
    ),
    (
        "--wall-thickness",
        "wall_thickness_m",
        float,
        "floor, ceiling and outer walls become slabs this thick (0: sheets), m",
    ),
    ("--decimate", "max_object_triangles", int, "at most N triangles per object (hull, mesh)"),
    ("--box-fill", "box_fill", float, "split a cluster's box while it is filled less than this"),
    ("--object-min-points", "object_min_points", int, "smallest cluster turned into an object"),
    ("--seed", "seed", int, "random seed"),
)


def scan_to_scene_parser() -> argparse.ArgumentParser:
    from ..halls.scan.options import OBJECT_MODES, ScanOptions

    d = ScanOptions()
    p = OneLineParser(
        prog="scan-to-scene",
        description=(
            "Reconstruct a point cloud (.ply .pcd .xyz .pts, .las/.laz with laspy) into a "
            "traceable scene: planar polygons for the large planes (floor, ceiling and walls as "
            "closed slabs), boxes or meshes for the rest, materials by rules. Needs open3d "
            "(pip install 'hallray[scan]'). See docs/scan.md."
        ),
    )
    p.add_argument("cloud", help="point cloud file")
    p.add_argument("-o", "--output", required=True, help="output scene (.glb)")
    for flag, name, kind, text in _OPTIONS:
        default = getattr(d, name)
        shown = "" if default is None else f" [{default}]"
        metavar = "N" if flag == "--decimate" else flag[2:].upper().replace("-", "_")
        p.add_argument(flag, dest=name, type=kind, default=default, metavar=metavar,
                       help=text + shown)  # fmt: skip
    p.add_argument(
        "--objects",
        choices=OBJECT_MODES,
        default=d.objects,
        help="what the clusters left after the planes become: upright boxes, convex hulls, "
        f"decimated alpha-shape meshes, or nothing [{d.objects}]",
    )
    p.add_argument(
        "--materials",
        metavar="RULES.yaml",
        help="material rules (materials, rules, default; see docs/scan.md)",
    )
    p.add_argument(
        "--positions",
        metavar="FILE",
        help="base_stations and points to store in the scene (YAML/JSON, a hall YAML, or a GLB)",
    )
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--elements", action="store_true", help="list every plane and object")
    return p


def scan_to_scene_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``scan-to-scene``."""
    return run_tool(_scan_to_scene, scan_to_scene_parser(), argv)


def _scan_to_scene(args: argparse.Namespace) -> int:
    from ..halls.scan.options import ScanOptions
    from ..halls.scan.write import scan_to_scene

    opt = ScanOptions(
        objects=args.objects, **{name: getattr(args, name) for _, name, _, _ in _OPTIONS}
    )
    from hallray.safe_output import check_output

    check_output(args.output, inputs=[args.cloud, args.materials, args.positions])
    summary = scan_to_scene(
        args.cloud, args.output, opt, rules=args.materials, positions=args.positions
    )
    if args.json:
        if not args.elements:
            summary = {k: v for k, v in summary.items() if k != "elements"}
        print(json.dumps(summary, indent=1))
        return 0
    _print_summary(summary, args.elements)
    return 0


def _print_summary(s: dict[str, Any], elements: bool) -> None:
    mats = ", ".join(f"{k} ({v})" for k, v in s["materials"].items())
    print(f"wrote {s['output']}: {s['triangles']} triangles, {s['bytes']} bytes")
    print(
        f"points     {s['input_points']} read, {s['downsampled_points']} after downsampling, "
        f"{s['outliers_removed']} outliers removed, {s['points_used']} used"
    )
    print(
        f"planes     {s['planes']} ({s['bounding_planes']} bounding: floor, ceiling, walls), "
        f"{s['plane_points']} points"
    )
    print(f"objects    {s['objects']}, {s['object_points']} points")
    print(f"unexplained {s['unexplained_points']} points (small clusters, noise)")
    print(f"materials  {mats}")
    print(
        f"residual   distance of the points to the mesh: mean {s['residual_mean_m'] * 100:.1f} cm, "
        f"p95 {s['residual_p95_m'] * 100:.1f} cm (noise estimate {s['noise_estimate_m'] * 100:.1f} cm)"
    )
    t = s["time_s"]
    print("time       " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in t.items()))
    if elements:
        print(f"\n{'name':<32} {'kind':<6} {'points':>7} {'tri':>5} {'area m2':>9} {'size m':>7}")
        for e in s["elements"]:
            print(
                f"{e['name']:<32} {e['kind']:<6} {e['points']:>7} {e['triangles']:>5} "
                f"{e['area_m2']:>9.2f} {e['size_m']:>7.2f}"
            )
