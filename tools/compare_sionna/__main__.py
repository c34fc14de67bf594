#!/usr/bin/env python3
"""Compare hallray with Sionna RT path by path on canonical wedges (issue 17; docs/fidelity.md).

A folder run as a program: its modules beside this file import each other by name.

    python tools/compare_sionna --help
    python tools/compare_sionna                        # every scene, markdown tables to stdout
    python tools/compare_sionna --out /tmp/cmp         # also report.md, results.npz, the scenes
    python tools/compare_sionna --scenes half_plane_soft --n-arc 24

What it does, for every canonical scene (built from code: ``sionna_canon.build_scenes``):

1. writes the geometry as PLY meshes plus one Mitsuba / Sionna RT scene XML with ITU-R P.2040
   radio materials; both tools load that same XML (hallray through ``raytrace.load_scene``);
2. runs Sionna RT in its own virtual environment (``--sionna-python``, default
   ``/tmp/sionna-venv/bin/python``; never a hallray dependency) through a small driver written to a
   temporary file, which saves its paths to ``.npz``; and hallray's ``trace`` in this process, on
   the same transmitter and receivers, with the same antennas (isotropic, vertical polarisation
   at both ends), mechanisms (line of sight, one reflection, one diffraction; no penetration) and
   materials;
3. matches the paths of the two tools by interaction type and vertex, and tabulates gain and
   phase differences per mechanism;
4. checks the total field of each tool (line of sight + reflections + the diffraction at the
   wedge's edge) for a jump at every shadow and reflection boundary of every sweep, and compares
   it, for the perfectly conducting wedges (corner and half-planes), with the exact solution for a
   point source (Biot-Tolstoy-Medwin, ``wedge_exact.wedge_exact``, checked there to satisfy the Helmholtz
   equation, the boundary conditions and continuity);
5. explains the diffraction differences with a numpy transcription of Sionna's diffraction matrix
   (``sionna_utd.sionna_diffraction_gain``, its source lines cited there), first checked against Sionna's own
   output, then changed one ingredient at a time into hallray's coefficient.

A maintainers' tool (docs/tools.md): not installed; Sionna RT is never a hallray dependency.
Sionna RT 2.2 needs an LLVM of version 16 or later for its CPU back end (Debian 12: ``apt-get
install libllvm19``; with LLVM 14 or 15, drjit stops with "Cannot select ... fmaximum").
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from sionna_analysis import SweepResult, analyse
from sionna_canon import Canon, build_scenes, write_scene
from sionna_paths import hallray_table, sionna_table
from sionna_report import table_boundaries, table_model, table_paths, table_truth
from sionna_run import DEFAULT_SIONNA_PYTHON, SionnaError, run_sionna
from wedge_exact import check_exact

from raytrace import TraceConfig, load_scene, trace
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.core.fileio import write_atomic


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(
        description="Compare hallray with Sionna RT path by path on canonical wedges (issue 17).")
    ap.add_argument("--sionna-python", default=os.environ.get("SIONNA_PYTHON", DEFAULT_SIONNA_PYTHON),
                    help="python of the venv with sionna-rt (default $SIONNA_PYTHON or "
                         f"{DEFAULT_SIONNA_PYTHON})")
    ap.add_argument("--frequency-hz", type=float, default=3.775e9)
    ap.add_argument("--scenes", default="all",
                    help="comma-separated subset of: metal_wedge, concrete_wedge, "
                         "half_plane_soft, half_plane_hard, wall (default all)")
    ap.add_argument("--n-arc", type=int, default=24,
                    help="receivers per sweep on the arc, besides 6 per boundary (default 24)")
    ap.add_argument("--delta-rad", type=float, default=3e-4,
                    help="spacing of the samples beside each boundary, rad (default 3e-4)")
    ap.add_argument("--elevation-m", type=float, default=3.0,
                    help="height of the source of the oblique sweeps above the receivers (m)")
    ap.add_argument("--solid-thickness-m", type=float, default=10.0,
                    help="slab thickness Sionna gives the concrete box (hallray: half-space for a "
                         "solid); default 10 m = half-space; 0.1 = Sionna's default")
    ap.add_argument("--samples", type=int, default=10**6, help="Sionna samples per source")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-checks", action="store_true",
                    help="skip the checks of the exact solution (Helmholtz residual etc.)")
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for report.md, results.npz and the exported scenes")
    ap.add_argument("--sionna-scenes", type=Path, default=None, metavar="DIR",
                    help="instead: Sionna RT's own canonical scenes in DIR (sionna-rt's "
                         "sionna/rt/scenes, or tests/data/sionna_rt), one link each, both tools "
                         "reading the same files (sionna_scenes.py)")
    return ap




def check_args(a: argparse.Namespace) -> None:
    """Refuse a missing Sionna, meaningless settings and an unusable --out before any work."""
    if not Path(a.sionna_python).is_file():
        raise SionnaError(f"no Sionna RT python at {a.sionna_python} (create the venv: "
                          "python3 -m venv /tmp/sionna-venv && /tmp/sionna-venv/bin/pip install "
                          "sionna-rt, or pass --sionna-python)")
    if not (np.isfinite(a.frequency_hz) and a.frequency_hz > 0):
        raise HallrayError("--frequency-hz must be positive")
    if a.n_arc < 3 or not (0 < a.delta_rad < 0.01):
        raise HallrayError("--n-arc must be >= 3 and 0 < --delta-rad < 0.01")
    if not (a.solid_thickness_m > 0):
        raise HallrayError("--solid-thickness-m must be positive")
    if not np.isfinite(a.elevation_m):
        raise HallrayError("--elevation-m must be a finite number of metres")
    if a.samples < 1:
        raise HallrayError("--samples must be >= 1")
    if a.out is not None and a.out.exists() and not a.out.is_dir():
        raise HallrayError(f"--out {a.out} exists and is not a folder")


def run_sionna_on(a: argparse.Namespace, scenes: dict[str, Canon], names: list[str]):
    """Export the scenes, run Sionna RT on them and load them in hallray (while the exported
    files exist: without --out they are in a temporary folder). Returns Sionna's arrays, its
    wall time (s) and hallray's scenes by name."""
    with tempfile.TemporaryDirectory(prefix="compare_sionna_") as tmp:
        work = Path(tmp)
        scene_dir = (a.out / "scenes") if a.out else work / "scenes"
        xmls = {nm: write_scene(scenes[nm], scene_dir) for nm in names}
        jobs = [{"name": nm, "xml": str(xmls[nm]),
                 "sweeps": [{"tx": scenes[nm].tx(sw).tolist(), "rx": scenes[nm].rx(sw).tolist()}
                            for sw in scenes[nm].sweeps]} for nm in names]
        n_rx = sum(len(sw.phi) for nm in names for sw in scenes[nm].sweeps)
        print(f"compare_sionna: {len(names)} scene(s), {n_rx} receivers; running Sionna RT ...",
              file=sys.stderr)
        sres, s_seconds = run_sionna(a.sionna_python, jobs, a.frequency_hz, a.samples, a.seed, work)
        try:
            # hallray's model (the box corners as solids), as docs/fidelity.md's figures were
            # measured: the concrete wedge's 10 m slab makes Sionna's surfaces a half-space
            loaded = {nm: load_scene(xmls[nm], surfaces=False) for nm in names}
        except HallrayError as exc:
            raise HallrayError(f"hallray: {exc}") from None
    return sres, s_seconds, loaded


