"""Accuracy report: the paper's Table II for our datasets, CDF plots (Fig. 2 style), hall top view.

Plots use matplotlib's object API with the Agg canvas (no global backend, no display needed).
Every file is written to a temporary file in the target directory and then renamed, so a failed
run never leaves a half-written file.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .api import run_method
from .dataset import ToaDataset, dataset_area, link_reports
from .errors import PositioningError
from .fixes import Fixes, Status
from .integrity import ALERT_LIMIT_M
from .metrics import cdf, error_2d, summarize
from .tdoa import Problem, make_problem
from .track import split_method, track_fixes

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

_SCENARIO_ORDER = {"static": 0, "semi-dynamic": 1}
_BAND_ORDER = {"c-band": 0, "mmwave": 1}
_BAND_LABEL = {"c-band": "C-band", "mmwave": "mmWave"}
_METHOD_LABEL = {"ls": "LS", "irls": "IRLS"}
METRICS = (
    ("mean", "mean_m", "mean [m]"),
    ("p90", "p90_m", "90th pct [m]"),
    ("availability", "availability_pct", "availability [%]"),
)


def method_label(name: str) -> str:
    """Display name of a method (``LS``, ``IRLS``, others as registered)."""
    return _METHOD_LABEL.get(name, name)


def band_label(band: str) -> str:
    return _BAND_LABEL.get(band, band)


# ----------------------------------------------------------------------------------------------
# atomic file output


def atomic_write(path: str | Path, write: Callable[[Any], None], *, binary: bool = False) -> None:
    """Call ``write(fh)`` on a temporary file beside ``path``, then rename it to ``path``
    (:func:`hallray.safe_output.replace_atomic`: the umask's mode, symlinks followed)."""
    from hallray.safe_output import replace_atomic

    real = Path(os.path.realpath(path))
    replace_atomic(real, write if binary else lambda fh: _write_text(fh, write))


def _write_text(fh: Any, write: Callable[[Any], None]) -> None:
    text = io.TextIOWrapper(fh, encoding="utf-8", newline="")
    write(text)
    text.flush()
    text.detach()  # leave the binary file open for the caller's fsync


def is_report_dir(path: Path) -> bool:
    """Whether a directory holds a previous report (``table.md``): accuracy-report replaces it."""
    return (path / "table.md").is_file()


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write(path, lambda fh: fh.write(text))


def save_figure(fig: Any, path: str | Path, dpi: int = 120) -> None:
    """Save a matplotlib Figure as PNG atomically."""
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi), binary=True)


# ----------------------------------------------------------------------------------------------
# evaluation


@dataclass(frozen=True)
class DatasetResult:
    """All methods run on one dataset."""

    dataset: ToaDataset
    fixes: dict[str, Fixes]
    errors: dict[str, np.ndarray]  # method -> (F,) 2D error, metres (NaN unsolved)
    summaries: dict[str, dict[str, float | int]]

    @property
    def label(self) -> str:
        ds = self.dataset
        return f"{ds.scenario} / {band_label(ds.band)} ({ds.name})"


def heights_for(ds: ToaDataset, mode: str | float) -> np.ndarray | None:
    """Device heights of a dataset's fixes: ``"true"`` -> the points' true z, ``"3d"`` -> None,
    a number -> that constant."""
    if mode == "3d":
        return None
    if mode == "true":
        return ds.true_xyz[:, 2]
    return np.full(ds.n_fixes, float(mode))


def dataset_problem(ds: ToaDataset, height: str | float = "true") -> Problem:
    """The dataset as a :class:`Problem`: schedule removed per measurement, its service area and
    its receiver reports (``snr_db``, first-lobe shape, band) attached."""
    return make_problem(
        ds.toa_unscheduled_s,
        ds.bs_xyz,
        None,
        heights_for(ds, height),
        area=dataset_area(ds),
        links=link_reports(ds),
    )


def solve_dataset(
    ds: ToaDataset,
    method: str,
    params: Mapping[str, Any],
    height: str | float = "true",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = ALERT_LIMIT_M,
    problem: Problem | None = None,
    track: Mapping[str, Any] | None = None,
) -> Fixes:
    """Run one method on every fix of a dataset (schedule removed per measurement), bounded to
    the dataset's service area, with integrity figures at ``alert_limit_m``.

    ``METHOD+track``: the method's fixes tracked per point over time
    (:func:`positioning.track.track_fixes` with the ``track`` parameters).
    """
    base, tracked = split_method(method)
    if tracked:
        single = solve_dataset(
            ds, base, params, height, outside=outside, alert_limit_m=alert_limit_m, problem=problem
        )
        return track_fixes(single, ds.point, ds.time_s, **(track or {}))
    prob = problem if problem is not None else dataset_problem(ds, height)
    p = dict(params)
    if "reference" in p and isinstance(p["reference"], str) and p["reference"] in ds.bs_names:
        p["reference"] = ds.bs_names.index(p["reference"])
    return run_method(prob, method, outside=outside, alert_limit_m=alert_limit_m, **p)


