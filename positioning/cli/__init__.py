"""The subpackage ``positioning.cli`` holds the commands ``estimate-positions``
(:mod:`~positioning.cli.estimate`) and ``accuracy-report`` (:mod:`~positioning.cli.accuracy`) and
what they share (:mod:`~positioning.cli.options`): argument parsing and printing only.

Until issue 35 ``positioning.cli`` was one module; its names keep working from here for one
release (a :class:`DeprecationWarning` names each one's new module).
"""

from __future__ import annotations

from ..deprecated import forward

#: Old name -> its new module.
MOVED = {
    "accuracy_report": "positioning.cli.accuracy",
    "accuracy_report_main": "positioning.cli.accuracy",
    "estimate_positions_main": "positioning.cli.estimate",
    "methods_help": "positioning.cli.options",
    "summary_line": "positioning.cli.options",
    "FIXES_COLUMNS": "positioning.report.fixes_file",
    "TWIN_COLUMNS": "positioning.report.fixes_file",
    "fixes_csv": "positioning.report.fixes_file",
}

__getattr__, __dir__ = forward(__name__, MOVED)