def trace_and_analyse(a, scenes, names, sres, loaded) -> tuple[list[SweepResult], float]:
    """hallray's trace of every sweep, matched with Sionna's paths and analysed; and the
    tracing's wall time (s)."""
    results: list[SweepResult] = []
    h_seconds = 0.0
    for nm in names:
        c = scenes[nm]
        try:
            scene = loaded[nm]
            for i, sw in enumerate(c.sweeps):
                t1 = time.perf_counter()
                cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=1,
                                  max_interactions=1, slab_delay=False)
                paths = trace(scene, c.tx(sw)[None], c.rx(sw), a.frequency_hz, cfg)
                h_seconds += time.perf_counter() - t1
                h = hallray_table(paths)
                s = sionna_table(sres, f"{nm}|{i}", a.frequency_hz)
                results.append(analyse(c, sw, h, s, a.frequency_hz, scene))
        except SionnaError:
            raise
        except HallrayError as exc:
            raise HallrayError(f"hallray: {exc}") from None
    return results, h_seconds


def markdown(a, versions, results, n_rx, seconds: dict[str, float], checks) -> str:
    """The report: versions and timings, then the four tables (and the exact solution's checks)."""
    load = os.getloadavg()
    md = [
        f"Sionna RT {versions.get('sionna_rt')} (Mitsuba {versions.get('mitsuba')}, "
        f"{versions.get('variant')}) vs hallray, {a.frequency_hz / 1e9:g} GHz, "
        f"{len(results)} sweeps, {n_rx} receivers; isotropic vertically polarised antennas; "
        "LoS, 1 reflection, 1 diffraction, no penetration.",
        f"Wall time: Sionna {seconds['sionna']:.0f} s (one process, including its start and JIT), "
        f"hallray trace {seconds['hallray']:.1f} s, analysis and exact solution "
        f"{seconds['analysis']:.0f} s; load average "
        f"{load[0]:.1f} / {load[1]:.1f} on {os.cpu_count()} cores (shared machine: noisy).",
        "",
        "### Matched paths: gain and phase of Sionna relative to hallray",
        "",
        table_paths(results),
        "",
        "### Diffraction at the studied edge: Sionna, its transcription, and the steps to hallray "
        "(abs dB median / p90 / max)",
        "",
        table_model(results),
        "",
        "### Total field against the exact solution (perfectly conducting wedge, point source)",
        "",
        table_truth(results),
        "",
        "### Step of the total field across each boundary",
        "",
        table_boundaries(results),
    ]
    if checks:
        md += ["", "### Checks of the exact solution", "",
               "| check | worst |", "|---|---|"] + [f"| {kk} | {v:.2e} |" for kk, v in checks.items()]
    return "\n".join(md) + "\n"


