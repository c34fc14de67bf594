"""The least squares of eq. 7 against one reference base station: which reference
(:func:`choose_reference`) and the global minimum of its cost in the service area
(:func:`solve_eq7`).

**Reference** (``reference=`` of ``ls``): the paper's LS takes "random base station as a reference
e" (section III). Choices (:data:`REFERENCE_CHOICES`):

* ``first``: the first received base station of each epoch (the default of ``ls``);
* ``random``: one received base station drawn per epoch, uniformly, from
  ``numpy.random.default_rng(seed)`` (one uniform number per epoch of the problem, in epoch
  order): the paper's;
* ``fixed:N``: base station N (an index; in the command line also a name, or just ``N``); an
  epoch without its ToA falls back to its first received base station (``REFERENCE_FALLBACK``);
* ``strongest``: informed by what the receiver reports (:class:`~positioning.model.problem.
  LinkInfo`): the received base station with the highest SNR among those whose first lobe looks
  like a lone pulse (width within 0.95-1.05 of an isolated pulse's, level within 3 dB of the
  strongest peak; unknown shape counts as lone); without reports, ``first``.

**Global minimum.** Eq. 7 can have two minima in the hall (a TDoA hyperbola pair crosses twice);
a Gauss-Newton descent from the closed-form start stops in whichever basin it starts in. The
cost is evaluated on a grid of the service area (``grid_m`` pitch; the base stations' box grown
by half its diagonal where the problem has no area), the two deepest cells at least
:data:`SEPARATION_M` apart and the closed-form start are each refined by Levenberg-Marquardt, and
the converged result of lowest cost inside the area is kept (none inside: the lowest-cost
converged one, which the caller bounds to the area; none converged: the closed-form start's);
where the closed-form start's descent reaches that minimum, its result is the one kept.
``grid_m = 0`` refines the closed-form start alone. A 3D solve (no known height) refines the
closed-form start alone.
"""

from __future__ import annotations

import numpy as np

from ..errors import PositioningError
from ..model.noise import NARROW_LOBE, WEAK_LOBE_DB, WIDE_LOBE
from ..model.problem import Problem
from ..model.residuals import tdoa_model
from ..model.tdoa import ranges_and_units
from .solver import Solution, first_valid, ill_conditioned, levenberg_marquardt, linear_start

#: The reference choices of ``ls`` (``fixed:N`` with N a base-station index).
REFERENCE_CHOICES = ("first", "random", "strongest", "fixed:N")
#: Default pitch of the grid over the service area, m.
GRID_M = 2.0
#: Grid starts (besides the closed-form one) and their least separation, m.
GRID_STARTS = 2
SEPARATION_M = 5.0
#: A descent replaces an earlier one of the same rank only with a cost lower by this fraction
#: (of 1 m^2 plus the cost): the same minimum reached twice keeps the closed-form start's.
COST_RTOL = 1e-9
#: Growth of the base stations' box (times its diagonal) that stands for a missing service area.
BOX_MARGIN = 0.5


def parse_reference(value: object, n_bs: int | None = None) -> str:
    """A reference choice in its canonical form: ``first``, ``random``, ``strongest`` or
    ``fixed:N``. None is ``first``; an index N (int or digits) is ``fixed:N``.

    Raises
    ------
    PositioningError
        One line listing the known choices (or naming the base-station count).
    """
    known = ", ".join(REFERENCE_CHOICES)
    if value is None:
        return "first"
    if isinstance(value, (bool, np.bool_)):
        raise PositioningError(f"reference must be one of {known}, got {value!r}")
    text = str(value).strip().lower()
    if text in ("none", "null", ""):
        return "first"
    if text in ("first", "random", "strongest"):
        return text
    index = text.split(":", 1)[1] if text.startswith("fixed:") else text
    try:
        f = float(index)
    except ValueError:
        raise PositioningError(f"reference must be one of {known}, got {value!r}") from None
    if not f.is_integer() or f < 0 or (n_bs is not None and f >= n_bs):
        extra = f" (there are {n_bs} base stations)" if n_bs is not None else ""
        raise PositioningError(
            f"reference fixed:N needs a base-station index N{extra}, got {value!r}"
        )
    return f"fixed:{int(f)}"


def reference_by_name(value: object, names: list[str]) -> object:
    """``value`` with a base-station name (``BS2`` or ``fixed:BS2``) replaced by ``fixed:<index>``;
    anything else unchanged."""
    if not isinstance(value, str):
        return value
    name = value[len("fixed:") :] if value.startswith("fixed:") else value
    return f"fixed:{names.index(name)}" if name in names else value


