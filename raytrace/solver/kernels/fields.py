"""Compiled field tracking along the paths (numba, options in :mod:`raytrace.core.jit`).

:func:`path_gains`: the field vector carried along each path
(:func:`raytrace.solver.evaluate.path_fields`), with the ITU-R P.2040 coefficients of its
penetrations and reflections computed on the way by the physics module's scalar helpers
(:mod:`raytrace.physics.materials`) and the diffraction operators computed beforehand
(:func:`raytrace.physics.utd.chain_diffraction`).

It differs from the numpy form it replaced in the last bits only (numpy's complex products use
fused multiply-adds on CPUs with AVX-512, its complex square roots and divisions are not
numba's; numba rounds each product and sum as written), about 1e-13 relative on the gains; the
delays of paths without penetrations are bitwise the same.
"""

from __future__ import annotations

import numpy as np

from ...core.constants import C0
from ...core.jit import inline, kernel
from ...core.vec import cross3, dot3
from ...physics.materials import clipped_cos1, group_delay1, reflection1, slab1

__all__ = ["path_gains"]


@inline
def _te_tm(e0, e1, e2, kx, ky, kz, ox, oy, oz, nx, ny, nz, c_te, c_tm):
    """The field ``e`` after an interaction (penetration or reflection) with TE/TM coefficients.

    Basis: ``s = k_in x n`` normalised (TE, perpendicular to the plane of incidence; at normal
    incidence any ``s`` perpendicular to ``k_in``: ``k_in x x``, or ``k_in x y`` for a ray near
    the x axis) and ``p = s x k`` on either side (TM), so that ``e' = c_te (e . s) s + c_tm (e .
    p_in) p_out``. With this basis the ITU-R P.2040 coefficients (``R_TM -> +1`` for a perfect
    conductor) map the field directly."""
    sx, sy, sz = cross3(kx, ky, kz, nx, ny, nz)
    ns = np.sqrt(sx * sx + sy * sy + sz * sz)
    if ns < 1e-9:
        hx, hy = (1.0, 0.0) if abs(kx) < 0.9 else (0.0, 1.0)
        sx, sy, sz = cross3(kx, ky, kz, hx, hy, 0.0)
        ns = np.sqrt(sx * sx + sy * sy + sz * sz)
    sx, sy, sz = sx / ns, sy / ns, sz / ns
    px, py, pz = cross3(sx, sy, sz, kx, ky, kz)
    qx, qy, qz = cross3(sx, sy, sz, ox, oy, oz)
    a = c_te * ((e0 * sx + e1 * sy) + e2 * sz)
    b = c_tm * ((e0 * px + e1 * py) + e2 * pz)
    return a * sx + b * qx, a * sy + b * qy, a * sz + b * qz


@inline
def _vertical_pol(dx, dy, dz):
    """The field of a vertically polarised antenna for a ray along ``d`` (unit): z made
    perpendicular to the ray (x for a vertical ray), unit."""
    vx, vy, vz = 0.0 - dz * dx, 0.0 - dz * dy, 1.0 - dz * dz
    n = np.sqrt(vx * vx + vy * vy + vz * vz)
    if n < 1e-9:
        vx, vy, vz = 1.0 - dx * dx, 0.0 - dx * dy, 0.0 - dx * dz
        n = np.sqrt(vx * vx + vy * vy + vz * vz)
    return vx / n, vy / n, vz / n


