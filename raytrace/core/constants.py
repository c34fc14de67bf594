"""Physical constants and unit helpers (SI inside; dB and GHz only at the edges)."""

from __future__ import annotations

import numpy as np

#: Speed of light in vacuum, m/s (exact, SI 2019).
C0 = 299_792_458.0
#: Vacuum permittivity, F/m (CODATA 2018).
EPS0 = 8.8541878128e-12
#: Boltzmann constant, J/K (exact, SI 2019).
K_BOLTZMANN = 1.380649e-23


def wavelength(frequency_hz: float | np.ndarray) -> float | np.ndarray:
    """Free-space wavelength, m, of a frequency in Hz."""
    return C0 / np.asarray(frequency_hz, dtype=float)


def db_to_linear_power(db: float | np.ndarray) -> float | np.ndarray:
    """Power ratio from decibels."""
    return 10.0 ** (np.asarray(db, dtype=float) / 10.0)


def linear_power_to_db(ratio: float | np.ndarray) -> float | np.ndarray:
    """Decibels from a power ratio (``-inf`` for zero)."""
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(np.asarray(ratio, dtype=float))


def dbm_to_watt(dbm: float | np.ndarray) -> float | np.ndarray:
    """Power in W from dBm."""
    return 1e-3 * db_to_linear_power(dbm)


def watt_to_dbm(watt: float | np.ndarray) -> float | np.ndarray:
    """Power in dBm from W."""
    return linear_power_to_db(np.asarray(watt, dtype=float) / 1e-3)
