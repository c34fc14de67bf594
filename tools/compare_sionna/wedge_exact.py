"""The exact field of a perfectly conducting wedge for a point source (Biot-Tolstoy-Medwin), and
its independent checks."""

from __future__ import annotations

import functools

import numpy as np
from sionna_canon import BOUNDARY_STEPS, boundaries


@functools.lru_cache(maxsize=4)
def _eta_grid(k: float, eta_max: float = 7.0) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature grid in eta and trapezoid weights: geometric from 1e-8 to 1e-2 (resolves the
    Lorentzian peak of a term whose boundary is 1e-5 rad away), then uniform to 7 with steps of
    2e-5 at 3.775 GHz, scaled with 1/k (< 0.1 rad of phase per step 3-4 m from the edge); the
    tail beyond eta = 7 is ~1e-6 of the field."""
    step = 2e-5 * 79.1 / k
    eta = np.concatenate([[0.0], np.geomspace(1e-8, 1e-2, 2000), np.arange(1e-2, eta_max, step)[1:]])
    w = np.zeros_like(eta)
    d = np.diff(eta)
    w[:-1] += d / 2
    w[1:] += d / 2
    return eta, w


def wedge_exact(src: np.ndarray, dst: np.ndarray, k: float, n: float, soft: bool) -> np.ndarray:
    """Exact total field of a point source ``exp(-j k R) / R`` beside a perfectly conducting
    (soft: Dirichlet, hard: Neumann) infinite wedge, local frame (edge on the z axis, face 0 at
    phi = 0, air at 0 < phi < n pi, ``n >= 1``): geometrical optics (direct field and the two
    single reflections where visible, images with sign -1 soft / +1 hard) plus the exact edge
    term of Biot and Tolstoy (J. Acoust. Soc. Am. 29, 381, 1957) in the form of Svensson, Fred,
    Vanderkooy (J. Acoust. Soc. Am. 106, 2331, 1999, eq. 3), transformed to frequency with
    ``eta`` as variable (``c t = l(eta)``):

        u_d = -(nu / 2 pi) int_0^inf sum_i eps_i beta_i(eta) exp(-j k l) / l d eta
        beta_i = sin(nu phi_i) / (cosh(nu eta) - cos(nu phi_i)),  nu = 1 / n
        phi_i = pi +- phi' +- phi,  l = sqrt(rho^2 + rho'^2 + (z - z')^2 + 2 rho rho' cosh eta)

    ``eps_i = -1`` for soft on the two image terms (phi' + phi). Its stationary point reproduces
    Keller's diffraction coefficient, which fixes the factor ``nu / 2 pi`` for this source
    normalisation. Checked in :func:`check_exact` (Helmholtz residual, both boundary conditions,
    continuity across every boundary).

    Parameters
    ----------
    src : (3,) float, m; dst : (P, 3) float, m (local frame)

    Returns
    -------
    (P,) complex
    """
    dst = np.atleast_2d(dst)
    rho_s, phi_s = np.hypot(src[0], src[1]), np.arctan2(src[1], src[0]) % (2 * np.pi)
    rho = np.hypot(dst[:, 0], dst[:, 1])
    phi = np.arctan2(dst[:, 1], dst[:, 0]) % (2 * np.pi)
    dz = dst[:, 2] - src[2]
    r_img = -1.0 if soft else 1.0
    nu = 1.0 / n
    # geometrical optics: direct, face 0 image (-phi'), face n image (2 n pi - phi')
    out = np.zeros(len(dst), complex)
    for img_phi, sign, lit in (
        (phi_s, 1.0, np.abs(phi - phi_s) < np.pi),
        (-phi_s, r_img, phi + phi_s < np.pi),
        (2 * n * np.pi - phi_s, r_img, phi + phi_s > (2 * n - 1) * np.pi),
    ):
        r = np.sqrt(rho**2 + rho_s**2 - 2 * rho * rho_s * np.cos(phi - img_phi) + dz**2)
        out += np.where(lit, sign * np.exp(-1j * k * r) / r, 0.0)
    eta, w = _eta_grid(float(k))
    ch, cnh = np.cosh(eta), np.cosh(nu * eta)
    for p in range(len(dst)):
        ell = np.sqrt(rho[p] ** 2 + rho_s**2 + dz[p] ** 2 + 2 * rho[p] * rho_s * ch)
        acc = np.zeros_like(eta)
        for ang, eps in ((np.pi + phi_s + phi[p], r_img), (np.pi + phi_s - phi[p], 1.0),
                         (np.pi - phi_s + phi[p], 1.0), (np.pi - phi_s - phi[p], r_img)):
            acc = acc + eps * np.sin(nu * ang) / (cnh - np.cos(nu * ang))
        out[p] += -nu / (2 * np.pi) * np.sum(w * acc * np.exp(-1j * k * ell) / ell)
    return out


def exact_ratio(src: np.ndarray, dst: np.ndarray, k: float, n: float, soft: bool) -> np.ndarray:
    """Exact total field of the scalar point source over its free-space field ``exp(-j k R)/R``
    (soft: Dirichlet, the field component along the edge; hard: Neumann, the magnetic one)."""
    r = np.linalg.norm(dst - src, axis=-1)
    return wedge_exact(src, dst, k, n, soft) / (np.exp(-1j * k * r) / r)


def check_exact(k: float, n_points: int = 24) -> dict[str, float]:
    """Independent checks of :func:`wedge_exact` (n = 1.5 and 2, soft and hard, an elevated
    source): the 3-D Helmholtz residual (7-point stencil, step lambda/100, truncation ~3e-4)
    relative to ``k^2 |G|`` at random points; the boundary condition on both faces (value,
    soft; one-sided normal derivative relative to ``k |G|``, hard); the step across each shadow
    and reflection boundary (extrapolated to it from samples 1e-4, 2e-4, 3e-4 rad either side, as
    for the tools; relative to |G|)."""
    rng = np.random.default_rng(17)
    out: dict[str, float] = {}
    h = 2 * np.pi / k / 100
    for n in (1.5, 2.0):
        src = np.array([4.0 * np.cos(0.9), 4.0 * np.sin(0.9), 1.0])

        def g0(d, src=src):
            return np.exp(-1j * k * np.linalg.norm(d - src, axis=-1)) / np.linalg.norm(d - src, axis=-1)

        rho, ph = rng.uniform(2, 4, n_points), rng.uniform(0.2, n * np.pi - 0.2, n_points)
        z = rng.uniform(-1, 1, n_points)
        pts = np.stack([rho * np.cos(ph), rho * np.sin(ph), z], 1)
        for soft in (True, False):
            tag = f"n={n:g} {'soft' if soft else 'hard'}"
            u0 = wedge_exact(src, pts, k, n, soft)
            lap = -6 * u0
            for ax in range(3):
                d = np.zeros(3)
                d[ax] = h
                lap = lap + wedge_exact(src, pts + d, k, n, soft) + wedge_exact(src, pts - d, k, n, soft)
            res = np.abs(lap / h**2 + k**2 * u0) / (k**2 * np.abs(g0(pts)))
            out[f"helmholtz {tag}"] = float(np.max(res))
            worst = 0.0
            for ang in (1e-9, n * np.pi - 1e-9):  # on face 0 and face n
                t = np.array([np.cos(ang), np.sin(ang), 0.0])
                nrm = np.array([-np.sin(ang), np.cos(ang), 0.0]) * (1 if ang < 1 else -1)
                on = rho[:, None] * t + z[:, None] * np.array([0.0, 0.0, 1.0])
                if soft:
                    val = np.abs(wedge_exact(src, on, k, n, soft)) / np.abs(g0(on))
                else:
                    u = [wedge_exact(src, on + j * h * nrm, k, n, soft) for j in range(3)]
                    val = np.abs(-3 * u[0] + 4 * u[1] - u[2]) / (2 * h) / (k * np.abs(g0(on)))
                worst = max(worst, float(np.max(val)))
            out[f"boundary condition {tag}"] = worst
            jumps = []
            for b in boundaries(n, 0.9).values():
                sides = []
                for sgn in (-1, 1):
                    q = np.array([[3.0 * np.cos(b + sgn * m * 1e-4), 3.0 * np.sin(b + sgn * m * 1e-4),
                                   0.0] for m in BOUNDARY_STEPS])
                    sides.append(extrapolate(wedge_exact(src, q, k, n, soft)))
                jumps.append(abs(sides[1] - sides[0]) / abs(g0(np.array([[3.0, 0.0, 0.0]])))[0])
            out[f"jump at boundaries {tag}"] = float(max(jumps))
    return out


def extrapolate(values: np.ndarray) -> complex:
    """Quadratic extrapolation to the boundary from samples at 1, 2, 3 steps from it."""
    return 3 * values[0] - 3 * values[1] + values[2]


