"""Deprecated: ``positioning.dataset`` moved to :mod:`positioning.io.dataset`.

Its names forward to their new modules for one release, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from .deprecated import forward

#: Old name -> its new module.
MOVED = {
    "KNOWN_SCHEMA_VERSIONS": "positioning.io.dataset",
    "REPORT_COLUMNS": "positioning.io.dataset",
    "REQUIRED_COLUMNS": "positioning.io.dataset",
    "ToaDataset": "positioning.io.dataset",
    "dataset_area": "positioning.io.dataset",
    "link_budget_offset_db": "positioning.io.dataset",
    "link_reports": "positioning.io.dataset",
    "load_dataset": "positioning.io.dataset",
}

__getattr__, __dir__ = forward(__name__, MOVED)
