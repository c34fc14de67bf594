"""First-order edge diffraction: Keller points, wedge geometry, UTD coefficients, knife edge.

Physics of one diffraction at a straight wedge edge, vectorised over P candidate
(source, receiver, edge) triples. Visibility is the tracer's business; nothing here casts rays.

* :func:`keller_points` -- the diffraction point on an edge (Keller's law of edge diffraction).
* :func:`wedge_geometry` -- wedge parameter ``n``, the angles ``phi'`` and ``phi`` of
  Kouyoumjian-Pathak measured from face 0, and the edge-fixed unit vectors.
* :func:`transition_function` -- the UTD transition function ``F(x)``.
* :func:`utd_coefficients` -- soft / hard diffraction coefficients ``D_s``, ``D_h``:
  Kouyoumjian-Pathak (KP) for a perfectly conducting wedge, Luebbers' scalar form with face
  reflection coefficients for a lossy one (normal incidence on the edge).
* :func:`face_reflection_matrix` -- a face's Fresnel reflection as a 2 x 2 matrix in the
  ray-fixed (``beta0``, ``phi``) components, exact at oblique incidence on the edge.
* :func:`diffraction_matrix` -- the dyadic coefficient (UTD with the faces' reflection
  matrices) and the spreading factor, which :func:`diffracted_field` applies to a field.
* :func:`diffracted_field` -- the diffracted field vector at the receiver (KP for perfect
  conductors; for lossy faces Luebbers' heuristic with the face rule below, which makes the field
  independent of how the mesh labels the faces).
* :func:`knife_edge_loss_db`, :func:`fresnel_kirchhoff_v` -- ITU-R P.526 single knife edge.

Conventions (see ``docs/diffraction.md`` for the formulas and their sources)
----------------------------------------------------------------------------
* Time dependence ``exp(+j omega t)``: a wave travelling a distance ``s`` carries
  ``exp(-j k s)``; ``k = 2 pi f / c``.
* Wedge: faces "0" and "n"; the exterior (free space) is ``0 <= phi <= n pi`` with
  ``phi`` measured from face 0 towards face n, right-handed about the oriented edge unit vector
  ``e``. With ``t0`` the unit vector lying in face 0, perpendicular to the edge and pointing from
  the edge into the face, and ``n0`` the outward normal of face 0: ``t0 = n0 x e`` and
  ``n0 = e x t0``; a point ``p`` has ``phi = atan2((p - q).n0, (p - q).t0)`` (``q`` on the edge).
  :func:`wedge_geometry` orients ``e`` itself: the caller only says which face is face 0.
* Lossy faces (Luebbers' heuristic with a reciprocal face rule, D8a): each face's term takes the
  reflection, off the face's plane, of the specular ray between source and receiver seen along
  the edge (each end taken in front of the plane). Reciprocal, continuous in both end points,
  independent of which face is called face 0, the geometrical-optics reflection wherever it is
  seen, and Luebbers' angles in his limits (distant source: the incident ray's ``phi'``; distant
  receiver: the diffracted ray's ``pi - phi``).
* ``n`` = exterior angle / pi: 2 for a half-plane (thin sheet), 1.5 for a right-angle convex
  corner of a box; for a convex wedge ``n = 1 + angle(n0, nn) / pi``.
* Ray-fixed unit vectors (KP): incident direction ``s'`` (source -> edge), ``phi'_hat =
  -(e x s') / |e x s'|``, ``beta0'_hat = s' x phi'_hat``; diffracted direction ``s``
  (edge -> receiver), ``phi_hat = (e x s) / |e x s|``, ``beta0_hat = s x phi_hat``.
  The soft coefficient acts on the ``beta0`` components (the E-field component in the plane of
  the edge and the ray; parallel to the edge at normal incidence), the hard one on the ``phi``
  components.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.special import wofz

from ..core.constants import C0
from ..core.errors import TraceInputError
from ..core.jit import carray as _c
from ..core.jit import helper, inline, kernel
from ..core.vec import broadcast_rows, cross3, dot3
from ..core.vec import cross as _cross
from ..core.vec import norm as _norm
from ..core.vec import rows as _rows
from .materials import clipped_cos1, reflection1

__all__ = [
    "KellerPoints",
    "WedgeGeometry",
    "DiffractedField",
    "keller_points",
    "keller_point",
    "KELLER_TOL_M",
    "wedge_geometry",
    "WedgeFrame",
    "wedge_frames",
    "framed_wedge_geometry",
    "diffraction_valid",
    "diffraction_valid1",
    "face_rule_angle",
    "transition_function",
    "utd_coefficients",
    "face_reflection_matrix",
    "diffraction_matrix",
    "ChainDiffraction",
    "chain_diffraction",
    "diffracted_field",
    "knife_edge_loss_db",
    "fresnel_kirchhoff_v",
    "KNIFE_EDGE_V_MIN",
]

#: Below this Fresnel-Kirchhoff parameter ITU-R P.526 takes the knife-edge loss as 0 dB.
KNIFE_EDGE_V_MIN = -0.78

_TWO_PI = 2.0 * np.pi
#: Angles (rad) closer than this to a wedge face are snapped onto the face (rounding only).
_ANGLE_SNAP_RAD = 1e-9
#: An exterior angle (rad) closer than this to 0 or 2 pi is a half-plane (n = 2).
_HALF_PLANE_RAD = 1e-6
#: Tolerance (m) of Keller's point for "on the edge line" and "on the finite edge".
KELLER_TOL_M = 1e-9
#: Smallest |sin beta0| (ray direction vs edge) for which diffraction is computed.
_MIN_SIN_BETA0 = 1e-9


# -- input checks ---------------------------------------------------------------------------------
def _points(name: str, value: object, rows: int | None = None) -> np.ndarray:
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


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = _norm(v)
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / norm[:, None], norm


# -- 1. Keller's law: the diffraction point --------------------------------------------------------
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
    src = _points("src", src)
    p = src.shape[0]
    dst = _points("dst", dst, p)
    a = _points("edge_start", edge_start, p)
    b = _points("edge_end", edge_end, p)
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


# -- 2. wedge geometry ----------------------------------------------------------------------------
@dataclass(frozen=True)
class WedgeGeometry:
    """Geometry of P diffractions, in the Kouyoumjian-Pathak edge-fixed frame.

    Attributes
    ----------
    edge_dir : (P, 3) float; edge unit vector ``e``, oriented so that ``phi`` grows from face 0
        towards face n right-handed about ``e`` (``t0 = n0 x e``)
    face0_tangent : (P, 3) float; ``t0``, unit vector in face 0, perpendicular to the edge,
        pointing from the edge into face 0
    normal_0, normal_n : (P, 3) float; outward unit normals of face 0 and face n (made
        perpendicular to the edge)
    n : (P,) float; exterior wedge angle / pi, in (0, 2]
    phi_in : (P,) float, rad; ``phi'``, angle of the source seen from the edge, 0 at face 0
    phi : (P,) float, rad; ``phi``, angle of the receiver, 0 at face 0 (both in ``[0, n pi]``
        where valid)
    s_in, s_out : (P,) float, metres; ``s'`` = |point - src|, ``s`` = |dst - point|
    sin_beta0 : (P,) float; sine of the angle between the incident ray and the edge
    s_hat_in, s_hat_out : (P, 3) float; incident (src -> point) and diffracted (point -> dst)
        unit directions
    beta_hat_in, phi_hat_in : (P, 3) float; ``beta0'_hat``, ``phi'_hat`` (incident ray)
    beta_hat_out, phi_hat_out : (P, 3) float; ``beta0_hat``, ``phi_hat`` (diffracted ray)
    lit_0, lit_n : (P,) bool; the source lights face 0 (``phi' <= pi``) / face n
        (``n pi - phi' <= pi``); at least one is True where valid, both for a source that sees
        both faces of a convex wedge (or grazes a half-plane)
    psi_0, psi_n : (P,) float, rad; in-plane angle, measured from the face, of the ray whose
        reflection in that face the face's diffraction term carries: the specular reflection off
        the face's plane between source and receiver, each taken in front of the plane (D8a,
        see :func:`face_rule_angle`); ``phi'`` on the face's reflection boundary
    cos_theta_0, cos_theta_n : (P,) float; cosine of the incidence angle (to the face normal) at
        which the reflection coefficients ``R_0`` and ``R_n`` are evaluated:
        ``sin(beta0) |sin(psi_0)|``, ``sin(beta0) |sin(psi_n)|``
    valid : (P,) bool; source and receiver in the exterior of the wedge, neither on the edge
        line, non-zero distances
    """

    edge_dir: np.ndarray
    face0_tangent: np.ndarray
    normal_0: np.ndarray
    normal_n: np.ndarray
    n: np.ndarray
    phi_in: np.ndarray
    phi: np.ndarray
    s_in: np.ndarray
    s_out: np.ndarray
    sin_beta0: np.ndarray
    s_hat_in: np.ndarray
    s_hat_out: np.ndarray
    beta_hat_in: np.ndarray
    phi_hat_in: np.ndarray
    beta_hat_out: np.ndarray
    phi_hat_out: np.ndarray
    lit_0: np.ndarray
    lit_n: np.ndarray
    psi_0: np.ndarray
    psi_n: np.ndarray
    cos_theta_0: np.ndarray
    cos_theta_n: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.n.shape[0])


def wedge_geometry(
    src: np.ndarray,
    dst: np.ndarray,
    point: np.ndarray,
    edge_dir: np.ndarray,
    normal_0: np.ndarray,
    normal_n: np.ndarray,
    face0_dir: np.ndarray | None = None,
) -> WedgeGeometry:
    """Wedge parameter, KP angles and edge-fixed unit vectors of P diffractions.

    Parameters
    ----------
    src : (P, 3) float, metres; source, or image source for a path reflected before the edge
    dst : (P, 3) float, metres; receiver, or image receiver for a path reflected after the edge
    point : (P, 3) float, metres; diffraction point on the edge (see :func:`keller_points`)
    edge_dir : (P, 3) float; edge direction, either sign (oriented here)
    normal_0, normal_n : (P, 3) float; outward normals of the face chosen as face 0 and of the
        other face (face n). For a thin sheet (half-plane) they are the sheet normal and its
        opposite: face 0 is the side whose outward normal is ``normal_0``.
    face0_dir : (P, 3) float or None; any vector from the edge into face 0 (e.g. face centroid
        minus a point of the edge); only its component perpendicular to the edge is used.
        Required for half-planes (the two normals alone do not say on which side of the edge the
        sheet lies). If None, the wedge is taken as convex (exterior angle >= pi), which holds for
        the convex edges of closed solids.

    Returns
    -------
    WedgeGeometry
        ``n = (angle from t0 to tn about e) / pi`` with ``t0 = n0 x e``, ``tn = e x nn``
        (``2`` where the faces are coplanar back to back, i.e. a half-plane).

    Raises
    ------
    TraceInputError
        Bad shapes, non-finite values, or a half-plane without ``face0_dir``.
    """
    src = _points("src", src)
    p = src.shape[0]
    frame = WedgeFrame(*_oriented_wedge(edge_dir, normal_0, normal_n, face0_dir, p))
    return framed_wedge_geometry(frame, src, dst, point)


class WedgeFrame(NamedTuple):
    """Edge-fixed frames of P wedges, as :func:`wedge_geometry` builds them (see there).

    Attributes
    ----------
    edge_dir, face0_tangent, normal_0, normal_n : (P, 3) float; ``e`` (oriented), ``t0``, and
        the face normals made perpendicular to the edge
    n : (P,) float; exterior wedge angle / pi
    """

    edge_dir: np.ndarray
    face0_tangent: np.ndarray
    normal_0: np.ndarray
    normal_n: np.ndarray
    n: np.ndarray

    def take(self, idx: np.ndarray) -> WedgeFrame:
        """The frames at ``idx``: computing them once per wedge and taking them per diffraction
        gives bitwise what :func:`wedge_geometry` computes per diffraction (row-wise
        arithmetic)."""
        return WedgeFrame(*(_rows(x, idx) for x in self))


def wedge_frames(
    edge_dir: np.ndarray,
    normal_0: np.ndarray,
    normal_n: np.ndarray,
    face0_dir: np.ndarray | None = None,
) -> WedgeFrame:
    """The edge-fixed frames of wedges (arguments as :func:`wedge_geometry`'s, (P, 3) each)."""
    e = _points("edge_dir", edge_dir)
    return WedgeFrame(*_oriented_wedge(e, normal_0, normal_n, face0_dir, e.shape[0]))


def framed_wedge_geometry(
    frame: WedgeFrame, src: np.ndarray, dst: np.ndarray, point: np.ndarray
) -> WedgeGeometry:
    """:func:`wedge_geometry` with the wedges' frames given (:func:`wedge_frames`, taken per
    diffraction with :meth:`WedgeFrame.take`); src, dst, point : (P, 3) float, metres."""
    src = _points("src", src)
    p = src.shape[0]
    dst = _points("dst", dst, p)
    point = _points("point", point, p)
    e, t0, n0, nn, n = frame
    (s_hat_in, s_in, s_hat_out, s_out, phi_in, phi, sin_beta0, phi_hat_in, beta_hat_in,
     phi_hat_out, beta_hat_out, lit_0, lit_n, valid, psi_0, psi_n, cos_theta_0,
     cos_theta_n) = _geometry(_c(e), _c(t0), _c(n0), _c(n), _c(src), _c(dst), _c(point))  # fmt: skip
    return WedgeGeometry(
        edge_dir=e,
        face0_tangent=t0,
        normal_0=n0,
        normal_n=nn,
        n=n,
        phi_in=phi_in,
        phi=phi,
        s_in=s_in,
        s_out=s_out,
        sin_beta0=sin_beta0,
        s_hat_in=s_hat_in,
        s_hat_out=s_hat_out,
        beta_hat_in=beta_hat_in,
        phi_hat_in=phi_hat_in,
        beta_hat_out=beta_hat_out,
        phi_hat_out=phi_hat_out,
        lit_0=lit_0,
        lit_n=lit_n,
        psi_0=psi_0,
        psi_n=psi_n,
        cos_theta_0=cos_theta_0,
        cos_theta_n=cos_theta_n,
        valid=valid,
    )


def diffraction_valid(
    frame: WedgeFrame, src: np.ndarray, dst: np.ndarray, point: np.ndarray
) -> np.ndarray:
    """``framed_wedge_geometry(frame, src, dst, point).valid`` without the rest (the same
    arithmetic): (P,) bool, source and receiver in the exterior of the wedge, neither on the
    edge line, non-zero distances. src, dst, point : (P, 3) float, metres (not checked)."""
    e, t0, n0, _, n = frame
    return _valid(_c(e), _c(t0), _c(n0), _c(n), _c(src), _c(dst), _c(point))


# the geometry of one diffraction, compiled (numba): the kernels below run it over P rows; the
# sums and products are in the order of the vectorised form they replaced (core.vec, einsum)
@inline
def _azimuth1(wx, wy, wz, t0x, t0y, t0z, n0x, n0y, n0z, npi):
    """The angle of vector ``w`` from face 0 of a wedge (axes ``t0``, ``n0``, exterior angle
    ``npi``), ``atan2(w . n0, w . t0)`` in ``[0, 2 pi)``, snapped onto a face where it is beyond
    it by rounding only (``_ANGLE_SNAP_RAD``), and whether it points into the wedge
    (``phi > n pi``, not snapped)."""
    phi = np.arctan2(dot3(wx, wy, wz, n0x, n0y, n0z), dot3(wx, wy, wz, t0x, t0y, t0z)) % _TWO_PI
    over = phi > npi
    near_face0 = over and phi >= _TWO_PI - _ANGLE_SNAP_RAD
    near_facen = over and phi <= npi + _ANGLE_SNAP_RAD
    if near_face0 and not near_facen:
        phi = 0.0
    if near_facen:
        phi = npi
    return phi, over and not near_face0 and not near_facen


@inline
def _unit_legs(ex, ey, ez, sx, sy, sz, dx, dy, dz, px, py, pz):
    """The incident and diffracted legs of a diffraction at ``p`` from ``s`` to ``d`` on an edge
    of unit direction ``e``: unit vectors, lengths, ``e x s`` and its norm (``sin beta_0``),
    as ``ix, iy, iz, s_in, ox, oy, oz, s_out, cix, ciy, ciz, sin_in, cox, coy, coz, sin_out``."""
    ix, iy, iz = px - sx, py - sy, pz - sz
    s_in = np.sqrt(ix * ix + iy * iy + iz * iz)
    ix, iy, iz = ix / s_in, iy / s_in, iz / s_in
    ox, oy, oz = dx - px, dy - py, dz - pz
    s_out = np.sqrt(ox * ox + oy * oy + oz * oz)
    ox, oy, oz = ox / s_out, oy / s_out, oz / s_out
    cix, ciy, ciz = cross3(ex, ey, ez, ix, iy, iz)
    cox, coy, coz = cross3(ex, ey, ez, ox, oy, oz)
    sin_in = np.sqrt(cix * cix + ciy * ciy + ciz * ciz)
    sin_out = np.sqrt(cox * cox + coy * coy + coz * coz)
    return (ix, iy, iz, s_in, ox, oy, oz, s_out, cix, ciy, ciz, sin_in, cox, coy, coz,
            sin_out)  # fmt: skip


@inline
def _legs(e, t0, n0, n, w, sx, sy, sz, dx, dy, dz, px, py, pz):
    """Unit vectors, lengths, azimuths and ``e x s`` of the incident and diffracted legs of a
    diffraction at ``p`` from ``s`` to ``d`` on the wedge of frame row ``w``. The frame is read
    before the first branch (see :func:`raytrace.scene.accel.facet_box_test`)."""
    ex, ey, ez = e[w, 0], e[w, 1], e[w, 2]
    t0x, t0y, t0z, n0x, n0y, n0z = t0[w, 0], t0[w, 1], t0[w, 2], n0[w, 0], n0[w, 1], n0[w, 2]
    npi = n[w] * np.pi
    (ix, iy, iz, s_in, ox, oy, oz, s_out, cix, ciy, ciz, sin_in, cox, coy, coz,
     sin_out) = _unit_legs(ex, ey, ez, sx, sy, sz, dx, dy, dz, px, py, pz)  # fmt: skip
    phi_in, in_s = _azimuth1(sx - px, sy - py, sz - pz, t0x, t0y, t0z, n0x, n0y, n0z, npi)
    phi, in_d = _azimuth1(dx - px, dy - py, dz - pz, t0x, t0y, t0z, n0x, n0y, n0z, npi)
    valid = (s_in > 0 and s_out > 0 and sin_in > _MIN_SIN_BETA0 and sin_out > _MIN_SIN_BETA0
             and not in_s and not in_d)  # fmt: skip
    return (ix, iy, iz, s_in, ox, oy, oz, s_out, phi_in, phi, cix, ciy, ciz, sin_in, cox, coy,
            coz, sin_out, valid)  # fmt: skip


@inline
def _ray_fixed(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz, cox, coy, coz, sin_out):
    """KP's ray-fixed unit vectors of one diffraction from :func:`_legs`' unit legs and
    ``e x s``: ``phi'_hat = -(e x s') / |e x s'|``, ``beta0'_hat = s' x phi'_hat``,
    ``phi_hat = (e x s) / |e x s|``, ``beta0_hat = s x phi_hat``, as the twelve components of
    ``beta0'_hat, phi'_hat, beta0_hat, phi_hat``."""
    hx, hy, hz = -cix / sin_in, -ciy / sin_in, -ciz / sin_in
    bx, by, bz = cross3(ix, iy, iz, hx, hy, hz)
    gx, gy, gz = cox / sin_out, coy / sin_out, coz / sin_out
    ax, ay, az = cross3(ox, oy, oz, gx, gy, gz)
    return bx, by, bz, hx, hy, hz, ax, ay, az, gx, gy, gz


@inline
def _into_wedge(wx, wy, wz, t0x, t0y, t0z, n0x, n0y, n0z, npi):
    """:func:`_azimuth1`'s second value (vector ``w`` points into the wedge), without the
    arctangent where the answer is known: on face 0's side of the plane through the edge
    (``w . n0 >= 0``) the angle is at most ``pi``, never beyond a face at ``n pi >= pi``."""
    if dot3(wx, wy, wz, n0x, n0y, n0z) >= 0.0 and npi >= np.pi:
        return False
    return _azimuth1(wx, wy, wz, t0x, t0y, t0z, n0x, n0y, n0z, npi)[1]


@helper
def diffraction_valid1(e, t0, n0, n, w, sx, sy, sz, dx, dy, dz, px, py, pz):
    """:func:`diffraction_valid` of one diffraction at ``p`` from ``s`` to ``d`` on the wedge of
    frame row ``w`` (``e, t0, n0, n`` of :class:`WedgeFrame`, one row per wedge), a compiled
    scalar helper for kernels: :func:`_legs`' ``valid`` with the same arithmetic, the azimuths
    only where they decide it (on the hall's RD and DR candidates, the arctangents were half
    the time of the exact tests)."""
    ex, ey, ez = e[w, 0], e[w, 1], e[w, 2]
    t0x, t0y, t0z, n0x, n0y, n0z = t0[w, 0], t0[w, 1], t0[w, 2], n0[w, 0], n0[w, 1], n0[w, 2]
    npi = n[w] * np.pi
    _, _, _, s_in, _, _, _, s_out, _, _, _, sin_in, _, _, _, sin_out = _unit_legs(
        ex, ey, ez, sx, sy, sz, dx, dy, dz, px, py, pz)  # fmt: skip
    if not (s_in > 0 and s_out > 0 and sin_in > _MIN_SIN_BETA0 and sin_out > _MIN_SIN_BETA0):
        return False
    if _into_wedge(sx - px, sy - py, sz - pz, t0x, t0y, t0z, n0x, n0y, n0z, npi):
        return False
    return not _into_wedge(dx - px, dy - py, dz - pz, t0x, t0y, t0z, n0x, n0y, n0z, npi)


@inline
def _face_rule(a_in, a_out, s_in, s_out):
    """:func:`face_rule_angle` of one diffraction."""
    height = s_out * abs(np.sin(a_out)) + s_in * abs(np.sin(a_in))
    return np.arctan2(height, s_in * np.cos(a_in) - s_out * np.cos(a_out))


@inline
def _face_rule_cs(a_in, a_out, s_in, s_out):
    """``cos psi, sin psi`` of :func:`_face_rule`'s angle ``psi``, without the angle: the
    reflection point's base and height over their hypotenuse (``sin psi >= 0``); ``(1, 0)``
    where both vanish, as ``atan2(0, 0) = 0``."""
    height = s_out * abs(np.sin(a_out)) + s_in * abs(np.sin(a_in))
    base = s_in * np.cos(a_in) - s_out * np.cos(a_out)
    h = np.sqrt(height * height + base * base)
    if h == 0.0:
        return 1.0, 0.0
    return base / h, height / h


@kernel("f8[::1](f8[::1], f8[::1], f8[::1], f8[::1])")
def _face_rules(a_in, a_out, s_in, s_out):
    """:func:`_face_rule` over P rows (:func:`face_rule_angle`)."""
    out = np.empty(len(a_in))
    for r in range(len(a_in)):
        out[r] = _face_rule(a_in[r], a_out[r], s_in[r], s_out[r])
    return out


_VECS = "f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1]"


@kernel(f"b1[::1]({_VECS})")
def _valid(e, t0, n0, n, src, dst, point):
    """:func:`diffraction_valid` over P rows."""
    out = np.empty(len(n), dtype=np.bool_)
    for r in range(len(n)):
        out[r] = diffraction_valid1(e, t0, n0, n, r, src[r, 0], src[r, 1], src[r, 2], dst[r, 0],
                                    dst[r, 1], dst[r, 2], point[r, 0], point[r, 1], point[r, 2])  # fmt: skip
    return out


@kernel(
    "Tuple((f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], f8[::1], f8[:, ::1], "
    "f8[:, ::1], f8[:, ::1], f8[:, ::1], b1[::1], b1[::1], b1[::1], f8[::1], f8[::1], f8[::1], "
    f"f8[::1]))({_VECS})"
)
def _geometry(e, t0, n0, n, src, dst, point):
    """:func:`framed_wedge_geometry` over P rows: the fields of :class:`WedgeGeometry` after the
    frame's, in the order ``s_hat_in, s_in, s_hat_out, s_out, phi_in, phi, sin_beta0,
    phi_hat_in, beta_hat_in, phi_hat_out, beta_hat_out, lit_0, lit_n, valid, psi_0, psi_n,
    cos_theta_0, cos_theta_n``."""
    p = len(n)
    s_hat_in, s_hat_out = np.empty((p, 3)), np.empty((p, 3))
    phi_hat_in, beta_hat_in = np.empty((p, 3)), np.empty((p, 3))
    phi_hat_out, beta_hat_out = np.empty((p, 3)), np.empty((p, 3))
    s_in, s_out, phi_in, phi, sin_beta0 = (np.empty(p), np.empty(p), np.empty(p), np.empty(p),
                                           np.empty(p))  # fmt: skip
    psi_0, psi_n, cos_0, cos_n = np.empty(p), np.empty(p), np.empty(p), np.empty(p)
    lit_0, lit_n = np.empty(p, dtype=np.bool_), np.empty(p, dtype=np.bool_)
    valid = np.empty(p, dtype=np.bool_)
    for r in range(p):
        (ix, iy, iz, si, ox, oy, oz, so, pin, pout, cix, ciy, ciz, sin_in, cox, coy, coz,
         sin_out, ok) = _legs(e, t0, n0, n, r, src[r, 0], src[r, 1], src[r, 2], dst[r, 0],
                              dst[r, 1], dst[r, 2], point[r, 0], point[r, 1], point[r, 2])  # fmt: skip
        s_hat_in[r, 0], s_hat_in[r, 1], s_hat_in[r, 2], s_in[r] = ix, iy, iz, si
        s_hat_out[r, 0], s_hat_out[r, 1], s_hat_out[r, 2], s_out[r] = ox, oy, oz, so
        phi_in[r], phi[r], sin_beta0[r], valid[r] = pin, pout, sin_in, ok
        (beta_hat_in[r, 0], beta_hat_in[r, 1], beta_hat_in[r, 2], phi_hat_in[r, 0],
         phi_hat_in[r, 1], phi_hat_in[r, 2], beta_hat_out[r, 0], beta_hat_out[r, 1],
         beta_hat_out[r, 2], phi_hat_out[r, 0], phi_hat_out[r, 1],
         phi_hat_out[r, 2]) = _ray_fixed(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz, cox, coy,
                                         coz, sin_out)  # fmt: skip
        npi = n[r] * np.pi
        lit_0[r] = pin <= np.pi
        lit_n[r] = npi - pin <= np.pi
        psi_0[r] = _face_rule(pin, pout, si, so)
        psi_n[r] = _face_rule(npi - pin, npi - pout, si, so)
        cos_0[r] = sin_in * abs(np.sin(psi_0[r]))
        cos_n[r] = sin_in * abs(np.sin(psi_n[r]))
    return (s_hat_in, s_in, s_hat_out, s_out, phi_in, phi, sin_beta0, phi_hat_in, beta_hat_in,
            phi_hat_out, beta_hat_out, lit_0, lit_n, valid, psi_0, psi_n, cos_0, cos_n)  # fmt: skip


def _oriented_wedge(
    edge_dir: np.ndarray,
    normal_0: np.ndarray,
    normal_n: np.ndarray,
    face0_dir: np.ndarray | None,
    p: int,
) -> tuple[np.ndarray, ...]:
    """Edge-fixed frame of P wedges: ``e`` oriented so that angles grow from face 0 towards face
    n, the face-0 tangent ``t0``, the normals projected perpendicular to the edge, and the wedge
    parameter ``n`` (exterior angle / pi; 2 for a half-plane). See :func:`wedge_geometry`."""
    e, _ = _unit(_points("edge_dir", edge_dir, p))
    n0 = _points("normal_0", normal_0, p)
    nn = _points("normal_n", normal_n, p)
    # mesh normals may be slightly off perpendicular to a merged edge: project and renormalise
    n0, _ = _unit(n0 - _dot(n0, e)[:, None] * e)
    nn, _ = _unit(nn - _dot(nn, e)[:, None] * e)
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(n0)) and np.all(np.isfinite(nn))):
        raise TraceInputError("edge_dir and face normals must be non-zero and not parallel")
    t0 = _cross(n0, e)
    if face0_dir is None:
        # convex wedge: face 0 lies behind the outward normal of face n
        score = -_dot(t0, nn)
        if np.any(np.abs(score) < 1e-9):
            raise TraceInputError("face0_dir is required for half-plane (thin-sheet) edges")
    else:
        f0 = _points("face0_dir", face0_dir, p)
        f0 = f0 - _dot(f0, e)[:, None] * e
        score = _dot(t0, f0)
        if np.any(np.abs(score) <= 1e-12 * np.maximum(np.linalg.norm(f0, axis=1), 1e-300)):
            raise TraceInputError("face0_dir must point from the edge into face 0")
    flip = score < 0
    e = np.where(flip[:, None], -e, e)
    t0 = np.where(flip[:, None], -t0, t0)
    tn = _cross(e, nn)
    ext = np.mod(np.arctan2(_dot(_cross(t0, tn), e), _dot(t0, tn)), _TWO_PI)
    ext = np.where((ext < _HALF_PLANE_RAD) | (ext > _TWO_PI - _HALF_PLANE_RAD), _TWO_PI, ext)
    return e, t0, n0, nn, ext / np.pi