def choose_reference(prob: Problem, choice: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The reference base station of every epoch (module docstring).

    Parameters
    ----------
    prob : Problem
    choice : str, a choice of :func:`parse_reference` (canonical or not)
    seed : int, seed of ``random``

    Returns
    -------
    ref : (E,) int, a received base station (0 in an epoch with none received); fallback : (E,)
    bool, ``fixed:N`` not received in that epoch (the first received one is used)
    """
    choice = parse_reference(choice, prob.n_bs)
    valid = prob.valid
    first = first_valid(valid)
    fallback = np.zeros(prob.n_epochs, dtype=bool)
    if choice == "first":
        return first, fallback
    if choice.startswith("fixed:"):
        n = int(choice.split(":")[1])
        has = valid[:, n]
        return np.where(has, n, first), ~has & valid.any(axis=1)
    if choice == "random":
        u = np.random.default_rng(seed).random(prob.n_epochs)
        k = np.minimum((u * prob.n_valid).astype(np.int64), np.maximum(prob.n_valid - 1, 0))
        # the k-th received base station of each epoch
        rank = np.cumsum(valid, axis=1) - 1
        pick = valid & (rank == k[:, None])
        return np.where(pick.any(axis=1), np.argmax(pick, axis=1), first), fallback
    links = prob.links
    if links is None or not np.isfinite(links.snr_db).any():
        return first, fallback
    lone = ~((links.lobe_width > WIDE_LOBE) | (links.lobe_width < NARROW_LOBE))
    lone &= ~(links.peak_ratio_db < WEAK_LOBE_DB)
    snr = np.where(np.isfinite(links.snr_db), links.snr_db, -np.inf)
    score = np.where(valid, np.where(lone, snr, snr - 1e6), -np.inf)
    best = np.argmax(score, axis=1)
    return np.where(np.isfinite(score.max(axis=1)), best, first), fallback


def search_box(prob: Problem) -> np.ndarray:
    """(2, 2) corners ``[lo, hi]`` of the region searched without a service area: the base
    stations' horizontal box grown by :data:`BOX_MARGIN` times its diagonal, m."""
    lo = prob.bs[:, :2].min(axis=0)
    hi = prob.bs[:, :2].max(axis=0)
    grow = BOX_MARGIN * float(np.linalg.norm(hi - lo))
    return np.array([lo - grow, hi + grow])


def search_grid(prob: Problem, step_m: float) -> np.ndarray:
    """(G, 2) grid of the service area at pitch ``step_m`` (cell centres; :func:`search_box`
    without an area)."""
    if prob.area is not None:
        return prob.area.grid(step_m)
    lo, hi = search_box(prob)
    xs = np.arange(lo[0] + 0.5 * step_m, hi[0], step_m)
    ys = np.arange(lo[1] + 0.5 * step_m, hi[1], step_m)
    return np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)


def inside(prob: Problem, xy: np.ndarray) -> np.ndarray:
    """(A,) bool: ``xy`` (A, 2) inside the service area (:func:`search_box` without one)."""
    if prob.area is not None:
        return prob.area.contains(xy)
    lo, hi = search_box(prob)
    with np.errstate(invalid="ignore"):
        return np.all((xy >= lo) & (xy <= hi), axis=1)


