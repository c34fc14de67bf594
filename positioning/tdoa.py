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

Solvers
-------
All solvers are batched over epochs: arrays carry a leading epoch axis ``E`` and Gauss-Newton with
Levenberg-Marquardt damping runs on all unfinished epochs at once (no Python loop per epoch).
Missing measurements (NaN ToA) enter with weight 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from .area import ServiceArea
from .errors import PositioningError

#: Speed of light in vacuum, m/s (exact, SI 2019). Same value as ``raytrace.core.constants.C0``;
#: repeated because ``positioning`` never imports ``raytrace``.
C0 = 299_792_458.0

#: Condition number of the normal matrix above which a fix is flagged ``ILL_CONDITIONED``.
COND_LIMIT = 1e10

#: Two base stations closer than this (m) are treated as the same position (an input error).
DUPLICATE_TOL_M = 1e-6

# Relative threshold for a singular normal matrix in the closed-form start.
_SINGULAR_REL = 1e-12


@dataclass(frozen=True)
class LinkInfo:
    """Per-measurement receiver reports and the band, for physics-aware estimators.

    Attributes
    ----------
    snr_db : (E, N) float, dB -- SNR before processing gain of the measured lobe (NaN unknown)
    peak_ratio_db : (E, N) float, dB -- first lobe's peak over the strongest peak (<= 0; NaN
        unknown or not a first-lobe receiver)
    lobe_width : (E, N) float -- first lobe's half-amplitude width over an isolated pulse's
        (1 lone path, > 1 overlapping paths, < 1 destructive interference; NaN unknown)
    bandwidth_hz : float or None -- signal bandwidth B
    center_frequency_hz : float or None -- carrier (for the free-space SNR of a LoS link)
    receiver : str -- ToA estimator that produced the data (``first-lobe``, ``first-path``,
        ``peak``, ``leading-edge``, or ``unknown``)
    snr_offset_db : float or None -- link budget constant ``P_tx + G_t + G_r - N`` (dB) so that
        a LoS link at d metres has ``SNR = snr_offset_db + 20 log10(lambda / (4 pi d))``; None if
        unknown
    subcarrier_spacing_hz : float or None -- delta_f; ``B / delta_f`` is the processing gain
    """

    snr_db: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    bandwidth_hz: float | None = None
    center_frequency_hz: float | None = None
    receiver: str = "unknown"
    snr_offset_db: float | None = None
    subcarrier_spacing_hz: float | None = None

    def take(self, idx: np.ndarray) -> LinkInfo:
        """The reports of epochs ``idx``."""
        return replace(
            self,
            snr_db=self.snr_db[idx],
            peak_ratio_db=self.peak_ratio_db[idx],
            lobe_width=self.lobe_width[idx],
        )