def face_rule_angle(
    a_in: np.ndarray, a_out: np.ndarray, s_in: np.ndarray, s_out: np.ndarray
) -> np.ndarray:
    """The face rule (D8a): in-plane angle (rad) of the reflection off a face's plane between a
    source at angle ``a_in`` (rad, from the face) and distance ``s_in`` (m) from the edge and a
    receiver at ``a_out``, ``s_out``, both taken in front of the plane; (P,) arrays broadcast.

    In the plane perpendicular to the edge, the source is at distance ``s' sin beta0`` and angle
    ``phi'`` from the face, the receiver at ``s sin beta0`` and ``phi``. The face reflects at the
    angle of the specular reflection off its plane between the two, each end taken on the face's
    side of the plane (an end behind it mirrored to the front):
    ``psi = atan2(s |sin phi| + s' |sin phi'|, s' cos phi' - s cos phi)`` (the ``sin beta0``
    cancels). This is reciprocal (swapping the ends gives ``pi - psi``, the same reflection),
    continuous everywhere, the geometrical-optics reflection angle wherever the face's reflection
    is seen (so ``phi'`` on its reflection boundary), and tends to Luebbers' ``phi'`` for a
    distant source and to his ``pi - phi`` for a distant receiver. :class:`WedgeGeometry` takes
    face 0's angle with ``(phi', phi)`` and face n's with ``(n pi - phi', n pi - phi)``
    (:func:`_face_rule`, which this evaluates elementwise).
    """
    shape, rows = broadcast_rows(*(np.asarray(v, dtype=float) for v in (a_in, a_out, s_in, s_out)))
    psi = _face_rules(*rows)
    return psi.reshape(shape)[()]  # a scalar for scalar input, as numpy gives


