"""ITU-R P.526 single knife edge: the Fresnel-Kirchhoff parameter and the loss ``J(v)``."""

from __future__ import annotations

import numpy as np

from ...core.errors import TraceInputError

__all__ = ["KNIFE_EDGE_V_MIN", "fresnel_kirchhoff_v", "knife_edge_loss_db"]


#: Below this Fresnel-Kirchhoff parameter ITU-R P.526 takes the knife-edge loss as 0 dB.
KNIFE_EDGE_V_MIN = -0.78


def fresnel_kirchhoff_v(
    h: float | np.ndarray,
    d1: float | np.ndarray,
    d2: float | np.ndarray,
    wavelength: float | np.ndarray,
) -> np.ndarray:
    """Fresnel-Kirchhoff diffraction parameter ``v = h sqrt(2 (d1 + d2) / (lambda d1 d2))``.

    ITU-R P.526-15 section 4.1, eq. (26). ``h`` (m) is the height of the edge above the straight
    line between the terminals (negative below it, i.e. line of sight clear), ``d1``, ``d2`` (m)
    the distances of the terminals from the edge, ``wavelength`` in m.
    """
    h, d1, d2, lam = (np.asarray(v, dtype=float) for v in (h, d1, d2, wavelength))
    if np.any(d1 <= 0) or np.any(d2 <= 0) or np.any(lam <= 0):
        raise TraceInputError("fresnel_kirchhoff_v needs positive d1, d2 and wavelength")
    return h * np.sqrt(2.0 * (d1 + d2) / (lam * d1 * d2))


def knife_edge_loss_db(v: float | np.ndarray) -> np.ndarray:
    """Single knife-edge diffraction loss ``J(v)``, dB (ITU-R P.526-15 section 4.1, eq. (31)).

    ``J(v) = 6.9 + 20 log10(sqrt((v - 0.1)^2 + 1) + v - 0.1)`` for ``v > -0.78``, else 0 dB.
    An approximation (about 1 dB) of the Fresnel-integral knife edge; the loss is relative to
    free space and refers to the total field (line of sight plus diffraction) where v < 0.
    """
    v = np.asarray(v, dtype=float)
    w = v - 0.1
    with np.errstate(invalid="ignore"):
        j = 6.9 + 20.0 * np.log10(np.sqrt(w * w + 1.0) + w)
    return np.where(v > KNIFE_EDGE_V_MIN, j, 0.0)
