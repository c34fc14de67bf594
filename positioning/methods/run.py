"""Run a registered method on a problem: :func:`run_method` (bounded to the service area, with
the integrity figures) and the public entry point :func:`locate`."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal, overload

import numpy as np

from ..errors import PositioningError
from ..estimators.bounded import bounded_refit
from ..estimators.fixes import Fixes, Status
from ..evaluation.trust import check_trustworthy, counts_of, ill_conditioned
from ..model.area import ServiceArea
from ..model.problem import LinkInfo, Problem, make_problem
from ..model.scale import check_height, check_stations, check_toa_scale
from ..model.tdoa import C0
from .registry import METHODS, resolve_params

#: What to do with a fix outside the service area: solve again inside it, or leave it unsolved.
OUTSIDE_CHOICES = ("constrain", "reject")


def apply_area(
    prob: Problem, res: Fixes, fit_weights: np.ndarray, outside: str
) -> tuple[np.ndarray, np.ndarray]:
    """Keep every solved fix inside ``prob.area`` (see :mod:`positioning.estimators.bounded`).

    Parameters
    ----------
    res : a method's fixes (``xyz`` (E, 3), ``status`` (E,) are used)
    fit_weights : (E, N) measurement weights of the bounded re-solve
    outside : "constrain" (re-solve inside, flag ``AREA_BOUND``) or "reject" (flag
        ``UNSOLVED | AREA_BOUND``, NaN position)

    Returns
    -------
    xyz (E, 3), status (E,) -- copies.
    """
    xyz = np.array(res.xyz, dtype=float)
    status = np.asarray(res.status, dtype=np.int64).copy()
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
    """Solve a prepared :class:`~positioning.model.problem.Problem` with one registered method.

    The method solves without bounds; fixes outside ``prob.area`` are then solved again inside it
    (``outside="constrain"``) or left unsolved (``"reject"``), both flagged ``AREA_BOUND``. With
    ``alert_limit_m`` the integrity figures (:mod:`positioning.evaluation.integrity`) are
    computed and fixes whose protection level exceeds it are flagged ``INTEGRITY``. The result is
    the method's :class:`Fixes` with the registered name, the resolved parameters and these.
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
    res = m.run(prob, p)
    fw = res.fit_weights
    if fw is None:
        fw = res.weights if m.measurement_weights else prob.valid.astype(float)
    xyz, status = apply_area(prob, res, np.asarray(fw, dtype=float), outside)
    hpl = chi2n = None
    limit = float("nan")
    if alert_limit_m is not None:
        from ..evaluation.integrity import integrity

        hpl, chi2n = integrity(prob, xyz, status)
        limit = float(alert_limit_m)
        solved = (status & int(Status.UNSOLVED)) == 0
        status |= np.where(solved & ~(hpl <= limit), int(Status.INTEGRITY), 0)
    return replace(
        res,
        xyz=xyz,
        status=status,
        iterations=np.asarray(res.iterations, dtype=np.int64),
        n_used=prob.n_valid,
        method=method,
        params=p,
        hpl_m=hpl,
        chi2n=chi2n,
        alert_limit_m=limit,
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
    checks: bool = ...,
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
    checks: bool = ...,
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
    checks: bool = True,
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
    checks : bool
        True (default): the checks the commands make (``estimate-positions``), with the same
        one-line messages: the scale rule on the stations (millimetres, kilometres), the ToAs
        (milliseconds, microseconds, nanoseconds) and ``height_m`` (:mod:`positioning.model.scale`),
        before the solve; after it, a run in which some fix is solved but none can be trusted
        (collinear stations in 2D, stations in one plane in 3D whose fixes' mirror images fit as
        well; :mod:`positioning.evaluation.trust`) raises. False skips them (a caller that has
        checked its input, or wants the fixes of a degenerate geometry anyway).
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
        Bad shapes or values, duplicate base-station positions, unknown method or parameter;
        with ``checks``: values beyond the hall scale (:class:`~positioning.model.scale.ScaleError`)
        and a result without a trustworthy fix.
    """
    prob = make_problem(toa_s, bs_xyz, tx_offsets_s, height_m, area=area, links=links)
    if checks:
        check_problem(prob)
    fixes = run_method(prob, method, outside=outside, alert_limit_m=alert_limit_m, **params)
    if checks:
        check_fixes(prob, fixes)
    return fixes if return_info else fixes.xyz


def check_problem(prob: Problem) -> None:
    """The commands' scale rule on a problem's input (:mod:`positioning.model.scale`), named as
    :func:`locate`'s arguments."""
    check_stations(prob.bs, "bs_xyz")
    check_toa_scale(prob.rho / C0, prob.bs, "toa_s")
    if prob.height is not None:
        check_height(prob.height, prob.bs, "height_m")


def check_fixes(prob: Problem, fixes: Fixes) -> None:
    """Refuse fixes of which some are solved but every solved one is ill-conditioned by the
    station geometry (the commands' rule, :func:`positioning.evaluation.trust.check_trustworthy`,
    with its message). Fixes that are only flagged not converged are returned, flagged: the
    caller reads their status (``return_info``)."""
    three_d = prob.height is None
    ill = ill_conditioned(prob.valid, prob.bs, three_d, xyz=np.asarray(fixes.xyz), rho=prob.rho)
    counts = counts_of(fixes, ill)
    solved = np.asarray(fixes.solved)
    if solved.any() and not (solved & ~ill).any():
        check_trustworthy({**counts, "trustworthy": 0}, "locate", "3d" if three_d else 0.0,
                          "height_m")  # fmt: skip
