"""The registry of positioning methods: their names, parameters (defaults and kinds) and how
each is run; :func:`resolve_params` validates parameters (also strings from the command line).

Running a method on a problem is :mod:`positioning.methods.run` (:func:`~positioning.methods.run.
run_method`, :func:`~positioning.methods.run.locate`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import PositioningError
from ..estimators import irls as _irls
from ..estimators import nlos as _nlos
from ..estimators import robust as _robust
from ..model.problem import Problem
from ..twin import estimator as _twin

#: Sentinel kinds of method parameters (used to validate and to parse CLI ``k=v`` strings).
_POS_FLOAT = "positive float"


_POS_INT = "positive int"


_OPT_INDEX = "base-station index or none"


_OPT_COUNT = "non-negative int or none"


_COUNT = "non-negative int"


_PROB = "probability in (0, 1)"


_MAP = "fingerprint map (file path)"


#: Map-free methods a ``twin`` fix may fall back to.
_FALLBACKS = ("nlos-aware", "irls", "ls", "m-estimator", "subset")


@dataclass(frozen=True)
class Method:
    """One registered positioning method.

    Attributes
    ----------
    name : str -- registry key (``ls``, ``irls``, ...)
    func : ``func(problem, **params) -> dict`` of arrays (see :mod:`positioning.irls`)
    params : mapping name -> (default, kind) where kind is a validation rule or a tuple of choices
    summary : one-line description (shown by ``estimate-positions --list-methods``)
    paper : True for the paper's own methods (LS, IRLS)
    measurement_weights : True if the result's ``weights`` weight the measurements (used by the
        bounded re-solve); False (LS, IRLS): every received measurement counts alike there
    needs_map : True for methods that need a fingerprint map (``twin``; not run by default)
    """

    name: str
    func: Callable[..., dict[str, np.ndarray]]
    params: Mapping[str, tuple[Any, Any]]
    summary: str
    paper: bool = False
    measurement_weights: bool = True
    needs_map: bool = False


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method(
            "ls",
            _irls.least_squares,
            {
                "reference": (None, _OPT_INDEX),
                "tol_m": (_irls.LS_TOL_M, _POS_FLOAT),
                "max_iter": (_irls.LS_MAX_ITER, _POS_INT),
            },
            "paper eq. 7: least squares of signed TDoAs against one reference base station",
            paper=True,
            measurement_weights=False,
        ),
        Method(
            "irls",
            _irls.irls,
            {
                "u_max": (_irls.U_MAX_M, _POS_FLOAT),
                "epsilon": (_irls.EPSILON_M, _POS_FLOAT),
                "max_iter": (_irls.MAX_ITER, _POS_INT),
                "ls_tol_m": (_irls.LS_TOL_M, _POS_FLOAT),
                "ls_max_iter": (_irls.LS_MAX_ITER, _POS_INT),
            },
            "paper Algorithm 1: every base station the reference once, Andrews-sine weights",
            paper=True,
            measurement_weights=False,
        ),
        Method(
            "m-estimator",
            _robust.m_estimator,
            {
                "loss": ("tukey", ("tukey", "huber")),
                "c": (None, "positive float or none"),
                "scale_floor_m": (_robust.SCALE_FLOOR_M, _POS_FLOAT),
                "tol_m": (1e-6, _POS_FLOAT),
                "max_iter": (50, _POS_INT),
                "gn_max_iter": (10, _POS_INT),
                "region_margin": (_robust.REGION_MARGIN, _POS_FLOAT),
            },
            "reference-free MM-estimator: least-median start over subsets, Tukey IRLS at robust scale",
        ),
        Method(
            "subset",
            _robust.subset,
            {
                "sigma_m": (_robust.SIGMA_M, _POS_FLOAT),
                "alpha": (0.01, _PROB),
                "max_drop": (None, _OPT_COUNT),
                "tol_m": (1e-9, _POS_FLOAT),
                "max_iter": (50, _POS_INT),
                "region_margin": (_robust.REGION_MARGIN, _POS_FLOAT),
            },
            "chi-square consistency test, drop the base station whose removal fits best",
        ),
        Method(
            "nlos-aware",
            _robust.nlos_aware,
            {
                "sigma_m": (_robust.SIGMA_M, _POS_FLOAT),
                "k": (_robust.NLOS_K, _POS_FLOAT),
                "max_drop": (1, _COUNT),
                "tol_m": (1e-6, _POS_FLOAT),
                "max_iter": (50, _POS_INT),
                "gn_max_iter": (10, _POS_INT),
                "region_margin": (_robust.REGION_MARGIN, _POS_FLOAT),
            },
            "one-sided loss (NLoS only delays): subset hypotheses scored, then IRLS",
        ),
        Method(
            "nlos-map",
            _nlos.nlos_map,
            {
                "estimate": ("mean", ("mean", "map")),
                "max_drop": (1, _COUNT),
                "grid_m": (2.0, "non-negative float"),
                "n_grid_starts": (3, _COUNT),
                "tol_m": (1e-4, _POS_FLOAT),
                "max_iter": (30, _POS_INT),
                "gn_max_iter": (5, _POS_INT),
                "region_margin": (_robust.REGION_MARGIN, _POS_FLOAT),
            },
            "physics mixture (noise, overlap, NLoS only delays; SNR and lobe shape), EM per start",
        ),
        Method(
            "twin",
            lambda prob, *, fallback, **p: _twin.twin(prob, fallback=_solver(fallback), **p),
            {
                "map": (None, _MAP),
                "fallback": ("nlos-aware", _FALLBACKS),
                "fallback_m": (_twin.FALLBACK_M, _POS_FLOAT),
                "prior_m": (None, "non-negative float or none"),
                "top": (_twin.TOP, _POS_INT),
                "bias": ("auto", ("auto", "cell", "interp", "resynth")),
                "paths": (None, _OPT_COUNT),
                "fd_jacobian": (True, "bool"),
                "resynth_m": (_twin.RESYNTH_M, _POS_FLOAT),
                "cells": ("nearest", ("nearest", "own")),
                "resynth_top": (_twin.RESYNTH_TOP, _POS_INT),
                "search_m": (_twin.SEARCH_M, "non-negative float"),
                "resynth_step": (_twin.RASTER_STEP_M, "non-negative float"),
            },
            "fingerprint-map match + refinement with the map's NLoS bias or, with a v2 map, "
            "its paths re-synthesised (--map MAP), 2D",
            needs_map=True,
        ),
    )
}


def method_names(include_map: bool = True) -> list[str]:
    """Registered method names, paper methods first (``include_map=False``: map-free only)."""
    return [m for m, spec in METHODS.items() if include_map or not spec.needs_map]


def _coerce(method: str, name: str, value: Any, kind: Any, n_bs: int | None) -> Any:
    """Validate (and, for strings from the CLI, parse) one parameter value."""
    where = f"method {method!r} parameter {name!r}"
    if kind == _MAP:
        if value is None or (isinstance(value, str) and not value.strip()):
            raise PositioningError(f"method {method!r} needs a fingerprint map (--map MAP)")
        return value
    if kind == "bool":
        text = str(value).strip().lower()
        if isinstance(value, (bool, np.bool_)) or text in ("true", "false", "1", "0"):
            return text in ("true", "1")
        raise PositioningError(f"{where} must be true or false, got {value!r}")
    if isinstance(kind, tuple):
        if value not in kind:
            raise PositioningError(f"{where} must be one of {', '.join(kind)}, got {value!r}")
        return value
    if isinstance(value, str) and value.strip().lower() in ("none", "null", ""):
        value = None
    if value is None:
        if kind in (_OPT_INDEX, _OPT_COUNT, "positive float or none", "non-negative float or none"):
            return None
        raise PositioningError(f"{where} must be a {kind}, got None")
    try:
        if kind in (_POS_INT, _OPT_INDEX, _OPT_COUNT, _COUNT):
            if isinstance(value, (bool, np.bool_)):
                raise ValueError
            f = float(value)
            if not f.is_integer():
                raise ValueError
            v: Any = int(f)
        else:
            v = float(value)
    except (TypeError, ValueError):
        raise PositioningError(f"{where} must be a {kind}, got {value!r}") from None
    ok = {
        _POS_FLOAT: lambda x: np.isfinite(x) and x > 0,
        "positive float or none": lambda x: np.isfinite(x) and x > 0,
        _POS_INT: lambda x: x > 0,
        _OPT_COUNT: lambda x: x >= 0,
        _COUNT: lambda x: x >= 0,
        _PROB: lambda x: 0 < x < 1,
        "non-negative float": lambda x: np.isfinite(x) and x >= 0,
        "non-negative float or none": lambda x: np.isfinite(x) and x >= 0,
        _OPT_INDEX: lambda x: x >= 0 and (n_bs is None or x < n_bs),
    }[kind](v)
    if not ok:
        extra = f" (there are {n_bs} base stations)" if kind == _OPT_INDEX else ""
        raise PositioningError(f"{where} must be a {kind}{extra}, got {value!r}")
    return v


def resolve_params(method: str, params: Mapping[str, Any], n_bs: int | None = None) -> dict:
    """Defaults filled in and every value validated; unknown method or parameter raises.

    Values may be strings (as from ``--param k=v``); they are parsed by the parameter's kind.
    """
    if method not in METHODS:
        raise PositioningError(f"unknown method {method!r}; choose one of: {', '.join(METHODS)}")
    spec = METHODS[method].params
    unknown = sorted(set(params) - set(spec))
    if unknown:
        raise PositioningError(
            f"method {method!r} has no parameter {unknown[0]!r}; "
            f"parameters: {', '.join(spec) or '(none)'}"
        )
    out = {}
    for name, (default, kind) in spec.items():
        out[name] = _coerce(method, name, params[name], kind, n_bs) if name in params else default
    return out


def _solver(method: str) -> Callable[[Problem], dict[str, np.ndarray]]:
    """The registered ``method`` with its default parameters, as ``f(problem) -> dict``."""
    return lambda prob: METHODS[method].func(prob, **resolve_params(method, {}, prob.n_bs))