def write_outputs(out: Path, results: list[SweepResult], report: str) -> None:
    """``out/results.npz`` (each sweep's matched gains, total fields, transcription variants;
    written atomically) and ``out/report.md``."""
    out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for i, r in enumerate(results):
        pre = f"s{i:02d}_"
        arrays[pre + "name"] = np.array(r.sweep.name)
        arrays[pre + "phi"] = r.sweep.phi
        arrays[pre + "label"] = r.label.astype(str)
        arrays[pre + "gain_hallray"] = r.h.gain[r.pair_h]
        arrays[pre + "gain_sionna"] = r.s.gain[r.pair_s]
        arrays[pre + "rx_index"] = r.h.rx[r.pair_h]
        arrays[pre + "vertex"] = r.h.vertex[r.pair_h]
        for tool in ("hallray", "sionna"):
            arrays[pre + f"total_{tool}"] = r.total[tool]
        if r.exact is not None:
            arrays[pre + "total_exact"] = r.exact
        for key, v in r.model.items():
            arrays[pre + "model_" + key.replace(" ", "_").replace(",", "")] = v
    tmp_npz = out / "results.npz.tmp"
    with open(tmp_npz, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp_npz, out / "results.npz")
    write_atomic(out / "report.md", report.encode("utf-8"))


def _main(a: argparse.Namespace) -> int:
    check_args(a)
    if a.sionna_scenes is not None:
        return _sionna_scenes(a)
    scenes = build_scenes(a.n_arc, a.delta_rad, a.elevation_m, a.solid_thickness_m)
    names = list(scenes) if a.scenes == "all" else [x.strip() for x in a.scenes.split(",")]
    unknown = [x for x in names if x not in scenes]
    if unknown:
        raise HallrayError(f"unknown scene(s) {', '.join(unknown)} (known: {', '.join(scenes)})")
    sres, s_seconds, loaded = run_sionna_on(a, scenes, names)
    versions = json.loads(str(sres["versions"]))
    t0 = time.perf_counter()
    results, h_seconds = trace_and_analyse(a, scenes, names, sres, loaded)
    a_seconds = time.perf_counter() - t0 - h_seconds
    k = 2 * np.pi * a.frequency_hz / C0
    checks = {} if a.no_checks else check_exact(k)
    n_rx = sum(len(sw.phi) for nm in names for sw in scenes[nm].sweeps)
    seconds = {"sionna": s_seconds, "hallray": h_seconds, "analysis": a_seconds}
    report = markdown(a, versions, results, n_rx, seconds, checks)
    print(report)
    if a.out:
        write_outputs(a.out, results, report)
    return 0


def _sionna_scenes(a: argparse.Namespace) -> int:
    """``--sionna-scenes``: Sionna RT's canonical scenes path by path (sionna_scenes.py)."""
    import sionna_scenes

    with tempfile.TemporaryDirectory(prefix="compare_sionna_") as tmp:
        print("compare_sionna: Sionna RT's canonical scenes; running Sionna RT ...", file=sys.stderr)
        sres, seconds = sionna_scenes.run(a.sionna_python, a.sionna_scenes, a.frequency_hz,
                                          a.samples, a.seed, Path(tmp))  # fmt: skip
    table, summary = sionna_scenes.compare(sres, a.sionna_scenes, a.frequency_hz)
    versions = json.loads(str(sres["versions"]))
    report = (f"Sionna RT's canonical scenes at {a.frequency_hz / 1e9:g} GHz, {versions} "
              f"({seconds:.1f} s): {summary['matched']} paths matched, "
              f"{summary['sionna_only']} found by Sionna only, {summary['hallray_only']} by "
              f"hallray only; largest differences: {summary['max_db']:.2g} dB, "
              f"{summary['max_ps']:.2g} ps, {summary['max_deg_reflection']:.2g} deg without "
              f"transmission\n\n{table}\n")  # fmt: skip
    print(report)
    if a.out:
        a.out.mkdir(parents=True, exist_ok=True)
        write_atomic(a.out / "sionna_scenes.md", report.encode("utf-8"))
    return 0 if summary["sionna_only"] == summary["hallray_only"] == 0 else 1


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
