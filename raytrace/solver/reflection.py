"""Image-method geometry: image points, plane crossings, reflecting sides and beams of facets.

Pure, vectorised geometry: image points, line-plane intersections, point-in-facet tests, and
the candidate generation of first- and second-order reflection paths. Visibility (Embree) and
field computation are done by the tracer.

A facet of a closed solid reflects only on its outward side; a facet of an open sheet on both.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..scene.accel import PLANE_TOL_M
from ..scene.elements import Facets


def mirror(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Image of points in planes ``normal . x = offset``.

    Parameters
    ----------
    points : (n, 3) float, metres
    normal : (n, 3) float, unit normals
    offset : (n,) float, metres

    Returns
    -------
    (n, 3) float, ``x - 2 (n . x - offset) n``
    """
    s = np.einsum("ij,ij->i", points, normal) - offset
    return points - 2.0 * s[:, None] * normal


def signed_distance(points: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Signed distance (m) of points from planes, positive on the normal's side; broadcasts."""
    return np.einsum("...j,...j->...", points, normal) - offset


def segment_plane_point(
    a: np.ndarray, b: np.ndarray, normal: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where the segments ``a -> b`` cross planes.

    Returns
    -------
    u : (n,) float, parameter along the segment (the crossing lies on it for 0 < u < 1)
    point : (n, 3) float, metres
    """
    sa = signed_distance(a, normal, offset)
    sb = signed_distance(b, normal, offset)
    den = sa - sb
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(np.abs(den) > 0, sa / den, np.nan)
    return u, a + u[:, None] * (b - a)


class Beam(NamedTuple):
    """Cones of rays from apexes through bounding spheres (see :func:`beam`); (...) shaped.

    Attributes
    ----------
    apex : (..., 3) float, metres
    axis : (..., 3) float, unit axis (NaN where the apex is the sphere's centre)
    cos_a, sin_a : (...) float, cosine and sine of the half-angle
    apex_inside : (...) bool, the apex is inside the sphere: every direction is in the beam
    """

    apex: np.ndarray
    axis: np.ndarray
    cos_a: np.ndarray
    sin_a: np.ndarray
    apex_inside: np.ndarray

    def take(self, idx: np.ndarray) -> Beam:
        """The beams at ``idx`` along the first axis."""
        return Beam(*(x[idx] for x in self))


def beam(apex: np.ndarray, centre: np.ndarray, radius: np.ndarray) -> Beam:
    """The cone of rays from ``apex`` through the sphere (centre, radius): every such ray lies
    within the half-angle ``asin(radius / |centre - apex|)`` of the axis. Broadcasts."""
    axis = centre - apex
    da = np.sqrt(np.einsum("...j,...j->...", axis, axis))
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = axis / da[..., None]
        sin_a = np.minimum(radius / da, 1.0)
    return Beam(apex, unit, np.sqrt(1.0 - sin_a * sin_a), sin_a, da <= radius)


def beam_reaches(b: Beam, target_centre: np.ndarray, target_radius: np.ndarray) -> np.ndarray:
    """Whether target spheres can meet beams (a conservative, necessary test). Broadcasts.

    The angle between the axis and the target's centre must be at most the beam's half-angle
    ``a`` plus the target's angular radius ``b`` (``sin b = target_radius / distance``),
    written without trigonometric functions as ``cos(angle) >= cos(a + b)``; ``a + b`` beyond
    pi needs both half-angles near pi/2, where ``cos(a + b) <= 0`` already admits everything in
    front and the apex is almost inside anyway.
    """
    v = target_centre - b.apex
    dt = np.sqrt(np.einsum("...j,...j->...", v, v))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_ang = np.einsum("...j,...j->...", b.axis, v) / dt
        sb = np.minimum(target_radius / dt, 1.0)
    reach = cos_ang >= b.cos_a * np.sqrt(1.0 - sb * sb) - b.sin_a * sb - 1e-7
    return reach | b.apex_inside | (dt <= target_radius)


def cone_reaches(
    apex: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    target_centre: np.ndarray,
    target_radius: np.ndarray,
) -> np.ndarray:
    """Whether a target sphere can meet the cone of rays from ``apex`` through a sphere.

    :func:`beam` then :func:`beam_reaches`; all arguments broadcast; (..., 3) points, (...)
    radii, metres.
    """
    return beam_reaches(beam(apex, centre, radius), target_centre, target_radius)


def reflecting_side(
    facets: Facets, points: np.ndarray, cols: np.ndarray | None = None
) -> np.ndarray:
    """Side (+1, -1) from which each facet can reflect a source at each point, 0 if it cannot.

    Parameters
    ----------
    points : (m, 3) float, metres
    cols : (c,) int, optional, only these facets

    Returns
    -------
    (m, K) int8 (or (m, c)): +1 in front, -1 behind (open sheets only), 0 on the plane or behind a closed
    solid's face.
    """
    idx = slice(None) if cols is None else cols
    s = points @ facets.normal[idx].T - facets.offset[idx][None, :]
    side = np.sign(s).astype(np.int8)
    side[np.abs(s) <= PLANE_TOL_M] = 0
    closed = ~facets.two_sided[idx]
    side[:, closed] = np.maximum(side[:, closed], 0)
    return side


def side_of(facets: Facets, points: np.ndarray, facet: np.ndarray) -> np.ndarray:
    """:func:`reflecting_side` of one point per facet: ``points`` (n, 3) float, metres, against
    ``facet`` (n,) int; (n,) int8 (+1, -1, 0), the same rule row by row."""
    s = np.einsum("ij,ij->i", points, facets.normal[facet]) - facets.offset[facet]
    side = np.sign(s).astype(np.int8)
    side[np.abs(s) <= PLANE_TOL_M] = 0
    closed = ~facets.two_sided[facet]
    side[closed] = np.maximum(side[closed], 0)
    return side
