"""Reciprocity of the tracer: every path from A to B against the same path from B to A.

In a reciprocal medium, with the same antenna at both ends, a path and its reverse (the same
interactions in reverse order, on the same facets, wedges and objects, through the same
reflection and diffraction points) have the same delay and the same complex gain. Tracing a scene
both ways and comparing path by path checks every mechanism at once, on real geometry, without a
reference tracer (docs/fidelity.md). ``tools/check_reciprocity.py`` prints the table for a scene.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ..core.constants import C0
from ..solver.paths import PENETRATION, Paths

__all__ = ["KindRow", "compare_reverse", "format_table", "POINT_GRID_M"]

#: Reflection and diffraction points of a path and its reverse are compared on this grid, m.
POINT_GRID_M = 1e-6


@dataclass
class KindRow:
    """Per kind of path (``"RD"``, ``"TRR"``, ... as seen from A), how it compares with the
    reverse trace.

    Attributes
    ----------
    paths : int, paths of this kind from A to B
    one_way : int, paths found in one direction only (either one)
    delay_m : float, metres; largest ``c |delay - delay_reverse|``
    db : float, dB; largest ``|20 log10(|gain| / |gain_reverse|)|``
    rel : float; largest ``|gain - gain_reverse| / |gain|``
    over : int, matched paths whose gains differ by more than the tolerance (dB)
    """

    paths: int = 0
    one_way: int = 0
    delay_m: float = 0.0
    db: float = 0.0
    rel: float = 0.0
    over: int = 0


def _keys(paths: Paths, reverse: bool) -> list[tuple]:
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


def compare_reverse(fwd: Paths, rev: Paths, tol_db: float = 1e-6) -> dict[str, KindRow]:
    """Match every path of ``fwd`` (traced from ends A to ends B) with its reverse in ``rev``
    (traced from B to A) and compare delays and gains, per kind of path.

    Parameters
    ----------
    fwd : Paths, A -> B (``tx`` = A, ``rx`` = B)
    rev : Paths, B -> A (``tx`` = B, ``rx`` = A)
    tol_db : float, dB; gain differences above it are counted in :attr:`KindRow.over`

    Returns
    -------
    dict kind -> KindRow, the kinds as seen from A (a path found only from B is counted under
    its reversed kind)
    """
    back: dict[tuple, list[int]] = defaultdict(list)
    for j, k in enumerate(_keys(rev, reverse=True)):
        back[k].append(j)
    rows: dict[str, KindRow] = defaultdict(KindRow)
    used = np.zeros(rev.n_paths, dtype=bool)
    label_f, label_r = fwd.kind_label, rev.kind_label  # computed once (a property)
    for i, k in enumerate(_keys(fwd, reverse=False)):
        r = rows[str(label_f[i])]
        r.paths += 1
        js = [j for j in back.get(k, []) if not used[j]]
        if not js:
            r.one_way += 1
            continue
        j = js[0]
        used[j] = True
        g1, g2 = fwd.gain[i], rev.gain[j]
        db = abs(20 * np.log10(max(abs(g1), 1e-300) / max(abs(g2), 1e-300)))
        r.delay_m = max(r.delay_m, abs(fwd.delay_s[i] - rev.delay_s[j]) * C0)
        r.db = max(r.db, db)
        r.rel = max(r.rel, abs(g1 - g2) / max(abs(g1), 1e-300))
        r.over += int(db > tol_db)
    for j in np.flatnonzero(~used):
        rows[str(label_r[j])[::-1]].one_way += 1
    return dict(rows)


def format_table(rows: dict[str, KindRow]) -> str:
    """The comparison as a text table, most frequent kinds first."""
    out = [f"{'kind':<8} {'paths':>7} {'one way':>8} {'max delay diff':>15} {'max |dB|':>10} "
           f"{'max rel':>9} {'> tol':>7}"]  # fmt: skip
    for kind, r in sorted(rows.items(), key=lambda kv: -kv[1].paths):
        out.append(f"{kind:<8} {r.paths:>7} {r.one_way:>8} {r.delay_m:>13.2e} m "
                   f"{r.db:>10.3g} {r.rel:>9.2e} {r.over:>7}")  # fmt: skip
    return "\n".join(out)
