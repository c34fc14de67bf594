"""The paper's comparison: Table II under each receiver beside the paper's, and the findings.

``reproduce-paper`` writes the four datasets under the paper's model as written (``paper``), the
realistic receiver (the default, ``search-back``) and the ideal one (``first-path``) from one trace, runs
``accuracy-report`` on each set, then calls :func:`write_comparison`. That reads the reports'
``table.csv`` and the datasets' ``toa.csv``
(first-arrival mechanism and true distance of every link) and states, with numbers, whether each
of the paper's orderings holds -- IRLS <= LS, mmWave <= C-band, static <= semi-dynamic -- and
which mechanism drives it: the share of links whose first arrival is line of sight, diffraction,
reflection or penetration, and the range-error percentiles per class, band and receiver.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.constants import C0
from ..core.fileio import write_atomic

#: First-arrival classes, in the order of the tables. A path with a diffraction is "diffraction",
#: else one with a penetration "penetration", else one with a reflection "reflection".
CLASSES = ("LoS", "diffraction", "penetration", "reflection", "none")

#: The paper's orderings: (name, what is compared, better side, worse side).
ORDERINGS = (
    ("IRLS <= LS", "method", "irls", "ls"),
    ("IRLS as written <= LS", "method", "irls-paper", "ls"),
    ("mmWave <= C-band", "band", "mmwave", "c-band"),
    ("static <= semi-dynamic", "scenario", "static", "semi-dynamic"),
)

_SETUPS = (
    ("static", "c-band"),
    ("static", "mmwave"),
    ("semi-dynamic", "c-band"),
    ("semi-dynamic", "mmwave"),
)
_BAND_LABEL = {"c-band": "C-band", "mmwave": "mmWave"}


def first_arrival_class(kind: Sequence[str]) -> np.ndarray:
    """(L,) str: the class of :data:`CLASSES` of each first-arrival kind label (``""``: none)."""
    out = []
    for k in kind:
        if k == "LoS":
            out.append("LoS")
        elif not k:
            out.append("none")
        elif "D" in k:
            out.append("diffraction")
        elif "T" in k:
            out.append("penetration")
        else:
            out.append("reflection")
    return np.array(out, dtype=object)


@dataclass(frozen=True)
class LinkErrors:
    """Per-link range errors of one dataset (L rows of its ``toa.csv``).

    Attributes
    ----------
    scenario, band, receiver : str, from ``meta.json``
    cls : (L,) str, first-arrival class (:data:`CLASSES`)
    error_m : (L,) float, metres: ``c (toa - tx_offset - clock_offset) - distance``, the range
        error the receiver made (NaN where nothing was detected)
    """

    scenario: str
    band: str
    receiver: str
    cls: np.ndarray
    error_m: np.ndarray


def link_errors(directory: str | Path) -> LinkErrors:
    """Read one dataset's per-link range errors (uses the truth columns, for evaluation only)."""
    directory = Path(directory)
    meta = json.loads((directory / "meta.json").read_text())
    kinds, err = [], []
    with (directory / "toa.csv").open(newline="") as fh:
        for row in csv.DictReader(fh):
            kinds.append(row["first_kind"])
            if row["toa_s"]:
                tau = float(row["toa_s"]) - float(row["tx_offset_s"]) - float(row["clock_offset_s"])
                err.append(C0 * tau - float(row["distance_m"]))
            else:
                err.append(np.nan)
    return LinkErrors(
        meta["scenario"], meta["band"], meta.get("toa_method", "?"),
        first_arrival_class(kinds), np.array(err),
    )  # fmt: skip


def mechanism_rows(links: Sequence[LinkErrors]) -> list[dict[str, object]]:
    """Share of links per first-arrival class and their range-error percentiles.

    One row per (receiver, scenario, band, class) with ``share`` (of all links), ``n``,
    ``detected`` (share with a ToA), ``median_m`` (signed), ``p90_abs_m`` and ``p99_abs_m``.
    """
    rows = []
    for le in links:
        total = le.cls.size
        for c in CLASSES:
            sel = le.cls == c
            if not sel.any():
                continue
            e = le.error_m[sel]
            ok = np.isfinite(e)
            a = np.abs(e[ok])
            rows.append({
                "receiver": le.receiver, "scenario": le.scenario, "band": le.band, "class": c,
                "n": int(sel.sum()), "share": sel.sum() / total, "detected": ok.mean(),
                "median_m": float(np.median(e[ok])) if ok.any() else np.nan,
                "p90_abs_m": float(np.percentile(a, 90)) if ok.any() else np.nan,
                "p99_abs_m": float(np.percentile(a, 99)) if ok.any() else np.nan,
            })  # fmt: skip
    return rows


