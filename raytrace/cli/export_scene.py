"""``hallray-export SCENE -o DIR/scene.xml``: a scene as Mitsuba 3 / Sionna RT XML.

Writes ``DIR/scene.xml`` (one ``ply`` shape per object, one radio-material BSDF per material),
``DIR/meshes/*.ply`` and ``DIR/scene.hallray.json`` (base stations, points, exact materials,
object names: :mod:`raytrace.scene.mitsuba`). ``DIR`` is built in a temporary directory beside
it and renamed when complete: bad input or an interruption leaves nothing. Bad input: one line
``error: ...`` on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from ..core.errors import HallrayError
from .harness import OneLineParser, add_scene_arguments, run_tool, scene_options


def parser() -> argparse.ArgumentParser:
    """The parser of ``hallray-export`` (also used by ``hallray export``)."""
    p = OneLineParser(
        prog="hallray-export",
        description=(
            "Write a scene as Mitsuba 3 / Sionna RT scene XML, to run Sionna RT on the same hall. "
            "-o DIR/NAME.xml writes the directory DIR: NAME.xml (one <shape type='ply'> per "
            "object; built-in ITU-R P.2040 materials as itu-radio-material with their type and "
            "thickness, other materials as radio-material with relative permittivity, "
            "conductivity and thickness), meshes/*.ply, and NAME.hallray.json (the base "
            "stations, points and other metadata, the exact materials and the object names, "
            "which Mitsuba XML has no place for). Reading DIR/NAME.xml back (trace-scene, "
            "render-scene, ...) gives the same scene. SCENE is a mesh file, a Mitsuba/Sionna "
            "XML or 'hall'. See docs/view.md."
        ),
    )
    add_scene_arguments(p)
    p.add_argument("-o", "--output", required=True, metavar="DIR/NAME.xml",
                   help="the XML to write; its directory DIR is the export (created whole)")  # fmt: skip
    p.add_argument("--band", default="c-band",
                   help="band whose centre frequency frequency-dependent non-ITU materials are "
                   "evaluated at for Sionna (their exact power law stays in the sidecar) "
                   "[c-band]")  # fmt: skip
    p.add_argument("--frequency-hz", type=float,
                   help="that reference frequency in Hz (overrides --band)")  # fmt: skip
    p.add_argument("--force", action="store_true",
                   help="kept for compatibility: an earlier export is replaced anyway, a "
                   "directory with other files never")  # fmt: skip
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    return p


def export_scene_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``hallray-export``; returns the exit status."""
    return run_tool(main, parser(), argv, interrupted="interrupted (nothing written)")


#: The name an export's marker records (:func:`hallray.safe_output.write_marker`).
EXPORT_COMMAND = "hallray-export"


def main(args: argparse.Namespace) -> int:
    """``hallray-export``: parse -> load -> export into a temporary directory -> rename."""
    from hallray.safe_output import check_output_dir, output_dir

    from ..emulation.bands import get_band
    from ..scene.bundled import resolve_scene
    from ..scene.io import load_scene
    from ..scene.mitsuba import export_mitsuba

    t0 = time.perf_counter()
    xml = Path(args.output)
    if xml.suffix.lower() != ".xml":
        raise HallrayError(f"output {args.output} must be DIR/NAME.xml")
    folder = xml.parent
    if folder.resolve() == Path.cwd().resolve() or str(folder) in ("", "."):
        raise HallrayError(
            f"output {args.output}: name a directory for the export (DIR/{xml.name}); it is "
            "written whole, with meshes/ and the sidecar beside the XML"
        )
    if args.frequency_hz is not None:
        freq = float(args.frequency_hz)
        if not (freq > 0 and freq < float("inf")):
            raise HallrayError(f"--frequency-hz must be a positive number, got {freq:g}")
    else:
        freq = float(get_band(args.band).center_frequency_hz)
    inputs = [resolve_scene(args.scene), args.materials]
    check_output_dir(folder, command=EXPORT_COMMAND, inputs=inputs, force=args.force,
                     replace_previous=True)  # fmt: skip
    tty = not args.quiet and sys.stderr.isatty()  # progress lines for a person at a terminal
    if tty:
        print(f"loading {args.scene}...", file=sys.stderr, flush=True)
    scene = load_scene(args.scene, args.materials, **scene_options(args))
    if tty:
        print(f"writing {len(scene.objects)} meshes...", file=sys.stderr, flush=True)
    bar = None
    if tty and len(scene.objects) >= 200:
        from tqdm import tqdm

        bar = tqdm(total=len(scene.objects), desc="meshes", unit="mesh", leave=False)
    try:
        with output_dir(folder, command=EXPORT_COMMAND, force=args.force, inputs=inputs,
                        replace_previous=True) as tmp:  # fmt: skip
            result = export_mitsuba(
                scene, tmp / xml.name, frequency_hz=freq,
                progress=(lambda k, n: bar.update(1)) if bar is not None else None,
            )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        kinds = {b.bsdf_type for b in result.bsdfs}
        print(
            f"wrote {folder}/: {xml.name}, {len(result.meshes)} meshes in meshes/, "
            f"{result.sidecar.name}; {result.n_triangles} triangles, {len(result.bsdfs)} "
            f"materials ({', '.join(sorted(kinds))}) in {time.perf_counter() - t0:.1f} s"
        )
        for name in result.frequency_dependent:
            print(f"  {name}: frequency-dependent, written for Sionna at {freq / 1e9:.6g} GHz")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(export_scene_main())
