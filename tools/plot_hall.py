#!/usr/bin/env python
"""Draw the top view of a hall (default: the reference hall) as a PNG.

    python tools/plot_hall.py                       # scenes/hall.yaml -> docs/hall_top.png
    python tools/plot_hall.py my_hall.yaml -o my_hall.png
    python tools/plot_hall.py scenes/hall.glb -o hall.png   # from a built GLB's metadata

Obstacles are coloured by material, base stations are triangles, points of interest numbered red
squares, the area of interest a dashed green rectangle, forklift routes dashed arrows.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import trimesh

from hallray.safe_output import check_output
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.core.fileio import write_atomic
from raytrace.halls.spec import load_hall_spec
from raytrace.scene.metadata import SceneMetadata
from raytrace.viz.topview import plot_top_view

ROOT = Path(__file__).resolve().parent.parent

#: Area names drawn on the reference hall's plan (x, y in m).
REFERENCE_LABELS = {
    "line 1": (18.0, 1.8),
    "press": (30.0, 1.3),
    "robot cell C": (37.0, 0.4),
    "supermarket": (12.6, 11.8),
    "AGV st.": (17.5, 12.7),
    "line 2": (31.0, 11.3),
    "robot cell A": (32.5, 15.9),
    "robot cell B": (32.0, 28.3),
    "machining\ncentre": (27.4, 31.5),
    "workbenches": (12.6, 29.3),
    "pallets": (18.2, 34.9),
    "press ": (11.2, 35.0),
    "line 3": (21.0, 40.3),
    "office": (3.0, 41.0),
    "air tank": (39.8, 40.9),
    "pallet racks": (0.8, 11.3),
    "pallet racks ": (41.2, 11.3),
    "pallet stacks": (40.9, 7.0),
}


def parser() -> argparse.ArgumentParser:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("hall", nargs="?", default=str(ROOT / "scenes" / "hall.yaml"),
                        help="hall YAML or built GLB [scenes/hall.yaml]")  # fmt: skip
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "hall_top.png"),
                        help="PNG to write [docs/hall_top.png]")  # fmt: skip
    parser.add_argument("--dpi", type=int, default=150, help="resolution [150]")
    parser.add_argument("--labels", action="store_true", help="write object names on the plan")
    return parser


def _main(args: argparse.Namespace) -> int:
    if not 20 <= args.dpi <= 1200:  # as render-scene
        raise HallrayError(f"--dpi must be 20..1200, got {args.dpi}")
    check_output(args.output, inputs=[args.hall], what="-o")
    try:
        if args.hall.lower().endswith(".glb"):
            if not Path(args.hall).is_file():
                raise HallrayError(f"cannot read {args.hall}: not found")
            source = trimesh.load(args.hall, file_type="glb")
            if "hallray" not in source.metadata:
                raise HallrayError(f"{args.hall} has no hallray metadata")
            if SceneMetadata.from_metadata(source.metadata).hall_size is None:
                raise HallrayError(f"{args.hall} is not a hall: no hall size in its metadata")
        else:
            source = load_hall_spec(args.hall)
    except HallrayError:
        raise
    except ValueError as exc:  # a file trimesh cannot read
        raise HallrayError(f"{args.hall}: {exc}") from None
    meta = source.metadata["hallray"] if isinstance(source, trimesh.Scene) else None
    name = (meta or {}).get("name") if meta else source.name
    fig, ax = plt.subplots(figsize=(9.0, 8.4), layout="constrained")
    plot_top_view(ax, source, label_objects=args.labels)
    if name == "reference_hall":
        for text, (x, y) in REFERENCE_LABELS.items():
            ax.text(
                x,
                y,
                text,
                fontsize=6.5,
                ha="center",
                va="center",
                color="0.1",
                zorder=9,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7},
            )
    size = meta["hall"]["size"] if meta else source.size
    ax.set_title(f"{name}: {size[0]:g} m x {size[1]:g} m x {size[2]:g} m, top view", fontsize=10)
    ax.set_xticks(range(0, int(size[0]) + 1, 5))
    ax.set_yticks(range(0, int(size[1]) + 1, 5))
    ax.grid(color="0.85", lw=0.5, zorder=0)
    ax.set_axisbelow(True)
    buf = io.BytesIO()
    # fixed metadata: no software version or date in the PNG, so a rebuild gives the same bytes
    fig.savefig(buf, format="png", dpi=args.dpi, metadata={"Software": None})
    plt.close(fig)
    write_atomic(args.output, buf.getvalue())
    print(f"wrote {args.output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