def read_table(path: str | Path) -> dict[tuple[str, str, str], dict[str, float]]:
    """An ``accuracy-report`` ``table.csv`` as ``(metric, scenario, band) -> column -> value``."""
    out: dict[tuple[str, str, str], dict[str, float]] = {}
    with Path(path).open(newline="") as fh:
        for row in csv.DictReader(fh):
            key = (row["metric"], row["scenario"], row["band"])
            vals = {}
            for k, v in row.items():
                if k in ("metric", "scenario", "band", "dataset"):
                    continue
                try:
                    vals[k] = float(v)
                except (TypeError, ValueError):
                    continue
            out[key] = vals
    return out


_NOT_METHODS = {"n_fixes", "n_unsolved", "paper_irls", "paper_ls", "fixes", "availability"}


def _methods(table: Mapping[tuple[str, str, str], Mapping[str, float]]) -> list[str]:
    first = next(iter(table.values()), {})
    return [k for k in first if k not in _NOT_METHODS and not k.startswith("paper")]


def _best(vals: Mapping[str, float], methods: Sequence[str]) -> tuple[str, float]:
    cand = [(vals[m], m) for m in methods if m in vals and np.isfinite(vals[m])]
    v, m = min(cand) if cand else (np.nan, "-")
    return m, v


def _f(v: float) -> str:
    return "-" if not np.isfinite(v) else (f"{v:.2f}" if abs(v) < 1e4 else f"{v:.3g}")