def evaluate(
    ds: ToaDataset,
    methods: Sequence[str],
    params: Mapping[str, Mapping[str, Any]] | None = None,
    height: str | float = "true",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = ALERT_LIMIT_M,
) -> DatasetResult:
    """Run ``methods`` on ``ds``; 2D errors and their summaries per method."""
    params = params or {}
    fixes, errors, summaries = {}, {}, {}
    prob = dataset_problem(ds, height)
    single: dict[str, Fixes] = {}  # a tracked method reuses its base method's fixes
    for m in methods:
        base, tracked = split_method(m)
        if base not in single:
            single[base] = solve_dataset(
                ds,
                base,
                params.get(base, {}),
                height,
                outside=outside,
                alert_limit_m=alert_limit_m,
                problem=prob,
            )
        f = single[base]
        if tracked:
            f = track_fixes(f, ds.point, ds.time_s, **params.get("track", {}))
        e = error_2d(f.xyz, ds.true_xyz)
        fixes[m], errors[m], summaries[m] = f, e, summarize(e)
        summaries[m]["availability_pct"] = 100.0 * f.availability
    return DatasetResult(dataset=ds, fixes=fixes, errors=errors, summaries=summaries)


def _sort_key(r: DatasetResult) -> tuple:
    ds = r.dataset
    return (
        _SCENARIO_ORDER.get(ds.scenario, 9),
        ds.scenario,
        _BAND_ORDER.get(ds.band, 9),
        ds.band,
        ds.name,
    )


def sort_results(results: Sequence[DatasetResult]) -> list[DatasetResult]:
    """Results in the paper's order: static before semi-dynamic, C-band before mmWave."""
    return sorted(results, key=_sort_key)


# ----------------------------------------------------------------------------------------------
# Table II


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


# ----------------------------------------------------------------------------------------------
# integrity table

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


# ----------------------------------------------------------------------------------------------
# figures


