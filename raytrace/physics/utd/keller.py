"""Keller's law of edge diffraction: the diffraction point on a straight edge (closed form).

:func:`keller_points` over P (source, receiver, edge) triples, and :func:`keller_point`, its
compiled scalar form, which the solver's kernels call too. Conventions: :mod:`raytrace.physics.utd`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...core.jit import carray as _c
from ...core.jit import inline, kernel
from ...core.vec import dot3
from .inputs import checked_points

__all__ = ["KELLER_TOL_M", "KellerPoints", "keller_points", "keller_point"]


#: Tolerance (m) of Keller's point for "on the edge line" and "on the finite edge".
KELLER_TOL_M = 1e-9


class KellerPoints(NamedTuple):
    """Diffraction points on straight edges (unpacks as ``point, t, on_edge``).

    Attributes
    ----------
    point : (P, 3) float, metres; the diffraction point on the infinite edge line (NaN where
        degenerate)
    t : (P,) float, metres; its distance from ``edge_start`` along the edge (NaN where degenerate)
    on_edge : (P,) bool; the point lies on the finite edge (``-tol <= t <= length + tol``) and
        the case is not degenerate (source or receiver on the edge line, zero-length edge)
    """

    point: np.ndarray
    t: np.ndarray
    on_edge: np.ndarray


def keller_points(
    src: np.ndarray,
    dst: np.ndarray,
    edge_start: np.ndarray,
    edge_end: np.ndarray,
    *,
    tol_m: float = KELLER_TOL_M,
) -> KellerPoints:
    """Diffraction point of each (source, receiver, edge) by Keller's law (closed form).

    The diffracted ray leaves the edge on the cone of the incident ray: equal angles
    ``beta0`` with the edge (Keller, J. Opt. Soc. Am. 52(2), 1962). With ``e`` the edge unit
    vector, ``t_s = (src - a).e``, ``t_d = (dst - a).e`` the projections on the edge line and
    ``rho_s``, ``rho_d`` the distances of source and receiver from the line, rotating both points
    into one half-plane bounded by the line turns the path into a straight segment, which crosses
    the line at ``t = t_s + (t_d - t_s) rho_s / (rho_s + rho_d)``. That point has equal slopes
    ``(t - t_s) / rho_s = (t_d - t) / rho_d`` (equal angles) and minimises ``|src - q| + |q - dst|``
    over the line.

    Parameters
    ----------
    src, dst : (P, 3) float, metres; source (or image source) and receiver (or image receiver)
    edge_start, edge_end : (P, 3) float, metres; edge end points
    tol_m : float, metres; tolerance for "on the line" and "on the finite edge"

    Returns
    -------
    KellerPoints
        ``point (P, 3)``, ``t (P,)`` in metres from ``edge_start``, ``on_edge (P,)`` bool.
    """
    src = checked_points("src", src)
    p = src.shape[0]
    dst = checked_points("dst", dst, p)
    a = checked_points("edge_start", edge_start, p)
    b = checked_points("edge_end", edge_end, p)
    return KellerPoints(*_keller(_c(src), _c(dst), _c(a), _c(b), float(tol_m)))


@inline
def keller_point(sx, sy, sz, dx, dy, dz, ax, ay, az, bx, by, bz, tol):
    """:func:`keller_points` of one (source, receiver, edge), a compiled scalar helper for
    kernels: ``px, py, pz, t, on_edge``, the point and ``t`` NaN where degenerate. Sums and
    products in the order of the vectorised form it replaced (``core.vec.norm``, ``einsum``), so
    that the solver's kernels, which call it too, find the same points bitwise."""
    vx, vy, vz = bx - ax, by - ay, bz - az
    length = np.sqrt(vx * vx + vy * vy + vz * vz)
    ex, ey, ez = vx / length, vy / length, vz / length
    qx, qy, qz = sx - ax, sy - ay, sz - az
    ts = dot3(qx, qy, qz, ex, ey, ez)
    rx, ry, rz = dx - ax, dy - ay, dz - az
    td = dot3(rx, ry, rz, ex, ey, ez)
    qx, qy, qz = qx - ts * ex, qy - ts * ey, qz - ts * ez
    rho_s = np.sqrt(qx * qx + qy * qy + qz * qz)
    rx, ry, rz = rx - td * ex, ry - td * ey, rz - td * ez
    rho_d = np.sqrt(rx * rx + ry * ry + rz * rz)
    degenerate = length <= tol or rho_s <= tol or rho_d <= tol
    t = np.nan if degenerate else ts + (td - ts) * rho_s / (rho_s + rho_d)
    on_edge = not degenerate and t >= -tol and t <= length + tol
    return ax + t * ex, ay + t * ey, az + t * ez, t, on_edge


@kernel("Tuple((f8[:, ::1], f8[::1], b1[::1]))(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], "
        "f8)")
def _keller(src, dst, a, b, tol):
    """:func:`keller_point` over P rows: ``point (P, 3), t (P,), on_edge (P,)``."""
    p = len(src)
    point, t, on_edge = np.empty((p, 3)), np.empty(p), np.empty(p, dtype=np.bool_)
    for r in range(p):
        point[r, 0], point[r, 1], point[r, 2], t[r], on_edge[r] = keller_point(
            src[r, 0], src[r, 1], src[r, 2], dst[r, 0], dst[r, 1], dst[r, 2], a[r, 0], a[r, 1],
            a[r, 2], b[r, 0], b[r, 1], b[r, 2], tol)  # fmt: skip
    return point, t, on_edge