def table2_markdown(tables: Mapping[str, Mapping], receivers: Sequence[str]) -> str:
    """Table II side by side: the paper's LS and IRLS, then per receiver LS, IRLS (guarded),
    IRLS as written (``irls-paper``) and the best."""
    # "published": the paper's own figures (not our ``paper`` receiver's)
    head = ["metric", "setup", "band", "published LS", "published IRLS"]
    for r in receivers:
        head += [f"{r} LS", f"{r} IRLS", f"{r} IRLS as written", f"{r} best"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for metric, label in (("mean", "mean [m]"), ("p90", "90th pct [m]")):
        for scen, band in _SETUPS:
            ref = next((t.get((metric, scen, band)) for t in tables.values() if t), None) or {}
            cells = [label, scen, _BAND_LABEL.get(band, band)]
            cells += [_f(ref.get("paper_ls", np.nan)), _f(ref.get("paper_irls", np.nan))]
            for r in receivers:
                vals = tables[r].get((metric, scen, band), {})
                m, v = _best(vals, _methods(tables[r]))
                cells += [
                    _f(vals.get("ls", np.nan)),
                    _f(vals.get("irls", np.nan)),
                    _f(vals.get("irls-paper", np.nan)),
                    f"{_f(v)} ({m})",
                ]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def ordering_findings(
    table: Mapping[tuple[str, str, str], Mapping[str, float]], methods: Sequence[str]
) -> list[dict[str, object]]:
    """Whether each of the paper's orderings holds in ``table``, per comparison, on mean and p90.

    Returns one dict per (ordering, comparison) with ``ordering``, ``where``, ``metric``,
    ``better`` and ``worse`` values and ``holds``.
    """
    out = []
    for name, axis, good, bad in ORDERINGS:
        for metric in ("mean", "p90"):
            if axis == "method":
                pairs = [((metric, s, b), (metric, s, b), f"{s} {_BAND_LABEL[b]}", (good, bad))
                         for s, b in _SETUPS]  # fmt: skip
            elif axis == "band":
                pairs = [((metric, s, good), (metric, s, bad), f"{s}, {m}", (m, m))
                         for s in ("static", "semi-dynamic") for m in methods]  # fmt: skip
            else:
                pairs = [((metric, good, b), (metric, bad, b), f"{_BAND_LABEL[b]}, {m}", (m, m))
                         for b in ("c-band", "mmwave") for m in methods]  # fmt: skip
            for kg, kb, where, (mg, mb) in pairs:
                vg = table.get(kg, {}).get(mg, np.nan)
                vb = table.get(kb, {}).get(mb, np.nan)
                if np.isfinite(vg) and np.isfinite(vb):
                    out.append({"ordering": name, "where": where, "metric": metric,
                                "better": vg, "worse": vb, "holds": bool(vg <= vb)})  # fmt: skip
    return out


def _mechanism_markdown(rows: Sequence[Mapping[str, object]]) -> str:
    head = "| receiver | setup | band | first arrival | share | detected | median [m] | p90 abs [m] | p99 abs [m] |"
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        lines.append(
            f"| {r['receiver']} | {r['scenario']} | {_BAND_LABEL.get(str(r['band']), r['band'])} "
            f"| {r['class']} | {100 * float(r['share']):.1f} % | {100 * float(r['detected']):.1f} % "
            f"| {_f(float(r['median_m']))} | {_f(float(r['p90_abs_m']))} | {_f(float(r['p99_abs_m']))} |"
        )
    return "\n".join(lines) + "\n"


def _summary_lines(findings: Sequence[Mapping[str, object]]) -> list[str]:
    lines = []
    for name, _, _, _ in ORDERINGS:
        sel = [f for f in findings if f["ordering"] == name]
        if not sel:
            continue
        n_ok = sum(bool(f["holds"]) for f in sel)
        fails = [f"{f['where']} ({f['metric']}: {_f(float(f['better']))} vs {_f(float(f['worse']))})"
                 for f in sel if not f["holds"]]  # fmt: skip
        verdict = "holds" if n_ok == len(sel) else ("fails" if n_ok == 0 else "holds in part")
        line = f"- **{name}** {verdict}: {n_ok} of {len(sel)} comparisons."
        if fails:
            line += (
                " Not where: " + "; ".join(fails[:8]) + ("; ..." if len(fails) > 8 else "") + "."
            )
        lines.append(line)
    return lines


def comparison_markdown(
    tables: Mapping[str, Mapping], links: Sequence[LinkErrors], receivers: Sequence[str]
) -> str:
    """The whole ``paper.md``: Table II side by side, the orderings per receiver, the mechanisms."""
    roles = {"paper": "the paper's model as written", "first-path": "the ideal one"}
    shown = sorted(receivers, key=lambda r: (r != "paper", r == "first-path"))  # Table II's order
    named = "; ".join(f"`{r}`: {roles.get(r, 'the realistic receiver')}" for r in shown)
    parts = [
        "# Our hall against the paper\n",
        "Table II (2D error, metres): the paper's LS and IRLS (published), then ours under each receiver "
        f"({named}): LS with the paper's random reference (drawn per epoch, "
        "seeded), IRLS with our guard (only converged, plausible per-reference estimates are "
        "averaged), IRLS as written (Algorithm 1, every estimate averaged) and the best of our "
        "methods, named.\n",
        table2_markdown(tables, receivers),
        "## The paper's orderings\n",
    ]
    for r in receivers:
        methods = [m for m in ("ls", "irls", "irls-paper") if m in _methods(tables[r])]
        parts.append(f"Receiver `{r}` (LS, IRLS and IRLS as written, mean and p90 per setup):\n")
        parts.append("\n".join(_summary_lines(ordering_findings(tables[r], methods))) + "\n")
    parts += [
        "## Why, by mechanism\n",
        "Share of links per first-arriving path and the range error the receiver makes on them "
        "(`c (ToA - schedule - clock offset) - distance`, signed median and percentiles of its "
        "magnitude):\n",
        _mechanism_markdown(mechanism_rows(links)),
    ]
    return "\n".join(parts)


def write_comparison(
    out: str | Path,
    reports: Mapping[str, str | Path],
    datasets: Mapping[str, Sequence[str | Path]],
    costs: str = "",
    main: str | None = None,
) -> str:
    """Write ``out`` (``paper.md``) from the reports and datasets of each receiver; returns it.

    Parameters
    ----------
    out : path of the markdown file
    reports : receiver -> report directory written by ``accuracy-report`` (holds ``table.csv``)
    datasets : receiver -> its dataset directories
    costs : markdown appended at the end (:func:`costs_markdown`)
    main : the receiver whose report holds the tracked rows (default: the first of ``reports``)
    """
    receivers = list(reports)
    main = main or receivers[0]
    tables = {r: read_table(Path(reports[r]) / "table.csv") for r in receivers}
    links = [link_errors(d) for r in receivers for d in datasets[r]]
    text = comparison_markdown(tables, links, receivers)
    tracked = Path(reports[main]) / "table_tracked.md"
    if tracked.is_file():
        text += (
            f"\n## Tracked rows (receiver `{main}`)\n\n"
            "Each point's epochs filtered by `METHOD+track` (latency: docs/positioning.md); kept "
            "apart from the single-epoch rows above.\n\n" + tracked.read_text()
        )
    if costs:
        text += "\n" + costs
    write_atomic(out, text.encode())
    return text


def method_costs(
    dataset_dir: str | Path,
    methods: Sequence[str],
    params: Mapping[str, Mapping[str, object]] | None = None,
    n_fixes: int = 2000,
    seed: int = 0,
) -> tuple[dict[str, float], int]:
    """Fixes per second of each single-epoch method on ``n_fixes`` random fixes of one dataset,
    batched in this process (the service area and receiver reports attached, as in the report).

    Tracked methods (``METHOD+track``) are timed as their filter alone on the method's fixes.
    A method with a map (``twin``) is timed twice: ``"twin (first run)"`` reads the map and
    fills its ToA raster around the fixes, ``"twin"`` is the run after it.
    Returns the rates by method and the number of fixes timed.
    """
    import time

    from positioning.estimators.track import split_method, track_fixes
    from positioning.io.dataset import load_dataset
    from positioning.io.prepare import dataset_problem
    from positioning.methods.registry import METHODS
    from positioning.methods.run import run_method

    ds = load_dataset(dataset_dir)
    prob = dataset_problem(ds)
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(ds.n_fixes, size=min(n_fixes, ds.n_fixes), replace=False))
    sub = prob.take(idx)
    params = params or {}
    out, fixes = {}, {}
    for m in methods:
        base, tracked = split_method(m)
        if base not in fixes:
            if METHODS[base].needs_map:
                # the first run reads the map and fills the twin's ToA raster around the fixes;
                # later runs (a positioning server) only look up
                t0 = time.perf_counter()
                run_method(sub, base, **dict(params.get(base, {})))
                out[f"{base} (first run)"] = len(idx) / max(time.perf_counter() - t0, 1e-9)
            t0 = time.perf_counter()
            fixes[base] = run_method(sub, base, **dict(params.get(base, {})))
            out[base] = len(idx) / max(time.perf_counter() - t0, 1e-9)
        if tracked:
            t0 = time.perf_counter()
            track_fixes(fixes[base], ds.point[idx], ds.time_s[idx])
            out[m] = len(idx) / max(time.perf_counter() - t0, 1e-9)
    order = [k for m in methods for k in (f"{m} (first run)", m)]
    return {k: out[k] for k in order if k in out}, len(idx)


def costs_markdown(
    maps: Sequence[Mapping[str, object]], rates: Mapping[str, float], n_fixes: int
) -> str:
    """The "What it costs" section: map build time and size per band, fixes/s per method."""
    lines = ["## What it costs\n"]
    if maps:
        lines += ["| map | cells | step [m] | build [s] | map.npz [kB] |", "|---|---|---|---|---|"]
        for m in maps:
            lines.append(
                f"| {m['band']} | {m['cells']} | {m['step_m']:g} | {float(m['seconds']):.1f} "  # type: ignore[arg-type]
                f"| {int(m['bytes']) / 1024:.0f} |"  # type: ignore[call-overload]
            )
        lines.append("")
    lines.append(
        f"Fixes per second, batched in one process, on {n_fixes} fixes of the static C-band "
        "dataset (tracked: the filter alone, on top of its method; a map method's first run "
        "includes reading the map and, for `twin` with a path map, filling its ToA raster "
        "around these fixes):\n"
    )
    lines += ["| method | fixes/s |", "|---|---|"]
    lines += [f"| {m} | {r:,.0f} |" for m, r in rates.items()]
    return "\n".join(lines) + "\n"
