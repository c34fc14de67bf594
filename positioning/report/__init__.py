"""The subpackage ``positioning.report`` writes what people and tools read: every method run on a
dataset (:mod:`~positioning.report.runs`), Table II and the integrity table
(:mod:`~positioning.report.tables`), the figures (:mod:`~positioning.report.figures`), the
report directory (:mod:`~positioning.report.write`, through :mod:`~positioning.report.files`) and
a method's ``fixes.csv`` (:mod:`~positioning.report.fixes_file`).

Until issue 35 ``positioning.report`` was one module; its names keep working from here for one
release (a :class:`DeprecationWarning` names each one's new module).
"""

from __future__ import annotations

from ..deprecated import forward

#: Old name -> its new module.
MOVED = {
    "dataset_problem": "positioning.io.prepare",
    "heights_for": "positioning.io.prepare",
    "plot_cdf_by_method": "positioning.report.figures",
    "plot_cdf_methods": "positioning.report.figures",
    "plot_topview": "positioning.report.figures",
    "point_mean_errors": "positioning.report.figures",
    "atomic_write": "positioning.report.files",
    "atomic_write_text": "positioning.report.files",
    "is_report_dir": "positioning.report.files",
    "safe_name": "positioning.report.files",
    "save_figure": "positioning.report.files",
    "DatasetResult": "positioning.report.runs",
    "band_label": "positioning.report.runs",
    "evaluate": "positioning.report.runs",
    "method_label": "positioning.report.runs",
    "solve_dataset": "positioning.report.runs",
    "sort_results": "positioning.report.runs",
    "INTEGRITY_COLUMNS": "positioning.report.tables",
    "METRICS": "positioning.report.tables",
    "PAPER_TABLE2": "positioning.report.tables",
    "integrity_markdown": "positioning.report.tables",
    "integrity_rows": "positioning.report.tables",
    "table_csv": "positioning.report.tables",
    "table_markdown": "positioning.report.tables",
    "table_rows": "positioning.report.tables",
    "write_report": "positioning.report.write",
}

__getattr__, __dir__ = forward(__name__, MOVED)
