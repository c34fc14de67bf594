"""Figures for the README and docs (run from a checkout: ``python tools/make_figures.py``).

``docs/hall_paths.png``: the bundled hall (top view and perspective view) with three links traced
at C-band with the default settings: BS1 -> P07 (line of sight), BS3 -> P23 (blocked by the
machining centre: a diffraction over it arrives first, a reflection is the strongest) and
BS2 -> P06 (blocked by the gantry of line 2: diffraction first).

``--scan`` also writes ``docs/hall_scan.png``: the same links on a scene reconstructed by
``scan-to-scene`` from a simulated laser scan of the hall (1.2 million points drawn, 2 cm
noise; needs open3d).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from raytrace.cli.harness import OneLineParser, run_tool

ROOT = Path(__file__).resolve().parent.parent

LINKS = ["BS1,P07", "BS3,P23", "BS2,P06"]


def parser() -> argparse.ArgumentParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("--out-dir", default=str(ROOT / "docs"), help="where to write [docs/]")
    p.add_argument("--scan", action="store_true", help="also the reconstructed-scan figure")
    return p


def _main(args: argparse.Namespace) -> int:
    from raytrace.cli.render_scene import render_scene_main

    out = Path(args.out_dir)
    link_args = [a for link in LINKS for a in ("--link", link)]
    code = render_scene_main(
        ["hall", "-o", str(out / "hall_paths.png"), "--title", "Reference hall: paths of three links",
         *link_args]
    )  # fmt: skip
    if code or not args.scan:
        return code
    import numpy as np  # noqa: F401  (the scan needs numpy and open3d)

    from raytrace.halls.scan import ScanOptions, scan_to_scene, simulate_scan
    from raytrace.scene.io import load_scene

    hall = load_scene("hall")
    pts = simulate_scan(hall, 1_200_000, noise_m=0.02, n_gaps=30, seed=11)
    with tempfile.TemporaryDirectory() as tmp:
        cloud = Path(tmp) / "hall_scan.xyz"
        np.savetxt(cloud, pts, fmt="%.4f")
        glb = Path(tmp) / "hall_scan.glb"
        summary = scan_to_scene(cloud, glb, ScanOptions(), positions=hall.source)
        title = (
            f"Reference hall from a simulated laser scan ({summary['planes']} planes, "
            f"{summary['objects']} objects)"
        )
        code = render_scene_main(
            [str(glb), "-o", str(out / "hall_scan.png"), "--title", title, *link_args]
        )
    return code


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
