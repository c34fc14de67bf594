"""The registry of positioning methods: their names, parameters (defaults and kinds) and how
each is run; :func:`resolve_params` validates parameters (also strings from the command line).

Running a method on a problem is :mod:`positioning.methods.run` (:func:`~positioning.methods.run.
run_method`, :func:`~positioning.methods.run.locate`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, fields
from typing import Any

import numpy as np

from hallray.errors import brief

from ..errors import PositioningError
from ..estimators.eq7 import REFERENCE_CHOICES, parse_reference
from ..estimators.fixes import Fixes
from ..estimators.irls import IrlsConfig, LsConfig, irls, least_squares
from ..estimators.nlos import NlosMapConfig, nlos_map
from ..estimators.robust import (
    MEstimatorConfig,
    NlosAwareConfig,
    SubsetConfig,
    m_estimator,
    nlos_aware,
    subset,
)
from ..model.problem import Problem
from ..twin.estimator import TwinConfig, twin

#: Sentinel kinds of method parameters (used to validate and to parse CLI ``k=v`` strings).
_POS_FLOAT = "positive float"
_POS_INT = "positive int"
_OPT_INDEX = "base-station index or none"
_OPT_COUNT = "non-negative int or none"
_COUNT = "non-negative int"
_PROB = "probability in (0, 1)"
_MAP = "fingerprint map (file path)"
_REFERENCE = f"reference choice ({', '.join(REFERENCE_CHOICES)})"
#: Map-free methods a ``twin`` fix may fall back to.
_FALLBACKS = ("nlos-aware", "irls", "ls", "m-estimator", "subset")

#: How a registered method runs: ``run(problem, params) -> Fixes`` with its parameters resolved.
Runner = Callable[[Problem, Mapping[str, Any]], Fixes]


@dataclass(frozen=True)
class Method:
    """One registered positioning method.

    Attributes
    ----------
    name : str -- registry key (``ls``, ``irls``, ...)
    run : ``run(problem, params) -> Fixes`` with the parameters resolved
        (:func:`resolve_params`): the estimator with its config built from them
    params : mapping name -> (default, kind) where kind is a validation rule or a tuple of choices
    summary : one-line description (shown by ``estimate-positions --list-methods``)
    paper : True for the paper's own methods (LS, IRLS)
    measurement_weights : True if the result's ``weights`` weight the measurements (used by the
        bounded re-solve); False (LS, IRLS): every received measurement counts alike there
    needs_map : True for methods that need a fingerprint map (``twin``; not run by default)
    """

    name: str
    run: Runner
    params: Mapping[str, tuple[Any, Any]]
    summary: str
    paper: bool = False
    measurement_weights: bool = True
    needs_map: bool = False

    @property
    def func(self) -> Callable[..., Fixes]:
        """Deprecated: ``func(problem, **params)``, the method as called before it took a config;
        use :attr:`run`. Works for one release, with a :class:`DeprecationWarning`."""
        warnings.warn(
            f"positioning.Method.func moved to positioning.Method.run (method {brief(self.name)}, "
            "run(problem, params)); the old path goes away in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return lambda prob, **params: self.run(prob, params)


def _params(config: type, kinds: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """The registry's parameters ``name -> (default, kind)`` of the config fields ``kinds`` names
    (in its order), each default the config's own."""
    defaults = {f.name: f.default for f in fields(config) if f.default is not MISSING}
    return {name: (defaults[name], kind) for name, kind in kinds.items()}


def _runner(estimator: Callable[[Problem, Any], Fixes], config: type) -> Runner:
    """``run(problem, params)`` of an estimator whose config takes the parameters as fields."""
    return lambda prob, params: estimator(prob, config(**params))


def _run_irls_paper(prob: Problem, params: Mapping[str, Any]) -> Fixes:
    """``irls-paper``: Algorithm 1 as written (no guard on the per-reference estimates)."""
    return irls(prob, IrlsConfig(guard=False, **params))


def _run_twin(prob: Problem, params: Mapping[str, Any]) -> Fixes:
    """``twin``: the ``map`` parameter is the config's fingerprint map; ``fallback`` names the
    map-free method (run with its defaults) that the twin falls back to."""
    p = dict(params)
    fallback = _solver(p.pop("fallback"))
    return twin(prob, TwinConfig(fingerprint_map=p.pop("map"), **p), fallback=fallback)


_MARGIN = {"region_margin": _POS_FLOAT}

METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method(
            "ls",
            _runner(least_squares, LsConfig),
            _params(LsConfig, {"reference": _REFERENCE, "seed": _COUNT, "tol_m": _POS_FLOAT,
                               "max_iter": _POS_INT, "grid_m": "non-negative float"}),
            "paper eq. 7: least squares of signed TDoAs against one reference base station "
            "(first, random: the paper's, strongest or fixed:N), lowest minimum in the area",
            paper=True,
            measurement_weights=False,
        ),
        Method(
            "irls",
            _runner(irls, IrlsConfig),
            _params(IrlsConfig, {"u_max": _POS_FLOAT, "epsilon": _POS_FLOAT, "max_iter": _POS_INT,
                                 "ls_tol_m": _POS_FLOAT, "ls_max_iter": _POS_INT,
                                 "ls_grid_m": "non-negative float"}),
            "paper Algorithm 1: every base station the reference once, Andrews-sine weights; "
            "guarded: only converged, plausible per-reference estimates are averaged",
            paper=True,
            measurement_weights=False,
        ),
        Method(
            "irls-paper",
            _run_irls_paper,
            _params(IrlsConfig, {"u_max": _POS_FLOAT, "epsilon": _POS_FLOAT, "max_iter": _POS_INT,
                                 "ls_tol_m": _POS_FLOAT, "ls_max_iter": _POS_INT,
                                 "ls_grid_m": "non-negative float"}),
            "paper Algorithm 1 as written: every per-reference estimate averaged, no guard",
            paper=True,
            measurement_weights=False,
        ),
        Method(
            "m-estimator",
            _runner(m_estimator, MEstimatorConfig),
            _params(MEstimatorConfig, {
                "loss": ("tukey", "huber"), "c": "positive float or none",
                "scale_floor_m": _POS_FLOAT, "tol_m": _POS_FLOAT, "max_iter": _POS_INT,
                "gn_max_iter": _POS_INT, **_MARGIN,
            }),
            "reference-free MM-estimator: least-median start over subsets, Tukey IRLS at robust scale",
        ),
        Method(
            "subset",
            _runner(subset, SubsetConfig),
            _params(SubsetConfig, {
                "sigma_m": _POS_FLOAT, "alpha": _PROB, "max_drop": _OPT_COUNT,
                "tol_m": _POS_FLOAT, "max_iter": _POS_INT, **_MARGIN,
            }),
            "chi-square consistency test, drop the base station whose removal fits best",
        ),
        Method(
            "nlos-aware",
            _runner(nlos_aware, NlosAwareConfig),
            _params(NlosAwareConfig, {
                "sigma_m": _POS_FLOAT, "k": _POS_FLOAT, "max_drop": _COUNT, "tol_m": _POS_FLOAT,
                "max_iter": _POS_INT, "gn_max_iter": _POS_INT, **_MARGIN,
            }),
            "one-sided loss (NLoS only delays): subset hypotheses scored, then IRLS",
        ),
        Method(
            "nlos-map",
            _runner(nlos_map, NlosMapConfig),
            _params(NlosMapConfig, {
                "estimate": ("mean", "map"), "max_drop": _COUNT, "grid_m": "non-negative float",
                "n_grid_starts": _COUNT, "tol_m": _POS_FLOAT, "max_iter": _POS_INT,
                "gn_max_iter": _POS_INT, **_MARGIN,
            }),
            "physics mixture (noise, overlap, NLoS only delays; SNR and lobe shape), EM per start",
        ),
        Method(
            "twin",
            _run_twin,
            {
                "map": (None, _MAP),
                "fallback": ("nlos-aware", _FALLBACKS),
                **_params(TwinConfig, {
                    "fallback_m": _POS_FLOAT, "prior_m": "non-negative float or none",
                    "top": _POS_INT, "bias": ("auto", "cell", "interp", "resynth"),
                    "paths": _OPT_COUNT, "fd_jacobian": "bool", "resynth_m": _POS_FLOAT,
                    "cells": ("nearest", "own"), "resynth_top": _POS_INT,
                    "search_m": "non-negative float", "resynth_step": "non-negative float",
                }),
            },
            "fingerprint-map match + refinement with the map's NLoS bias or, with a v2 map, "
            "its paths re-synthesised (--map MAP), 2D",
            needs_map=True,
        ),
    )
}  # fmt: skip


def method_names(include_map: bool = True) -> list[str]:
    """Registered method names, paper methods first (``include_map=False``: map-free only)."""
    return [m for m, spec in METHODS.items() if include_map or not spec.needs_map]


def _coerce(method: str, name: str, value: Any, kind: Any, n_bs: int | None) -> Any:
    """Validate (and, for strings from the CLI, parse) one parameter value."""
    where = f"method {brief(method)} parameter {brief(name)}"
    if kind == _MAP:
        if value is None or (isinstance(value, str) and not value.strip()):
            raise PositioningError(f"method {brief(method)} needs a fingerprint map (--map MAP)")
        return value
    if kind == "bool":
        text = str(value).strip().lower()
        if isinstance(value, (bool, np.bool_)) or text in ("true", "false", "1", "0"):
            return text in ("true", "1")
        raise PositioningError(f"{where} must be true or false, got {brief(value)}")
    if kind == _REFERENCE:
        try:
            return parse_reference(value, n_bs)
        except PositioningError as exc:
            raise PositioningError(f"method {method!r} parameter {name!r}: {exc}") from None
    if isinstance(kind, tuple):
        if value not in kind:
            raise PositioningError(f"{where} must be one of {', '.join(kind)}, got {brief(value)}")
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
        raise PositioningError(f"{where} must be a {kind}, got {brief(value)}") from None
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
        raise PositioningError(f"{where} must be a {kind}{extra}, got {brief(value)}")
    return v


def resolve_params(method: str, params: Mapping[str, Any], n_bs: int | None = None) -> dict:
    """Defaults filled in and every value validated; unknown method or parameter raises.

    Values may be strings (as from ``--param k=v``); they are parsed by the parameter's kind.
    """
    if method not in METHODS:
        raise PositioningError(f"unknown method {brief(method)}; choose one of: {', '.join(METHODS)}")
    spec = METHODS[method].params
    unknown = sorted(set(params) - set(spec))
    if unknown:
        raise PositioningError(
            f"method {brief(method)} has no parameter {brief(unknown[0])}; "
            f"parameters: {', '.join(spec) or '(none)'}"
        )
    out = {}
    for name, (default, kind) in spec.items():
        out[name] = _coerce(method, name, params[name], kind, n_bs) if name in params else default
    return out


def _solver(method: str) -> Callable[[Problem], Fixes]:
    """The registered ``method`` with its default parameters, as ``f(problem) -> Fixes``."""
    return lambda prob: METHODS[method].run(prob, resolve_params(method, {}, prob.n_bs))
