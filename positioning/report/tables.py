"""The report's tables: Table II of the paper beside ours (mean, p90, availability per method)
and the integrity table (flagged fixes, errors within the protection level), as Markdown and CSV."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..estimators.fixes import Status
from ..evaluation.metrics import summarize
from .runs import DatasetResult, band_label, method_label, sort_results

#: The paper's Table II (metres): (scenario, band) -> metric -> method -> value.
PAPER_TABLE2: dict[tuple[str, str], dict[str, dict[str, float]]] = {
    ("static", "c-band"): {"mean": {"irls": 0.24, "ls": 0.45}, "p90": {"irls": 0.38, "ls": 0.48}},
    ("static", "mmwave"): {"mean": {"irls": 0.21, "ls": 0.36}, "p90": {"irls": 0.35, "ls": 0.46}},
    ("semi-dynamic", "c-band"): {
        "mean": {"irls": 0.66, "ls": 0.83},
        "p90": {"irls": 0.75, "ls": 0.94},
    },
    ("semi-dynamic", "mmwave"): {
        "mean": {"irls": 0.44, "ls": 0.52},
        "p90": {"irls": 0.58, "ls": 0.62},
    },
}
METRICS = (
    ("mean", "mean_m", "mean [m]"),
    ("p90", "p90_m", "90th pct [m]"),
    ("availability", "availability_pct", "availability [%]"),
)


def table_rows(results: Sequence[DatasetResult], methods: Sequence[str]) -> list[dict[str, Any]]:
    """Rows of Table II: per metric (mean, p90) and dataset, the value of each method (m)."""
    rows = []
    for metric, key, _ in METRICS:
        for r in sort_results(results):
            ds = r.dataset
            paper = PAPER_TABLE2.get((ds.scenario, ds.band), {}).get(metric, {})
            if metric == "availability":
                paper = {"irls": 100.0, "ls": 100.0}  # the paper solves every epoch
            row: dict[str, Any] = {
                "metric": metric,
                "scenario": ds.scenario,
                "band": ds.band,
                "dataset": ds.name,
                "n_fixes": ds.n_fixes,
                "n_unsolved": max(r.fixes[m].n_unsolved for m in methods) if methods else 0,
            }
            for m in methods:
                row[m] = r.summaries[m][key]
            row["paper_irls"] = paper.get("irls", float("nan"))
            row["paper_ls"] = paper.get("ls", float("nan"))
            rows.append(row)
    return rows


def _fmt(v: float) -> str:
    return "" if not np.isfinite(v) else f"{v:.2f}"


def table_markdown(rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> str:
    """Markdown version of Table II (values in metres, 2 decimals)."""
    head = ["metric", "setup", "band", "dataset", "fixes", *map(method_label, methods)]
    head += ["paper IRLS", "paper LS"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    labels = {m: lab for m, _, lab in METRICS}
    for r in rows:
        cells = [labels[r["metric"]], r["scenario"], band_label(r["band"]), r["dataset"]]
        cells.append(
            f"{r['n_fixes']}" + (f" ({r['n_unsolved']} unsolved)" if r["n_unsolved"] else "")
        )
        cells += [_fmt(r[m]) for m in methods]
        cells += [_fmt(r["paper_irls"]), _fmt(r["paper_ls"])]
        out.append("| " + " | ".join(cells) + " |")
    out.append("")
    out.append(
        "2D positioning error in metres; 90th pct = numpy linear percentile; availability = share "
        "of epochs with a position. Unsolved fixes (too few base stations, or outside the service "
        "area with --outside reject) are excluded from the error statistics. Fixes outside the "
        "service area are solved again inside it (--outside constrain). Paper columns: Table II "
        "of the paper for the same setup and band."
    )
    return "\n".join(out) + "\n"


def table_csv(rows: Sequence[Mapping[str, Any]], methods: Sequence[str]) -> str:
    """CSV version of Table II (same rows as the markdown; full precision)."""
    cols = ["metric", "scenario", "band", "dataset", "n_fixes", "n_unsolved", *methods]
    cols += ["paper_irls", "paper_ls"]
    return _csv_text(rows, cols)


INTEGRITY_COLUMNS = (
    "scenario",
    "band",
    "dataset",
    "method",
    "n_fixes",
    "availability_pct",
    "out_of_area",
    "not_converged",
    "ill_conditioned",
    "alert_limit_m",
    "flagged_pct",
    "unflagged_mean_m",
    "unflagged_p90_m",
    "flagged_mean_m",
    "flagged_p90_m",
    "bounded_by_hpl_pct",
    "hpl_median_m",
)


def integrity_rows(results: Sequence[DatasetResult], methods: Sequence[str]) -> list[dict]:
    """Per dataset and method: availability, doubtful-fix counts, and the errors of the fixes
    flagged (HPL above the alert limit) and not flagged, the share of fixes whose error is within
    their HPL, and the median HPL."""
    rows = []
    for r in sort_results(results):
        ds = r.dataset
        for m in methods:
            f, e = r.fixes[m], r.errors[m]
            solved = f.solved & np.isfinite(e)
            fl = f.flagged & solved
            un = ~f.flagged & solved
            su, sf = summarize(e[un]), summarize(e[fl])
            with np.errstate(invalid="ignore"):
                within = np.mean(e[solved] <= f.hpl_m[solved]) if solved.any() else np.nan
            hpl = f.hpl_m[solved]
            rows.append(
                {
                    "scenario": ds.scenario,
                    "band": ds.band,
                    "dataset": ds.name,
                    "method": m,
                    "n_fixes": f.n_epochs,
                    "availability_pct": 100.0 * f.availability,
                    "out_of_area": f.count(Status.AREA_BOUND),
                    "not_converged": f.count(Status.NOT_CONVERGED),
                    "ill_conditioned": f.count(Status.ILL_CONDITIONED),
                    "alert_limit_m": f.alert_limit_m,
                    "flagged_pct": 100.0 * fl.sum() / max(solved.sum(), 1),
                    "unflagged_mean_m": su["mean_m"],
                    "unflagged_p90_m": su["p90_m"],
                    "flagged_mean_m": sf["mean_m"],
                    "flagged_p90_m": sf["p90_m"],
                    "bounded_by_hpl_pct": 100.0 * within,
                    "hpl_median_m": float(np.median(hpl)) if hpl.size else np.nan,
                }
            )
    return rows


def integrity_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown of :func:`integrity_rows`."""
    head = [
        "setup",
        "band",
        "method",
        "avail. %",
        "out of area",
        "not conv.",
        "ill-cond.",
        "flagged %",
        "unflagged mean / p90 [m]",
        "flagged mean / p90 [m]",
        "error <= HPL %",
        "median HPL [m]",
    ]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            r["scenario"],
            band_label(r["band"]),
            method_label(r["method"]),
            f"{r['availability_pct']:.1f}",
            str(r["out_of_area"]),
            str(r["not_converged"]),
            str(r["ill_conditioned"]),
            f"{r['flagged_pct']:.1f}",
            f"{_fmt(r['unflagged_mean_m'])} / {_fmt(r['unflagged_p90_m'])}",
            f"{_fmt(r['flagged_mean_m'])} / {_fmt(r['flagged_p90_m'])}",
            f"{r['bounded_by_hpl_pct']:.1f}",
            _fmt(r["hpl_median_m"]),
        ]
        out.append("| " + " | ".join(cells) + " |")
    limit = rows[0]["alert_limit_m"] if rows else float("nan")
    out.append("")
    out.append(
        f"Flagged: horizontal protection level (HPL) above the alert limit ({limit:g} m). "
        "HPL bounds the error when at most one base station is biased; 'error <= HPL' is the "
        "share of solved fixes for which it did."
    )
    return "\n".join(out) + "\n"


def integrity_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """CSV of :func:`integrity_rows` (columns :data:`INTEGRITY_COLUMNS`)."""
    return _csv_text(rows, INTEGRITY_COLUMNS)


def _csv_text(rows: Sequence[Mapping[str, Any]], cols: Sequence[str]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(
            [
                r[c] if not isinstance(r[c], float) else ("" if np.isnan(r[c]) else f"{r[c]:.6g}")
                for c in cols
            ]
        )
    return buf.getvalue()
