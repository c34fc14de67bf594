"""TDoA positioning from ToA measurements: the paper's LS and IRLS plus robust estimators.

Works on ToA arrays from any source (the ray tracer's datasets or a real device's logs); it never
imports :mod:`raytrace`. Entry point: :func:`locate`. Methods: :data:`METHODS`. Fixes are kept
inside a :class:`ServiceArea`; :class:`LinkInfo` carries the receiver's per-link reports.
"""

from __future__ import annotations

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