# -- 3. UTD coefficients --------------------------------------------------------------------------
#: From this argument on, ``G(x)`` is summed from the large-argument series of ``F``
#: (:func:`_g_large`) instead of the Faddeeva function: eleven terms, the first one left out is
#: below 7e-16 of ``F`` there.
X_SERIES = 100.0
#: Terms of the series (``m = 0 .. _SERIES_TERMS - 1``).
_SERIES_TERMS = 11


@inline
def _g_large(x):
    """``G(x) = F(x) / sqrt(x)`` for ``x >= X_SERIES`` from KP's large-argument series
    ``F(x) ~ sum_m (2m-1)!! (j / 2x)^m``, summed by Horner's rule in ``y^2 = (1 / 2x)^2``
    separately over the even (real) and odd (imaginary) terms."""
    y = 0.5 / x
    y2 = y * y
    re = 0.0
    im = 0.0
    # coefficients (2m-1)!! (-1)^floor(m/2), highest first
    top = _SERIES_TERMS - 1
    for m in range(top - top % 2, -1, -2):  # even m: (2m-1)!! (-1)^(m/2) y^m
        re = re * y2 + _DOUBLE_FACTORIAL[m] * (1.0 if m % 4 == 0 else -1.0)
    for m in range(top - (top + 1) % 2, 0, -2):  # odd m: (2m-1)!! (-1)^((m-1)/2) y^m
        im = im * y2 + _DOUBLE_FACTORIAL[m] * (1.0 if m % 4 == 1 else -1.0)
    im *= y
    r = np.sqrt(x)
    return complex(re / r, im / r)


