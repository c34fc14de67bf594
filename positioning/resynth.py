"""The twin's refinement with re-synthesised paths (fingerprint maps of schema version 2).

A map of version 2 stores per cell and base station the K strongest paths. Within a cell the
paths' delays change smoothly with the position ``p`` (each path's wave is spherical about its
virtual source, :func:`positioning.lobe.move_paths`), while the first-lobe receiver's ToA does
not: paths that overlap within one pulse move its lobe by up to a pulse width, and that bias
changes within centimetres. So the twin does not interpolate the receiver's ToA; it moves the
nearest cell's paths to ``p`` and re-runs the receiver (:class:`positioning.lobe.LobeReceiver`):

    rho_n = c toa_n(p) + beta + e_n,    toa_n(p) = receiver(paths of cell(p), moved to p)

:func:`refine_resynth` solves it by Gauss-Newton on ``(x, y, beta)`` from a start position per
candidate: the Jacobian of ``c toa_n`` is the geometric one, ``(p - b_n) / |p - b_n|`` (default:
one receiver run per iteration), or that plus the bias gradient by finite differences
(:data:`FD_STEP_M`, clipped to :data:`MAX_BIAS_SLOPE` because the receiver's ToA jumps where a
path crosses a threshold; three runs per iteration). Steps are limited to
:data:`MAX_STEP_M` and the position to ``box`` metres around the start cell. The cell is the
map cell nearest to the current iterate (switching cells as it moves); where the nearest node is
a hole of the lattice the candidate's own cell is used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fingerprint import FingerprintMap
from .lobe import C0, LobeReceiver, move_paths

#: Finite-difference step of the bias gradient, m.
FD_STEP_M = 0.02
#: Largest magnitude of a bias-gradient component used in the Jacobian (m/m).
MAX_BIAS_SLOPE = 1.0
#: Largest Gauss-Newton step per iteration, m.
MAX_STEP_M = 0.2
#: Gauss-Newton iterations.
ITERATIONS = 5
#: Added to the RMS residual of a solution whose prediction misses a received base station, m.
MISSING_PENALTY_M = 1.0


@dataclass(frozen=True)
class PathMap:
    """A version-2 map's paths and receiver model.

    Attributes
    ----------
    cell_xyz : (N, 3) m
    delay : (N, B, K) s; gain : (N, B, K) complex; direction : (N, B, K, 3); radius : (N, B, K) m
    model : LobeReceiver
    """

    cell_xyz: np.ndarray
    delay: np.ndarray
    gain: np.ndarray
    direction: np.ndarray
    radius: np.ndarray
    model: LobeReceiver

    @classmethod
    def from_map(cls, fmap: FingerprintMap, k: int | None = None) -> PathMap:
        """The paths of ``fmap`` (the ``k`` strongest of those stored; None or 0: all)."""
        s = slice(None) if not k else slice(0, int(k))
        return cls(
            fmap.cell_xyz, fmap.path_delay_s[:, :, s], fmap.path_gain[:, :, s].astype(complex),
            fmap.path_dir[:, :, s], fmap.path_radius_m[:, :, s],
            LobeReceiver.from_meta(fmap.meta["receiver_model"]),
        )  # fmt: skip

    def predict(self, cell: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """(A, B) ``c toa``, m, of the receiver at ``xyz`` (A, 3) from the paths of ``cell``
        (A,) moved there; NaN where it detects nothing."""
        A = cell.size
        disp = xyz - self.cell_xyz[cell]  # (A, 3)
        d = self.delay[cell]  # (A, B, K)
        B, K = d.shape[1:]
        ok = np.isfinite(d)
        u = np.where(ok[..., None], self.direction[cell], 0.0)
        r = np.where(ok, self.radius[cell], 1.0)
        dd, gg = move_paths(np.where(ok, d, 0.0), self.gain[cell], u, r,
                            np.repeat(disp[:, None, :], B, axis=1), self.model.frequency_hz)  # fmt: skip
        dd = np.where(ok, dd, np.nan)
        gg = np.where(ok, gg, 0.0)
        return C0 * self.model.toa(dd.reshape(A * B, K), gg.reshape(A * B, K)).reshape(A, B)


def refine_resynth(
    rho: np.ndarray,
    valid: np.ndarray,
    height: np.ndarray,
    bs: np.ndarray,
    pmap: PathMap,
    nearest_cell,
    start_xy: np.ndarray,
    start_cell: np.ndarray,
    box_m: float,
    iters: int = ITERATIONS,
    fd_jacobian: bool = False,
    search_m: float = 0.0,
    search_n: int = 5,
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on ``(x, y, beta)`` with re-synthesised ToAs (module docstring).

    Parameters
    ----------
    rho : (A, B) m, pseudo-ranges; valid : (A, B) bool; height : (A,) m, device height
    bs : (B, 3) m
    pmap : PathMap
    nearest_cell : callable ``(A, 2) xy -> (A,) int`` map cell nearest to each position
        (-1: none)
    start_xy : (A, 2) m; start_cell : (A,) int, the candidate's cell (-1: no candidate)
    box_m : float, m, the solution stays within this of the start cell's centre (per axis)
    iters : int, Gauss-Newton iterations
    fd_jacobian : bool, add the bias gradient by finite differences to the geometric Jacobian
        (three receiver runs per iteration instead of one)
    search_m, search_n : float m, int; with ``search_m > 0`` the start is first replaced by the
        best of a ``search_n`` x ``search_n`` grid spanning +-``search_m`` around it (the
        re-synthesised misfit has local minima where the receiver's bias changes fast)

    Returns
    -------
    xy (A, 2) m; RMS residual about the offset (A,) m (inf where no candidate or no fit)
    """
    A = rho.shape[0]
    xy = start_xy.copy()
    ok_row = start_cell >= 0
    sc = np.maximum(start_cell, 0)
    centre = pmap.cell_xyz[sc, :2]
    h = np.asarray(height, dtype=float)

    def cells_at(p: np.ndarray) -> np.ndarray:
        if nearest_cell is None:
            return sc
        c = nearest_cell(p)
        return np.where(c >= 0, c, sc)

    if search_m > 0 and search_n > 1:
        off = np.linspace(-search_m, search_m, int(search_n))
        gx, gy = np.meshgrid(off, off, indexing="ij")
        grid = np.column_stack([gx.ravel(), gy.ravel()])  # (G, 2)
        G = len(grid)
        cand_xy = np.clip((xy[:, None, :] + grid[None]).reshape(-1, 2),
                          np.repeat(centre - box_m, G, 0), np.repeat(centre + box_m, G, 0))  # fmt: skip
        rep = np.repeat(np.arange(A), G)
        cell = cells_at_rep = nearest_cell(cand_xy) if nearest_cell is not None else sc[rep]
        cell = np.where(cells_at_rep >= 0, cells_at_rep, sc[rep])
        pred = pmap.predict(cell, np.column_stack([cand_xy, h[rep]]))
        use = valid[rep] & np.isfinite(pred)
        res = np.where(use, rho[rep] - pred, 0.0)
        n = np.maximum(use.sum(axis=1), 1)
        cost = np.sum(res * res, axis=1) - res.sum(axis=1) ** 2 / n
        cost = cost + 1e6 * (use.sum(axis=1) < valid[rep].sum(axis=1))
        best = np.argmin(cost.reshape(A, G), axis=1)
        xy = cand_xy.reshape(A, G, 2)[np.arange(A), best]
    best_xy = xy.copy()
    best_rms = np.full(A, np.inf)
    for it in range(iters + 1):
        cell = cells_at(xy)
        p = np.column_stack([xy, h])
        diff = p[:, None, :] - bs[None]
        R = np.linalg.norm(diff, axis=2)
        U = diff[..., :2] / np.maximum(R, 1e-12)[..., None]  # (A, B, 2)
        last = it == iters
        if fd_jacobian and not last:
            ev = np.concatenate([p, p + [FD_STEP_M, 0, 0], p + [0, FD_STEP_M, 0]])
            pred = pmap.predict(np.tile(cell, 3), ev).reshape(3, A, -1)
            slope = np.stack([(pred[1] - pred[0]) / FD_STEP_M,
                              (pred[2] - pred[0]) / FD_STEP_M], -1) - U  # fmt: skip
            slope = np.where(np.isfinite(slope), np.clip(slope, -MAX_BIAS_SLOPE, MAX_BIAS_SLOPE),
                             0.0)  # fmt: skip
            J = U + slope
        else:
            pred = pmap.predict(cell, p)[None]
            J = U
        # the iterate's misfit; the best iterate is kept (the receiver's bias is not smooth, so
        # a Gauss-Newton step may go uphill)
        rms = _rms(rho, valid, pred[0])
        better = rms < best_rms
        best_xy[better], best_rms[better] = xy[better], rms[better]
        if last:
            break
        use = (valid & np.isfinite(pred[0])).astype(float)
        s = np.where(use > 0, rho - pred[0], 0.0)
        n = np.maximum(use.sum(axis=1), 1)
        beta = np.sum(use * s, axis=1) / n
        r = (s - beta[:, None]) * use
        Jc = (J - (np.sum(use[..., None] * J, axis=1) / n[:, None])[:, None]) * use[..., None]
        M = Jc.transpose(0, 2, 1) @ Jc + 1e-6 * np.eye(2)
        g = Jc.transpose(0, 2, 1) @ r[..., None]
        step = np.linalg.solve(M, g)[..., 0]
        step = np.where(np.isfinite(step), step, 0.0)
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        step *= np.minimum(1.0, MAX_STEP_M / np.maximum(norm, 1e-12))
        xy = np.clip(xy + step, centre - box_m, centre + box_m)
    return best_xy, np.where(ok_row, best_rms, np.inf)


def _rms(rho: np.ndarray, valid: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """(A,) RMS residual about the offset, m, of the received base stations; plus
    :data:`MISSING_PENALTY_M` where the prediction misses one; inf with fewer than 3."""
    use = valid & np.isfinite(pred)
    s = np.where(use, rho - pred, np.nan)
    n = use.sum(axis=1)
    mean = np.nansum(s, axis=1) / np.maximum(n, 1)
    d = np.where(use, s - mean[:, None], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.sum(d * d, axis=1) / np.maximum(n - 1, 1))
    rms = rms + MISSING_PENALTY_M * (n < valid.sum(axis=1))
    return np.where((n >= 3) & np.isfinite(rms), rms, np.inf)
