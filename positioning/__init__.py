"""TDoA positioning from ToA measurements: the paper's LS and IRLS plus robust estimators.

Works on ToA arrays from any source (the ray tracer's datasets or a real device's logs); it never
imports :mod:`raytrace`. Entry point: :func:`locate`. Methods: :data:`METHODS`. Fixes are kept
inside a :class:`ServiceArea`; :class:`LinkInfo` carries the receiver's per-link reports.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

#: Where each public name lives. Imported on first use (PEP 562): ``hallray.harness``,
#: which every command-line tool's harness imports, must not pull in the estimators (scipy.stats
#: alone is 0.45 s of a ``trace-scene`` start).
_WHERE = {
    "METHODS": "api", "Method": "api", "locate": "api", "method_names": "api",
    "resolve_params": "api", "run_method": "api",
    "ServiceArea": "area", "area_from_meta": "area",
    "PositioningError": "errors",
    "Fixes": "fixes", "Status": "fixes", "status_label": "fixes",
    "andrews_weight": "irls",
    "cdf": "metrics", "error_2d": "metrics", "summarize": "metrics",
    "C0": "tdoa", "LinkInfo": "tdoa", "Problem": "tdoa", "make_problem": "tdoa",
    "pseudoranges": "tdoa", "range_differences": "tdoa", "signed_tdoa": "tdoa",
}  # fmt: skip

if TYPE_CHECKING:
    from .api import METHODS, Method, locate, method_names, resolve_params, run_method
    from .area import ServiceArea, area_from_meta
    from .errors import PositioningError
    from .fixes import Fixes, Status, status_label
    from .irls import andrews_weight
    from .metrics import cdf, error_2d, summarize
    from .tdoa import (
        C0,
        LinkInfo,
        Problem,
        make_problem,
        pseudoranges,
        range_differences,
        signed_tdoa,
    )


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is not None:
        value = getattr(import_module(f".{module}", __name__), name)
        globals()[name] = value  # later look-ups are plain attribute reads
        return value
    if not name.startswith("_"):
        # ``positioning.twin`` and the like without importing them first, as before
        try:
            return import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module 'positioning' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


__all__ = [
    "C0",
    "METHODS",
    "Fixes",
    "LinkInfo",
    "Method",
    "PositioningError",
    "Problem",
    "ServiceArea",
    "Status",
    "andrews_weight",
    "area_from_meta",
    "cdf",
    "error_2d",
    "locate",
    "make_problem",
    "method_names",
    "pseudoranges",
    "range_differences",
    "resolve_params",
    "run_method",
    "signed_tdoa",
    "status_label",
    "summarize",
]
