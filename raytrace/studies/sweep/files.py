"""A sweep's files: one result file per cell (``OUT/cells/<key>.json``, with its dataset
files when asked) and the results tables over the finished cells (``results.csv``,
``results.md``).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ...core.fileio import write_atomic
from .config import DATASET_FILES, Cell, SweepConfig


def cell_path(out_dir: str | os.PathLike[str], key: str) -> Path:
    return Path(out_dir) / "cells" / f"{key}.json"


def dataset_dir(out_dir: str | os.PathLike[str], key: str) -> Path:
    return Path(out_dir) / "datasets" / key


def write_cell_result(out_dir: str | os.PathLike[str], result: Mapping[str, Any]) -> Path:
    """Write a cell's result atomically to ``OUT/cells/<key>.json`` (and, first, its dataset
    files to ``OUT/datasets/<key>/``, so a cell file implies complete dataset files)."""
    result = dict(result)
    files = result.pop("_files", None) or {}
    if files:
        d = dataset_dir(out_dir, result["key"])
        d.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            write_atomic(d / name, text.encode("utf-8"))
    path = cell_path(out_dir, result["key"])
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, (json.dumps(result, indent=1, sort_keys=True) + "\n").encode())
    return path


def read_cell_result(out_dir: str | os.PathLike[str], cell: Cell) -> dict[str, Any] | None:
    """The stored result of a cell, or None if absent, unreadable or not this cell's."""
    path = cell_path(out_dir, cell.key)
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(result, dict) or result.get("key") != cell.key:
        return None
    if result.get("params") != cell.params or result.get("methods") != cell.methods:
        return None
    if cell.datasets and not all(
        (dataset_dir(out_dir, cell.key) / n).is_file() for n in DATASET_FILES
    ):
        return None
    return result


def table_rows(
    config: SweepConfig, results: Mapping[str, Mapping[str, Any]]
) -> tuple[list[str], list[list[Any]]]:
    """Header and rows of the results table, one row per finished cell in grid order."""
    methods = list(config.methods)
    head = ["cell", *config.varying, "los_fraction", "los_fraction_3gpp", "detected_fraction"]
    for m in methods:
        head += [f"{m}_mean_m", f"{m}_median_m", f"{m}_p90_m", f"{m}_unsolved"]
    head += ["n_fixes", "generate_s", "trace_s", "toa_s", "locate_s", "total_s"]
    rows = []
    for cell in config.cells():
        res = results.get(cell.key)
        if res is None:
            continue
        row: list[Any] = [cell.key, *(cell.value(k) for k in config.varying)]
        st = res["stats"]
        row += [st["los_fraction"], st["los_fraction_3gpp"], st["detected_fraction"]]
        for m in methods:
            e = res["errors"][m]
            row += [e["mean_m"], e["median_m"], e["p90_m"], e["n_unsolved"]]
        t = res["timing_s"]
        row += [st["n_fixes"], t["generate"], t["trace"], t["toa"], t["locate"], t["total"]]
        rows.append(row)
    return head, rows


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    if isinstance(v, (list, tuple)):
        return "x".join(str(x) for x in v)
    return str(v)


def results_table_markdown(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Markdown of the sweep's results table (:func:`table_rows`: any header, one row per cell).

    Floats with 3 decimals (2 in the seconds columns, ``*_s``), lists as ``AxB`` (sizes,
    grids), None as ``-``. Not :func:`positioning.report.tables.table_markdown`, which writes the
    paper's Table II (fixed columns: metric and dataset rows, the paper's values beside ours).
    """
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [_fmt(v, 2 if h.endswith("_s") else 3) for h, v in zip(head, row)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def results_table_csv(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """CSV of the sweep's results table: full precision, lists as ``AxB``, None empty (unlike
    :func:`positioning.report.tables.table_csv`, Table II's fixed columns at 6 significant digits)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for row in rows:
        w.writerow(
            [
                "" if v is None else ("x".join(map(str, v)) if isinstance(v, list) else v)
                for v in row
            ]
        )
    return buf.getvalue()


def write_tables(
    out_dir: str | os.PathLike[str], config: SweepConfig, results: Mapping[str, Mapping[str, Any]]
) -> tuple[Path, Path]:
    """``OUT/results.csv`` and ``OUT/results.md`` (atomically) over the finished cells."""
    out = Path(out_dir)
    head, rows = table_rows(config, results)
    csv_path, md_path = out / "results.csv", out / "results.md"
    write_atomic(csv_path, results_table_csv(head, rows).encode())
    title = f"# Sweep {config.name}: {len(rows)} of {len(config.cells())} cells\n\n"
    if config.fixed:
        fixed = ", ".join(f"{k} = {_fmt(v)}" for k, v in config.fixed.items())
        title += f"Fixed: {fixed}. "
    title += "Methods: " + ", ".join(
        f"{m} ({', '.join(f'{k}={v}' for k, v in p.items())})" for m, p in config.methods.items()
    )
    title += ". Errors are 2D, in metres, over all fixes (epochs x points) of a cell.\n\n"
    write_atomic(md_path, (title + results_table_markdown(head, rows)).encode())
    return csv_path, md_path
