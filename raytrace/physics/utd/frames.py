"""The geometry of one diffraction at a straight wedge: edge-fixed frames, Kouyoumjian-Pathak
angles, ray-fixed unit vectors, validity, and the face rule (D8a). Conventions:
:mod:`raytrace.physics.utd`.

* :func:`wedge_frames` / :class:`WedgeFrame`: each wedge's oriented edge ``e``, face-0 tangent
  ``t0``, face normals and wedge parameter ``n`` (computed once per wedge);
* :func:`wedge_geometry`, :func:`framed_wedge_geometry` / :class:`WedgeGeometry`: the angles
  ``phi'``, ``phi``, distances and unit vectors of P diffractions;
* :func:`diffraction_valid`, :func:`diffraction_valid1`: source and receiver in the wedge's
  exterior (the latter a compiled scalar helper for the solver's kernels);
* :func:`face_rule_angle`: the angle at which each face's reflection is taken.

The compiled scalar helpers :func:`legs1`, :func:`ray_fixed1` and :func:`face_rule_cs1` are
shared with :func:`raytrace.physics.utd.operators.chain_diffraction`, which computes the same
geometry for the tracer's paths; their sums and products are in the order of the vectorised form
they replaced (``core.vec``, ``einsum``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ...core.errors import TraceInputError
from ...core.jit import carray as _c
from ...core.jit import helper, inline, kernel
from ...core.vec import broadcast_rows, cross3, dot3
from ...core.vec import cross as _cross
from ...core.vec import norm as _norm
from ...core.vec import rows as _rows
from .inputs import checked_points

__all__ = ["WedgeGeometry", "wedge_geometry", "WedgeFrame", "wedge_frames",
           "framed_wedge_geometry", "diffraction_valid", "diffraction_valid1", "face_rule_angle",
           "legs1", "ray_fixed1", "face_rule_cs1"]

_TWO_PI = 2.0 * np.pi


#: Angles (rad) closer than this to a wedge face are snapped onto the face (rounding only).
_ANGLE_SNAP_RAD = 1e-9


#: An exterior angle (rad) closer than this to 0 or 2 pi is a half-plane (n = 2).
_HALF_PLANE_RAD = 1e-6


#: Smallest |sin beta0| (ray direction vs edge) for which diffraction is computed.
_MIN_SIN_BETA0 = 1e-9


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = _norm(v)
    with np.errstate(divide="ignore", invalid="ignore"):
        return v / norm[:, None], norm


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
    point : (P, 3) float, metres; diffraction point on the edge (see
        :func:`~raytrace.physics.utd.keller_points`)
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
    src = checked_points("src", src)
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
    e = checked_points("edge_dir", edge_dir)
    return WedgeFrame(*_oriented_wedge(e, normal_0, normal_n, face0_dir, e.shape[0]))


def framed_wedge_geometry(
    frame: WedgeFrame, src: np.ndarray, dst: np.ndarray, point: np.ndarray
) -> WedgeGeometry:
    """:func:`wedge_geometry` with the wedges' frames given (:func:`wedge_frames`, taken per
    diffraction with :meth:`WedgeFrame.take`); src, dst, point : (P, 3) float, metres."""
    src = checked_points("src", src)
    p = src.shape[0]
    dst = checked_points("dst", dst, p)
    point = checked_points("point", point, p)
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
def legs1(e, t0, n0, n, w, sx, sy, sz, dx, dy, dz, px, py, pz):
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
def ray_fixed1(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz, cox, coy, coz, sin_out):
    """KP's ray-fixed unit vectors of one diffraction from :func:`legs1`' unit legs and
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
    scalar helper for kernels: :func:`legs1`' ``valid`` with the same arithmetic, the azimuths
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
def face_rule_cs1(a_in, a_out, s_in, s_out):
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
         sin_out, ok) = legs1(e, t0, n0, n, r, src[r, 0], src[r, 1], src[r, 2], dst[r, 0],
                              dst[r, 1], dst[r, 2], point[r, 0], point[r, 1], point[r, 2])  # fmt: skip
        s_hat_in[r, 0], s_hat_in[r, 1], s_hat_in[r, 2], s_in[r] = ix, iy, iz, si
        s_hat_out[r, 0], s_hat_out[r, 1], s_hat_out[r, 2], s_out[r] = ox, oy, oz, so
        phi_in[r], phi[r], sin_beta0[r], valid[r] = pin, pout, sin_in, ok
        (beta_hat_in[r, 0], beta_hat_in[r, 1], beta_hat_in[r, 2], phi_hat_in[r, 0],
         phi_hat_in[r, 1], phi_hat_in[r, 2], beta_hat_out[r, 0], beta_hat_out[r, 1],
         beta_hat_out[r, 2], phi_hat_out[r, 0], phi_hat_out[r, 1],
         phi_hat_out[r, 2]) = ray_fixed1(ix, iy, iz, cix, ciy, ciz, sin_in, ox, oy, oz, cox, coy,
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
    e, _ = _unit(checked_points("edge_dir", edge_dir, p))
    n0 = checked_points("normal_0", normal_0, p)
    nn = checked_points("normal_n", normal_n, p)
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
        f0 = checked_points("face0_dir", face0_dir, p)
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