ModelFun = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Problem:
    """Validated positioning input of E epochs and N base stations.

    Attributes
    ----------
    rho : (E, N) float, metres
        Pseudo-ranges ``c (toa - tx_offset)`` minus a per-epoch constant (the smallest of the epoch,
        which keeps the numbers small; any common constant is absorbed like the clock offset).
        NaN where the base station was not received.
    valid : (E, N) bool
        Finite ToA.
    bs : (N, 3) float, metres
        Base-station positions.
    height : (E,) float, metres, or None
        Known device height for the 2D solve; None for a 3D solve.
    area : ServiceArea or None
        Where a device can be (floor polygon); None: fixes are not bounded.
    links : LinkInfo or None
        What the receiver reported about each measurement (SNR, first-lobe shape), for the
        estimators that use it (``nlos-map``, the integrity figures); None: not known.
    """

    rho: np.ndarray
    valid: np.ndarray
    bs: np.ndarray
    height: np.ndarray | None
    area: ServiceArea | None = None
    links: LinkInfo | None = None

    @property
    def dims(self) -> int:
        """Number of position unknowns: 2 with a known height, else 3."""
        return 2 if self.height is not None else 3

    @property
    def n_epochs(self) -> int:
        return int(self.rho.shape[0])

    @property
    def n_bs(self) -> int:
        return int(self.rho.shape[1])

    @property
    def n_valid(self) -> np.ndarray:
        """(E,) int: received base stations per epoch."""
        return np.count_nonzero(self.valid, axis=1)

    @property
    def min_bs(self) -> int:
        """Fewest base stations for a fix: dims + 1 (one is spent on the clock offset)."""
        return self.dims + 1

    @property
    def solvable(self) -> np.ndarray:
        """(E,) bool: epochs with at least :attr:`min_bs` received base stations."""
        return self.n_valid >= self.min_bs

    def take(self, idx: np.ndarray) -> Problem:
        """The sub-problem of epochs ``idx`` (area and link reports kept)."""
        return replace(
            self,
            rho=self.rho[idx],
            valid=self.valid[idx],
            height=None if self.height is None else self.height[idx],
            links=None if self.links is None else self.links.take(idx),
        )

    def position(self, theta: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(A, 3) positions from unknowns ``theta`` (A, >= dims) of epochs ``idx`` (A,)."""
        if self.height is None:
            return theta[:, :3]
        return np.column_stack([theta[:, 0], theta[:, 1], self.height[idx]])


def make_problem(
    toa_s: np.ndarray,
    bs_xyz: np.ndarray,
    tx_offsets_s: np.ndarray | None = None,
    height_m: float | np.ndarray | None = None,
    area: ServiceArea | None = None,
    links: LinkInfo | None = None,
) -> Problem:
    """Validate input and build the :class:`Problem` (pseudo-ranges with the schedule removed).

    Parameters
    ----------
    toa_s : (E, N) float, seconds
        Measured ToAs in the device clock; NaN = not received.
    bs_xyz : (N, 3) float, metres
        Base-station positions; two base stations at the same position are an error.
    tx_offsets_s : (N,) float, seconds, optional
        Transmission schedule ``delta_n`` to remove (default zeros).
    height_m : float or (E,) float, metres, optional
        Known device height (2D solve); None solves in 3D.
    area : ServiceArea, optional
        Where a device can be; fixes outside are solved again inside (see ``locate``).
    links : LinkInfo, optional
        Receiver reports per measurement, (E, N) arrays.

    Raises
    ------
    PositioningError
        Wrong shapes, infinite values, non-finite base-station positions, offsets or heights,
        or duplicate base-station positions.
    """
    toa = np.asarray(toa_s, dtype=float)
    if toa.ndim != 2:
        raise PositioningError(
            f"toa_s must be a 2-D array (epochs, base stations), got shape {toa.shape}"
        )
    if np.isinf(toa).any():
        raise PositioningError("toa_s contains infinite values (use NaN for 'not received')")
    bs = np.asarray(bs_xyz, dtype=float)
    if bs.ndim != 2 or bs.shape[1] != 3:
        raise PositioningError(f"bs_xyz must have shape (N, 3), got {bs.shape}")
    if bs.shape[0] != toa.shape[1]:
        raise PositioningError(
            f"toa_s has {toa.shape[1]} base-station columns but bs_xyz has {bs.shape[0]} rows"
        )
    if not np.isfinite(bs).all():
        raise PositioningError("bs_xyz contains non-finite coordinates")
    n = bs.shape[0]
    if n >= 2:
        dist = np.linalg.norm(bs[:, None, :] - bs[None, :, :], axis=2)
        i, j = np.nonzero(np.triu(dist < DUPLICATE_TOL_M, k=1))
        if i.size:
            raise PositioningError(
                f"bs_xyz: base stations {i[0]} and {j[0]} have the same position "
                f"{bs[i[0]].tolist()}"
            )
    if tx_offsets_s is None:
        off = np.zeros(n)
    else:
        off = np.asarray(tx_offsets_s, dtype=float)
        if off.shape != (n,):
            raise PositioningError(f"tx_offsets_s must have shape ({n},), got {off.shape}")
        if not np.isfinite(off).all():
            raise PositioningError("tx_offsets_s contains non-finite values")
    height: np.ndarray | None = None
    if height_m is not None:
        h = np.asarray(height_m, dtype=float)
        if h.ndim == 0:
            h = np.full(toa.shape[0], float(h))
        if h.shape != (toa.shape[0],):
            raise PositioningError(
                f"height_m must be a scalar or have shape ({toa.shape[0]},), got {h.shape}"
            )
        if not np.isfinite(h).all():
            raise PositioningError("height_m contains non-finite values")
        height = h
    if area is not None and not isinstance(area, ServiceArea):
        area = ServiceArea(np.asarray(area, dtype=float), "given")
    if links is not None:
        for name in ("snr_db", "peak_ratio_db", "lobe_width"):
            if np.shape(getattr(links, name)) != toa.shape:
                raise PositioningError(
                    f"links.{name} must have shape {toa.shape}, got {np.shape(getattr(links, name))}"
                )
    return Problem(
        rho=pseudoranges(toa, off),
        valid=np.isfinite(toa),
        bs=bs,
        height=height,
        area=area,
        links=links,
    )


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


# ----------------------------------------------------------------------------------------------
# geometry helpers


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
    R = np.sqrt(np.einsum("anj,anj->an", diff, diff))
    # The gradient is undefined at a base station; 1e-12 m only avoids 0/0 there.
    U = diff[..., :dims] / np.maximum(R, 1e-12)[..., None]
    return R, U


def tdoa_model(prob: Problem, ref: np.ndarray) -> tuple[ModelFun, np.ndarray]:
    """Residual function of eq. 7 with a per-epoch reference base station.

    Parameters
    ----------
    prob : Problem
    ref : (E,) int -- reference base station of each epoch

    Returns
    -------
    fun : ``fun(theta (A, dims), idx (A,)) -> (r (A, N), J (A, N, dims))`` with
        ``r_n = dd_ne - (|p - b_n| - |p - b_e|)`` (0 where missing) and ``J = d pred / d theta``.
    W : (E, N) float -- weights: 1 for received ``n != e``, else 0.
    """
    E, N = prob.rho.shape
    ar = np.arange(E)
    dd = prob.rho - prob.rho[ar, ref][:, None]
    W = (prob.valid & (np.arange(N)[None, :] != ref[:, None])).astype(float)
    dims = prob.dims

    def fun(theta: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = prob.position(theta, idx)
        R, U = ranges_and_units(p, prob.bs, dims)
        a = np.arange(idx.size)
        re = ref[idx]
        r = dd[idx] - (R - R[a, re][:, None])
        J = U - U[a, re][:, None, :]
        return np.where(np.isfinite(r), r, 0.0), J

    return fun, W


def pseudorange_model(prob: Problem) -> ModelFun:
    """Residual function of the reference-free pseudo-range model ``rho_n = |p - b_n| + beta``.

    Unknowns ``theta = (x, y[, z], beta)``, ``beta`` (m) being the common clock offset times c.
    Minimising it by least squares is the same as TDoA least squares with the correct (full)
    covariance of the differences, and it treats every base station alike.

    Returns ``fun(theta (A, dims+1), idx (A,)) -> (r (A, N), J (A, N, dims+1))`` with
    ``r = rho - |p - b_n| - beta`` (0 where missing).
    """
    dims = prob.dims

    def fun(theta: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = prob.position(theta, idx)
        R, U = ranges_and_units(p, prob.bs, dims)
        r = prob.rho[idx] - R - theta[:, dims : dims + 1]
        J = np.concatenate([U, np.ones(U.shape[:2] + (1,))], axis=2)
        return np.where(np.isfinite(r), r, 0.0), J

    return fun


def pseudorange_residuals(prob: Problem, theta: np.ndarray) -> np.ndarray:
    """(E, N) residuals ``rho_n - |p - b_n| - beta`` in metres, NaN where missing or unsolved."""
    idx = np.arange(prob.n_epochs)
    p = prob.position(theta, idx)
    R, _ = ranges_and_units(p, prob.bs, prob.dims)
    return prob.rho - R - theta[:, prob.dims][:, None]


# ----------------------------------------------------------------------------------------------
# batched Levenberg-Marquardt


def _safe_solve(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched ``solve(A, b)``; singular matrices give NaN instead of raising for the batch."""
    k = A.shape[-1]
    scale = np.trace(A, axis1=1, axis2=2) / k
    det = np.linalg.det(A)
    bad = ~np.isfinite(det) | ~(np.abs(det) > _SINGULAR_REL * np.abs(scale) ** k) | (scale <= 0)
    A_safe = np.where(bad[:, None, None], np.eye(k)[None], A)
    x = np.linalg.solve(A_safe, b)
    x[bad] = np.nan
    return x, bad


def levenberg_marquardt(
    fun: ModelFun,
    theta0: np.ndarray,
    W: np.ndarray,
    *,
    tol: float,
    max_iter: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched weighted nonlinear least squares ``min sum_n W_n r_n(theta)^2`` per epoch.

    Gauss-Newton steps ``(J^T W J + lambda diag(J^T W J)) delta = J^T W r`` with Marquardt
    damping: ``lambda`` starts at 1e-3, shrinks 10x after a step that lowers the cost (so near the
    solution the iteration is Gauss-Newton, quadratically convergent) and grows 10x after a step
    that does not (which is then rejected). Epochs leave the batch once a step is shorter than
    ``tol``, so late epochs do not cost the finished ones anything.

    Parameters
    ----------
    fun : ``fun(theta (A, k), idx (A,)) -> (r (A, M), J (A, M, k))``, residual = obs - model
    theta0 : (E, k) float -- start; rows with NaN are skipped (left NaN)
    W : (E, M) float -- non-negative weights (0 = unused)
    tol : float -- step-length tolerance, same unit as theta (m)
    max_iter : int

    Returns
    -------
    theta : (E, k) float; iterations : (E,) int; converged : (E,) bool
    """
    E, k = theta0.shape
    theta = theta0.copy()
    iterations = np.zeros(E, dtype=np.int64)
    converged = np.zeros(E, dtype=bool)
    act = np.flatnonzero(np.isfinite(theta0).all(axis=1))
    if act.size == 0 or max_iter <= 0:
        return theta, iterations, converged
    r, J = fun(theta[act], act)
    Wa = W[act]
    cost = np.sum(Wa * r * r, axis=1)
    lam = np.full(act.size, 1e-3)
    diag = np.arange(k)
    for _ in range(max_iter):
        JW = J * Wa[..., None]
        A = np.matmul(JW.transpose(0, 2, 1), J)
        g = np.matmul(JW.transpose(0, 2, 1), r[..., None])
        # Marquardt scaling plus a tiny absolute term so an all-zero row/column stays solvable.
        A[:, diag, diag] += lam[:, None] * A[:, diag, diag] + 1e-12
        delta, _ = _safe_solve(A, g)
        delta = delta[..., 0]
        delta = np.where(np.isfinite(delta), delta, 0.0)
        th_new = theta[act] + delta
        r_new, J_new = fun(th_new, act)
        cost_new = np.sum(Wa * r_new * r_new, axis=1)
        ok = cost_new <= cost
        sel = act[ok]
        theta[sel] = th_new[ok]
        r[ok], J[ok], cost[ok] = r_new[ok], J_new[ok], cost_new[ok]
        lam = np.where(ok, np.maximum(lam * 0.1, 1e-12), np.minimum(lam * 10.0, 1e12))
        iterations[act] += 1
        # A rejected step shorter than tol means no nearby point is better: converged as well.
        done = np.linalg.norm(delta, axis=1) <= tol
        converged[act[done]] = True
        keep = ~done
        if not keep.any():
            break
        act, r, J, Wa, cost, lam = act[keep], r[keep], J[keep], Wa[keep], cost[keep], lam[keep]
    return theta, iterations, converged


def ill_conditioned(fun: ModelFun, theta: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(E,) bool: normal matrix ``J^T W J`` at ``theta`` has condition number above COND_LIMIT."""
    E = theta.shape[0]
    out = np.zeros(E, dtype=bool)
    idx = np.flatnonzero(np.isfinite(theta).all(axis=1))
    if idx.size == 0:
        return out
    _, J = fun(theta[idx], idx)
    JW = J * W[idx][..., None]
    A = np.matmul(JW.transpose(0, 2, 1), J)
    ev = np.linalg.eigvalsh(A)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = ev[:, -1] / ev[:, 0]
    out[idx] = ~(np.abs(cond) <= COND_LIMIT) | (ev[:, 0] <= 0)
    return out


# ----------------------------------------------------------------------------------------------
# closed-form start


def first_valid(mask: np.ndarray) -> np.ndarray:
    """(E,) index of the first True per row (0 for an all-False row)."""
    return np.argmax(mask, axis=1)


def linear_start(prob: Problem, W: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Closed-form starting positions from the linearised TDoA equations (spherical intersection).

    With ``r_e = |p - b_e|`` unknown and ``dd_n = rho_n - rho_e``, squaring
    ``|p - b_n| = dd_n + r_e`` and subtracting the same for ``e`` gives equations linear in ``p``
    for a given ``r_e``::

        2 (b_n - b_e) . p = |b_n|^2 - |b_e|^2 - dd_n^2 - 2 dd_n r_e

    (with the known height moved to the right in 2D). Their weighted least-squares solution is
    ``p(r_e) = a + r_e c``; putting it into ``|p(r_e) - b_e| = r_e`` gives a quadratic in ``r_e``
    (Chan / Fang). Of its non-negative roots the one with the smaller TDoA residual is taken (ties,
    as in an exactly determined set, go to the one nearer the base stations' centroid). Where the
    linear system is singular (e.g. collinear base stations) or no root exists, the start is the
    centroid of the received base stations.

    Parameters
    ----------
    prob : Problem
    W : (E, N) -- weights; a base station takes part where ``W > 0`` and it is received
    ref : (E,) int -- reference base station per epoch (must be received)

    Returns
    -------
    (E, 3) float, metres (z = height in 2D).
    """
    E, N = prob.rho.shape
    dims = prob.dims
    ar = np.arange(E)
    bs = prob.bs
    use = (W > 0) & prob.valid
    Wm = (use & (np.arange(N)[None, :] != ref[:, None])).astype(float)
    rho = np.where(prob.valid, prob.rho, 0.0)
    d = rho - rho[ar, ref][:, None]
    be = bs[ref]
    G = 2.0 * (bs[None, :, :dims] - be[:, None, :dims])
    g0 = np.sum(bs**2, axis=1)[None, :] - np.sum(be**2, axis=1)[:, None] - d**2
    if prob.height is not None:
        g0 = g0 - 2.0 * (bs[None, :, 2] - be[:, None, 2]) * prob.height[:, None]
    g1 = -2.0 * d
    Gw = G * Wm[..., None]
    A = np.matmul(Gw.transpose(0, 2, 1), G)
    rhs = np.matmul(Gw.transpose(0, 2, 1), np.stack([g0, g1], axis=2))
    sol, bad = _safe_solve(A, rhs)
    a, c = sol[..., 0], sol[..., 1]
    D = a - be[:, :dims]
    hz2 = 0.0 if prob.height is None else (prob.height - be[:, 2]) ** 2
    qa = np.sum(c * c, axis=1) - 1.0
    qb = 2.0 * np.sum(D * c, axis=1)
    qc = np.sum(D * D, axis=1) + hz2
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (qb + np.where(qb >= 0, sq, -sq))
        r1 = np.where(np.abs(qa) > 1e-12, q / qa, -qc / qb)
        r2 = np.where(np.abs(qa) > 1e-12, qc / q, np.nan)
        # No real root (noise): the vertex of the parabola is the least-violating r_e.
        vertex = np.maximum(-qb / (2.0 * qa), 0.0)
    r1 = np.where(disc < 0, vertex, r1)
    r2 = np.where(disc < 0, np.nan, r2)

    cent = _centroid(prob, use)

    def candidate(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ok = np.isfinite(r) & (r >= -1e-9)
        xy = a + r[:, None] * c
        p = _embed(prob, xy, ar)
        R, _ = ranges_and_units(p, bs, dims)
        res = d - (R - R[ar, ref][:, None])
        sse = np.sum(Wm * np.where(np.isfinite(res), res, 0.0) ** 2, axis=1)
        sse = np.where(ok & np.isfinite(p).all(axis=1), sse, np.inf)
        return p, sse

    p1, s1 = candidate(r1)
    p2, s2 = candidate(r2)
    with np.errstate(invalid="ignore"):
        tie = np.abs(s1 - s2) <= 1e-9 * (1.0 + np.minimum(s1, s2))
    closer2 = np.linalg.norm((p2 - cent)[:, :2], axis=1) < np.linalg.norm(
        (p1 - cent)[:, :2], axis=1
    )
    pick2 = np.where(tie & np.isfinite(s1), closer2, s2 < s1)
    p = np.where(pick2[:, None], p2, p1)
    fail = bad | ~np.isfinite(np.minimum(s1, s2)) | ~np.isfinite(p).all(axis=1)
    return np.where(fail[:, None], cent, p)


def _embed(prob: Problem, xy: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(A, 3) positions from (A, dims) coordinates (adds the known height in 2D)."""
    if prob.height is None:
        return xy[:, :3]
    return np.column_stack([xy[:, 0], xy[:, 1], prob.height[idx]])


def _centroid(prob: Problem, use: np.ndarray) -> np.ndarray:
    """(E, 3) centroid of the used base stations (height replaced by the known one in 2D)."""
    w = use.astype(float)
    n = np.maximum(w.sum(axis=1), 1.0)
    cent = (w @ prob.bs) / n[:, None]
    if prob.height is not None:
        cent[:, 2] = prob.height
    return cent


# ----------------------------------------------------------------------------------------------
# ready-made solvers


@dataclass(frozen=True)
class Solution:
    """Batched solver output (E epochs)."""

    theta: np.ndarray  # (E, k) unknowns (x, y[, z][, beta]); NaN where not solved
    xyz: np.ndarray  # (E, 3) positions, metres
    iterations: np.ndarray  # (E,) int
    converged: np.ndarray  # (E,) bool
    ill: np.ndarray  # (E,) bool, ILL_CONDITIONED


def solve_tdoa(
    prob: Problem,
    ref: np.ndarray,
    rows: np.ndarray,
    *,
    tol: float,
    max_iter: int,
) -> Solution:
    """Least squares of eq. 7 with reference ``ref`` (E,) on the epochs where ``rows`` (E,) is True.

    The start is :func:`linear_start`; the solve is :func:`levenberg_marquardt`.
    """
    fun, W = tdoa_model(prob, ref)
    start = linear_start(prob, W + (np.arange(prob.n_bs)[None, :] == ref[:, None]), ref)
    theta0 = np.where(rows[:, None], start[:, : prob.dims], np.nan)
    theta, it, conv = levenberg_marquardt(fun, theta0, W, tol=tol, max_iter=max_iter)
    ill = ill_conditioned(fun, theta, W)
    xyz = np.where(rows[:, None], _embed(prob, theta, np.arange(prob.n_epochs)), np.nan)
    return Solution(theta=theta, xyz=xyz, iterations=it, converged=conv, ill=ill)


def pseudorange_start(prob: Problem, W: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(E, dims+1) closed-form start ``(x, y[, z], beta)`` using the base stations with ``W > 0``.

    Position from :func:`linear_start` referenced to the first used base station, ``beta`` the
    weighted mean of ``rho_n - |p - b_n|``. NaN rows where ``rows`` is False.
    """
    use = (W > 0) & prob.valid
    ref = first_valid(use)
    p = linear_start(prob, use.astype(float), ref)
    R, _ = ranges_and_units(p, prob.bs, prob.dims)
    w = np.where(use, W, 0.0)
    beta = np.sum(w * np.where(use, prob.rho - R, 0.0), axis=1) / np.maximum(w.sum(axis=1), 1e-300)
    theta = np.column_stack([p[:, : prob.dims], beta])
    return np.where(rows[:, None], theta, np.nan)


def solve_pseudorange(
    prob: Problem,
    W: np.ndarray,
    rows: np.ndarray,
    *,
    tol: float,
    max_iter: int,
    theta0: np.ndarray | None = None,
) -> Solution:
    """Weighted least squares of the pseudo-range model on the epochs where ``rows`` is True.

    Parameters
    ----------
    W : (E, N) float -- measurement weights (0 = excluded); missing ToAs are excluded anyway.
    theta0 : (E, dims+1) float, optional -- start (default :func:`pseudorange_start`).
    """
    W = np.where(prob.valid, W, 0.0)
    fun = pseudorange_model(prob)
    if theta0 is None:
        theta0 = pseudorange_start(prob, W, rows)
    theta0 = np.where(rows[:, None], theta0, np.nan)
    theta, it, conv = levenberg_marquardt(fun, theta0, W, tol=tol, max_iter=max_iter)
    ill = ill_conditioned(fun, theta, W)
    xyz = _embed(prob, theta, np.arange(prob.n_epochs))
    return Solution(theta=theta, xyz=xyz, iterations=it, converged=conv, ill=ill)
