"""The twin's refinement with re-synthesised paths (fingerprint maps of schema version 2).

A map of version 2 stores per cell and base station the K strongest paths. Within a cell the
paths' delays change smoothly with the position ``p`` (each path's wave is spherical about its
virtual source, :func:`positioning.twin.lobe.move_paths`), while the first-lobe receiver's ToA does
not: paths that overlap within one pulse move its lobe by up to a pulse width, and that bias
changes within centimetres. So the twin does not interpolate the receiver's ToA; it moves the
nearest cell's paths to ``p`` and re-runs the receiver
(:class:`positioning.twin.lobe.LobeReceiver`):

    rho_n = c toa_n(p) + beta + e_n,    toa_n(p) = receiver(paths of cell(p), moved to p)

:func:`refine_resynth` solves it by Gauss-Newton on ``(x, y, beta)`` from a start position per
candidate: the Jacobian of ``c toa_n`` is the geometric one, ``(p - b_n) / |p - b_n|`` (default:
one receiver run per iteration), or that plus the bias gradient by finite differences
(:data:`FD_STEP_M`, clipped to :data:`MAX_BIAS_SLOPE` because the receiver's ToA jumps where a
path crosses a threshold; three runs per iteration). Steps are limited to
:data:`MAX_STEP_M` and the position to ``box`` metres around the start cell. The cell is the
map cell nearest to the current iterate (switching cells as it moves); where the nearest node is
a hole of the lattice the candidate's own cell is used.

Re-running the receiver at every iterate costs about 4 links x 3 candidates x 41 receiver runs per
fix (120 fixes/s). By default (``raster``) the re-synthesised ToAs are instead sampled once on a
fine lattice (:class:`ToaRaster`, 5 cm; a sample takes the paths of the map node whose square
holds it, the same nearest-cell rule, and a hole node the nearest cell's) and interpolated
bilinearly; the bias gradient of the Jacobian is the raster's slope, and the solution is the
raster sample of least exact misfit within :data:`SNAP` samples of Gauss-Newton's (the blend
between samples misses the ToA's structure finer than 5 cm at mmWave). Tiles of the raster are
re-synthesised on first use and kept with the loaded map, so fixes near cells visited before
cost only look-ups (over 10 000 fixes per CPU second); :func:`positioning.twin.lattice.prepare`
fills the whole raster up front.
"""

from __future__ import annotations

from collections.abc import Callable
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


#: Default spacing (m) of the ToA raster (:class:`ToaRaster`) the twin re-synthesises into.
RASTER_STEP_M = 0.05
#: Raster samples per tile side; tiles are re-synthesised on first use. A tile also holds the
#: first row and column of its neighbours (``TILE + 1`` samples a side), so the four samples
#: of a bilinear look-up are always in one tile.
TILE = 8
_T1 = TILE + 1
#: The raster solution is the best raster sample within this many samples of Gauss-Newton's
#: (0: Gauss-Newton's own, on the bilinear blend).
SNAP = 2
#: Raster samples re-synthesised per receiver call (bounds memory: about 60 MB at 16 paths).
RASTER_BATCH = 8192


