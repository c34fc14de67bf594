"""``twin``: positioning against a ray-traced fingerprint map that knows where the NLoS biases are.

With 4 base stations in 2D a single epoch has one redundant measurement, so no residual test can
tell which base station is biased. The map (:mod:`positioning.twin.fingerprint`, written by
``accuracy-map``) predicts, per grid cell and base station, the first-arrival ToA of the receiver
including its NLoS excess. The twin moves that bias from the unknowns into the model::

    rho_n = |p - b_n| + bias_n(p) + beta + e_n,       bias_n(p) = c toa_s[cell, n] - |cell - b_n|

(``rho_n`` the pseudo-range of :mod:`positioning.model.tdoa`, ``beta`` the clock offset times c).

1. **Prior.** The map-free ``fallback`` method (default ``nlos-aware``) gives a fix; only cells
   within ``prior_m`` of it are candidates (:func:`window_match`). A search of the whole map
   (:func:`coarse_match`, used where there is no prior) aliases: with three TDoAs and a rough
   bias field a far cell often matches as well as the right one.
2. **Match.** For every candidate cell the least-squares misfit of the measured pseudo-ranges to
   the predicted ones ``c toa_s`` with the offset free, ``min_beta sum_n (rho_n - c toa_s[c, n]
   - beta)^2``, batched over fixes and cells.
3. **Refine** the ``top`` best cells (:func:`refine_at_cells`): Gauss-Newton on ``(x, y, beta)``
   of the model above with the cell's own bias (``bias="cell"``) or the bias interpolated
   bilinearly from the median-smoothed lattice (``bias="interp"``), the position kept within
   :data:`REFINE_BOX` grid steps of the cell; the candidate with the smallest residual wins.
   With a map of schema version 2 (paths stored) the default ``bias="auto"`` refines the best
   of those again with the nearest cell's paths moved to the iterate and the receiver re-run on
   them (``bias="resynth"``, :mod:`positioning.twin.resynth`), used where it fits within
   :data:`RESYNTH_M`; the re-synthesised ToAs come from a 5 cm raster filled around the visited
   cells on first use (``resynth_step``; :func:`prepare` fills all of it).
4. **Judge.** ``match_m`` = RMS residual of all received base stations at the refined fix
   (offset re-fitted); per base station ``nlos`` = the matched cell's bias exceeds
   :data:`NLOS_BIAS_M`.
5. **Fall back.** A fix with ``match_m > fallback_m`` does not fit the map (a stale map: forklifts
   that moved): it is replaced by the fallback method's fix and flagged ``MAP_MISMATCH``; the
   received base stations the map calls LoS are reported ``stale``.
6. **Bound.** Every fix is moved into the map's service area (``meta["service_area"]``, else the
   cells' bounding box) if it lies outside.

Measured choices (``docs/positioning.md``): the first-lobe receiver's bias on the bundled hall is
rough between 0.5 m cells, so ``bias="cell"`` is used with a v1 map (not ``interp``).

The map is checked on load (:func:`positioning.twin.fingerprint.read_map`, one-line errors); a map
whose base stations are not the dataset's (count or positions off by more than
:data:`BS_TOL_M`) is refused.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PositioningError
from ..estimators.fixes import Fixes, Status, config_params
from ..estimators.irls import irls
from ..model.problem import Problem
from .fingerprint import FingerprintMap
from .lattice import Lattice, check_bs, load, nearest_cell, raster_for
from .match import REFINE_BOX, coarse_match, refine_at_cells, window_match
from .resynth import RASTER_STEP_M, PathMap, refine_resynth

#: A map bias above this (m) marks the base station as NLoS at the fix.
NLOS_BIAS_M = 0.25
#: Default threshold on match_m (m) above which a fix falls back to the map-free method.
FALLBACK_M = 0.6
#: Default search radius around the map-free fix (m) and candidate cells refined per fix.
PRIOR_M = 4.0
#: Default search radius with ``bias="resynth"`` (m): the re-synthesised fit rejects the far
#: cells that alias with the cell-held one, so the window can hold the right cell even where the
#: map-free prior is 10 m off (mmWave P21, P23; docs/positioning.md).
RESYNTH_PRIOR_M = 15.0
#: Default candidate cells refined per fix.
TOP = 3
#: ``bias="resynth"``: largest RMS residual (m) of the re-synthesised solution that is used.
RESYNTH_M = 0.3
#: ``bias="resynth"``: best cell-held solutions refined again with re-synthesised paths.
RESYNTH_TOP = 3
#: ``bias="resynth"``: fixes re-synthesised per block (bounds memory: about 60 MB per block
#: with 16 paths per link; all 13 800 fixes of a 60 s dataset at once took 10 GB).
RESYNTH_CHUNK = 256
#: The same with the ToA raster (``resynth_step > 0``): only (fixes x top x 25, B) values per
#: block, so blocks are larger (fewer passes of numpy's per-call overhead).
RASTER_CHUNK = 4096
#: ``bias="resynth"``: half-width (m) of the 5 x 5 grid the Gauss-Newton start is chosen from.
SEARCH_M = 0.3


def clamp_to_polygon(xy: np.ndarray, poly: np.ndarray, inset: float = 1e-6) -> tuple:
    """Points outside the polygon moved to the nearest boundary point (``inset`` m inside
    along the move). Returns (xy (A, 2), moved (A,) bool)."""
    from matplotlib.path import Path as MplPath

    fin = np.isfinite(xy).all(axis=1)
    inside = np.ones(len(xy), dtype=bool)
    if fin.any():
        inside[fin] = MplPath(poly).contains_points(xy[fin], radius=1e-9)
    out = fin & ~inside
    if not out.any():
        return xy, out
    q = xy[out]
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(
        np.einsum("avk,vk->av", q[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=1), 0.0, 1.0
    )
    near = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(near - q[:, None, :], axis=2)
    j = np.argmin(d, axis=1)
    foot = near[np.arange(len(q)), j]
    centre = poly.mean(axis=0)
    nudge = centre - foot
    nudge /= np.maximum(np.linalg.norm(nudge, axis=1, keepdims=True), 1e-12)
    res = xy.copy()
    res[out] = foot + inset * nudge
    return res, out


@dataclass(frozen=True)
class TwinConfig:
    """Settings of the twin estimator (:func:`twin`; the registry's parameters of ``twin``, with
    ``map`` for :attr:`fingerprint_map`).

    Attributes
    ----------
    fingerprint_map : FingerprintMap or path of a map file
    fallback_m : float, m -- ``match_m`` above which a fix falls back
    prior_m : float or None, m -- only cells within this distance of the fallback fix are
        candidates (0: the whole map; None: :data:`RESYNTH_PRIOR_M` with ``bias="resynth"``,
        else :data:`PRIOR_M`)
    top : int -- candidate cells refined per fix
    bias : ``"cell"`` or ``"interp"``, the bias model of the refinement
        (:func:`~positioning.twin.match.refine_at_cells`); ``"resynth"`` (a map of schema version
        2 only): then Gauss-Newton with the nearest cell's paths moved to the iterate and the
        receiver re-run on them (:func:`positioning.twin.resynth.refine_resynth`); ``"auto"``
        (default): ``"resynth"`` for a map with paths, else ``"cell"``
    paths : int or None, the strongest paths per cell and base station the re-synthesis uses
        (None or 0: all the map stores)
    fd_jacobian : bool, ``resynth`` only: Jacobian with the bias gradient by finite
        differences (default; False: the geometric Jacobian,
        :func:`positioning.twin.resynth.refine_resynth`)
    resynth_m : float, m, ``resynth`` only: the re-synthesised solution is used when its RMS
        residual is at most this, else the cell-held one
    cells : ``"own"`` -- each candidate's paths are moved from its own cell;
        ``"nearest"`` (default) -- from the cell nearest to the iterate (switching as it moves)
    resynth_top : int, ``resynth`` only: how many of the best cell-held solutions are refined
        again with re-synthesised paths
    search_m : float, m, ``resynth`` only: > 0 starts Gauss-Newton from the best point of a
        5 x 5 grid spanning +-search_m around the cell-held solution (default 0.3 m; 0: from the
        cell-held solution itself)
    resynth_step : float, m, ``resynth`` only: the re-synthesised ToAs are sampled on a raster
        of this spacing around the visited cells and interpolated bilinearly
        (:class:`positioning.twin.resynth.ToaRaster`, kept with a map loaded from a file, so later
        fixes near the same cells cost only look-ups; default 0.05 m); 0: the receiver is re-run
        at every iterate (exact, about 90x slower)
    """

    fingerprint_map: FingerprintMap | str | Path
    fallback_m: float = FALLBACK_M
    prior_m: float | None = None
    top: int = TOP
    bias: str = "auto"
    paths: int | None = None
    fd_jacobian: bool = True
    resynth_m: float = RESYNTH_M
    cells: str = "nearest"
    resynth_top: int = RESYNTH_TOP
    search_m: float = SEARCH_M
    resynth_step: float = RASTER_STEP_M


#: Largest difference between a fix's device height and the map's, m, for the cell and interp
#: bias models (the map's ToAs are of its height).
MAP_HEIGHT_TOL_M = 0.05


def twin(
    prob: Problem, config: TwinConfig, fallback: Callable[[Problem], Fixes] | None = None
) -> Fixes:
    """The twin estimator (module docstring). 2D only: the map is at one device height.

    Parameters
    ----------
    prob : Problem (2D: ``height`` known)
    config : TwinConfig, the map and the settings
    fallback : ``fallback(sub_problem) -> Fixes``, the map-free method that gives the search
        prior and the fix where the map does not fit (:func:`positioning.locate` binds the
        ``fallback`` method name, default ``nlos-aware``); None:
        :func:`positioning.estimators.irls.irls`

    Returns
    -------
    :class:`Fixes` of method ``twin``: ``weights`` (E, N) 1 used, 0 not received; ``extra``:
    ``nlos`` (E, N) bool, ``stale`` (E, N) bool, ``match_m`` (E,) m, ``fallback`` (E,) bool.
    """
    fmap, lat, bias, prior_m = _setup(prob, config)
    E, B = prob.rho.shape
    rows = np.flatnonzero(prob.solvable)
    status = np.where(prob.solvable, 0, int(Status.UNSOLVED)).astype(np.int64)
    xyz = np.full((E, 3), np.nan)
    match = np.full(E, np.nan)
    nlos = np.zeros((E, B), dtype=bool)
    stale = np.zeros((E, B), dtype=bool)
    bad = np.zeros(E, dtype=bool)
    if rows.size:
        # every epoch: the problem itself, whose memo holds what its own map-free methods fitted
        sub = prob if rows.size == E else prob.take(rows)
        fb = fallback(sub) if fallback is not None else irls(sub)
        cell_xy = fmap.cell_xyz[:, :2]
        cand = _cells_near(sub, lat, cell_xy, fb.xyz[:, :2], prior_m, config.top)
        xy_k, rms_k = refine_at_cells(sub, lat, cell_xy, cand,
                                      mode="cell" if bias == "resynth" else bias)  # fmt: skip
        if bias == "resynth":
            xy_k, rms_k, cand = _refine_resynth(sub, lat, fmap, cand, xy_k, rms_k, config)
        k = np.argmin(rms_k, axis=1)
        ar = np.arange(rows.size)
        xy, m, cell = xy_k[ar, k], rms_k[ar, k], cand[ar, k]
        m = np.where(np.isfinite(m), m, np.nan)
        cbias = lat.pred[np.maximum(cell, 0)] - np.linalg.norm(
            fmap.cell_xyz[np.maximum(cell, 0)][:, None, :] - prob.bs[None], axis=2
        )
        worse = ~(m <= config.fallback_m)
        xyz[rows] = np.column_stack([xy, sub.height])
        xyz[rows[worse]] = fb.xyz[worse]
        status[rows[worse]] |= np.asarray(fb.status, np.int64)[worse] | int(Status.MAP_MISMATCH)
        match[rows] = m
        nlos[rows] = sub.valid & (cell >= 0)[:, None] & (cbias > NLOS_BIAS_M)
        stale[rows] = sub.valid & worse[:, None] & ~nlos[rows]
        bad[rows] = worse
    xyz[:, :2], _ = clamp_to_polygon(xyz[:, :2], lat.polygon)
    return Fixes(
        xyz=xyz,
        status=status,
        iterations=np.where(prob.solvable, 1, 0),
        weights=prob.valid.astype(float),
        n_used=prob.n_valid,
        method="twin",
        params=config_params(config),
        extra={"nlos": nlos, "stale": stale, "match_m": match, "fallback": bad},
    )


def _setup(prob: Problem, config: TwinConfig) -> tuple[FingerprintMap, Lattice, str, float]:
    """The map and its lattice, the bias model and the prior's radius of a twin solve; refuses a
    missing map, a 3D solve, another site's map or a bias model the map cannot give."""
    if config.fingerprint_map is None:
        raise PositioningError("method 'twin' needs a fingerprint map (--map MAP)")
    if prob.height is None:
        raise PositioningError("twin solves in 2D only (the map is at one height): drop --3d")
    fmap, lat = load(config.fingerprint_map)
    check_bs(fmap, prob.bs)
    bias = config.bias
    if bias == "auto":
        bias = "resynth" if fmap.has_paths else "cell"
    if bias not in ("cell", "interp", "resynth"):
        raise PositioningError(f"twin: unknown bias model {bias!r} (cell, interp, resynth, auto)")
    if bias == "resynth" and not fmap.has_paths:
        raise PositioningError("twin: bias=resynth needs a map with paths (schema version 2)")
    if bias != "resynth":  # the cells' ToAs are of the map's height: the fixes must be at it
        map_h = float(np.median(fmap.cell_xyz[:, 2]))
        off = np.abs(np.asarray(prob.height, dtype=float) - map_h)
        if np.nanmax(off, initial=0.0) > MAP_HEIGHT_TOL_M:
            h = float(np.asarray(prob.height)[int(np.nanargmax(off))])
            raise PositioningError(
                f"twin: the map is at device height {map_h:g} m but a fix is at {h:g} m: build "
                "the map at the devices' height (accuracy-map --height), or use a map with paths "
                "(bias resynth moves them to the height)"
            )
    prior_m = config.prior_m
    if prior_m is None:
        prior_m = RESYNTH_PRIOR_M if bias == "resynth" else PRIOR_M
    return fmap, lat, bias, prior_m


