"""The report's figures: CDFs of the 2D error (the paper's Fig. 2 style, log x axis) and a top
view of the hall with each point's mean error.

Plots use matplotlib's object API with the Agg canvas (no global backend, no display needed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PositioningError
from ..estimators.fixes import Status
from ..evaluation.metrics import cdf
from ..io.dataset import dataset_area
from .files import save_figure
from .runs import DatasetResult, band_label, method_label, sort_results


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
    from matplotlib.collections import PatchCollection
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
        if polys:  # one artist for the ~100 footprints (a patch each was a third of the figure)
            ax.add_collection(PatchCollection(
                [Polygon(poly, closed=True) for _, poly in polys], fc="0.85", ec="0.55", lw=0.6,
                zorder=1,
            ))  # fmt: skip
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
