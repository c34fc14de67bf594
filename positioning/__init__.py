"""TDoA positioning from ToA measurements: the paper's LS and IRLS plus robust estimators.

Works on ToA arrays from any source (the ray tracer's datasets or a real device's logs); it never
imports :mod:`raytrace`. Entry point: :func:`locate`. Methods: :data:`METHODS`. Fixes are kept
inside a :class:`ServiceArea`; :class:`LinkInfo` carries the receiver's per-link reports.

This module is the one stable public API; the code lives in layered subpackages along the flow
ToA -> problem -> estimate -> evaluate -> report: ``model``, ``io``, ``estimators``, ``twin``,
``evaluation``, ``methods``, ``report``, ``cli`` (docs/architecture.md). The modules of the flat
package before (``positioning.tdoa``, ``positioning.irls``, ...) forward their names for one
release with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

#: Where each public name lives (module under ``positioning``). Imported on first use (PEP 562):
#: importing ``positioning`` (or ``positioning.errors``, which every error path needs) must not
#: pull in the estimators (scipy.stats alone is 0.45 s of a command's start).
_WHERE = {
    "METHODS": "methods.registry", "Method": "methods.registry",
    "method_names": "methods.registry", "resolve_params": "methods.registry",
    "locate": "methods.run", "run_method": "methods.run",
    "ServiceArea": "model.area", "area_from_meta": "model.area",
    "PositioningError": "errors",
    "Fixes": "estimators.fixes", "Status": "estimators.fixes", "status_label": "estimators.fixes",
    "andrews_weight": "estimators.irls",
    "cdf": "evaluation.metrics", "error_2d": "evaluation.metrics",
    "summarize": "evaluation.metrics",
    "C0": "model.tdoa", "pseudoranges": "model.tdoa", "range_differences": "model.tdoa",
    "signed_tdoa": "model.tdoa",
    "LinkInfo": "model.problem", "Problem": "model.problem", "make_problem": "model.problem",
    "read_dataset": "io.frames", "read_fixes": "io.frames", "read_accuracy_map": "io.frames",
}  # fmt: skip

if TYPE_CHECKING:
    from .errors import PositioningError
    from .estimators.fixes import Fixes, Status, status_label
    from .estimators.irls import andrews_weight
    from .evaluation.metrics import cdf, error_2d, summarize
    from .io.frames import read_accuracy_map, read_dataset, read_fixes
    from .methods.registry import METHODS, Method, method_names, resolve_params
    from .methods.run import locate, run_method
    from .model.area import ServiceArea, area_from_meta
    from .model.problem import LinkInfo, Problem, make_problem
    from .model.tdoa import C0, pseudoranges, range_differences, signed_tdoa


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
    "read_accuracy_map",
    "read_dataset",
    "read_fixes",
    "resolve_params",
    "run_method",
    "signed_tdoa",
    "status_label",
    "summarize",
]
