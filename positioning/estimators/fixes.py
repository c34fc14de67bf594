"""The one result type of every estimator and of :func:`positioning.locate`: :class:`Fixes`,
positions plus per-epoch diagnostics (:class:`Status` flags)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields
from enum import IntFlag
from typing import Any

import numpy as np


class Status(IntFlag):
    """Per-epoch status bits of a fix (0 = ``OK``); several bits may be set at once.

    ``UNSOLVED``
        Fewer usable base stations than unknowns allow (3 in 2D, 4 in 3D): position is NaN.
    ``NOT_CONVERGED``
        An iteration hit its ``max_iter`` before its tolerance; the last estimate is returned.
    ``ALL_WEIGHTS_ZERO``
        IRLS: every reference's uncertainty exceeded ``u_max`` (eq. 11 gives all weights 0);
        the previous weighted average is kept and the iteration stops.
    ``REFERENCE_FALLBACK``
        LS: the requested reference base station had no ToA in this epoch; the first base
        station with a ToA was used instead.
    ``NO_REDUNDANCY``
        A robust estimator had too few base stations to identify an outlier, so its result is the
        plain least-squares fit of the pseudo-range model: ``m-estimator`` and ``subset`` need
        ``dims + 3`` received base stations (two spare measurements; 5 in 2D), ``nlos-aware``
        ``dims + 2`` (one spare; it also uses the sign of the NLoS excess).
    ``OUTLIER_REJECTED``
        A robust estimator dropped (or weighted to zero) at least one base station.
    ``INCONSISTENT``
        ``subset``: the residuals still fail the consistency test after dropping every base station
        that could be identified (or the outlier could not be isolated); the last fit is returned.
    ``ILL_CONDITIONED``
        The geometry is (nearly) degenerate at the solution (normal matrix condition number
        above 1e10, e.g. collinear base stations): the position is returned but unreliable.
    ``AREA_BOUND``
        The unbounded fix left the service area. With ``outside="constrain"`` (default) the
        position is the method's best fit inside the area
        (:mod:`positioning.estimators.bounded`); with ``outside="reject"`` the fix is also
        ``UNSOLVED`` (NaN).
    ``INTEGRITY``
        The fix's horizontal protection level exceeds the alert limit
        (:mod:`positioning.evaluation.integrity`): the measurements cannot vouch for it to within
        the limit.
    ``MAP_MISMATCH``
        ``twin``: the best map match fits poorly (a stale map, e.g. moved forklifts); the fix is
        the fallback map-free method's.
    ``TRACK_GATED``
        ``METHOD+track``: the epoch's fix failed the innovation gate; the track's prediction is
        reported.
    ``TRACK_RESTART``
        ``METHOD+track``: too many consecutive gated fixes; the track restarted at this fix.
    """

    OK = 0
    UNSOLVED = 1
    NOT_CONVERGED = 2
    ALL_WEIGHTS_ZERO = 4
    REFERENCE_FALLBACK = 8
    NO_REDUNDANCY = 16
    OUTLIER_REJECTED = 32
    INCONSISTENT = 64
    ILL_CONDITIONED = 128
    AREA_BOUND = 256
    INTEGRITY = 512
    MAP_MISMATCH = 1024
    TRACK_GATED = 2048
    TRACK_RESTART = 4096


#: Flags that make a solved fix untrustworthy whatever the user's accuracy needs: the solve did not
#: converge, the geometry is degenerate, or the fit wanted to be outside the service area.
#: (``INTEGRITY`` is relative to the user's alert limit and is reported separately.)
UNTRUSTED = Status.UNSOLVED | Status.NOT_CONVERGED | Status.ILL_CONDITIONED | Status.AREA_BOUND


def status_label(code: int) -> str:
    """Text form of a status code: ``"ok"`` or flag names joined by ``|`` (lower case)."""
    code = int(code)
    if code == 0:
        return "ok"
    return "|".join(f.name.lower() for f in Status if f.value and code & f.value)


@dataclass(frozen=True)
class Fixes:
    """Positions and diagnostics of E epochs solved by one method.

    Every estimator returns one (``method`` its name, ``params`` its config's fields);
    :func:`positioning.methods.run.run_method` returns it bounded to the service area, with the
    registered method's name and parameters and the integrity figures.

    Attributes
    ----------
    xyz : (E, 3) float, metres
        Estimated positions; in a 2D solve z is the known device height. NaN where unsolved.
    status : (E,) int
        Bit flags of :class:`Status` (0 = ok).
    iterations : (E,) int
        Outer iterations: Gauss-Newton/LM iterations for ``ls``, reweighting iterations of
        Algorithm 1 for ``irls``, IRLS iterations for ``m-estimator`` and ``nlos-aware``, and the
        Gauss-Newton iterations of the final fit for ``subset``.
    weights : (E, N) float
        Per base station: for ``irls`` the normalised weight of the estimate referenced to that base
        station (eq. 9); for ``m-estimator``/``nlos-aware`` the final robust weight of its
        measurement; for ``ls``/``subset`` 1 if used, 0 if missing or dropped.
    n_used : (E,) int
        Base stations with a finite ToA in the epoch.
    method : str
        Method name as registered in :data:`positioning.METHODS`.
    params : dict
        The method parameters actually used (defaults filled in).
    hpl_m : (E,) float, metres
        Horizontal protection level (:mod:`positioning.evaluation.integrity`); NaN where unsolved
        or not computed.
    chi2n : (E,) float
        Normalised chi-square of the fix's pseudo-range residuals, ``SSE / sigma^2 / (n - k)``
        (about 1 for consistent LoS measurements; NaN without redundancy or unsolved).
    alert_limit_m : float
        Alert limit against which ``INTEGRITY`` was set (NaN: integrity not evaluated).
    extra : dict of str -> array
        Method-specific per-epoch outputs (e.g. ``twin``: ``nlos`` (E, N) bool, ``match_m`` (E,));
        empty for most methods.
    fit_weights : (E, N) float or None
        Measurement weights of the bounded re-solve inside the service area
        (:mod:`positioning.estimators.bounded`) where they are not ``weights`` (``nlos-map``: its
        final inverse-variance weights); None: the registry decides (``weights`` for a method whose
        weights weight measurements, else every received measurement alike).
    """

    xyz: np.ndarray
    status: np.ndarray
    iterations: np.ndarray
    weights: np.ndarray
    n_used: np.ndarray
    method: str
    params: dict[str, Any] = field(default_factory=dict)
    hpl_m: np.ndarray | None = None
    chi2n: np.ndarray | None = None
    alert_limit_m: float = float("nan")
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    fit_weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        nan = np.full(self.xyz.shape[0], np.nan)
        if self.hpl_m is None:
            object.__setattr__(self, "hpl_m", nan)
        if self.chi2n is None:
            object.__setattr__(self, "chi2n", nan.copy())

    @property
    def n_epochs(self) -> int:
        """Number of epochs E."""
        return int(self.xyz.shape[0])

    @property
    def solved(self) -> np.ndarray:
        """(E,) bool: True where a position was produced."""
        return (self.status & Status.UNSOLVED) == 0

    @property
    def n_unsolved(self) -> int:
        """Number of epochs without a position (NaN rows)."""
        return int(np.count_nonzero(~self.solved))

    @property
    def availability(self) -> float:
        """Share of epochs with a position (0..1; NaN for no epoch)."""
        return float(np.mean(self.solved)) if self.n_epochs else float("nan")

    @property
    def flagged(self) -> np.ndarray:
        """(E,) bool: solved fixes whose protection level exceeds the alert limit."""
        return self.solved & ((self.status & int(Status.INTEGRITY)) != 0)

    @property
    def trusted(self) -> np.ndarray:
        """(E,) bool: solved, converged, well-conditioned fixes found inside the service area
        (none of :data:`UNTRUSTED`)."""
        return (self.status & int(UNTRUSTED)) == 0

    def count(self, flag: Status) -> int:
        """Number of epochs with ``flag`` set."""
        return int(np.count_nonzero(self.status & int(flag)))

    def labels(self) -> list[str]:
        """Per-epoch status as text (see :func:`status_label`)."""
        return [status_label(s) for s in self.status]

    def __getitem__(self, key: str) -> np.ndarray:
        """Deprecated: ``result["xyz"]``, the access to an estimator's result while it was a dict
        of arrays; ``xyz``, ``status``, ``iterations``, ``weights`` and ``fit_weights`` are
        attributes now, every other key is in :attr:`extra`. Works for one release, with a
        :class:`DeprecationWarning`."""
        attribute = key in _DICT_ATTRIBUTES
        new = f"positioning.Fixes.{key}" if attribute else f"positioning.Fixes.extra[{key!r}]"
        warnings.warn(
            f"positioning.Fixes[{key!r}] moved to {new}; the old path goes away in the next "
            "release",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(self, key) if attribute else self.extra[key]


#: The keys of the estimators' old dict results that are attributes of :class:`Fixes`.
_DICT_ATTRIBUTES = ("xyz", "status", "iterations", "weights", "fit_weights")


def config_params(config: Any) -> dict[str, Any]:
    """The fields of a config dataclass as a dict, for :attr:`Fixes.params` (shallow: a field
    holding a fingerprint map keeps that object, no copy)."""
    return {f.name: getattr(config, f.name) for f in fields(config)}
