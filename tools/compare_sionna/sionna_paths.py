"""The paths of the two tools as one table each, and their matching."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sionna_run import SionnaError

#: Paths of the two tools are the same path when their vertices agree to this (m); Sionna works
#: in float32 (about 1e-6 m at 20 m).
MATCH_TOL_M = 5e-3


@dataclass
class PathTable:
    """Paths of one sweep: receiver index, kind ("LoS", "R", "D"), vertex, gain (complex field
    ratio including exp(-j k length)), delay."""

    rx: np.ndarray
    kind: np.ndarray
    vertex: np.ndarray
    gain: np.ndarray
    delay: np.ndarray
    element: np.ndarray | None = None  # hallray: wedge / facet index of the first interaction


def sionna_table(res: dict[str, np.ndarray], key: str, frequency_hz: float) -> PathTable:
    a, tau, typ = res[key + "|a"], res[key + "|tau"], res[key + "|type"][0]
    vert, valid = res[key + "|vertex"][0], res[key + "|valid"]
    r, p = np.nonzero(valid & (np.abs(a) > 0))
    kinds = {0: "LoS", 1: "R", 8: "D"}
    t = typ[r, p]
    if np.any(~np.isin(t, list(kinds))):
        raise SionnaError(f"unexpected Sionna interaction types {set(t.tolist())}")
    # Sionna's a excludes the propagation phase; the channel is a exp(-j 2 pi f tau)
    g = a[r, p] * np.exp(-2j * np.pi * frequency_hz * tau[r, p].astype(float))
    v = vert[r, p].astype(float)
    kind = np.array([kinds[int(x)] for x in t])
    v[kind == "LoS"] = np.nan
    return PathTable(r, kind, v, g, tau[r, p].astype(float))


def hallray_table(paths) -> PathTable:
    first = paths.interaction[:, 0] if paths.interaction.shape[1] else np.zeros(paths.n_paths)
    kinds = {0: "LoS", 1: "R", 3: "D"}
    kind = np.array([kinds[int(x)] for x in first])
    v = (paths.points[:, 0] if paths.points.shape[1] else np.full((paths.n_paths, 3), np.nan))
    el = paths.elements[:, 0] if paths.elements.shape[1] else np.full(paths.n_paths, -1)
    return PathTable(paths.rx_index.copy(), kind, v.copy(), paths.gain.copy(),
                     paths.delay_s.copy(), el.copy())


def match(h: PathTable, s: PathTable) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (index in h, index in s) of the same path: same receiver and kind, vertices within
    MATCH_TOL_M (nearest first). Unmatched paths are the complement."""
    hi, si = [], []
    for r in np.unique(np.concatenate([h.rx, s.rx])):
        for kind in ("LoS", "R", "D"):
            a = np.nonzero((h.rx == r) & (h.kind == kind))[0]
            b = np.nonzero((s.rx == r) & (s.kind == kind))[0]
            if not len(a) or not len(b):
                continue
            if kind == "LoS":
                hi.append(a[0])
                si.append(b[0])
                continue
            d = np.linalg.norm(h.vertex[a][:, None] - s.vertex[b][None], axis=2)
            used = set()
            for i in np.argsort(d.min(axis=1)):
                j = int(np.argmin(np.where(np.isin(np.arange(len(b)), list(used)), np.inf, d[i])))
                if d[i, j] < MATCH_TOL_M and j not in used:
                    used.add(j)
                    hi.append(a[i])
                    si.append(b[j])
    return np.array(hi, int), np.array(si, int)