#: (2m - 1)!! for m = 0 .. _SERIES_TERMS - 1 ((-1)!! = 1)
_DOUBLE_FACTORIAL = np.array([float(np.prod(np.arange(2 * m - 1, 0, -2))) for m in range(11)])


@kernel("c16[::1](f8[::1])")
def _g_series(x):
    """:func:`_g_large` over n arguments."""
    out = np.empty(len(x), dtype=np.complex128)
    for i in range(len(x)):
        out[i] = _g_large(x[i])
    return out


def _transition_over_sqrt(x: np.ndarray) -> np.ndarray:
    """``G(x) = F(x) / sqrt(x)``, finite at 0: ``G(0) = sqrt(pi) exp(j pi/4)``.

    ``int_u^inf exp(-j t^2) dt = exp(-j u^2) (sqrt(pi)/2) exp(-j pi/4) w(u exp(j 3pi/4))`` with the
    Faddeeva function ``w(z) = exp(-z^2) erfc(-j z)`` (scipy.special.wofz), stable for all u >= 0:
    no cancellation between ``1/2`` and a Fresnel integral at large argument. From
    :data:`X_SERIES` on (most diffractions away from a shadow or reflection boundary), the
    large-argument series (:func:`_g_large`), about five times cheaper, agrees with it to about
    1e-15 relative.
    """
    x = np.asarray(x, dtype=float)
    flat = x.reshape(-1)
    out = np.empty(flat.shape, dtype=complex)
    large = flat >= X_SERIES
    if large.any():
        out[large] = _g_series(_c(flat[large]))
    near = np.flatnonzero(~large)
    if len(near):
        out[near] = _g_faddeeva(flat[near])
    return out.reshape(x.shape)


def _g_faddeeva(x: np.ndarray) -> np.ndarray:
    """``G(x)`` of :func:`_transition_over_sqrt` from the Faddeeva function, (n,) -> (n,)."""
    u = np.sqrt(x)
    return np.sqrt(np.pi) * np.exp(0.25j * np.pi) * wofz(u * np.exp(0.75j * np.pi))


def transition_function(x: float | np.ndarray) -> np.ndarray:
    """UTD transition function ``F(x) = 2j sqrt(x) exp(jx) int_sqrt(x)^inf exp(-j t^2) dt``.

    Kouyoumjian and Pathak, Proc. IEEE 62(11), 1974. ``F -> 1`` for large x (the GTD limit),
    ``F ~ sqrt(pi x) exp(j (pi/4 + x))`` for small x.

    Parameters
    ----------
    x : float or (...) float array, >= 0

    Returns
    -------
    (...) complex128
    """
    x = np.asarray(x, dtype=float)
    if np.any(x < 0) or not np.all(np.isfinite(x)):
        raise TraceInputError("transition_function needs finite x >= 0")
    return np.sqrt(x) * _transition_over_sqrt(x)


