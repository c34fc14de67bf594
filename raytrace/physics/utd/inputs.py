"""Checks of the UTD functions' array inputs (one-line :class:`~raytrace.core.errors.
TraceInputError` on bad shapes or values)."""

from __future__ import annotations

import numpy as np

from ...core.errors import TraceInputError

__all__ = ["checked_points"]


def checked_points(name: str, value: object, rows: int | None = None) -> np.ndarray:
    """``value`` as a (P, 3) float array of finite points (a single (3,) point becomes (1, 3)).

    Parameters
    ----------
    name : str, the argument's name in the error message
    value : array-like, (P, 3) or (3,)
    rows : int, optional, the number of rows it must have

    Raises
    ------
    TraceInputError
        Another shape, another number of rows, or a NaN or infinite value.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise TraceInputError(f"{name} must have shape (P, 3), got {np.shape(value)}")
    if rows is not None and arr.shape[0] != rows:
        raise TraceInputError(f"{name} has {arr.shape[0]} rows, expected {rows}")
    if not np.all(np.isfinite(arr)):
        raise TraceInputError(f"{name} contains NaN or infinite values")
    return arr
