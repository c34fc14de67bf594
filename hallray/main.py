"""The ``hallray`` command: one entry point for every tool of the project.

``hallray SUBCOMMAND [options]`` runs the tool's own entry point with the options after the
subcommand, so a subcommand takes exactly the options of the command it stands for and gives the
same one-line errors and exit statuses (:mod:`hallray.harness`); only the program name in its
usage line reads ``hallray SUBCOMMAND``. ``hallray --help`` lists the subcommands; it imports
neither package (the tools' modules load numba kernels and Embree, seconds of work), so it
answers at once. The old console-script names (``trace-scene``, ``make-dataset``, ...) call the
same functions.

Only this module (with ``hallray.cli``) may import :mod:`raytrace` and :mod:`positioning`
among hallray's modules, and no module may import it (``tools/check_layers.py``).
"""

from __future__ import annotations

import difflib
import importlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .harness import EXIT_BAD_INPUT, EXIT_OK, command_name


@dataclass(frozen=True)
class Subcommand:
    """One subcommand: the entry point it runs (``module:function``, a ``main(argv) -> int``),
    the console script of the same tool, and a line for ``hallray --help``."""

    name: str
    target: str
    script: str
    summary: str

    def entry(self) -> Callable[[Sequence[str] | None], int]:
        """The tool's entry point (imports its module: the first call may take seconds)."""
        module, function = self.target.split(":")
        return getattr(importlib.import_module(module), function)


#: The subcommands in the order of the main job, then the hall and scene tools.
SUBCOMMANDS: tuple[Subcommand, ...] = (
    Subcommand("paper", "raytrace.cli.reproduce_paper:reproduce_paper_main", "reproduce-paper",
               "the main job: datasets, maps, Table II beside the paper's, findings"),
    Subcommand("trace", "raytrace.cli.trace_scene:trace_scene_main", "trace-scene",
               "trace a scene: paths of all links, per-link table, paths file"),
    Subcommand("dataset", "raytrace.cli.make_dataset:make_dataset_main", "make-dataset",
               "ToA datasets (static / semi-dynamic, a band, a receiver)"),
    Subcommand("positions", "positioning.cli.estimate:estimate_positions_main",
               "estimate-positions", "position every epoch of a ToA dataset (fixes.csv)"),
    Subcommand("report", "positioning.cli.accuracy:accuracy_report_main", "accuracy-report",
               "Table II, integrity, CDFs and top views for ToA datasets"),
    Subcommand("map", "raytrace.cli.accuracy_map:accuracy_map_main", "accuracy-map",
               "accuracy / fingerprint map of a hall's floor (npz, csv, heatmaps)"),
    Subcommand("view", "raytrace.cli.view:view_main", "hallray-view",
               "interactive 3D view of a scene and its paths in one offline HTML page"),
    Subcommand("render", "raytrace.cli.render_scene:render_scene_main", "render-scene",
               "top and perspective pictures of a scene and its paths (PNG)"),
    Subcommand("export", "raytrace.cli.export_scene:export_scene_main", "hallray-export",
               "Mitsuba 3 / Sionna RT scene XML with PLY meshes and radio materials"),
    Subcommand("scan", "raytrace.cli.scan_to_scene:scan_to_scene_main", "scan-to-scene",
               "point cloud -> traceable hall mesh with materials"),
    Subcommand("build-hall", "raytrace.cli.build_hall:build_hall_main", "build-hall",
               "hall YAML -> hall mesh (GLB)"),
    Subcommand("make-hall", "raytrace.cli.make_hall:make_hall_main", "make-hall",
               "synthetic 3GPP TR 38.901 indoor-factory hall"),
    Subcommand("los-check", "raytrace.cli.make_hall:hall_los_check_main", "hall-los-check",
               "line of sight of generated halls against 3GPP's model"),
    Subcommand("sweep", "raytrace.cli.run_sweep:run_sweep_main", "run-sweep",
               "the pipeline over a grid of halls, seeds, bands and estimators"),
)

#: Subcommand by name; the old console-script names are accepted too (``hallray trace-scene``).
BY_NAME: dict[str, Subcommand] = {
    **{s.script: s for s in SUBCOMMANDS},
    **{s.name: s for s in SUBCOMMANDS},
}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("hallray")
    except PackageNotFoundError:  # a checkout on sys.path, not installed
        return "unknown"


def usage() -> str:
    """The text of ``hallray --help``."""
    width = max(len(s.name) for s in SUBCOMMANDS)
    rows = "\n".join(f"  {s.name:<{width}}  {s.summary}" for s in SUBCOMMANDS)
    return (
        "usage: hallray [--help] [--version] SUBCOMMAND [options]\n\n"
        "Ray tracing of industrial halls and 5G TDoA positioning.\n\n"
        f"subcommands:\n{rows}\n\n"
        "'hallray SUBCOMMAND --help' shows a subcommand's options. The tools keep their own\n"
        "names too (reproduce-paper, trace-scene, make-dataset, ...): 'hallray paper' and\n"
        "'reproduce-paper' are the same command.\n"
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``hallray``; returns the exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print(usage(), end="", file=sys.stderr)
        print("error: missing SUBCOMMAND", file=sys.stderr)
        return EXIT_BAD_INPUT
    first = args[0]
    if first in ("-h", "--help"):
        print(usage(), end="")
        return EXIT_OK
    if first == "--version":
        print(f"hallray {_version()}")
        return EXIT_OK
    if first == "help":  # hallray help [SUBCOMMAND]
        return main([args[1], "--help"] if len(args) > 1 else ["--help"])
    sub = BY_NAME.get(first)
    if sub is None:
        near = difflib.get_close_matches(first, list(BY_NAME), n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        what = "option" if first.startswith("-") else "subcommand"
        print(f"error: unknown {what} {first!r}{hint}; 'hallray --help' lists the subcommands",
              file=sys.stderr)  # fmt: skip
        return EXIT_BAD_INPUT
    try:
        entry = sub.entry()
    except ImportError as exc:  # an optional extra missing, or a broken install
        print(f"error: hallray {sub.name} cannot start: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    with command_name(f"hallray {sub.name}"):
        return int(entry(args[1:]))


if __name__ == "__main__":
    raise SystemExit(main())