@inline
def _wedge_factor(beta, sign, n, kl):
    """``cot((pi + sign beta) / 2n) F(kL a^sign(beta))`` in a form finite at the boundaries,
    as ``(x, f)`` with the term ``= f G(x)`` (``G`` = :func:`_transition_over_sqrt`).

    With ``N`` the integer nearest to ``(sign beta + pi) / (2 pi n)`` (KP's ``N^+`` for
    sign = +1, ``-N^-`` for sign = -1) and ``eps = pi + sign beta - 2 pi n N`` in ``[-n pi, n pi]``,
    exactly ``cot((pi + sign beta)/2n) = cot(eps/2n)`` and ``a^sign(beta) = 2 sin^2(eps/2)``, so
    the term is ``cot(eps/2n) sqrt(x) G(x)``, ``x = 2 kL sin^2(eps/2)``, ``G = F / sqrt(x)``, and
    ``cot(eps/2n) |sin(eps/2)| = sgn(eps) sin(eps/2) cos(eps/2n) / sin(eps/2n)`` (``sin(eps/2)``
    has the sign of ``eps`` for ``|eps| <= 2 pi``), so
    ``f = sgn(eps) sin(eps/2) cos(eps/2n) / sin(eps/2n) sqrt(2 kL)``; the ratio of the two sines
    is well conditioned and tends to ``n`` as eps -> 0 (``n`` at eps = 0). The term's limit for
    eps -> 0 is ``n sqrt(2 pi kL) sgn(eps) exp(j pi/4)`` (KP's boundary value); the jump of
    sgn(eps) is the one that cancels the jump of the geometrical-optics field. ``eps > 0`` is the
    side where that field is (the incident field at a shadow boundary, the reflected one at a
    reflection boundary), and exactly on the boundary (``eps = 0``) the term takes that side's
    value: there the tracer counts the geometrical-optics field (a ray that grazes an edge only
    touches it; a reflection point on a facet's edge is in the facet), so the total field is
    its limit from either side, half the geometrical-optics field.
    """
    big_n = np.rint((sign * beta + np.pi) / (_TWO_PI * n))
    eps = np.pi + sign * beta - _TWO_PI * n * big_n
    s = np.sin(0.5 * eps)
    x = 2.0 * kl * (s * s)
    a = eps / (2.0 * n)
    sa = np.sin(a)
    ratio = s * np.cos(a) / sa if sa != 0.0 else n
    return x, (1.0 if eps >= 0.0 else -1.0) * ratio * np.sqrt(2.0 * kl)


@inline
def _four_factors(n, phi, phi_in, kl):
    """:func:`_wedge_factor`'s ``(x, f)`` of ``D1``, ``D2`` (``beta = phi - phi'``, sign +1, -1)
    and ``D3``, ``D4`` (``beta = phi + phi'``) of one diffraction, flat."""
    b_m, b_p = phi - phi_in, phi + phi_in
    x1, f1 = _wedge_factor(b_m, 1.0, n, kl)
    x2, f2 = _wedge_factor(b_m, -1.0, n, kl)
    x3, f3 = _wedge_factor(b_p, 1.0, n, kl)
    x4, f4 = _wedge_factor(b_p, -1.0, n, kl)
    return x1, f1, x2, f2, x3, f3, x4, f4


@kernel("Tuple((f8[:, ::1], f8[:, ::1]))(f8[::1], f8[::1], f8[::1], f8[::1])")
def _wedge_factors(n, phi, phi_in, kl):
    """:func:`_wedge_factor` of the four terms of P diffractions, (P, 4) each: ``D1``, ``D2``
    (``beta = phi - phi'``, sign +1, -1) and ``D3``, ``D4`` (``beta = phi + phi'``)."""
    p = len(n)
    x, f = np.empty((p, 4)), np.empty((p, 4))
    for r in range(p):
        (x[r, 0], f[r, 0], x[r, 1], f[r, 1], x[r, 2], f[r, 2], x[r, 3],
         f[r, 3]) = _four_factors(n[r], phi[r], phi_in[r], kl[r])  # fmt: skip
    return x, f


