"""The raised-cosine pulse of eq. 2 (time and frequency domain) and its sampling
(:class:`PulseShape`); :func:`raised_cosine1` is the same pulse as a compiled scalar helper for
kernels (:mod:`raytrace.core.jit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from positioning.model.pulse import raised_cosine as periods_raised_cosine

from ...core.errors import HallrayError
from ...core.jit import inline
from ..bands import Band

#: Default raised-cosine roll-off (see :class:`PulseShape`).
DEFAULT_ROLL_OFF = 0.25


def raised_cosine(t: np.ndarray | float, period_s: float, roll_off: float) -> np.ndarray:
    """Raised-cosine pulse of eq. 2: ``(1/T) sinc(t/T) cos(pi beta t/T) / (1 - (2 beta t/T)^2)``.

    :func:`positioning.model.pulse.raised_cosine` at ``t / T`` periods (the one implementation,
    shared with the twin's receiver): the factor ``cos(pi u / 2) / (1 - u^2)``, ``u = 2 beta t / T``,
    is evaluated without the cancellation near ``|u| = 1``; at ``t = +-T/(2 beta)`` exactly it
    takes its limit ``pi/4``, so ``h = (pi / (4 T)) sinc(1 / (2 beta))`` there.

    Parameters
    ----------
    t : (...) float, seconds
        Times.
    period_s : float, s
        Symbol period T (zero crossings at ``t = k T``, ``k != 0``).
    roll_off : float
        beta in [0, 1]; 0 is the sinc pulse.

    Returns
    -------
    (...) float, 1/s
        ``h(0) = 1/T``; the pulse integrates to 1 (its spectrum is 1 at f = 0).
    """
    return periods_raised_cosine(np.asarray(t, dtype=float) / period_s, roll_off, period_s)


@inline
def raised_cosine1(x, roll_off):
    """``T h(x T)`` of :func:`raised_cosine` at one ``x = t / T`` (dimensionless, 1 at x = 0): the
    same pulse and the same cancellation-free form, as a compiled scalar helper for kernels
    (tested equal to :func:`raised_cosine` to 1e-15)."""
    if x == 0.0:
        s = 1.0
    else:
        s = math.sin(math.pi * x) / (math.pi * x)
    if roll_off == 0.0:
        return s
    e = 1.0 - abs(2.0 * roll_off * x)
    if e == 0.0:
        return s * (0.25 * math.pi)
    return s * math.sin(0.5 * math.pi * e) / (e * (2.0 - e))


def raised_cosine_spectrum(f: np.ndarray | float, period_s: float, roll_off: float) -> np.ndarray:
    """Fourier transform of :func:`raised_cosine` (dimensionless, 1 in the flat band).

    1 for ``|f| <= (1 - beta)/(2T)``, ``(1 + cos(pi T/beta (|f| - (1 - beta)/(2T)))) / 2`` up to
    ``(1 + beta)/(2T)``, 0 beyond.
    """
    f = np.abs(np.asarray(f, dtype=float))
    f1 = (1.0 - roll_off) / (2.0 * period_s)
    f2 = (1.0 + roll_off) / (2.0 * period_s)
    out = np.where(f <= f1, 1.0, 0.0)
    if roll_off > 0.0:
        taper = (f > f1) & (f <= f2)
        out = np.where(taper, 0.5 * (1.0 + np.cos(np.pi * period_s / roll_off * (f - f1))), out)
    return out


@dataclass(frozen=True)
class PulseShape:
    """Raised-cosine pulse settings and its sampling.

    Parameters
    ----------
    roll_off : float
        beta of eq. 2, default 0.25. The symbol period is ``T = (1 + beta) / B``, so that the
        pulse spectrum (two-sided width ``(1 + beta) / T``) fills exactly the channel bandwidth B:
        flat over the central ``(1 - beta)/(1 + beta)`` = 60 %, cosine taper to the band edges.
        0.25 keeps the main lobe narrow (first zeros at +-T = +-1.25/B, 12.5 ns at 100 MHz) with
        sidelobes at -14.3 dB (sinc: -13.3 dB; 0.5 would give -17.5 dB and a 20 % wider main
        lobe).
    oversampling : int
        Samples per T of the evaluated response (default 8: the grid maximum is within
        ``T/16`` of the true peak before the sub-sample refinement).
    span : int
        The pulse is evaluated within ``+-span T`` of each path (default 16: the tail beyond is
        below ``1 / (pi span (4 beta^2 span^2 - 1))`` ~ 3e-4 of the peak, -70 dB).
    """

    roll_off: float = DEFAULT_ROLL_OFF
    oversampling: int = 8
    span: int = 16

    def __post_init__(self) -> None:
        if not (isinstance(self.roll_off, (int, float)) and 0.0 <= self.roll_off <= 1.0):
            raise HallrayError(f"pulse roll_off must be in [0, 1], got {self.roll_off!r}")
        for name, lo in (("oversampling", 2), ("span", 2)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise HallrayError(f"pulse {name} must be an integer >= {lo}, got {value!r}")

    def period_s(self, band: Band) -> float:
        """Symbol period ``T = (1 + beta) / B`` of eq. 2, s."""
        return (1.0 + self.roll_off) / band.bandwidth_hz

    def sample_period_s(self, band: Band) -> float:
        """Spacing of the evaluated response, ``T / oversampling``, s."""
        return self.period_s(band) / self.oversampling