class ToaRaster:
    """The re-synthesised ``c toa`` of every base station on a fine lattice at one height,
    computed tile by tile on first use and interpolated bilinearly between samples.

    Sample ``k`` of the fine lattice (spacing ``h``, a whole fraction of the map's step) lies
    at ``x0 - step/2 + (k + 1/2) h``, inside the Voronoi square of map node ``k // m``
    (``m = step / h``); its value is the receiver's ToA on the paths of that node's cell moved
    to the sample (:meth:`PathMap.predict`). A node that is a hole of the map (inside a solid)
    takes the nearest cell's paths. Between samples the value is bilinear, so the cost of a
    query is four look-ups, not a receiver run: at ``h`` = 5 cm a threshold crossing of the
    receiver (a jump of the ToA) is placed within half a sample.

    Parameters
    ----------
    pmap : PathMap
    node_cell : (ny, nx) int, the map cell at each lattice node (-1: hole)
    x0, y0 : float, m, the first lattice node; step : float, m, the map's step
    height : float, m, device height of the raster
    h : float, m, requested sample spacing (rounded so that it divides ``step``)
    """

    def __init__(self, pmap: PathMap, node_cell: np.ndarray, x0: float, y0: float, step: float,
                 height: float, h: float = RASTER_STEP_M) -> None:  # fmt: skip
        from scipy.ndimage import distance_transform_edt

        hole = np.asarray(node_cell) < 0
        if hole.all():
            raise ValueError("ToaRaster: the map has no cells")
        _, (jy, jx) = distance_transform_edt(hole, return_indices=True)
        self.node_fill = np.asarray(node_cell)[jy, jx]  # (ny, nx) nearest cell of every node
        self.m = max(1, int(round(step / h)))
        self.h = step / self.m
        self.step, self.height, self.pmap = float(step), float(height), pmap
        self.X0, self.Y0 = x0 - step / 2, y0 - step / 2
        ny, nx = hole.shape
        self.NY, self.NX = ny * self.m, nx * self.m
        self.nty, self.ntx = -(-self.NY // TILE), -(-self.NX // TILE)
        self.B = pmap.delay.shape[1]
        self.slot = np.full((self.nty, self.ntx), -1, dtype=np.int64)
        self.tiles = np.empty((0, _T1, _T1, self.B), dtype=np.float64)
        self.n_tiles = 0
        #: receiver runs (links) spent on tiles so far
        self.links = 0

    def _ensure(self, tile: np.ndarray) -> None:
        """Re-synthesise the tiles of flat indices ``tile`` that are not computed yet."""
        missing = self.slot.ravel()[tile] < 0
        if not missing.any():
            return
        t = np.unique(tile[missing])
        n = self.n_tiles + t.size
        if n > len(self.tiles):
            grown = np.empty((max(n, 2 * len(self.tiles), 16), _T1, _T1, self.B))
            grown[: self.n_tiles] = self.tiles[: self.n_tiles]
            self.tiles = grown
        ty, tx = np.divmod(t, self.ntx)
        a = np.arange(_T1)
        ky = (ty[:, None, None] * TILE + a[None, :, None]) + 0 * a[None, None, :]
        kx = (tx[:, None, None] * TILE + a[None, None, :]) + 0 * a[None, :, None]
        ky, kx = np.minimum(ky.ravel(), self.NY - 1), np.minimum(kx.ravel(), self.NX - 1)
        ny, nx = self.node_fill.shape
        cell = self.node_fill[np.minimum(ky // self.m, ny - 1), np.minimum(kx // self.m, nx - 1)]
        xyz = np.column_stack([self.X0 + (kx + 0.5) * self.h, self.Y0 + (ky + 0.5) * self.h,
                               np.full(kx.size, self.height)])  # fmt: skip
        val = np.empty((kx.size, self.B))
        for s in range(0, kx.size, RASTER_BATCH):
            r = slice(s, s + RASTER_BATCH)
            val[r] = self.pmap.predict(cell[r], xyz[r])
        self.links += kx.size * self.B
        self.tiles[self.n_tiles : n] = val.reshape(t.size, _T1, _T1, self.B)
        self.slot.ravel()[t] = np.arange(self.n_tiles, n)
        self.n_tiles = n

    def fill(self, batch_tiles: int = 256, progress=None) -> None:
        """Re-synthesise every tile not computed yet (``progress(done, total)`` after each
        batch of ``batch_tiles``)."""
        todo = np.flatnonzero(self.slot.ravel() < 0)
        for s in range(0, todo.size, batch_tiles):
            self._ensure(todo[s : s + batch_tiles])
            if progress is not None:
                progress(min(s + batch_tiles, todo.size), todo.size)

    def sample_index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(kx, ky) int indices of the sample nearest to each ``xy`` (A, 2), clipped."""
        u = np.rint((xy[:, 0] - self.X0) / self.h - 0.5)
        v = np.rint((xy[:, 1] - self.Y0) / self.h - 0.5)
        kx = np.clip(np.where(np.isfinite(u), u, 0.0), 0, self.NX - 1).astype(np.int64)
        ky = np.clip(np.where(np.isfinite(v), v, 0.0), 0, self.NY - 1).astype(np.int64)
        return kx, ky

    def sample_xy(self, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        """(A, 2) positions of samples ``(kx, ky)`` (clipped to the lattice)."""
        kx, ky = np.clip(kx, 0, self.NX - 1), np.clip(ky, 0, self.NY - 1)
        return np.column_stack([self.X0 + (kx + 0.5) * self.h, self.Y0 + (ky + 0.5) * self.h])

    def nearest(self, xy: np.ndarray) -> np.ndarray:
        """``c toa`` (A, B), m, of the sample nearest to each ``xy`` (A, 2): one look-up, the
        receiver's exact output there (the final sample step of :func:`refine_resynth`)."""
        kx, ky = self.sample_index(xy)
        tid = (ky // TILE) * self.ntx + kx // TILE
        self._ensure(tid)
        flat = self.tiles[: self.n_tiles].reshape(-1, self.B)
        return flat[self.slot.ravel()[tid] * _T1 * _T1 + (ky % TILE) * _T1 + kx % TILE]

    def predict(self, xy: np.ndarray, grad: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """``c toa`` (A, B), m, at ``xy`` (A, 2) and its gradient (A, B, 2), m/m (None with
        ``grad=False``); NaN where a neighbouring sample detects nothing. Positions off the
        lattice take its edge."""
        u = (xy[:, 0] - self.X0) / self.h - 0.5
        v = (xy[:, 1] - self.Y0) / self.h - 0.5
        u = np.clip(np.where(np.isfinite(u), u, 0.0), 0.0, self.NX - 1.0)
        v = np.clip(np.where(np.isfinite(v), v, 0.0), 0.0, self.NY - 1.0)
        kx = np.minimum(u.astype(np.int64), max(self.NX - 2, 0))
        ky = np.minimum(v.astype(np.int64), max(self.NY - 2, 0))
        fx, fy = (u - kx)[:, None], (v - ky)[:, None]
        tid = (ky // TILE) * self.ntx + kx // TILE
        self._ensure(tid)
        flat = self.tiles[: self.n_tiles].reshape(-1, self.B)
        i00 = self.slot.ravel()[tid] * _T1 * _T1 + (ky % TILE) * _T1 + kx % TILE
        v = flat[i00[:, None] + np.array([0, 1, _T1, _T1 + 1])]  # (A, 4, B)
        gx_, gy_ = 1.0 - fx, 1.0 - fy
        w = np.concatenate([gx_ * gy_, fx * gy_, gx_ * fy, fx * fy], axis=1)  # (A, 4)
        val = np.einsum("ak,akb->ab", w, v)
        if not grad:
            return val, None
        v00, v01, v10, v11 = v[:, 0], v[:, 1], v[:, 2], v[:, 3]
        d0, d1 = v01 - v00, v11 - v10
        gx = ((1 - fy) * d0 + fy * d1) / self.h
        gy = ((1 - fx) * (v10 - v00) + fx * (v11 - v01)) / self.h
        return val, np.stack([gx, gy], axis=-1)


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
    raster: ToaRaster | None = None,
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
    raster : ToaRaster or None -- the re-synthesised ToAs are looked up in this raster (all rows
        at its height; ``pmap`` and ``nearest_cell`` unused) and the Jacobian's bias gradient is
        its bilinear slope; None: the receiver is re-run at every iterate

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
        xy = _search_start(rho, valid, h, pmap, nearest_cell, xy, sc, centre, box_m, search_m,
                           search_n, raster)  # fmt: skip
    best_xy = xy.copy()
    best_rms = np.full(A, np.inf)
    for it in range(iters + 1):
        p = np.column_stack([xy, h])
        diff = p[:, None, :] - bs[None]
        R = np.linalg.norm(diff, axis=2)
        U = diff[..., :2] / np.maximum(R, 1e-12)[..., None]  # (A, B, 2)
        last = it == iters
        pred, J = _prediction(xy, p, U, pmap, cells_at, raster, fd_jacobian and not last,
                              fd_jacobian)  # fmt: skip
        # the iterate's misfit; the best iterate is kept (the receiver's bias is not smooth, so
        # a Gauss-Newton step may go uphill)
        rms = residual_rms(rho, valid, pred[0])
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
        step = normal_step(Jc, r, 1e-6)
        step = np.where(np.isfinite(step), step, 0.0)
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        step *= np.minimum(1.0, MAX_STEP_M / np.maximum(norm, 1e-12))
        xy = np.clip(xy + step, centre - box_m, centre + box_m)
    if raster is not None and SNAP > 0:
        best_xy, best_rms = _snap(rho, valid, raster, best_xy, best_rms)
    return best_xy, np.where(ok_row, best_rms, np.inf)


def _prediction(
    xy: np.ndarray,
    p: np.ndarray,
    U: np.ndarray,
    pmap: PathMap,
    cells_at: Callable[[np.ndarray], np.ndarray],
    raster: ToaRaster | None,
    fd_step: bool,
    fd_jacobian: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """``c toa`` (1 or 3, A, B), m, re-synthesised at the iterate ``xy`` (A, 2) (``p`` (A, 3) with
    its height) and the Jacobian (A, B, 2) of :func:`refine_resynth`: the geometric one ``U``
    (A, B, 2), plus the bias gradient clipped to :data:`MAX_BIAS_SLOPE` where ``fd_jacobian`` --
    the raster's slope, or (``fd_step``, no raster) finite differences of two more receiver runs
    (the first row of the prediction is the iterate's own)."""
    A = xy.shape[0]
    if raster is not None:
        val, grad = raster.predict(xy)
        pred = val[None]
        slope = grad - U
        slope = np.where(np.isfinite(slope), np.clip(slope, -MAX_BIAS_SLOPE, MAX_BIAS_SLOPE),
                         0.0)  # fmt: skip
        return pred, (U + slope if fd_jacobian else U)
    if fd_step:
        cell = cells_at(xy)
        ev = np.concatenate([p, p + [FD_STEP_M, 0, 0], p + [0, FD_STEP_M, 0]])
        pred = pmap.predict(np.tile(cell, 3), ev).reshape(3, A, -1)
        slope = np.stack([(pred[1] - pred[0]) / FD_STEP_M,
                          (pred[2] - pred[0]) / FD_STEP_M], -1) - U  # fmt: skip
        slope = np.where(np.isfinite(slope), np.clip(slope, -MAX_BIAS_SLOPE, MAX_BIAS_SLOPE),
                         0.0)  # fmt: skip
        return pred, U + slope
    return pmap.predict(cells_at(xy), p)[None], U


def _search_start(
    rho: np.ndarray,
    valid: np.ndarray,
    h: np.ndarray,
    pmap: PathMap,
    nearest_cell: Callable[[np.ndarray], np.ndarray] | None,
    xy: np.ndarray,
    sc: np.ndarray,
    centre: np.ndarray,
    box_m: float,
    search_m: float,
    search_n: int,
    raster: ToaRaster | None,
) -> np.ndarray:
    """(A, 2) start of :func:`refine_resynth`: the best point, by the re-synthesised misfit
    about the offset, of a ``search_n`` x ``search_n`` grid spanning +-``search_m`` around
    ``xy`` (A, 2), kept within ``box_m`` of the cell centres ``centre`` (A, 2); ``sc`` (A,) the
    candidates' cells. A point whose prediction misses a received base station is not chosen."""
    A = rho.shape[0]
    off = np.linspace(-search_m, search_m, int(search_n))
    gx, gy = np.meshgrid(off, off, indexing="ij")
    grid = np.column_stack([gx.ravel(), gy.ravel()])  # (G, 2)
    G = len(grid)
    cand_xy = np.clip((xy[:, None, :] + grid[None]).reshape(-1, 2),
                      np.repeat(centre - box_m, G, 0), np.repeat(centre + box_m, G, 0))  # fmt: skip
    rep = np.repeat(np.arange(A), G)
    if raster is not None:
        pred = raster.predict(cand_xy, grad=False)[0]
    else:
        cell = cells_at_rep = nearest_cell(cand_xy) if nearest_cell is not None else sc[rep]
        cell = np.where(cells_at_rep >= 0, cells_at_rep, sc[rep])
        pred = pmap.predict(cell, np.column_stack([cand_xy, h[rep]]))
    pred = pred.reshape(A, G, -1)
    use = valid[:, None, :] & np.isfinite(pred)
    res = np.where(use, rho[:, None, :] - pred, 0.0)
    nu = use.sum(axis=2)
    cost = np.einsum("agb,agb->ag", res, res) - res.sum(axis=2) ** 2 / np.maximum(nu, 1)
    cost = cost + 1e6 * (nu < valid.sum(axis=1)[:, None])
    best = np.argmin(cost, axis=1)
    return cand_xy.reshape(A, G, 2)[np.arange(A), best]


def _snap(
    rho: np.ndarray, valid: np.ndarray, raster: ToaRaster, best_xy: np.ndarray, best_rms: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The raster's samples are the receiver's exact output, its bilinear blend between them is
    not (at mmWave the ToA has structure finer than the samples): the solution is the best sample
    within :data:`SNAP` samples of the Gauss-Newton result ``best_xy`` (A, 2), by the exact
    misfit; where none has a finite misfit, ``best_xy`` and ``best_rms`` (A,) stay."""
    A = rho.shape[0]
    k = np.arange(-SNAP, SNAP + 1)
    gx, gy = np.meshgrid(k, k, indexing="ij")
    S = gx.size
    kx, ky = raster.sample_index(best_xy)
    sx = (kx[:, None] + gx.ravel()[None]).ravel()
    sy = (ky[:, None] + gy.ravel()[None]).ravel()
    pts = raster.sample_xy(sx, sy)
    rms = residual_rms(rho[:, None], valid[:, None], raster.nearest(pts).reshape(A, S, -1))
    j = np.argmin(rms, axis=1)
    pick = np.isfinite(rms[np.arange(A), j])
    best_xy = np.where(pick[:, None], pts.reshape(A, S, 2)[np.arange(A), j], best_xy)
    best_rms = np.where(pick, rms[np.arange(A), j], best_rms)
    return best_xy, best_rms


def normal_step(J: np.ndarray, r: np.ndarray, damping: float) -> np.ndarray:
    """(A, 2) least-squares step ``(J^T J + damping I)^-1 J^T r`` of ``J`` (A, B, 2) and ``r``
    (A, B), by the closed-form 2 x 2 inverse (a batched LAPACK call costs more than the
    arithmetic here); NaN where singular."""
    a = np.einsum("ab,ab->a", J[..., 0], J[..., 0]) + damping
    b = np.einsum("ab,ab->a", J[..., 0], J[..., 1])
    d = np.einsum("ab,ab->a", J[..., 1], J[..., 1]) + damping
    g0 = np.einsum("ab,ab->a", J[..., 0], r)
    g1 = np.einsum("ab,ab->a", J[..., 1], r)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = a * d - b * b
        return np.column_stack([(d * g0 - b * g1) / det, (a * g1 - b * g0) / det])


def residual_rms(rho: np.ndarray, valid: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """The misfit :func:`refine_resynth` minimises and judges its solutions by.

    (...,) RMS residual about the offset, m, of the received base stations (last axis;
    ``rho``, ``valid`` broadcast against ``pred``); plus :data:`MISSING_PENALTY_M` where the
    prediction misses one; inf with fewer than 3."""
    use = valid & np.isfinite(pred)
    s = np.where(use, rho - pred, 0.0)
    n = use.sum(axis=-1)
    mean = s.sum(axis=-1) / np.maximum(n, 1)
    d = np.where(use, s - mean[..., None], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.einsum("...b,...b->...", d, d) / np.maximum(n - 1, 1))
    rms = rms + MISSING_PENALTY_M * (n < valid.sum(axis=-1))
    return np.where((n >= 3) & np.isfinite(rms), rms, np.inf)