def _reflection_pair(
    r: tuple[np.ndarray, np.ndarray] | None, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    if r is None:  # perfect conductor: R_soft = -1, R_hard = +1
        return np.full(shape, -1.0 + 0j), np.full(shape, 1.0 + 0j)
    soft, hard = r
    return (
        np.broadcast_to(np.asarray(soft, dtype=complex), shape),
        np.broadcast_to(np.asarray(hard, dtype=complex), shape),
    )


#: ``-exp(-j pi / 4)``, the numerator of KP's ``C`` (:func:`_utd_terms`).
_C_NUMERATOR = complex(-np.exp(-0.25j * np.pi))


def _utd_terms(n, phi, phi_in, sin_beta0, distance_m, wavenumber):
    """``C (D1 + D2)``, ``C D3``, ``C D4`` of (D7) (broadcast, complex): the polarisation-free
    parts of the KP coefficient, before the face reflection coefficients multiply D3 and D4."""
    shape, (n, phi, phi_in, sin_beta0, dist, k) = broadcast_rows(
        *(np.asarray(v, dtype=float) for v in (n, phi, phi_in, sin_beta0, distance_m, wavenumber))
    )
    x, f = _wedge_factors(n, phi, phi_in, k * dist)
    w = f * _transition_over_sqrt(x)  # the four terms, one Faddeeva call for all
    c = _C_NUMERATOR / (2.0 * n * np.sqrt(_TWO_PI * k) * sin_beta0)
    return (
        (c * (w[:, 0] + w[:, 1])).reshape(shape),
        (c * w[:, 2]).reshape(shape),
        (c * w[:, 3]).reshape(shape),
    )


def utd_coefficients(
    n: float | np.ndarray,
    phi: float | np.ndarray,
    phi_in: float | np.ndarray,
    sin_beta0: float | np.ndarray,
    distance_m: float | np.ndarray,
    wavenumber: float | np.ndarray,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Soft and hard UTD wedge diffraction coefficients (KP 1974; Luebbers 1984), scalar form.

    ``D = C [D1 + D2 + R_n D3 + R_0 D4]`` with ``C = -exp(-j pi/4) / (2n sqrt(2 pi k) sin beta0)``
    and ``D1 = cot((pi + (phi - phi'))/2n) F(kL a+(phi - phi'))``,
    ``D2 = cot((pi - (phi - phi'))/2n) F(kL a-(phi - phi'))``,
    ``D3 = cot((pi + (phi + phi'))/2n) F(kL a+(phi + phi'))``,
    ``D4 = cot((pi - (phi + phi'))/2n) F(kL a-(phi + phi'))``,
    ``a+-(beta) = 2 cos^2((2 n pi N+- - beta)/2)``, ``N+-`` the integers nearest to solving
    ``2 pi n N+- - beta = +-pi``. For a perfect conductor (``r_0 = r_n = None``) ``R = -1`` (soft)
    and ``+1`` (hard): KP's ``D_s,h = C [D1 + D2 -+ (D3 + D4)]``. Finite and continuous apart from
    the jumps at shadow and reflection boundaries that make the total field continuous.

    This is the two-dimensional (normal incidence on the edge) form: the caller chooses the angles
    at which ``R_0`` and ``R_n`` are taken (see :class:`WedgeGeometry` ``cos_theta_0/_n`` for the
    labelling-independent rule). :func:`diffracted_field` uses the same terms with the faces'
    reflection as 2 x 2 matrices (:func:`face_reflection_matrix`), exact at oblique incidence.

    Parameters
    ----------
    n : wedge parameter (exterior angle / pi)
    phi, phi_in : rad; ``phi`` (receiver) and ``phi'`` (source) from face 0, in ``[0, n pi]``
    sin_beta0 : sine of the angle between the incident ray and the edge
    distance_m : metres; distance parameter ``L`` (``s s' sin^2 beta0 / (s + s')`` for a
        spherical wave)
    wavenumber : rad/m; ``k = 2 pi f / c``
    r_0, r_n : (soft, hard) reflection coefficients of face 0 and face n, e.g. Fresnel
        ``(r_te, r_tm)`` at :attr:`WedgeGeometry.cos_theta_0` / ``cos_theta_n``; None for a
        perfect conductor.

    Returns
    -------
    d_soft, d_hard : complex128 arrays (broadcast shape), sqrt(metres)
    """
    d12, d3, d4 = _utd_terms(n, phi, phi_in, sin_beta0, distance_m, wavenumber)
    r0s, r0h = _reflection_pair(r_0, d12.shape)
    rns, rnh = _reflection_pair(r_n, d12.shape)
    return d12 + rns * d3 + r0s * d4, d12 + rnh * d3 + r0h * d4


def face_reflection_matrix(
    r_te: np.ndarray, r_tm: np.ndarray, cos_beta: np.ndarray, psi: np.ndarray
) -> np.ndarray:
    """Reflection by a wedge face as a 2 x 2 matrix in ray-fixed edge components.

    Frame of the face: ``e_f`` along the edge, ``t_f`` in the face pointing away from the edge,
    ``n_f = e_f x t_f`` the outward normal (for face 0 of :func:`wedge_geometry` ``e_f = e``, for
    face n ``e_f = -e``). A ray on Keller's cone, ``s' = c e_f - s (cos psi t_f + sin psi n_f)``
    (``c = cos beta``, signed, ``s = sin beta``; the source seen from the edge at in-plane angle
    ``psi`` from the face), is reflected into the specular ray. The Fresnel reflection
    (``E_r = R_TE (E . u) u + R_TM (E . p_i) p_r`` with ``u = s' x n_f / |s' x n_f|``,
    ``p = u x k``; P.2040 convention, as the tracer's reflections) written from the incident
    components ``(E . beta0'_hat, E . phi'_hat)`` to the reflected ray's ``(E . beta0_hat,
    E . phi_hat)`` (KP ray-fixed vectors) is, with ``m^2 = s^2 cos^2 psi + c^2`` (the squared
    sine of the incidence angle on the face)::

        T = 1/m^2 [[ -R_TE cos^2 psi + R_TM c^2 sin^2 psi,   -c sin psi cos psi (R_TE + R_TM) ],
                   [  c sin psi cos psi (R_TE + R_TM),        R_TE c^2 sin^2 psi - R_TM cos^2 psi ]]

    (docs/diffraction.md, (D8b)). A perfect conductor gives ``diag(1, -1)`` at any obliquity
    (KP's ``-+`` signs); at normal incidence on the edge (``c = 0``) ``diag(-R_TE, -R_TM)``
    (Luebbers' soft = TE, hard = TM); at oblique incidence a lossy face couples the two
    components. Reversing ``e_f`` together with the ray-fixed vectors leaves ``T`` unchanged.

    Parameters
    ----------
    r_te, r_tm : (P,) complex; Fresnel (or slab) coefficients at incidence cosine
        ``sin(beta) |sin(psi)|``
    cos_beta : (P,) float; ``s' . e_f`` (signed)
    psi : (P,) float, rad

    Returns
    -------
    (P, 2, 2) complex128; rows (beta0, phi) of the reflected ray, columns (beta0', phi') of the
    incident one
    """
    r_te, r_tm = np.asarray(r_te, dtype=complex), np.asarray(r_tm, dtype=complex)
    c, psi = np.asarray(cos_beta, dtype=float), np.asarray(psi, dtype=float)
    shape = np.broadcast(r_te, r_tm, c, psi).shape
    r_te, r_tm, c, psi = (np.broadcast_to(x, shape).reshape(-1) for x in (r_te, r_tm, c, psi))
    out = _face_matrices(_c(r_te, complex), _c(r_tm, complex), _c(c), _c(np.cos(psi)),
                         _c(np.sin(psi)))  # fmt: skip
    return out.reshape(shape + (2, 2))


@inline
def _face_matrix1(r_te, r_tm, c, cp, sp):
    """:func:`face_reflection_matrix` of one face, from ``cos psi``, ``sin psi``: its entries
    ``t00, t01, t10, t11`` (complex)."""
    cb2 = c * c
    m2 = (1.0 - cb2) * cp * cp + cb2
    # normal incidence on the face (m -> 0): R_TM = -R_TE there and T -> diag(-R_TE, -R_TM)
    if m2 < 1e-24:
        return -r_te, 0j, 0j, -r_tm
    inv = 1.0 / m2
    cross = c * sp * cp * (r_te + r_tm) * inv
    return ((-r_te * cp * cp + r_tm * cb2 * sp * sp) * inv, -cross, cross,
            (r_te * cb2 * sp * sp - r_tm * cp * cp) * inv)  # fmt: skip


@kernel("c16[:, :, ::1](c16[::1], c16[::1], f8[::1], f8[::1], f8[::1])")
def _face_matrices(r_te, r_tm, c, cp, sp):
    """:func:`_face_matrix1` over P rows, (P, 2, 2)."""
    out = np.empty((len(c), 2, 2), dtype=np.complex128)
    for r in range(len(c)):
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _face_matrix1(
            r_te[r], r_tm[r], c[r], cp[r], sp[r]
        )
    return out


@inline
def _dyadic1(r0_te, r0_tm, rn_te, rn_tm, cos_b, cp0, sp0, cpn, spn, d12, d3, d4):
    """The entries ``d00, d01, d10, d11`` of :func:`_dyadic`'s ``D`` of one diffraction."""
    a00, a01, a10, a11 = _face_matrix1(r0_te, r0_tm, cos_b, cp0, sp0)
    b00, b01, b10, b11 = _face_matrix1(rn_te, rn_tm, -cos_b, cpn, spn)
    return (-d3 * b00 - d4 * a00 + d12, -d3 * b01 - d4 * a01, -d3 * b10 - d4 * a10,
            -d3 * b11 - d4 * a11 + d12)  # fmt: skip


@kernel(
    "c16[:, :, ::1](c16[::1], c16[::1], c16[::1], c16[::1], f8[::1], f8[::1], f8[::1], f8[::1], "
    "f8[::1], c16[::1], c16[::1], c16[::1])"
)
def _dyadic(r0_te, r0_tm, rn_te, rn_tm, cos_b, cp0, sp0, cpn, spn, d12, d3, d4):
    """``D = C(D1 + D2) I - C D3 T_n - C D4 T_0`` of :func:`diffraction_matrix` over P rows
    (P, 2, 2): ``T_0`` of face 0 at ``cos_b``, ``T_n`` of face n at ``-cos_b``
    (:func:`_face_matrix1`, from ``cos psi``, ``sin psi`` of each face)."""
    out = np.empty((len(cos_b), 2, 2), dtype=np.complex128)
    for r in range(len(cos_b)):
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _dyadic1(
            r0_te[r], r0_tm[r], rn_te[r], rn_tm[r], cos_b[r], cp0[r], sp0[r], cpn[r], spn[r],
            d12[r], d3[r], d4[r],
        )
    return out


# -- 3b. the diffractions of unfolded paths, compiled end to end ----------------------------------
_F8, _F8_2 = "f8[::1]", "f8[:, ::1]"


@kernel(
    f"Tuple(({_F8_2}, {_F8_2}, c16[:, ::1], i8[::1], f8[:, :, ::1], c16[::1], {_F8_2}, {_F8}, "
    f"b1[::1], {_F8}))({_F8_2}, {_F8_2}, {_F8_2}, {_F8}, i8[::1], f8[:, :, ::1], i8, {_F8_2}, f8)"
)
def _chain_geometry(e, t0, n0, n, wedge, chain, j, seg_len, k):
    """The geometry of the diffraction at vertex ``j`` of P unfolded chains, and what the UTD
    coefficient needs of it (:func:`chain_diffraction`): the wedge factors ``x, f`` (P, 4) of
    :func:`_wedge_factors`, ``G(x)`` (P, 4) where ``x >= X_SERIES`` (:func:`_g_large`) and the
    flat indices of the others (for the Faddeeva function), the ray-fixed basis (P, 4, 3), KP's
    ``C`` (P,), per row ``cos_b``,
    ``cos psi_0``, ``sin psi_0``, ``cos psi_n``, ``sin psi_n``, ``cos_theta_0``,
    ``cos_theta_n`` (P, 7), the spreading ``A`` (P,), the validity and the incident leg's
    unfolded length ``s'`` along the path (P,).

    The unfolded source and receiver are recovered from the chain as
    :func:`raytrace.solver.diffraction.field_model` did in numpy (the path is straight on either
    side of the edge once unfolded), and each quantity is computed as :func:`_geometry` and
    :func:`diffraction_matrix` compute it, in the same order."""
    p = len(wedge)
    x, f = np.empty((p, 4)), np.empty((p, 4))
    g = np.empty((p, 4), dtype=np.complex128)
    near = np.empty(4 * p, dtype=np.int64)
    n_near = 0
    basis = np.empty((p, 4, 3))
    c = np.empty(p, dtype=np.complex128)
    reals = np.empty((p, 7))
    spreading, s_path = np.empty(p), np.empty(p)
    valid = np.empty(p, dtype=np.bool_)
    sq = np.sqrt(_TWO_PI * k)
    for r in range(p):
        w = wedge[r]
        s_in = seg_len[r, 0]
        for i in range(1, j):
            s_in += seg_len[r, i]
        s_out = seg_len[r, j]
        for i in range(j + 1, seg_len.shape[1]):
            s_out += seg_len[r, i]
        px, py, pz = chain[r, j, 0], chain[r, j, 1], chain[r, j, 2]
        ax, ay, az = px - chain[r, j - 1, 0], py - chain[r, j - 1, 1], pz - chain[r, j - 1, 2]
        na = np.sqrt(ax * ax + ay * ay + az * az)
        ax, ay, az = ax / na, ay / na, az / na
        bx, by, bz = chain[r, j + 1, 0] - px, chain[r, j + 1, 1] - py, chain[r, j + 1, 2] - pz
        nb = np.sqrt(bx * bx + by * by + bz * bz)
        bx, by, bz = bx / nb, by / nb, bz / nb
        (ix, iy, iz, si, ox, oy, oz, so, pin, pout, cix, ciy, ciz, sin_in, cox, coy, coz,
         sin_out, ok) = _legs(e, t0, n0, n, w, px - s_in * ax, py - s_in * ay, pz - s_in * az,
                              px + s_out * bx, py + s_out * by, pz + s_out * bz, px, py, pz)  # fmt: skip
        (basis[r, 0, 0], basis[r, 0, 1], basis[r, 0, 2], basis[r, 1, 0], basis[r, 1, 1],
         basis[r, 1, 2], basis[r, 2, 0], basis[r, 2, 1], basis[r, 2, 2], basis[r, 3, 0],
         basis[r, 3, 1], basis[r, 3, 2]) = _ray_fixed(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz,
                                                      cox, coy, coz, sin_out)  # fmt: skip
        npi = n[w] * np.pi
        cp0, sp0 = _face_rule_cs(pin, pout, si, so)
        cpn, spn = _face_rule_cs(npi - pin, npi - pout, si, so)
        reals[r, 1], reals[r, 2], reals[r, 3], reals[r, 4] = cp0, sp0, cpn, spn
        reals[r, 5], reals[r, 6] = sin_in * sp0, sin_in * spn
        # diffraction_matrix: an invalid row gets harmless stand-ins
        g_in, g_out, sin_b = (si, so, sin_in) if ok else (1.0, 1.0, 1.0)
        nw, ph, ph_in = (n[w], pout, pin) if ok else (2.0, 0.0, 0.0)
        dist = g_in * g_out * (sin_b * sin_b) / (g_in + g_out)
        (x[r, 0], f[r, 0], x[r, 1], f[r, 1], x[r, 2], f[r, 2], x[r, 3],
         f[r, 3]) = _four_factors(nw, ph, ph_in, k * dist)  # fmt: skip
        for q in range(4):
            if x[r, q] >= X_SERIES:
                g[r, q] = _g_large(x[r, q])
            else:
                near[n_near] = 4 * r + q
                n_near += 1
        c[r] = _C_NUMERATOR / (2.0 * nw * sq * sin_b)
        reals[r, 0] = dot3(ix, iy, iz, e[w, 0], e[w, 1], e[w, 2]) if ok else 0.0
        spreading[r] = np.sqrt(g_in / (g_out * (g_in + g_out)))
        valid[r] = ok
        s_path[r] = s_in
    return x, f, g, near[:n_near].copy(), basis, c, reals, spreading, valid, s_path


@kernel(
    "c16[:, :, ::1](f8[:, ::1], c16[:, ::1], c16[::1], f8[:, ::1], c16[::1], f8[::1], i8[::1], "
    "b1[::1], f8)"
)
def _chain_dyadic(f, g, c, reals, eta, thickness, material, two_sided, freq):
    """``D = C(D1 + D2) I - C D3 T_n - C D4 T_0`` (:func:`_dyadic`) of P diffractions from
    :func:`_chain_geometry`'s output and ``G(x)`` (P, 4), with each face's ITU-R P.2040
    reflection (:func:`raytrace.physics.materials.reflection1`: Fresnel for a solid's face, a
    slab for an open sheet's) at its incidence cosine."""
    out = np.empty((len(c), 2, 2), dtype=np.complex128)
    for r in range(len(c)):
        m = material[r]
        ct0, ctn = reals[r, 5], reals[r, 6]
        r0_te, r0_tm = reflection1(eta[m], clipped_cos1(ct0), two_sided[r], thickness[m], freq)
        rn_te, rn_tm = reflection1(eta[m], clipped_cos1(ctn), two_sided[r], thickness[m], freq)
        cr = c[r]
        d12 = cr * (f[r, 0] * g[r, 0] + f[r, 1] * g[r, 1])
        d3, d4 = cr * (f[r, 2] * g[r, 2]), cr * (f[r, 3] * g[r, 3])
        out[r, 0, 0], out[r, 0, 1], out[r, 1, 0], out[r, 1, 1] = _dyadic1(
            r0_te, r0_tm, rn_te, rn_tm, reals[r, 0], reals[r, 1], reals[r, 2], reals[r, 3],
            reals[r, 4], d12, d3, d4,
        )
    return out


class ChainDiffraction(NamedTuple):
    """The diffractions of unfolded paths (:func:`chain_diffraction`), P rows.

    Attributes
    ----------
    d_matrix : (P, 2, 2) complex128, sqrt(metres), the dyadic coefficient (rows ``beta0_hat``,
        ``phi_hat`` of the diffracted ray, columns ``beta0'_hat``, ``phi'_hat`` of the incident
        one), as :func:`diffraction_matrix`
    basis : (P, 4, 3) float, ``beta0'_hat, phi'_hat, beta0_hat, phi_hat``
    spreading : (P,) float, 1/sqrt(metres), ``A = sqrt(s' / (s (s' + s)))`` (1 where not valid)
    valid : (P,) bool, as :attr:`WedgeGeometry.valid`
    s_in : (P,) float, metres, the unfolded incident leg ``s'`` along the path
    """

    d_matrix: np.ndarray
    basis: np.ndarray
    spreading: np.ndarray
    valid: np.ndarray
    s_in: np.ndarray


def chain_diffraction(
    frame: WedgeFrame,
    wedge: np.ndarray,
    chain: np.ndarray,
    j: int,
    seg_len: np.ndarray,
    frequency_hz: float,
    eta: np.ndarray,
    thickness_m: np.ndarray,
    material: np.ndarray,
    two_sided: np.ndarray,
) -> ChainDiffraction:
    """The UTD diffraction at vertex ``j`` of P unfolded vertex chains (a tracer's paths), in
    two compiled passes around the Faddeeva function: :func:`framed_wedge_geometry` and
    :func:`diffraction_matrix` with the faces' ITU-R P.2040 reflection coefficients at
    :attr:`WedgeGeometry.cos_theta_0` / ``cos_theta_n``, for the source and receiver unfolded
    along the chain (the path is straight on either side of the edge once unfolded: the source
    at ``s'`` = the length of the chain up to the edge, back along the incident segment).

    Parameters
    ----------
    frame : WedgeFrame, one row per wedge of the scene (:func:`wedge_frames`)
    wedge : (P,) int, the wedge of each diffraction
    chain : (P, k + 2, 3) float, metres, the transmitter, the vertices and the receiver
    j : int, 1..k, the vertex of the diffraction in the chain
    seg_len : (P, k + 1) float, metres, the chain's segment lengths
    frequency_hz : float
    eta : (n_materials,) complex, thickness_m : (n_materials,) float, m: the materials' relative
        permittivity and open-sheet thickness
    material : (P,) int, the wedge's material; two_sided : (P,) bool, the wedge is an open
        sheet's (its faces reflect as slabs)

    Returns
    -------
    ChainDiffraction

    Raises
    ------
    TraceInputError
        Shapes that do not match, ``j`` not a vertex of the chain, a wedge or material index
        out of range, a frequency that is not positive.
    """
    if not (np.isscalar(frequency_hz) and np.isfinite(frequency_hz) and frequency_hz > 0):
        raise TraceInputError(f"frequency_hz must be a positive number, got {frequency_hz!r}")
    chain, seg_len = np.asarray(chain, dtype=float), np.asarray(seg_len, dtype=float)
    wedge, material = np.asarray(wedge).reshape(-1), np.asarray(material).reshape(-1)
    p = len(wedge)
    if chain.ndim != 3 or chain.shape[0] != p or chain.shape[2] != 3:
        raise TraceInputError(f"chain must have shape ({p}, k + 2, 3), got {chain.shape}")
    if seg_len.shape != (p, chain.shape[1] - 1):
        raise TraceInputError(f"seg_len must have shape ({p}, {chain.shape[1] - 1}), got {seg_len.shape}")
    if not 1 <= int(j) <= chain.shape[1] - 2:
        raise TraceInputError(f"j must be a vertex of the chain (1..{chain.shape[1] - 2}), got {j}")
    if len(material) != p or np.shape(two_sided) != (p,):
        raise TraceInputError("material and two_sided need one value per diffraction")
    if p and (wedge.min() < 0 or wedge.max() >= len(frame.n)):
        raise TraceInputError(f"wedge indices must be in 0..{len(frame.n) - 1}")
    if p and (material.min() < 0 or material.max() >= len(eta) or len(eta) != len(thickness_m)):
        raise TraceInputError(f"material indices must be in 0..{len(eta) - 1} (one thickness each)")
    k = _TWO_PI * float(frequency_hz) / C0
    e, t0, n0, _, n = frame
    x, f, g, near, basis, c, reals, spreading, valid, s_in = _chain_geometry(
        _c(e), _c(t0), _c(n0), _c(n), _c(wedge, np.int64), _c(chain), int(j), _c(seg_len), k
    )
    if len(near):  # G(x) of the terms near a boundary: one Faddeeva call for all
        g.reshape(-1)[near] = _g_faddeeva(x.reshape(-1)[near])
    d_mat = _chain_dyadic(f, g, c, reals, _c(eta, complex), _c(thickness_m),
                          _c(material, np.int64), _c(two_sided, bool), float(frequency_hz))  # fmt: skip
    return ChainDiffraction(d_mat, basis, spreading, valid, s_in)


# -- 4. the diffracted field ----------------------------------------------------------------------
class DiffractedField(NamedTuple):
    """Diffracted field of P candidates (see :func:`diffracted_field`).

    Attributes
    ----------
    field : (P, 3) complex128; field vector at ``dst`` (zero where not ``valid``)
    length_m : (P,) float, metres; unfolded path length ``s' + s``
    delay_s : (P,) float, seconds; ``(s' + s) / c``
    d_soft, d_hard : (P,) complex128, sqrt(metres); UTD coefficients ``D_s``, ``D_h`` (the
        diagonal of ``d_matrix``)
    d_matrix : (P, 2, 2) complex128, sqrt(metres); the dyadic coefficient in ray-fixed components,
        rows (beta0, phi) of the diffracted ray, columns (beta0', phi') of the incident one:
        ``[E_beta0, E_phi] = -d_matrix [E_beta0', E_phi'] A exp(-j k s)``; off-diagonal terms
        only for lossy faces at oblique incidence
    spreading : (P,) float, 1/sqrt(metres); ``A = sqrt(s' / (s (s' + s)))``
    valid : (P,) bool; as :attr:`WedgeGeometry.valid`
    """

    field: np.ndarray
    length_m: np.ndarray
    delay_s: np.ndarray
    d_soft: np.ndarray
    d_hard: np.ndarray
    d_matrix: np.ndarray
    spreading: np.ndarray
    valid: np.ndarray


def _fresnel_pair(eta: object, cos_theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from .materials import fresnel  # the one Fresnel implementation of the project

    r_te, r_tm, _, _ = fresnel(np.asarray(eta, dtype=complex), cos_theta)
    return np.asarray(r_te, dtype=complex), np.asarray(r_tm, dtype=complex)


def diffraction_matrix(
    geometry: WedgeGeometry,
    frequency_hz: float,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
    eta_0: complex | np.ndarray | None = None,
    eta_n: complex | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The dyadic diffraction coefficient and the spreading factor of :func:`diffracted_field`,
    which applies them to an incident field (arguments as there).

    Returns
    -------
    d_matrix : (P, 2, 2) complex128, sqrt(metres); ``D = C(D1 + D2) I - C D3 T_n - C D4 T_0``
        in ray-fixed components (rows ``beta0_hat``, ``phi_hat`` of the diffracted ray, columns
        ``beta0'_hat``, ``phi'_hat`` of the incident one); finite but meaningless where
        ``geometry.valid`` is False
    spreading : (P,) float, 1/sqrt(metres); ``A = sqrt(s' / (s (s' + s)))`` (1 where not valid)
    """
    g = geometry
    p = len(g)
    if not (np.isscalar(frequency_hz) and np.isfinite(frequency_hz) and frequency_hz > 0):
        raise TraceInputError(f"frequency_hz must be a positive number, got {frequency_hz!r}")
    k = _TWO_PI * float(frequency_hz) / C0
    if r_0 is None and eta_0 is not None:
        r_0 = _fresnel_pair(eta_0, g.cos_theta_0)
    if r_n is None and eta_n is not None:
        r_n = _fresnel_pair(eta_n, g.cos_theta_n)
    ok = g.valid
    s_in = np.where(ok, g.s_in, 1.0)
    s_out = np.where(ok, g.s_out, 1.0)
    sin_b = np.where(ok, g.sin_beta0, 1.0)
    dist = s_in * s_out * sin_b**2 / (s_in + s_out)
    d12, d3, d4 = _utd_terms(
        np.where(ok, g.n, 2.0),
        np.where(ok, g.phi, 0.0),
        np.where(ok, g.phi_in, 0.0),
        sin_b,
        dist,
        k,
    )
    # each face's reflection in its own frame (e_f = e for face 0, -e for face n)
    cos_b = np.where(ok, np.einsum("ij,ij->i", g.s_hat_in, g.edge_dir), 0.0)
    faces = [_c(x, complex) for x in (*_reflection_pair(r_0, (p,)), *_reflection_pair(r_n, (p,)))]
    d_mat = _dyadic(*faces, _c(cos_b), _c(np.cos(g.psi_0)), _c(np.sin(g.psi_0)),
                    _c(np.cos(g.psi_n)), _c(np.sin(g.psi_n)), _c(d12, complex), _c(d3, complex),
                    _c(d4, complex))  # fmt: skip
    return d_mat, np.sqrt(s_in / (s_out * (s_in + s_out)))


def diffracted_field(
    geometry: WedgeGeometry,
    e_in: np.ndarray,
    frequency_hz: float,
    *,
    r_0: tuple[np.ndarray, np.ndarray] | None = None,
    r_n: tuple[np.ndarray, np.ndarray] | None = None,
    eta_0: complex | np.ndarray | None = None,
    eta_n: complex | np.ndarray | None = None,
    phase: bool = True,
) -> DiffractedField:
    """Field diffracted by the edge towards the receiver (UTD, spherical incidence).

    ``[E_beta0, E_phi](dst) = -D [E_i . beta0'_hat, E_i . phi'_hat] A exp(-j k s)`` with the
    dyadic coefficient (ray-fixed components, KP 1974; Luebbers 1984 for lossy faces)

        ``D = C(D1 + D2) I - C D3 T_n - C D4 T_0``

    ``T_0``, ``T_n`` the faces' reflection matrices (:func:`face_reflection_matrix`, perfect
    conductor: ``diag(1, -1)``, which is KP's ``D_s,h = C[D1 + D2 -+ (D3 + D4)]``), evaluated per
    face at the angle ``psi_0`` / ``psi_n`` of :class:`WedgeGeometry` (the specular
    reflection off the face's plane between the two ends, D8a), ``A = sqrt(s' / (s (s' +
    s)))``, ``L = s s' sin^2(beta0) / (s + s')``. Continuous with the geometrical-optics field at
    both reflection boundaries, also at oblique incidence on lossy faces, and independent of which
    face the caller calls face 0.

    Parameters
    ----------
    geometry : WedgeGeometry
        From :func:`wedge_geometry`; ``s' = geometry.s_in`` is the (unfolded) incident length,
        ``s = geometry.s_out`` the diffracted one.
    e_in : (P, 3) complex
        Incident field vector at the diffraction point, in the tracer's normalisation (free-space
        field relative to the transmitted one, ``|E| = lambda / (4 pi d)`` at distance d from an
        isotropic source), including the phase ``exp(-j k s')`` and any reflection / penetration
        coefficients met before the edge. Its component along the incident ray is ignored.
    frequency_hz : float, Hz
    r_0, r_n : (TE, TM) pairs of (P,) complex, optional
        Reflection coefficients of face 0 and face n at ``geometry.cos_theta_0`` /
        ``cos_theta_n`` (P.2040 convention, ``R_TM -> +1`` for a perfect conductor). Use them
        for thin sheets (slab coefficients).
    eta_0, eta_n : complex or (P,) complex, optional
        Relative permittivities of the faces, used (through :func:`raytrace.physics.materials.fresnel`,
        half-space Fresnel coefficients) where ``r_0`` / ``r_n`` are not given. Neither given:
        perfect conductor (KP).
    phase : bool
        Include ``exp(-j k s)`` of the diffracted leg (default). False if the caller applies the
        phase of the whole unfolded length itself.

    Returns
    -------
    DiffractedField
        ``field (P, 3)`` at ``dst``; for a path reflected after the edge, ``dst`` is the image
        receiver, and the caller applies the reflection to this field. ``delay_s = (s' + s) / c``.
    """
    g = geometry
    p = len(g)
    e_in = np.asarray(e_in, dtype=complex)
    if e_in.shape != (p, 3):
        raise TraceInputError(f"e_in must have shape ({p}, 3), got {e_in.shape}")
    if not np.all(np.isfinite(e_in)):
        raise TraceInputError("e_in contains NaN or infinite values")
    d_mat, spreading = diffraction_matrix(g, frequency_hz, r_0=r_0, r_n=r_n, eta_0=eta_0,
                                          eta_n=eta_n)  # fmt: skip
    ok = g.valid
    length = g.s_in + g.s_out
    comp_in = np.stack(
        [np.einsum("ij,ij->i", e_in, g.beta_hat_in), np.einsum("ij,ij->i", e_in, g.phi_hat_in)],
        axis=1,
    )
    comp_out = -np.einsum("pij,pj->pi", d_mat, comp_in)
    k = _TWO_PI * float(frequency_hz) / C0
    amp = spreading * (np.exp(-1j * k * np.where(ok, g.s_out, 1.0)) if phase else 1.0)
    field = (comp_out[:, :1] * g.beta_hat_out + comp_out[:, 1:] * g.phi_hat_out) * amp[:, None]
    field = np.where(ok[:, None], field, 0.0)
    d_mat = np.where(ok[:, None, None], d_mat, 0.0)
    return DiffractedField(
        field=field,
        length_m=length,
        delay_s=length / C0,
        d_soft=d_mat[:, 0, 0].copy(),
        d_hard=d_mat[:, 1, 1].copy(),
        d_matrix=d_mat,
        spreading=np.where(ok, spreading, 0.0),
        valid=ok,
    )


# -- 5. ITU-R P.526 knife edge --------------------------------------------------------------------
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
