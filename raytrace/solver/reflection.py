"""Specular reflection by the image method over planar facets.

Pure, vectorised geometry: image points, line-plane intersections, point-in-facet tests, and
the candidate generation of first- and second-order reflection paths. Visibility (Embree) and
field computation are done by the tracer.

A facet of a closed solid reflects only on its outward side; a facet of an open sheet on both.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..scene.model import Facets

#: Barycentric tolerance of the point-in-triangle test (dimensionless): a reflection point on
#: the shared edge of two triangles of one facet must not fall through the crack.
BARY_TOL = 1e-9
#: Points closer than this to a facet's plane (m) are on it: no reflection from there.
PLANE_TOL_M = 1e-9


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


def points_in_facets(points: np.ndarray, facet: np.ndarray, facets: Facets) -> np.ndarray:
    """Whether each point (on its facet's plane) lies inside that facet.

    A facet is a union of triangles; the point is inside if it is in any of them (barycentric
    test in 3D, with :data:`BARY_TOL`).

    Parameters
    ----------
    points : (n, 3) float, metres
    facet : (n,) int, facet index of each point

    Returns
    -------
    (n,) bool
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=bool)
    # cheap rejection by the facet's bounding box first: most candidates fail here
    lo, hi = facet_boxes(facets)
    near = np.all((points >= lo[facet]) & (points <= hi[facet]), axis=1)
    out = np.zeros(n, dtype=bool)
    if near.any():
        idx = np.flatnonzero(near)
        out[idx] = _in_triangles(points[idx], facet[idx], facets)
    return out


def _in_triangles(points: np.ndarray, facet: np.ndarray, facets: Facets) -> np.ndarray:
    """Barycentric test of points against all triangles of their facets."""
    n = len(points)
    counts = facets.tri_count[facet]
    rep = np.repeat(np.arange(n), counts)
    # index of each expanded triangle: tri_start[f] + 0..count-1
    within = np.arange(len(rep)) - np.repeat(np.cumsum(counts) - counts, counts)
    tri = facets.triangles[np.repeat(facets.tri_start[facet], counts) + within]
    p = points[rep]
    v0 = tri[:, 1] - tri[:, 0]
    v1 = tri[:, 2] - tri[:, 0]
    v2 = p - tri[:, 0]
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    inside_tri = (v >= -BARY_TOL) & (w >= -BARY_TOL) & (v + w <= 1 + BARY_TOL)
    out = np.zeros(n, dtype=bool)
    np.logical_or.at(out, rep, inside_tri)
    return out


def facet_boxes(facets: Facets, grow: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) lower and upper corners of each facet's axis-aligned bounding box, grown by
    ``grow`` metres (cached on the facets)."""
    cache = facets.__dict__.get("_boxes")
    if cache is not None and cache[0] == grow:
        return cache[1], cache[2]
    # a facet's triangles are contiguous, starting at tri_start
    lo = np.minimum.reduceat(facets.triangles.min(axis=1), facets.tri_start, axis=0) - grow
    hi = np.maximum.reduceat(facets.triangles.max(axis=1), facets.tri_start, axis=0) + grow
    object.__setattr__(facets, "_boxes", (grow, lo, hi))
    return lo, hi


def facet_spheres(facets: Facets) -> tuple[np.ndarray, np.ndarray]:
    """Bounding sphere of each facet: centre (K, 3) and radius (K,), metres (cached)."""
    cache = facets.__dict__.get("_spheres")
    if cache is not None:
        return cache
    lo, hi = facet_boxes(facets, 0.0)
    centre = 0.5 * (lo + hi)
    owner = np.repeat(np.arange(len(facets)), facets.tri_count * 3)
    d = np.linalg.norm(facets.triangles.reshape(-1, 3) - centre[owner], axis=1)
    radius = np.maximum.reduceat(d, 3 * facets.tri_start)
    out = (centre, radius * (1 + 1e-9) + 1e-9)
    object.__setattr__(facets, "_spheres", out)
    return out


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


def facing_pairs(facets: Facets, known: np.ndarray | None = None) -> np.ndarray:
    """(K, K) bool: facet j can receive a reflection from facet i (necessary condition).

    Some part of facet i must lie strictly on a reflecting side of facet j and vice versa
    (closed solids reflect outward only). Excludes i == j and facets in the same plane. The result
    is cached on the facets and read-only.

    Parameters
    ----------
    facets : Facets
    known : (k0, k0) bool, optional, the result for the first k0 facets (the same facets in the
        same order, e.g. a static scene that moving objects are appended to): only the rows and
        columns of the others are computed
    """
    cache = facets.__dict__.get("_facing")
    if cache is not None:
        return cache
    k = len(facets)
    k0 = 0 if known is None else int(known.shape[0])
    # sees[i, j]: any vertex of facet i on a reflecting side of facet j; a facet's vertices are
    # contiguous, so one reduceat per block
    starts = 3 * (np.cumsum(facets.tri_count) - facets.tri_count)
    verts = facets.triangles.reshape(-1, 3)

    def sees(rows: slice, cols: slice) -> np.ndarray:
        v0 = starts[rows.start] if rows.start < k else len(verts)
        s = verts[v0 : starts[rows.stop] if rows.stop < k else len(verts)]
        s = s @ facets.normal[cols].T - facets.offset[None, cols]
        first = starts[rows] - v0
        front = np.logical_or.reduceat(s > PLANE_TOL_M, first, axis=0)
        back = np.logical_or.reduceat(s < -PLANE_TOL_M, first, axis=0)
        return front | (back & facets.two_sided[None, cols])

    every = slice(0, k)
    if k0 == 0:
        both = sees(every, every)
        ok = both & both.T
    else:
        ok = np.zeros((k, k), dtype=bool)
        ok[:k0, :k0] = known
    if 0 < k0 < k:
        new = slice(k0, k)
        s_new_all = sees(new, every)  # (k - k0, k)
        s_all_new = sees(every, new)  # (k, k - k0)
        ok[k0:, :] = s_new_all & s_all_new.T
        ok[:, k0:] = s_all_new & s_new_all.T
    np.fill_diagonal(ok, False)
    ok.setflags(write=False)
    object.__setattr__(facets, "_facing", ok)
    return ok