@inline
def _diffracted(e0, e1, e2, d_basis, d_matrix, d_amp, q):
    """The field ``e`` after diffraction ``q`` of :func:`path_gains`:
    ``[E_beta0, E_phi] = -D [e . beta0'_hat, e . phi'_hat] A`` on ``beta0_hat``, ``phi_hat``, in
    :func:`raytrace.physics.utd.diffracted_field`'s order of operations (straight-line: its
    arrays are read with no branch, :func:`raytrace.core.jit.inline`)."""
    b = d_basis[q]
    c0 = (e0 * b[0, 0] + e1 * b[0, 1]) + e2 * b[0, 2]
    c1 = (e0 * b[1, 0] + e1 * b[1, 1]) + e2 * b[1, 2]
    d = d_matrix[q]
    o0 = -(d[0, 0] * c0 + d[0, 1] * c1)
    o1 = -(d[1, 0] * c0 + d[1, 1] * c1)
    amp = d_amp[q]
    return ((o0 * b[2, 0] + o1 * b[3, 0]) * amp, (o0 * b[2, 1] + o1 * b[3, 1]) * amp,
            (o0 * b[2, 2] + o1 * b[3, 2]) * amp)  # fmt: skip


@kernel(
    "Tuple((c16[::1], f8[::1]))(f8[:, :, ::1], i1[:, ::1], i8[:, ::1], i8[:, ::1], "
    "f8[:, :, :, ::1], i8[:, :, ::1], f8[:, :, ::1], i8[::1], c16[::1], c16[::1], f8[::1], "
    "f8[:, ::1], i8[::1], b1[::1], i8[:, ::1], c16[:, :, ::1], f8[:, :, ::1], f8[::1], b1[::1], "
    "c16[::1], f8, f8, f8, b1, i8, i8)"
)
def path_gains(chain, kinds, elem, count, pen_normal, pen_obj, pen_thickness, obj_material, eta,
               eta_slope, thickness, f_normal, f_material, f_two_sided, d_slot, d_matrix, d_basis,
               d_amp, d_valid, amp_scale, f, k0, wavelength, slab_delay, reflection,
               diffraction):  # fmt: skip
    """Complex gain and delay of M paths with ``k`` vertices: the field vector carried from the
    transmitter to the receiver and projected on the receiving antenna's polarisation.

    The field starts vertically polarised (:func:`_vertical_pol`). Along segment ``j``: its
    penetrations (the slab's TE/TM transmission on the slab face's plane of incidence, ITU-R
    P.2040 sec. 2.2.2.2, :func:`raytrace.physics.materials.slab1`; its group delay added to the
    delay when ``slab_delay``, :func:`~raytrace.physics.materials.group_delay1`); then vertex
    ``j``: a reflection (:func:`~raytrace.physics.materials.reflection1` on the facet's plane:
    Fresnel for a solid's face, a slab for an open sheet's) or a diffraction (``[E_beta0, E_phi]
    = -D [E . beta0'_hat, E . phi'_hat] A``, zero where not valid, in
    :func:`raytrace.physics.utd.diffracted_field`'s order of operations). The TE/TM basis is
    :func:`_te_tm`'s. A path without a diffraction spreads as ``lambda / (4 pi d)`` over its
    unfolded length ``d``; a diffracted one carries its spreading in ``d_amp`` and
    ``amp_scale``.

    Parameters
    ----------
    chain : (M, k + 2, 3) float, m, the transmitter, the vertices and the receiver
    kinds : (M, k) int8, vertex codes (``reflection``, ``diffraction``); elem : (M, k) int, a
        reflection's facet
    count : (M, k + 1) int, penetrations per segment; pen_normal : (M, k + 1, K, 3) float,
        their slab faces' unit normals; pen_obj : (M, k + 1, K) int, their objects;
        pen_thickness : (M, k + 1, K) float, m, their slab thickness
    obj_material : (O,) int; eta, eta_slope : (n_materials,) complex, the relative
        permittivity and ``f d eta / d f``; thickness : (n_materials,) float, m, an open
        sheet's thickness
    f_normal : (F, 3) float, f_material : (F,) int, f_two_sided : (F,) bool, of the facets
    d_slot : (M, k) int, a diffraction vertex's row in the next four (-1 elsewhere)
    d_matrix : (D, 2, 2) complex, sqrt(m), a diffraction's dyadic coefficient; d_basis :
        (D, 4, 3) float, its ``beta0'_hat, phi'_hat, beta0_hat, phi_hat``; d_amp : (D,)
        float, its spreading factor; d_valid : (D,) bool
    amp_scale : (M,) complex, an extra factor of the whole path (diffraction's incident leg)
    f, k0, wavelength : Hz, rad/m, m
    slab_delay : bool; reflection, diffraction : int, the codes in ``kinds``

    Returns
    -------
    gain : (M,) complex, ``e . e_rx`` times the path's spreading and phase ``exp(-j k0 d)``
    delay : (M,) float, s, ``d / c`` plus the slabs' group delays
    """
    m, k = kinds.shape[0], kinds.shape[1]
    gain = np.empty(m, dtype=np.complex128)
    delay = np.empty(m)
    dirs = np.empty((k + 1, 3))
    for r in range(m):
        total = 0.0
        for j in range(k + 1):
            vx = chain[r, j + 1, 0] - chain[r, j, 0]
            vy = chain[r, j + 1, 1] - chain[r, j, 1]
            vz = chain[r, j + 1, 2] - chain[r, j, 2]
            ln = np.sqrt(vx * vx + vy * vy + vz * vz)
            total = ln if j == 0 else total + ln
            dn = ln if ln > 1e-300 else 1e-300
            dirs[j, 0], dirs[j, 1], dirs[j, 2] = vx / dn, vy / dn, vz / dn
        px, py, pz = _vertical_pol(dirs[0, 0], dirs[0, 1], dirs[0, 2])
        e0, e1, e2 = px + 0j, py + 0j, pz + 0j
        extra = 0.0
        has_d = False
        for j in range(k + 1):
            dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
            for s in range(count[r, j]):
                nx, ny, nz = pen_normal[r, j, s, 0], pen_normal[r, j, s, 1], pen_normal[r, j, s, 2]
                mat = obj_material[pen_obj[r, j, s]]
                th = pen_thickness[r, j, s]
                c = clipped_cos1(dot3(nx, ny, nz, dx, dy, dz))
                _, _, t_te, t_tm = slab1(eta[mat], c, th, f, False)
                if slab_delay:
                    extra += group_delay1(eta[mat], c, th, eta_slope[mat])
                e0, e1, e2 = _te_tm(e0, e1, e2, dx, dy, dz, dx, dy, dz, nx, ny, nz, t_te, t_tm)
            if j == k:
                break
            if kinds[r, j] == reflection:
                fi = elem[r, j]
                nx, ny, nz = f_normal[fi, 0], f_normal[fi, 1], f_normal[fi, 2]
                mat = f_material[fi]
                c = clipped_cos1(dot3(nx, ny, nz, dx, dy, dz))
                r_te, r_tm = reflection1(eta[mat], c, f_two_sided[fi], thickness[mat], f)
                e0, e1, e2 = _te_tm(e0, e1, e2, dx, dy, dz, dirs[j + 1, 0], dirs[j + 1, 1],
                                    dirs[j + 1, 2], nx, ny, nz, r_te, r_tm)  # fmt: skip
            elif kinds[r, j] == diffraction:
                has_d = True
                q = d_slot[r, j]
                if not d_valid[q]:
                    e0, e1, e2 = 0j, 0j, 0j
                    continue
                e0, e1, e2 = _diffracted(e0, e1, e2, d_basis, d_matrix, d_amp, q)
        qx, qy, qz = _vertical_pol(dirs[k, 0], dirs[k, 1], dirs[k, 2])
        proj = (e0 * qx + e1 * qy) + e2 * qz
        # free-space spreading over the unfolded length (diffracted paths carry their own)
        spread = 1.0 if has_d else wavelength / (4 * np.pi * total)
        gain[r] = spread * amp_scale[r] * np.exp(-1j * k0 * total) * proj
        delay[r] = total / C0 + extra
    return gain, delay
