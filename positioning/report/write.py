"""Accuracy report: the paper's Table II for our datasets, CDF plots (Fig. 2 style), hall top
view, written into one directory (:func:`write_report`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..errors import PositioningError
from ..estimators.track import split_method
from .figures import plot_cdf_by_method, plot_cdf_methods, plot_topview
from .files import atomic_write_text, safe_name
from .runs import DatasetResult, sort_results
from .tables import (
    integrity_csv,
    integrity_markdown,
    integrity_rows,
    table_csv,
    table_markdown,
    table_rows,
)


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
    atomic_write_text(out / "integrity.csv", integrity_csv(irows))
    atomic_write_text(out / "integrity.md", integrity_markdown(irows))
    written += [out / "table.csv", out / "table.md", out / "integrity.csv", out / "integrity.md"]
    return md, written