def grid_costs(prob: Problem, ref: np.ndarray, idx: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(A, G) eq. 7 cost of the epochs ``idx`` at the grid points (height known), m^2.

    Per group of epochs with the same height and reference, with ``D[g, n] = R[g, n] - R[g, e]``
    the predicted range differences: ``sum_n w (dd_n - D_gn)^2 = sum_n w dd_n^2 - 2 (w dd) . D_g
    + w . D_g^2``, three matrix products.
    """
    N = prob.n_bs
    e = ref[idx]
    dd = prob.rho[idx] - prob.rho[idx, e][:, None]
    w = (prob.valid[idx] & (np.arange(N)[None, :] != e[:, None])).astype(float)
    dd = np.where(w > 0, dd, 0.0)
    h = prob.height[idx]
    out = np.empty((idx.size, grid.shape[0]))
    for hv in np.unique(h):
        xyz = np.column_stack([grid, np.full(grid.shape[0], hv)])
        R = np.linalg.norm(xyz[:, None, :] - prob.bs[None], axis=2)  # (G, N)
        for ev in np.unique(e[h == hv]):
            sel = np.flatnonzero((h == hv) & (e == ev))
            D = R - R[:, [ev]]
            ws, ds = w[sel], dd[sel]
            out[sel] = (
                np.sum(ws * ds * ds, axis=1)[:, None] - 2.0 * (ws * ds) @ D.T + ws @ (D * D).T
            )
    return np.maximum(out, 0.0)


def grid_starts(prob: Problem, ref: np.ndarray, rows: np.ndarray, step_m: float) -> np.ndarray:
    """(GRID_STARTS, E, 2) the deepest grid cells of the eq. 7 cost of each epoch, each at least
    :data:`SEPARATION_M` from the ones before (NaN where none)."""
    E = prob.n_epochs
    grid = search_grid(prob, step_m)
    out = np.full((GRID_STARTS, E, 2), np.nan)
    idx = np.flatnonzero(rows)
    if idx.size == 0 or grid.shape[0] == 0:
        return out
    cost = grid_costs(prob, ref, idx, grid)
    near = np.linalg.norm(grid[:, None, :] - grid[None, :, :], axis=2) < SEPARATION_M  # (G, G)
    ar = np.arange(idx.size)
    for m in range(min(GRID_STARTS, grid.shape[0])):
        k = np.argmin(cost, axis=1)
        ok = np.isfinite(cost[ar, k])
        out[m, idx[ok]] = grid[k[ok]]
        if m + 1 < GRID_STARTS:
            cost[near[k]] = np.inf
    return out


def solve_eq7(
    prob: Problem,
    ref: np.ndarray,
    rows: np.ndarray,
    *,
    tol: float,
    max_iter: int,
    grid_m: float = GRID_M,
) -> Solution:
    """Least squares of eq. 7 with reference ``ref`` (E,) on the epochs ``rows`` (E,): its lowest
    minimum inside the service area (module docstring).

    Returns
    -------
    Solution; ``iterations`` are the chosen descent's.
    """
    E = prob.n_epochs
    fun, W = tdoa_model(prob, ref)
    start = linear_start(prob, W + (np.arange(prob.n_bs)[None, :] == ref[:, None]), ref)
    starts = [np.where(rows[:, None], start[:, : prob.dims], np.nan)]
    if grid_m > 0 and prob.height is not None:
        starts += list(grid_starts(prob, ref, rows, grid_m))
    best = None
    for theta0 in starts:
        theta, it, conv = levenberg_marquardt(fun, theta0, W, tol=tol, max_iter=max_iter)
        cost = np.full(E, np.inf)
        ok = np.flatnonzero(np.isfinite(theta).all(axis=1))
        if ok.size:
            r, _ = fun(theta[ok], ok)
            cost[ok] = np.sum(W[ok] * r * r, axis=1)
        xyz = prob.position(np.where(np.isfinite(theta), theta, 0.0), np.arange(E))
        rank = np.where(conv, np.where(inside(prob, xyz[:, :2]), 0, 1), 2)
        if best is None:
            best = [theta, it, conv, cost, rank]
            continue
        # better: a lower rank (converged inside, converged, not converged), then a cost lower
        # by more than rounding (the same minimum reached again keeps the closed-form start's)
        lower = cost < best[3] * (1.0 - COST_RTOL) - COST_RTOL
        take = (rank < best[4]) | ((rank == best[4]) & (rank < 2) & lower)
        for b, new in zip(best, (theta, it, conv, cost, rank)):
            b[take] = new[take]
    theta, it, conv = best[0], best[1], best[2]
    ill = ill_conditioned(fun, theta, W)
    xyz = np.where(rows[:, None], prob.position(theta, np.arange(E)), np.nan)
    return Solution(theta=theta, xyz=xyz, iterations=it, converged=conv, ill=ill)


def eq7_cost(prob: Problem, ref: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """(E,) eq. 7 cost of every epoch at positions ``xyz`` (E, 3), m^2."""
    E, N = prob.rho.shape
    ar = np.arange(E)
    R, _ = ranges_and_units(xyz, prob.bs, prob.dims)
    dd = prob.rho - prob.rho[ar, ref][:, None]
    w = prob.valid & (np.arange(N)[None, :] != ref[:, None])
    r = np.where(w, dd - (R - R[ar, ref][:, None]), 0.0)
    return np.sum(r * r, axis=1)