def _new_figure(w: float, h: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _xlim(curves: Sequence[np.ndarray]) -> tuple[float, float]:
    """Log-x limits that show the whole of every curve: from a decade-aligned value below the
    smallest positive error (at least 1 mm) to 1.3x the largest. On a log axis the bulk (cm to
    dm) and the NLoS tail (metres to tens of metres) are both readable."""
    fin = [c[np.isfinite(c) & (c > 0)] for c in curves]
    fin = [c for c in fin if c.size]
    if not fin:
        return 1e-2, 10.0
    lo = max(min(float(np.percentile(c, 1.0)) for c in fin), 1e-3)
    hi = max(float(c.max()) for c in fin)
    lo = 10.0 ** np.floor(np.log10(lo))
    return lo, max(hi * 1.3, lo * 10.0)


def _grid(n: int) -> tuple[int, int]:
    ncols = min(n, 3)
    return (n + ncols - 1) // ncols, ncols


def _cdf_axes(ax: Any, title: str, xlim: tuple[float, float]) -> None:
    ax.set_title(title)
    ax.set_xscale("log")
    ax.set_xlabel("2D positioning error [m] (log scale)")
    ax.set_ylabel("CDF (share of all epochs)")
    ax.set_xlim(*xlim)
    ax.set_ylim(0.0, 1.0)
    ax.axhline(0.9, color="0.6", lw=0.8, ls=":")
    ax.grid(True, which="both", alpha=0.3)


def _cdf_curve(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CDF over *all* epochs: unsolved ones count in the denominator, so an estimator cannot
    look better by leaving hard epochs out (the curve ends at the availability)."""
    x, y = cdf(errors)
    n_all = max(int(np.size(errors)), 1)
    return x, y * (x.size / n_all)


def _legend_text(name: str, s: Mapping[str, float], errors: np.ndarray) -> str:
    fin = errors[np.isfinite(errors)]
    mx = float(fin.max()) if fin.size else float("nan")
    return f"{name}: p90 {s['p90_m']:.2f} m, max {mx:.1f} m, avail. {s.get('availability_pct', 100.0):.0f} %"


def plot_cdf_by_method(
    results: Sequence[DatasetResult], methods: Sequence[str], path: str | Path
) -> None:
    """One panel per method, one CDF curve per dataset (the paper's Fig. 2 a/b), log x axis;
    the legend gives each curve's p90, max and availability."""
    nrows, ncols = _grid(len(methods))
    fig = _new_figure(4.6 * ncols, 3.6 * nrows)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    res = sort_results(results)
    xlim = _xlim([r.errors[m] for r in res for m in methods])
    for ax, m in zip(axes, methods, strict=False):
        for r in res:
            x, y = _cdf_curve(r.errors[m])
            label = _legend_text(
                f"{r.dataset.scenario} {band_label(r.dataset.band)}", r.summaries[m], r.errors[m]
            )
            ax.step(x, y, where="post", label=label)
        _cdf_axes(ax, method_label(m), xlim)
        ax.legend(fontsize=6, loc="upper left")
    for ax in axes[len(methods) :]:
        ax.set_visible(False)
    save_figure(fig, path)


def plot_cdf_methods(result: DatasetResult, methods: Sequence[str], path: str | Path) -> None:
    """CDF of every method on one dataset, log x axis; legend: p90, max, availability."""
    fig = _new_figure(6.0, 4.2)
    ax = fig.subplots()
    xlim = _xlim([result.errors[m] for m in methods])
    for m in methods:
        x, y = _cdf_curve(result.errors[m])
        label = _legend_text(method_label(m), result.summaries[m], result.errors[m])
        ax.step(x, y, where="post", label=label)
    _cdf_axes(ax, result.label, xlim)
    ax.legend(fontsize=7, loc="upper left")
    save_figure(fig, path)


def _polygon_list(meta: Mapping[str, Any]) -> list[tuple[str, np.ndarray]]:
    """Valid ``obstacles_2d`` footprints (malformed entries are skipped: they are decoration)."""
    out = []
    obs = meta.get("obstacles_2d")
    if not isinstance(obs, list):
        return out
    for o in obs:
        try:
            poly = np.asarray(o["polygon"], dtype=float)
        except (KeyError, TypeError, ValueError):
            continue
        if poly.ndim == 2 and poly.shape[0] >= 3 and poly.shape[1] == 2 and np.isfinite(poly).all():
            out.append((str(o.get("name", "")), poly))
    return out


def _hall_xy(meta: Mapping[str, Any]) -> np.ndarray | None:
    try:
        h = np.asarray(meta["hall_xy"], dtype=float)
    except (KeyError, TypeError, ValueError):
        return None
    return h if h.shape == (2, 2) and np.isfinite(h).all() else None


def point_mean_errors(
    result: DatasetResult, method: str
) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Per point: names, true xy (P, 2) and mean 2D error (P,) of ``method`` (NaN if unsolved)."""
    ds = result.dataset
    names = list(dict.fromkeys(ds.point.tolist()))
    xy = np.empty((len(names), 2))
    err = np.empty(len(names))
    e = result.errors[method]
    for i, n in enumerate(names):
        sel = ds.point == n
        xy[i] = ds.true_xyz[sel][0, :2]
        fin = e[sel][np.isfinite(e[sel])]
        err[i] = fin.mean() if fin.size else np.nan
    return names, xy, err


def plot_topview(result: DatasetResult, methods: Sequence[str], path: str | Path) -> None:
    """Top view of the hall, one panel per method: each point coloured and sized by its mean 2D
    error, base stations marked, ``obstacles_2d`` footprints greyed, ``hall_xy`` outlined."""
    from matplotlib.colors import Normalize
    from matplotlib.patches import Polygon, Rectangle

    ds = result.dataset
    per = {m: point_mean_errors(result, m) for m in methods}
    allerr = np.concatenate([per[m][2] for m in methods])
    fin = allerr[np.isfinite(allerr)]
    vmax = float(np.percentile(fin, 98)) if fin.size else 1.0
    norm = Normalize(vmin=0.0, vmax=max(vmax, 1e-3))
    nrows, ncols = _grid(len(methods))
    fig = _new_figure(4.6 * ncols, 4.0 * nrows)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    polys = _polygon_list(ds.meta)
    hall = _hall_xy(ds.meta)
    try:
        area = dataset_area(ds)
    except PositioningError:  # a malformed area was refused when solving; here it is decoration
        area = None
    sc = None
    for ax, m in zip(axes, methods, strict=False):
        for _, poly in polys:
            ax.add_patch(Polygon(poly, closed=True, fc="0.85", ec="0.55", lw=0.6, zorder=1))
        if hall is not None:
            (x0, y0), (x1, y1) = hall
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="k", lw=1.0))
        if area is not None:
            ax.add_patch(
                Polygon(
                    area.polygon,
                    closed=True,
                    fill=False,
                    ec="tab:blue",
                    lw=1.4,
                    ls="--",
                    label="service area",
                    zorder=2,
                )
            )
        names, xy, err = per[m]
        size = 30.0 + 170.0 * np.clip(np.nan_to_num(err, nan=0.0) / norm.vmax, 0.0, 1.0)
        sc = ax.scatter(
            xy[:, 0], xy[:, 1], c=err, s=size, cmap="viridis", norm=norm, ec="k", lw=0.4, zorder=3
        )
        nan = ~np.isfinite(err)
        if nan.any():
            ax.scatter(xy[nan, 0], xy[nan, 1], marker="x", c="r", s=40, zorder=4)
        ax.scatter(ds.bs_xyz[:, 0], ds.bs_xyz[:, 1], marker="^", c="r", s=80, ec="k", zorder=5)
        for n, b in zip(ds.bs_names, ds.bs_xyz, strict=True):
            ax.annotate(n, b[:2], xytext=(4, 4), textcoords="offset points", fontsize=7)
        s = result.summaries[m]
        nb = result.fixes[m].count(Status.AREA_BOUND)
        ax.set_title(
            f"{method_label(m)}: mean {s['mean_m']:.2f} m, {nb} fixes area-bound", fontsize=9
        )
        if area is not None:
            ax.legend(fontsize=7, loc="lower right")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    for ax in axes[len(methods) :]:
        ax.set_visible(False)
    if sc is not None:
        fig.colorbar(sc, ax=axes[: len(methods)].tolist(), label="mean 2D error per point [m]")
    fig.suptitle(result.label)
    save_figure(fig, path)


def safe_name(text: str) -> str:
    """File-name-safe version of a dataset name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "dataset"


def write_report(
    results: Sequence[DatasetResult], methods: Sequence[str], out_dir: str | Path
) -> tuple[str, list[Path]]:
    """Write ``table.md``, ``table.csv`` and the PNG figures; return (markdown, written paths).

    Files: ``cdf_by_method.png`` (panel per method, curve per dataset),
    ``cdf_<dataset>.png`` (methods compared on one dataset), ``topview_<dataset>.png``.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PositioningError(f"{out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    tracked = [m for m in methods if split_method(m)[1]]
    methods = [m for m in methods if not split_method(m)[1]]
    rows = table_rows(results, methods)
    md = table_markdown(rows, methods)
    written: list[Path] = []
    if tracked:  # tracked rows never mix with single-epoch ones: their own table and CDFs
        t_rows = table_rows(results, tracked)
        t_md = table_markdown(t_rows, tracked)
        atomic_write_text(out / "table_tracked.csv", table_csv(t_rows, tracked))
        atomic_write_text(out / "table_tracked.md", t_md)
        plot_cdf_by_method(results, tracked, out / "cdf_tracked_by_method.png")
        written += [out / "table_tracked.csv", out / "table_tracked.md"]
        written.append(out / "cdf_tracked_by_method.png")
        md = md + "\nTracked (METHOD+track, filtered over each point's epochs):\n\n" + t_md
    if not methods:
        return md, written
    names: dict[str, int] = {}
    for r in sort_results(results):
        base = safe_name(r.dataset.name)
        names[base] = names.get(base, 0) + 1
        if names[base] > 1:
            base = f"{base}_{names[base]}"
        for kind, fn in (("cdf", plot_cdf_methods), ("topview", plot_topview)):
            p = out / f"{kind}_{base}.png"
            fn(r, methods, p)
            written.append(p)
    p = out / "cdf_by_method.png"
    plot_cdf_by_method(results, methods, p)
    written.append(p)
    atomic_write_text(out / "table.csv", table_csv(rows, methods))
    atomic_write_text(out / "table.md", md)
    irows = integrity_rows(results, methods)
    atomic_write_text(out / "integrity.csv", _csv_text(irows, INTEGRITY_COLUMNS))
    atomic_write_text(out / "integrity.md", integrity_markdown(irows))
    written += [out / "table.csv", out / "table.md", out / "integrity.csv", out / "integrity.md"]
    return md, written