def _cells_near(
    sub: Problem, lat: Lattice, cell_xy: np.ndarray, prior: np.ndarray, prior_m: float, top: int
) -> np.ndarray:
    """(A, top) candidate cells of each fix: the best within ``prior_m`` of its prior (A, 2), or
    of the whole map where there is no prior (fallback unsolved), nothing near it or
    ``prior_m`` is 0."""
    if prior_m > 0:
        cand, _ = window_match(sub, lat, prior, prior_m, top)
        # no prior (fallback unsolved) or nothing near it: the whole map
        lost = ~np.isfinite(prior).all(axis=1) | (cand[:, 0] < 0)
        if lost.any():
            cand[lost], _ = coarse_match(
                sub.take(np.flatnonzero(lost)), lat, lat.coarse, cell_xy, top=top
            )
    else:
        cand, _ = coarse_match(sub, lat, lat.coarse, cell_xy, top=top)
    return cand


def _refine_resynth(
    sub: Problem,
    lat: Lattice,
    fmap: FingerprintMap,
    cand: np.ndarray,
    xy_k: np.ndarray,
    rms_k: np.ndarray,
    config: TwinConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``bias="resynth"``: the ``resynth_top`` best cell-held solutions ``xy_k`` (A, K, 2) of the
    candidates ``cand`` (A, K) refined again with re-synthesised paths
    (:func:`~positioning.twin.resynth.refine_resynth`), per device height and in blocks of fixes.

    Returns the solutions, their RMS residuals and their cells, (A, resynth_top, ...): the
    re-synthesised ones where one fits within ``resynth_m``, else the cell-held ones.
    """
    rows = np.arange(sub.n_epochs)
    n_r = min(int(config.resynth_top), cand.shape[1])
    best = np.argsort(rms_k, axis=1, kind="stable")[:, :n_r]
    c_r = np.where(np.isfinite(np.take_along_axis(rms_k, best, axis=1)),
                   np.take_along_axis(cand, best, axis=1), -1)  # fmt: skip
    s_r = np.take_along_axis(xy_k, best[..., None], axis=1)
    rep = np.repeat(rows, n_r)
    pmap = PathMap.from_map(fmap, config.paths)
    near = (lambda xy: nearest_cell(lat, xy)) if config.cells == "nearest" else None
    s_flat, c_flat = s_r.reshape(-1, 2), c_r.ravel()
    xy_f, rms_f = np.empty_like(s_flat), np.empty(rep.size)
    h_mm = np.rint(sub.height[rep] * 1000.0).astype(np.int64)
    use_raster = config.resynth_step > 0 and config.cells == "nearest"
    # per device height (one raster each), in blocks of fixes: without the raster the start
    # grid holds (fixes x top x 25, B, K) path arrays
    for hv in np.unique(h_mm) if use_raster else [None]:
        idx = np.flatnonzero(h_mm == hv) if use_raster else np.arange(rep.size)
        raster = (raster_for(lat, pmap, config.paths, config.resynth_step, hv) if use_raster
                  else None)  # fmt: skip
        chunk = (RASTER_CHUNK if use_raster else RESYNTH_CHUNK) * n_r
        for c0 in range(0, idx.size, chunk):
            b = idx[c0 : c0 + chunk]
            xy_f[b], rms_f[b] = refine_resynth(
                sub.rho[rep[b]], sub.valid[rep[b]], sub.height[rep[b]], sub.bs, pmap,
                near, s_flat[b], c_flat[b], lat.step * (REFINE_BOX + 0.5),
                fd_jacobian=config.fd_jacobian, search_m=config.search_m, raster=raster,
            )  # fmt: skip
    # the re-synthesised solution wins where it fits within resynth_m; where the nearest cell's
    # paths do not explain the measurements (a path appears or vanishes between cell and
    # device) the cell-held solution is kept
    rms_f = rms_f.reshape(-1, n_r)
    fits = np.min(rms_f, axis=1) <= config.resynth_m
    xy_k = np.where(fits[:, None, None], xy_f.reshape(-1, n_r, 2), s_r)
    rms_k = np.where(fits[:, None], rms_f, np.take_along_axis(rms_k, best, axis=1))
    return xy_k, rms_k, np.take_along_axis(cand, best, axis=1)
