"""Public entry point :func:`locate` and the table of positioning methods."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, overload

import numpy as np

from . import irls as _irls
from . import nlos as _nlos
from . import robust as _robust
from . import twin as _twin
from .area import ServiceArea
from .bounded import bounded_refit
from .errors import PositioningError
from .fixes import Fixes, Status
from .tdoa import LinkInfo, Problem, make_problem

#: What to do with a fix outside the service area: solve again inside it, or leave it unsolved.
OUTSIDE_CHOICES = ("constrain", "reject")

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


_FIXES_KEYS = ("xyz", "status", "iterations", "weights", "fit_weights")


def _solver(method: str) -> Callable[[Problem], dict[str, np.ndarray]]:
    """The registered ``method`` with its default parameters, as ``f(problem) -> dict``."""
    return lambda prob: METHODS[method].func(prob, **resolve_params(method, {}, prob.n_bs))



def apply_area(
    prob: Problem, res: Mapping[str, np.ndarray], fit_weights: np.ndarray, outside: str
) -> tuple[np.ndarray, np.ndarray]:
    """Keep every solved fix inside ``prob.area`` (see :mod:`positioning.bounded`).

    Parameters
    ----------
    res : a method's result (``xyz`` (E, 3), ``status`` (E,))
    fit_weights : (E, N) measurement weights of the bounded re-solve
    outside : "constrain" (re-solve inside, flag ``AREA_BOUND``) or "reject" (flag
        ``UNSOLVED | AREA_BOUND``, NaN position)

    Returns
    -------
    xyz (E, 3), status (E,) -- copies.
    """
    xyz = np.array(res["xyz"], dtype=float)
    status = np.asarray(res["status"], dtype=np.int64).copy()
    if prob.area is None:
        return xyz, status
    solved = (status & int(Status.UNSOLVED)) == 0
    out = solved & ~prob.area.contains(xyz[:, :2])
    idx = np.flatnonzero(out)
    if idx.size == 0:
        return xyz, status
    if outside == "reject":
        xyz[idx] = np.nan
        status[idx] |= int(Status.UNSOLVED | Status.AREA_BOUND)
        return xyz, status
    xyz[idx], _ = bounded_refit(prob, idx, xyz[idx], fit_weights[idx])
    status[idx] |= int(Status.AREA_BOUND)
    return xyz, status


def run_method(
    prob: Problem,
    method: str = "irls",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = None,
    **params: Any,
) -> Fixes:
    """Solve a prepared :class:`~positioning.tdoa.Problem` with one registered method.

    The method solves without bounds; fixes outside ``prob.area`` are then solved again inside it
    (``outside="constrain"``) or left unsolved (``"reject"``), both flagged ``AREA_BOUND``. With
    ``alert_limit_m`` the integrity figures (:mod:`positioning.integrity`) are computed and fixes
    whose protection level exceeds it are flagged ``INTEGRITY``.
    """
    if outside not in OUTSIDE_CHOICES:
        raise PositioningError(
            f"outside must be one of {', '.join(OUTSIDE_CHOICES)}, got {outside!r}"
        )
    if alert_limit_m is not None and not (np.isfinite(alert_limit_m) and alert_limit_m > 0):
        raise PositioningError(
            f"alert limit must be a positive number of metres, got {alert_limit_m!r}"
        )
    p = resolve_params(method, params, prob.n_bs)
    m = METHODS[method]
    res = m.func(prob, **p)
    fw = res.get("fit_weights")
    if fw is None:
        fw = res["weights"] if m.measurement_weights else prob.valid.astype(float)
    xyz, status = apply_area(prob, res, np.asarray(fw, dtype=float), outside)
    hpl = chi2n = None
    limit = float("nan")
    if alert_limit_m is not None:
        from .integrity import integrity

        hpl, chi2n = integrity(prob, xyz, status)
        limit = float(alert_limit_m)
        solved = (status & int(Status.UNSOLVED)) == 0
        status |= np.where(solved & ~(hpl <= limit), int(Status.INTEGRITY), 0)
    return Fixes(
        xyz=xyz,
        status=status,
        iterations=np.asarray(res["iterations"], dtype=np.int64),
        weights=res["weights"],
        n_used=prob.n_valid,
        method=method,
        params=p,
        hpl_m=hpl,
        chi2n=chi2n,
        alert_limit_m=limit,
        extra={k: v for k, v in res.items() if k not in _FIXES_KEYS},
    )


@overload
def locate(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    method: str = ...,
    *,
    tx_offsets_s: np.ndarray | None = ...,
    height_m: float | np.ndarray | None = ...,
    area: ServiceArea | np.ndarray | None = ...,
    outside: str = ...,
    links: LinkInfo | None = ...,
    alert_limit_m: float | None = ...,
    return_info: Literal[False] = ...,
    **params: Any,
) -> np.ndarray: ...


@overload
def locate(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    method: str = ...,
    *,
    tx_offsets_s: np.ndarray | None = ...,
    height_m: float | np.ndarray | None = ...,
    area: ServiceArea | np.ndarray | None = ...,
    outside: str = ...,
    links: LinkInfo | None = ...,
    alert_limit_m: float | None = ...,
    return_info: Literal[True],
    **params: Any,
) -> Fixes: ...


def locate(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    method: str = "irls",
    *,
    tx_offsets_s: np.ndarray | None = None,
    height_m: float | np.ndarray | None = None,
    area: ServiceArea | np.ndarray | None = None,
    outside: str = "constrain",
    links: LinkInfo | None = None,
    alert_limit_m: float | None = None,
    return_info: bool = False,
    **params: Any,
) -> np.ndarray | Fixes:
    """Position E epochs from the ToAs of N base stations.

    Parameters
    ----------
    toa_s : (E, N) float, seconds
        Measured ToA of the first-arriving path of each base station in the device clock (any
        common offset per epoch, i.e. the unknown device clock offset, is allowed). NaN = not
        received.
    bs_xyz : (N, 3) float, metres
        Base-station positions. Two base stations at the same position raise
        :class:`PositioningError`.
    method : str
        One of :data:`METHODS`: ``ls``, ``irls`` (the paper's), ``m-estimator``, ``subset``,
        ``nlos-aware``, ``nlos-map``.
    tx_offsets_s : (N,) float, seconds, optional
        Transmission schedule to remove (base station n transmits ``tx_offsets_s[n]`` after the
        first); default zeros.
    height_m : float or (E,) float, metres, optional
        Known device height: solve for (x, y) with 3-D distances (the "2D" solve of the paper,
        done without ignoring the height difference). None: solve for (x, y, z).
    area : ServiceArea or (M, 2) polygon vertices, metres, optional
        Where the device can be. A fix outside it is solved again inside it (the method's
        weighted fit restricted to the area, ``outside="constrain"``) or left unsolved
        (``outside="reject"``); either way flagged ``AREA_BOUND``. None: no bound.
    outside : "constrain" (default) or "reject".
    links : LinkInfo, optional
        Receiver reports per measurement (SNR, first-lobe shape, band), used by ``nlos-map``
        and the integrity figures.
    alert_limit_m : float, optional
        Compute the integrity figures (``Fixes.hpl_m``, ``Fixes.chi2n``) and flag ``INTEGRITY``
        where the horizontal protection level exceeds this limit (metres). None: not computed.
    return_info : bool
        False (default): return only the positions. True: return a :class:`Fixes` with per-epoch
        status, iterations, weights and ``n_unsolved``.
    **params
        Method parameters (see ``METHODS[method].params``), validated.

    Returns
    -------
    (E, 3) float, metres (z = ``height_m`` in 2D), or :class:`Fixes`. An epoch with fewer than 3
    (2D) or 4 (3D) received base stations gives a NaN row and is counted in
    ``Fixes.n_unsolved``; it does not raise.

    Raises
    ------
    PositioningError
        Bad shapes or values, duplicate base-station positions, unknown method or parameter.
    """
    prob = make_problem(toa_s, bs_xyz, tx_offsets_s, height_m, area=area, links=links)
    fixes = run_method(prob, method, outside=outside, alert_limit_m=alert_limit_m, **params)
    return fixes if return_info else fixes.xyz
