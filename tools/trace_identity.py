#!/usr/bin/env python3
"""Check that the tracer's output has not changed: save a reference, then compare against it.

Run from a checkout: ``python tools/trace_identity.py save REF.pkl`` (with the code to compare
against), then ``python tools/trace_identity.py check REF.pkl`` after a change. Traces the hall's
links at both bands (one thread) and a 4 m grid (one process, one thread), default
``TraceConfig``, plus the hall's links restricted to every 7th object (``involving``) and with
three interactions (RDR paths). ``check`` reports, per case, whether the paths are bitwise identical and else
the largest relative difference of delays, gains and points. Not a test (it takes a minute).
"""

from __future__ import annotations

import argparse
import pickle
import time

import numpy as np

from hallray.safe_output import check_output
from raytrace import TraceConfig, load_scene, trace
from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.core.fileio import write_atomic
from raytrace.scene.metadata import SceneMetadata

FIELDS = ("link", "tx_index", "rx_index", "n_reflections", "n_penetrations", "n_diffractions",
          "interaction", "objects", "elements", "delay_s", "gain", "points")  # fmt: skip


def cases() -> dict[str, dict[str, np.ndarray]]:
    """Each case's paths as a dict of arrays."""
    from raytrace.solver.parallel import receiver_chunks
    from raytrace.solver.tracer import join_chunks
    from raytrace.studies.accuracy_map import MapSettings, make_grid

    scene = load_scene("hall")
    inp = SceneMetadata.from_scene(scene, require=True)
    grid = make_grid(scene, MapSettings(step_m=4.0), inp.point_names, inp.point_xyz).cell_xyz
    out = {}
    for name, rx, f in (("hall_3.775GHz", inp.point_xyz, 3.775e9),
                        ("hall_26.85GHz", inp.point_xyz, 26.85e9),
                        ("grid4m_3.775GHz", grid, 3.775e9)):  # fmt: skip
        t0 = time.process_time()
        parts = []
        for c in receiver_chunks(len(inp.bs_xyz), len(rx)):
            p = trace(scene, inp.bs_xyz, rx[c.start : c.stop], f, TraceConfig(), threads=1)
            parts.append(p.with_receivers(rx, c.start))
        paths = join_chunks(parts, len(inp.bs_xyz))
        print(f"{name}: {paths.n_paths} paths, {time.process_time() - t0:.2f} s CPU")
        out[name] = {k: np.asarray(getattr(paths, k)) for k in FIELDS}
    # the restricted traces (involving some objects) and the RDR stage (3 interactions)
    some = np.arange(0, len(scene.objects), 7)
    for name, kw in (("hall_involving_every_7th_object", dict(involving=some)),
                     ("hall_rdr_3_interactions", dict(config=TraceConfig(max_interactions=3)))):  # fmt: skip
        t0 = time.process_time()
        kw = {"config": TraceConfig(), **kw}
        paths = trace(scene, inp.bs_xyz, inp.point_xyz, 3.775e9, threads=1, **kw)
        print(f"{name}: {paths.n_paths} paths, {time.process_time() - t0:.2f} s CPU")
        out[name] = {k: np.asarray(getattr(paths, k)) for k in FIELDS}
    return out


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a), np.asarray(b)
    fin = np.isfinite(a) if a.dtype.kind == "f" else np.ones(a.shape, bool)
    if a.dtype.kind == "f" and not np.array_equal(np.isnan(a), np.isnan(b)):
        return float("inf")
    d = np.abs(a[fin] - b[fin])
    s = np.maximum(np.abs(a[fin]), np.abs(b[fin]))
    return float((d / np.where(s > 0, s, 1.0)).max()) if d.size else 0.0


def load_reference(path: str) -> dict[str, dict[str, np.ndarray]]:
    """The cases saved by ``save``; a missing file is an OSError, anything else one line."""
    with open(path, "rb") as fh:
        try:
            ref = pickle.load(fh)
        except Exception as exc:  # not a pickle, truncated, classes that no longer exist, ...
            raise HallrayError(
                f"{path}: not a reference saved by trace_identity.py ({exc})"
            ) from None
    if not (isinstance(ref, dict) and all(isinstance(r, dict) and set(FIELDS) <= set(r)
                                          for r in ref.values())):  # fmt: skip
        raise HallrayError(f"{path}: not a reference saved by trace_identity.py")
    return ref


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("save", "check"),
                    help="save: write the reference; check: compare against it")  # fmt: skip
    ap.add_argument("ref", help="the reference file (.pkl)")
    return ap


def _main(args: argparse.Namespace) -> int:
    # the reference (to read, or where to write it) before the minute of tracing
    if args.mode == "save":
        check_output(args.ref, what="save")
    else:
        ref = load_reference(args.ref)
    got = cases()
    if args.mode == "save":
        write_atomic(args.ref, pickle.dumps(got))  # never a half-written reference
        return 0
    bad = 0
    for name, r in ref.items():
        if name not in got:
            print(f"{name}: not in this run")
            continue
        g = got[name]
        if len(r["link"]) != len(g["link"]):
            print(f"{name}: DIFFERENT number of paths {len(r['link'])} -> {len(g['link'])}")
            bad += 1
            continue
        worst, exact = 0.0, True
        for k in FIELDS:
            same = np.array_equal(r[k], g[k], equal_nan=r[k].dtype.kind in "fc")
            exact &= same
            if not same:
                if r[k].dtype.kind in "fc":
                    worst = max(worst, _rel(r[k], g[k]))
                else:
                    worst = float("inf")
                    print(f"  {name}: {k} differs")
        status = "bitwise identical" if exact else f"max relative difference {worst:.3g}"
        print(f"{name}: {len(r['link'])} paths, {status}")
        bad += worst > 1e-12
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
