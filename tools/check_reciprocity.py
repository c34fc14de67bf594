#!/usr/bin/env python3
"""Reciprocity of the tracer: trace a scene's links both ways and compare each path with its
reverse, per kind of path.

Run from a checkout: ``python tools/check_reciprocity.py [--scene hall] [--band c-band]
[--max-reflections 2] [--max-penetrations 2] [--max-diffractions 1] [--tol-db 1e-6]``.

A path from A to B and the same path from B to A (the interactions in reverse order, on the same
facets, wedges and objects, through the same reflection and diffraction points) must have the
same delay and the same complex gain in a reciprocal medium with the same antenna at both ends.
Prints, per kind (``RD``, ``TRR``, ...), how many paths were found one way only, and the largest
differences of delay (m) and gain (dB, and relative) between a path and its reverse. Not a test:
a diagnostic for the physics (docs/tracing.md, "Penetration"; docs/diffraction.md, (D8a)).
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from raytrace import TraceConfig, load_scene, trace  # noqa: E402
from raytrace.core.constants import C0  # noqa: E402
from raytrace.core.errors import HallrayError  # noqa: E402
from raytrace.emulation.bands import get_band  # noqa: E402
from raytrace.scene.metadata import SceneMetadata  # noqa: E402
from raytrace.solver.paths import PENETRATION  # noqa: E402

#: Reflection and diffraction points of a path and its reverse are compared on this grid, m.
POINT_GRID_M = 1e-6


def _keys(paths, reverse: bool) -> list[tuple]:
    """A key per path: its link (as A, B), interaction kinds, objects and elements in the order
    from A, and its reflection and diffraction points rounded to :data:`POINT_GRID_M` (a
    penetration's point is its entry point, which depends on the direction: left out)."""
    out = []
    for i in range(paths.n_paths):
        inter = paths.interaction[i]
        m = inter > 0
        kinds, objs = inter[m], paths.objects[i][m]
        elems, pts = paths.elements[i][m], paths.points[i][m]
        pts = np.where((kinds == PENETRATION)[:, None], 0.0, pts)
        a, b = int(paths.tx_index[i]), int(paths.rx_index[i])
        if reverse:
            kinds, objs, elems, pts = kinds[::-1], objs[::-1], elems[::-1], pts[::-1]
            a, b = b, a
        grid = np.rint(pts / POINT_GRID_M).astype(np.int64)
        out.append((a, b, kinds.tobytes(), objs.tobytes(), elems.tobytes(), grid.tobytes()))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall")
    ap.add_argument("--band", default="c-band")
    ap.add_argument("--max-reflections", type=int, default=2)
    ap.add_argument("--max-penetrations", type=int, default=2)
    ap.add_argument("--max-diffractions", type=int, default=1)
    ap.add_argument("--tol-db", type=float, default=1e-6, help="gain difference counted, dB")
    args = ap.parse_args()
    try:
        scene = load_scene(args.scene)
        inp = SceneMetadata.from_scene(scene, require=True)
        f = get_band(args.band).center_frequency_hz
        cfg = TraceConfig(max_reflections=args.max_reflections,
                          max_penetrations=args.max_penetrations,
                          max_diffractions=args.max_diffractions)  # fmt: skip
        fwd = trace(scene, inp.bs_xyz, inp.point_xyz, f, cfg)
        rev = trace(scene, inp.point_xyz, inp.bs_xyz, f, cfg)
    except HallrayError as exc:  # a bad scene, band or limit: one line, no traceback
        print(f"error: {exc}", file=sys.stderr)
        return 2
    back = defaultdict(list)
    for j, k in enumerate(_keys(rev, reverse=True)):
        back[k].append(j)
    rows: dict[str, dict] = defaultdict(lambda: {"n": 0, "one_way": 0, "delay_m": 0.0,
                                                 "db": 0.0, "rel": 0.0, "over": 0})  # fmt: skip
    used = np.zeros(rev.n_paths, dtype=bool)
    label_f, label_r = fwd.kind_label, rev.kind_label  # computed once (a property)
    for i, k in enumerate(_keys(fwd, reverse=False)):
        r = rows[str(label_f[i])]
        r["n"] += 1
        js = [j for j in back.get(k, []) if not used[j]]
        if not js:
            r["one_way"] += 1
            continue
        j = js[0]
        used[j] = True
        g1, g2 = fwd.gain[i], rev.gain[j]
        db = abs(20 * np.log10(max(abs(g1), 1e-300) / max(abs(g2), 1e-300)))
        r["delay_m"] = max(r["delay_m"], abs(fwd.delay_s[i] - rev.delay_s[j]) * C0)
        r["db"] = max(r["db"], db)
        r["rel"] = max(r["rel"], abs(g1 - g2) / max(abs(g1), 1e-300))
        r["over"] += int(db > args.tol_db)
    for j in np.flatnonzero(~used):
        rows[str(label_r[j])[::-1]]["one_way"] += 1
    print(f"{args.scene}, {args.band}: {fwd.n_paths} paths one way, {rev.n_paths} the other")
    print(f"{'kind':<8} {'paths':>7} {'one way':>8} {'max delay diff':>15} {'max |dB|':>10} "
          f"{'max rel':>9} {'> tol':>7}")  # fmt: skip
    for kind, r in sorted(rows.items(), key=lambda kv: -kv[1]["n"]):
        print(f"{kind:<8} {r['n']:>7} {r['one_way']:>8} {r['delay_m']:>13.2e} m "
              f"{r['db']:>10.3g} {r['rel']:>9.2e} {r['over']:>7}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
