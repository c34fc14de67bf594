"""The validated input of every estimator: :class:`Problem` (E epochs, N base stations) and the
receiver's per-link reports, :class:`LinkInfo`.

:func:`make_problem` checks the arrays (shapes, finite values, distinct base stations) and turns
the ToAs into pseudo-ranges with the schedule removed (:func:`positioning.model.tdoa.pseudoranges`,
paper eqs. 4-6).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import PositioningError
from .area import ServiceArea
from .tdoa import pseudoranges

#: Two base stations closer than this (m) are treated as the same position (an input error).
DUPLICATE_TOL_M = 1e-6


@dataclass(frozen=True)
class LinkInfo:
    """Per-measurement receiver reports and the band, for physics-aware estimators.

    Attributes
    ----------
    snr_db : (E, N) float, dB -- SNR before processing gain of the measured lobe (NaN unknown)
    peak_ratio_db : (E, N) float, dB -- first lobe's peak over the strongest peak (<= 0; NaN
        unknown or not a first-lobe receiver)
    lobe_width : (E, N) float -- first lobe's half-amplitude width over an isolated pulse's
        (1 lone path, > 1 overlapping paths, < 1 destructive interference; NaN unknown)
    bandwidth_hz : float or None -- signal bandwidth B
    center_frequency_hz : float or None -- carrier (for the free-space SNR of a LoS link)
    receiver : str -- ToA estimator that produced the data (``first-lobe``, ``first-path``,
        ``peak``, ``leading-edge``, or ``unknown``)
    snr_offset_db : float or None -- link budget constant ``P_tx + G_t + G_r - N`` (dB) so that
        a LoS link at d metres has ``SNR = snr_offset_db + 20 log10(lambda / (4 pi d))``; None if
        unknown
    subcarrier_spacing_hz : float or None -- delta_f; ``B / delta_f`` is the processing gain
    """

    snr_db: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    bandwidth_hz: float | None = None
    center_frequency_hz: float | None = None
    receiver: str = "unknown"
    snr_offset_db: float | None = None
    subcarrier_spacing_hz: float | None = None

    def take(self, idx: np.ndarray) -> LinkInfo:
        """The reports of epochs ``idx``."""
        return replace(
            self,
            snr_db=self.snr_db[idx],
            peak_ratio_db=self.peak_ratio_db[idx],
            lobe_width=self.lobe_width[idx],
        )


class Memo:
    """Results several estimators compute alike on the very same :class:`Problem` (the
    hypothesis fits of the robust ones, the integrity figures' fault hypotheses), kept for the
    next one that asks: see
    :meth:`Problem.with_memo`. It answers only for the problem it was made for (the same array
    objects): a sub-problem (:meth:`Problem.take`, ``dataclasses.replace``) computes afresh."""

    def __init__(self, prob: Problem) -> None:
        self._of = _identity(prob)
        self._kept: dict[object, Any] = {}

    def get(self, prob: Problem, key: object, compute: Callable[[], Any]) -> Any:
        """``compute()`` for ``key`` (hashable), once per key for this problem; a result the
        caller only reads."""
        if any(a is not b for a, b in zip(_identity(prob), self._of, strict=True)):
            return compute()
        if key not in self._kept:
            self._kept[key] = compute()
        return self._kept[key]


def _identity(prob: Problem) -> tuple[Any, ...]:
    """The problem's inputs themselves (held, so that no other object can take their place)."""
    return tuple(getattr(prob, f) for f in ("rho", "valid", "bs", "height", "area", "links"))


@dataclass(frozen=True)
class Problem:
    """Validated positioning input of E epochs and N base stations.

    Attributes
    ----------
    rho : (E, N) float, metres
        Pseudo-ranges ``c (toa - tx_offset)`` minus a per-epoch constant (the smallest of the epoch,
        which keeps the numbers small; any common constant is absorbed like the clock offset).
        NaN where the base station was not received.
    valid : (E, N) bool
        Finite ToA.
    bs : (N, 3) float, metres
        Base-station positions.
    height : (E,) float, metres, or None
        Known device height for the 2D solve; None for a 3D solve.
    area : ServiceArea or None
        Where a device can be (floor polygon); None: fixes are not bounded.
    links : LinkInfo or None
        What the receiver reported about each measurement (SNR, first-lobe shape), for the
        estimators that use it (``nlos-map``, the integrity figures); None: not known.
    memo : Memo or None
        Work kept between the estimators run on this problem (:meth:`with_memo`); None: none.
    """

    rho: np.ndarray
    valid: np.ndarray
    bs: np.ndarray
    height: np.ndarray | None
    area: ServiceArea | None = None
    links: LinkInfo | None = None
    memo: Memo | None = field(default=None, compare=False, repr=False)

    def with_memo(self) -> Problem:
        """This problem with a :class:`Memo`: the estimators run on it keep what they compute
        alike (several methods on one dataset)."""
        prob = replace(self, memo=None)
        object.__setattr__(prob, "memo", Memo(prob))
        return prob

    @property
    def dims(self) -> int:
        """Number of position unknowns: 2 with a known height, else 3."""
        return 2 if self.height is not None else 3

    @property
    def n_epochs(self) -> int:
        return int(self.rho.shape[0])

    @property
    def n_bs(self) -> int:
        return int(self.rho.shape[1])

    @property
    def n_valid(self) -> np.ndarray:
        """(E,) int: received base stations per epoch."""
        return np.count_nonzero(self.valid, axis=1)

    @property
    def min_bs(self) -> int:
        """Fewest base stations for a fix: dims + 1 (one is spent on the clock offset)."""
        return self.dims + 1

    @property
    def solvable(self) -> np.ndarray:
        """(E,) bool: epochs with at least :attr:`min_bs` received base stations."""
        return self.n_valid >= self.min_bs

    def take(self, idx: np.ndarray) -> Problem:
        """The sub-problem of epochs ``idx`` (area and link reports kept)."""
        return replace(
            self,
            rho=self.rho[idx],
            valid=self.valid[idx],
            height=None if self.height is None else self.height[idx],
            links=None if self.links is None else self.links.take(idx),
            memo=None,
        )

    def position(self, theta: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(A, 3) positions from unknowns ``theta`` (A, >= dims) of epochs ``idx`` (A,)."""
        if self.height is None:
            return theta[:, :3]
        return np.column_stack([theta[:, 0], theta[:, 1], self.height[idx]])


def make_problem(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    tx_offsets_s: np.ndarray | None = None,
    height_m: float | np.ndarray | None = None,
    area: ServiceArea | None = None,
    links: LinkInfo | None = None,
) -> Problem:
    """Validate input and build the :class:`Problem` (pseudo-ranges with the schedule removed).

    Parameters
    ----------
    toa_s : (E, N) float, seconds
        Measured ToAs in the device clock; NaN = not received.
    bs_xyz : (N, 3) float, metres
        Base-station positions; two base stations at the same position are an error.
    tx_offsets_s : (N,) float, seconds, optional
        Transmission schedule ``delta_n`` to remove (default zeros).
    height_m : float or (E,) float, metres, optional
        Known device height (2D solve); None solves in 3D.
    area : ServiceArea, optional
        Where a device can be; fixes outside are solved again inside (see ``locate``).
    links : LinkInfo, optional
        Receiver reports per measurement, (E, N) arrays.

    Raises
    ------
    PositioningError
        Wrong shapes, infinite values, non-finite base-station positions, offsets or heights,
        or duplicate base-station positions.
    """
    toa = np.asarray(toa_s, dtype=float)
    if toa.ndim != 2:
        raise PositioningError(
            f"toa_s must be a 2-D array (epochs, base stations), got shape {toa.shape}"
        )
    if np.isinf(toa).any():
        raise PositioningError("toa_s contains infinite values (use NaN for 'not received')")
    bs = np.asarray(bs_xyz, dtype=float)
    if bs.ndim != 2 or bs.shape[1] != 3:
        raise PositioningError(f"bs_xyz must have shape (N, 3), got {bs.shape}")
    if bs.shape[0] != toa.shape[1]:
        raise PositioningError(
            f"toa_s has {toa.shape[1]} base-station columns but bs_xyz has {bs.shape[0]} rows"
        )
    if not np.isfinite(bs).all():
        raise PositioningError("bs_xyz contains non-finite coordinates")
    n = bs.shape[0]
    if n >= 2:
        dist = np.linalg.norm(bs[:, None, :] - bs[None, :, :], axis=2)
        i, j = np.nonzero(np.triu(dist < DUPLICATE_TOL_M, k=1))
        if i.size:
            raise PositioningError(
                f"bs_xyz: base stations {i[0]} and {j[0]} have the same position "
                f"{bs[i[0]].tolist()}"
            )
    if tx_offsets_s is None:
        off = np.zeros(n)
    else:
        off = np.asarray(tx_offsets_s, dtype=float)
        if off.shape != (n,):
            raise PositioningError(f"tx_offsets_s must have shape ({n},), got {off.shape}")
        if not np.isfinite(off).all():
            raise PositioningError("tx_offsets_s contains non-finite values")
    height: np.ndarray | None = None
    if height_m is not None:
        h = np.asarray(height_m, dtype=float)
        if h.ndim == 0:
            h = np.full(toa.shape[0], float(h))
        if h.shape != (toa.shape[0],):
            raise PositioningError(
                f"height_m must be a scalar or have shape ({toa.shape[0]},), got {h.shape}"
            )
        if not np.isfinite(h).all():
            raise PositioningError("height_m contains non-finite values")
        height = h
    if area is not None and not isinstance(area, ServiceArea):
        area = ServiceArea(np.asarray(area, dtype=float), "given")
    if links is not None:
        for name in ("snr_db", "peak_ratio_db", "lobe_width"):
            if np.shape(getattr(links, name)) != toa.shape:
                raise PositioningError(
                    f"links.{name} must have shape {toa.shape}, got {np.shape(getattr(links, name))}"
                )
    return Problem(
        rho=pseudoranges(toa, off),
        valid=np.isfinite(toa),
        bs=bs,
        height=height,
        area=area,
        links=links,
    )
