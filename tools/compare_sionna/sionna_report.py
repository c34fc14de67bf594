"""The comparison's markdown tables."""

from __future__ import annotations

import numpy as np
from sionna_analysis import SweepResult, local_paths
from sionna_canon import BOUNDARY_STEPS
from wedge_exact import extrapolate


def _db(x: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.maximum(np.abs(x), 1e-300))


def _stats(v: np.ndarray) -> str:
    a = np.abs(v)
    return f"{np.median(a):.3g} / {np.quantile(a, 0.9):.3g} / {np.max(a):.3g}"


def _phase_deg(ratio: np.ndarray) -> np.ndarray:
    return np.degrees(np.angle(ratio))


def table_paths(results: list[SweepResult]) -> str:
    """Matched paths per mechanism: Sionna relative to hallray."""
    rows: dict[str, list] = {}
    for r in results:
        gh, gs = r.h.gain[r.pair_h], r.s.gain[r.pair_s]
        for lab in np.unique(r.label):
            sel = r.label == lab
            d = rows.setdefault(lab, [[], [], 0, 0])
            d[0].append(_db(gs[sel]) - _db(gh[sel]))
            d[1].append(_phase_deg(gs[sel] / gh[sel]))
        # unmatched, by kind (diffraction at other edges counted apart)
        for tool, t, used in (("hallray", r.h, r.pair_h), ("sionna", r.s, r.pair_s)):
            rest = np.setdiff1d(np.arange(len(t.kind)), used)
            local = local_paths(r.canon, t, r.tx, r.rx)
            for i in rest:
                if t.kind[i] == "LoS":
                    lab = "LoS"
                elif t.kind[i] == "R":
                    lab = f"R {r.canon.material} ({'half-space' if r.canon.solid else 'slab'})"
                elif local[i]:
                    lab = (f"D {r.canon.name} / {'oblique' if r.sweep.oblique else 'normal'} / "
                           f"lit: {r.sweep.lit}")
                else:
                    lab = "D other edges"
                d = rows.setdefault(lab, [[], [], 0, 0])
                d[2 if tool == "hallray" else 3] += 1
    out = ["| mechanism | matched | only hallray / only Sionna | gain Sionna - hallray, signed median (dB) "
           "| abs dB median / p90 / max | abs phase median / p90 / max (deg) |",
           "|---|---|---|---|---|---|"]
    for lab in sorted(rows, key=lambda x: (x[0] != "L", x[0] != "R", x)):
        ddb, dph, oh, os_ = rows[lab]
        if ddb:
            a, p = np.concatenate(ddb), np.concatenate(dph)
            out.append(f"| {lab} | {len(a)} | {oh} / {os_} | {np.median(a):+.3g} | {_stats(a)} "
                       f"| {_stats(p)} |")
        else:
            out.append(f"| {lab} | 0 | {oh} / {os_} | | | |")
    return "\n".join(out)


def table_model(results: list[SweepResult]) -> str:
    """Diffraction paths: Sionna's value against its numpy transcription, and the transcription
    changed step by step into hallray's coefficient. Cells: abs dB median / p90 / max; max abs
    phase (deg)."""
    keys = ["Sionna vs transcription", "transcription vs hallray", "+ KP grouping vs hallray",
            "+ face rule (D8a) vs hallray", "hallray API vs hallray trace"]
    rows: dict[str, dict[str, list]] = {}
    for r in results:
        if not len(r.model):
            continue
        is_d = r.h.kind[r.pair_h] == "D"
        gs, gh = r.s.gain[r.pair_s][is_d], r.h.gain[r.pair_h][is_d]
        m = r.model
        pairs = dict(zip(keys, (
            (gs, m["sionna"]), (m["sionna"], gh), (m["kp grouping"], gh),
            (m["kp grouping, D8a faces"], gh), (m["hallray api"], gh)), strict=True))
        for lab in np.unique(r.label[is_d]):
            sel = r.label[is_d] == lab
            d = rows.setdefault(lab, {})
            for key, (x, y) in pairs.items():
                d.setdefault(key, []).append(x[sel] / y[sel])
    out = ["| diffraction | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
    for lab in sorted(rows):
        cells = []
        for key in keys:
            ratio = np.concatenate(rows[lab][key])
            cells.append(f"{_stats(_db(ratio))} dB; {np.max(np.abs(_phase_deg(ratio))):.3g} deg")
        out.append(f"| {lab} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def table_boundaries(results: list[SweepResult]) -> str:
    """Step of the total field across each boundary (quadratic extrapolation from 3 samples each
    side): 20 log10 |T(b+) / T(b-)| in dB, for each tool, the exact solution and GO alone."""
    out = ["| sweep | boundary | hallray (dB) | Sionna (dB) | exact (dB) | GO alone, hallray (dB) |",
           "|---|---|---|---|---|---|"]
    for r in results:
        phi = r.sweep.phi
        for lab, b in r.sweep.boundaries.items():
            cells = []
            series = [r.total["hallray"], r.total["sionna"], r.exact, r.go["hallray"]]
            for v in series:
                if v is None:
                    cells.append("")
                    continue
                sides = []
                for sgn in (-1, 1):
                    idx = [int(np.argmin(np.abs(phi - (b + sgn * m * r.sweep.delta))))
                           for m in BOUNDARY_STEPS]
                    sides.append(extrapolate(v[idx]))
                step = _db(sides[1] / sides[0])
                cells.append(f"{step:+.3f}" if abs(step) < 300 else ("-inf" if step < 0 else "+inf"))
            out.append(f"| {r.sweep.name} | {lab} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def table_truth(results: list[SweepResult]) -> str:
    """Total field of each tool against the exact solution."""
    out = ["| sweep | tool | abs dB median / p90 / max | abs phase median / p90 / max (deg) |",
           "|---|---|---|---|"]
    for r in results:
        if r.exact is None:
            continue
        for tool in ("hallray", "sionna"):
            ratio = r.total[tool] / r.exact
            out.append(f"| {r.sweep.name} | {tool} | {_stats(_db(ratio))} | "
                       f"{_stats(_phase_deg(ratio))} |")
    return "\n".join(out)


