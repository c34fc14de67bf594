"""TDoA measurement model (paper eqs. 4-7) and the batched least-squares machinery.

Measurement model
-----------------
Base station ``n`` at ``b_n`` transmits at its scheduled offset ``delta_n`` (paper: BS k at
k * 10 ms). The device, at ``p``, time-stamps the first-arriving path in its own clock, which is
off by an unknown ``t_clk`` common to all base stations of one epoch::

    toa_n = t_clk + delta_n + |p - b_n| / c + e_n                       (eq. 4, 3-D distance)

with ``e_n`` the ToA error (noise, eq. 3, plus a non-negative NLoS excess delay). Removing the
schedule and multiplying by ``c`` gives the *pseudo-range* ``rho_n = c (toa_n - delta_n)
= |p - b_n| + c t_clk + c e_n``. The signed TDoA of base station ``n`` against a reference ``e``
(eq. 5 without the absolute value, see below) times ``c`` is the range difference of eq. 6::

    dd_ne = c [(toa_n - delta_n) - (toa_e - delta_e)] = |p - b_n| - |p - b_e| + c (e_n - e_e)

in which the device clock offset ``t_clk`` cancels.

Deviations from the paper (documented in ``docs/positioning.md``):

* Eq. 5 takes ``|.|`` of the TDoA, which loses the sign that eq. 6 needs (a base station farther
  than the reference has a positive difference, a nearer one a negative). We use the signed value.
* Eq. 4 writes 2-D distances although the base stations are at 4 m and the devices at 1 m (a
  ranging error of up to 0.45 m at 10 m). We keep 3-D distances in the model and solve either for
  ``(x, y)`` with the device height known (``height_m``, the "2D" solve) or for ``(x, y, z)``.

The equations as array functions are here: :func:`pseudoranges`, :func:`signed_tdoa`,
:func:`range_differences` and the ranges with their gradient, :func:`ranges_and_units`. The
validated input is :class:`~positioning.model.problem.Problem`; its residual functions (eq. 7 and
the reference-free pseudo-range model) are in :mod:`positioning.model.residuals`, the batched
solvers in :mod:`positioning.estimators.solver`.
"""

from __future__ import annotations

import numpy as np

#: Speed of light in vacuum, m/s (exact, SI 2019). Same value as ``raytrace.core.constants.C0``;
#: repeated because ``positioning`` never imports ``raytrace``.
C0 = 299_792_458.0


def pseudoranges(toa_s: np.ndarray, tx_offsets_s: np.ndarray | None = None) -> np.ndarray:
    """Pseudo-ranges ``c (toa_n - delta_n)`` less the smallest of each epoch.

    Parameters
    ----------
    toa_s : (E, N) float, seconds (NaN = not received)
    tx_offsets_s : (N,) float, seconds, optional

    Returns
    -------
    (E, N) float, metres. The schedule is subtracted *before* the per-epoch constant so that no
    precision is lost to large clock offsets; the constant cancels in every TDoA.
    """
    toa = np.asarray(toa_s, dtype=float)
    t = toa if tx_offsets_s is None else toa - np.asarray(tx_offsets_s, dtype=float)[None, :]
    finite = np.isfinite(t)
    anchor = np.min(np.where(finite, t, np.inf), axis=1)
    anchor = np.where(np.isfinite(anchor), anchor, 0.0)
    return C0 * (t - anchor[:, None])


def signed_tdoa(
    toa_s: np.ndarray, reference: int, tx_offsets_s: np.ndarray | None = None
) -> np.ndarray:
    """Signed TDoA against a reference base station, schedule removed (eq. 5 without ``|.|``).

    Parameters
    ----------
    toa_s : (E, N) float, seconds
    reference : int
        Index ``e`` of the reference base station.
    tx_offsets_s : (N,) float, seconds, optional

    Returns
    -------
    (E, N) float, seconds: ``(toa_n - delta_n) - (toa_e - delta_e)``; 0 in column ``e``, NaN
    where either ToA is missing. The device clock offset cancels.
    """
    toa = np.asarray(toa_s, dtype=float)
    t = toa if tx_offsets_s is None else toa - np.asarray(tx_offsets_s, dtype=float)[None, :]
    return t - t[:, [reference]]


def range_differences(
    toa_s: np.ndarray, reference: int, tx_offsets_s: np.ndarray | None = None
) -> np.ndarray:
    """Signed range differences ``dd_ne = c * TDoA_ne`` (left-hand side of eq. 6), metres, (E, N)."""
    return C0 * signed_tdoa(toa_s, reference, tx_offsets_s)


def ranges(p: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """(A, N) 3-D ranges ``|p - b_n|`` in metres of positions ``p`` (A, 3) from ``bs`` (N, 3):
    :func:`ranges_and_units` without the gradient (the same numbers)."""
    return _norms(p[:, None, :] - bs[None, :, :])


def _norms(diff: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("anj,anj->an", diff, diff))


def ranges_and_units(p: np.ndarray, bs: np.ndarray, dims: int) -> tuple[np.ndarray, np.ndarray]:
    """3-D ranges and their gradient with respect to the unknown coordinates.

    Parameters
    ----------
    p : (A, 3) float, metres
    bs : (N, 3) float, metres
    dims : 2 or 3 -- number of unknown coordinates (x, y[, z])

    Returns
    -------
    R : (A, N) float, metres -- ``|p - b_n|`` (3-D)
    U : (A, N, dims) float -- ``d R / d (x, y[, z]) = (p - b_n)[:dims] / R``
    """
    diff = p[:, None, :] - bs[None, :, :]
    R = _norms(diff)
    # The gradient is undefined at a base station; 1e-12 m only avoids 0/0 there.
    U = diff[..., :dims] / np.maximum(R, 1e-12)[..., None]
    return R, U
