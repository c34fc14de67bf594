"""The geometry of an InF hall: base stations on a grid, clutter boxes in a brick pattern of
production rows until they cover the requested density (trimmed beside low base stations),
and test points on the free floor. Coordinates rounded to 1 mm for the YAML.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.errors import HallrayError
from .params import (
    BS_CLEARANCE_M,
    CELL_SIZE_RANGE,
    DENSITY_TOL,
    GAP_FRACTION,
    MAX_GAP_M,
    MIN_BOX_SIDE_FRACTION,
    POINT_BS_CLEARANCE_M,
    POINT_CLUTTER_CLEARANCE_M,
    POINT_WALL_CLEARANCE_M,
    ROUND_DECIMALS,
    WALL_AISLE_M,
    InFParams,
)

#: Draws of candidate points before giving up (times the number of points).
_POINT_ATTEMPTS = 200
#: Candidate points are drawn in batches of this size.
_POINT_BATCH = 256


def round_coord(x: float) -> float:
    """Round to :data:`ROUND_DECIMALS` (a plain float with a short repr, -0.0 normalised)."""
    return float(round(float(x), ROUND_DECIMALS)) + 0.0


def _r_array(a: np.ndarray) -> np.ndarray:
    """:func:`round_coord` elementwise (Python's decimal-correct rounding, not ``np.round``'s
    scaling, so that 11.514 stays 11.514 and prints short in the YAML)."""
    a = np.asarray(a, dtype=float)
    return np.array([round_coord(v) for v in a.ravel()], dtype=float).reshape(a.shape)


def bs_positions(p: InFParams) -> np.ndarray:
    """``(B, 3)``: an ``nx x ny`` grid, cell centres of the hall floor (D/2 from the walls)."""
    lx, ly, _ = p.size
    nx, ny = p.bs_grid
    xs = (np.arange(nx) + 0.5) * lx / nx
    ys = (np.arange(ny) + 0.5) * ly / ny
    gx, gy = np.meshgrid(xs, ys, indexing="xy")  # row-major over y: BS1 is south-west
    xyz = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, p.bs_height)])
    return _r_array(xyz)


def _splits(rng: np.random.Generator, length: float, size: float) -> np.ndarray:
    """Break points ``0 = b_0 < b_1 < ... < b_n = length``: pieces uniform in
    ``CELL_SIZE_RANGE * size``; the last piece is merged when too short, so none is below
    ``CELL_SIZE_RANGE[0] * size`` unless the whole length is."""
    lo, hi = CELL_SIZE_RANGE
    n_max = int(math.ceil(length / (lo * size))) + 1
    pieces = rng.uniform(lo * size, hi * size, n_max)
    edges = np.concatenate([[0.0], np.cumsum(pieces)])
    edges = edges[edges < length]
    if len(edges) > 1 and length - edges[-1] < lo * size:
        edges = edges[:-1]
    return np.append(edges, length)


def _cells(rng: np.random.Generator, p: InFParams) -> np.ndarray:
    """``(C, 4)`` cells ``x0, y0, x1, y1`` (m): rows along x, cells along each row."""
    lx, ly, _ = p.size
    x0, y0 = WALL_AISLE_M, WALL_AISLE_M
    w, h = lx - 2 * WALL_AISLE_M, ly - 2 * WALL_AISLE_M
    if w <= 0 or h <= 0:
        return np.zeros((0, 4))
    rows = _splits(rng, h, p.clutter_size)
    out = []
    for ya, yb in zip(rows[:-1], rows[1:]):
        cols = _splits(rng, w, p.clutter_size)
        n = len(cols) - 1
        out.append(
            np.column_stack(
                [x0 + cols[:-1], np.full(n, y0 + ya), x0 + cols[1:], np.full(n, y0 + yb)]
            )
        )
    return np.vstack(out)


def _boxes_in_cells(cells: np.ndarray) -> np.ndarray:
    """``(C, 4)`` box footprints: each cell minus the gap on every side, rounded."""
    side = np.minimum(cells[:, 2] - cells[:, 0], cells[:, 3] - cells[:, 1])
    gap = np.minimum(GAP_FRACTION * side, MAX_GAP_M)
    fp = cells + np.column_stack([gap, gap, -gap, -gap])
    return _r_array(fp)


def _near(footprints: np.ndarray, xy: np.ndarray, clearance: float) -> np.ndarray:
    """``(n, C)`` bool: point ``xy[i]`` within ``clearance`` of footprint ``c`` (axis-aligned
    rectangles ``x0, y0, x1, y1``; the distance is the Chebyshev one, a square keep-out)."""
    x, y = xy[:, 0:1], xy[:, 1:2]
    return (
        (x > footprints[None, :, 0] - clearance)
        & (x < footprints[None, :, 2] + clearance)
        & (y > footprints[None, :, 1] - clearance)
        & (y < footprints[None, :, 3] + clearance)
    )


def _make_way(footprints: np.ndarray, xy: np.ndarray, clearance: float) -> np.ndarray:
    """Footprints trimmed so that none comes within ``clearance`` (Chebyshev) of a point of
    ``xy`` (low base stations): a box around or beside a base station loses the slice on one side
    of it, the side that leaves the larger box (the base station stands in a niche or aisle
    beside the machine, not inside it)."""
    fp = footprints.copy()
    for x, y in xy:
        hit = _near(fp, np.array([[x, y]]), clearance)[0]
        if not hit.any():
            continue
        f = fp[hit]
        # the four trims: keep the part west, east, south or north of the keep-out square
        cand = np.stack(
            [
                np.column_stack([f[:, 0], f[:, 1], np.minimum(f[:, 2], x - clearance), f[:, 3]]),
                np.column_stack([np.maximum(f[:, 0], x + clearance), f[:, 1], f[:, 2], f[:, 3]]),
                np.column_stack([f[:, 0], f[:, 1], f[:, 2], np.minimum(f[:, 3], y - clearance)]),
                np.column_stack([f[:, 0], np.maximum(f[:, 1], y + clearance), f[:, 2], f[:, 3]]),
            ]
        )  # (4, h, 4)
        w = np.clip(cand[..., 2] - cand[..., 0], 0.0, None)
        h = np.clip(cand[..., 3] - cand[..., 1], 0.0, None)
        best = np.argmax(w * h, axis=0)  # first of equal areas: deterministic
        fp[hit] = _r_array(cand[best, np.arange(len(f))])
    return fp


def place_clutter(
    rng: np.random.Generator, p: InFParams, bs_xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Footprints ``(K, 4)``, heights ``(K,)`` and materials of the clutter boxes."""
    lx, ly, _ = p.size
    cells = _cells(rng, p)
    footprints = _boxes_in_cells(cells)
    if not p.high and len(cells):
        footprints = _make_way(footprints, bs_xy, BS_CLEARANCE_M)
    area = (footprints[:, 2] - footprints[:, 0]) * (footprints[:, 3] - footprints[:, 1])
    eligible = np.minimum(footprints[:, 2] - footprints[:, 0], footprints[:, 3] - footprints[:, 1])
    eligible = eligible >= MIN_BOX_SIDE_FRACTION * p.clutter_size
    order = rng.permutation(len(cells))
    order = order[eligible[order]]
    target = p.density * lx * ly
    cum = np.cumsum(area[order])
    available = float(cum[-1]) if len(cum) else 0.0
    if target > 0 and available < target - DENSITY_TOL * lx * ly:
        raise HallrayError(
            f"{p.profile}: cannot place clutter of density {p.density:g} in a "
            f"{lx:g} x {ly:g} m hall: at most {available / (lx * ly):.3f} fits with "
            f"{p.clutter_size:g} m clutter, a {WALL_AISLE_M:g} m aisle along the walls and "
            "room around the base stations"
        )
    n = int(np.searchsorted(cum, target))  # cum[n-1] < target <= cum[n]
    if n < len(cum) and (n == 0 or cum[n] - target < target - cum[n - 1]):
        n += 1  # the closer of the two cumulative areas
    chosen = np.sort(order[:n])  # cells in layout order: names run row by row
    heights = np.full(len(chosen), p.clutter_height)
    if p.height_spread > 0:
        heights = p.clutter_height * rng.uniform(
            1.0 - p.height_spread, 1.0 + p.height_spread, len(chosen)
        )
    names = list(p.materials)
    probs = np.array([p.materials[m] for m in names])
    mat_idx = rng.choice(len(names), size=len(chosen), p=probs)
    heights = _r_array(heights)
    return footprints[chosen], heights, [names[i] for i in mat_idx]


def place_points(
    rng: np.random.Generator, p: InFParams, footprints: np.ndarray, bs_xy: np.ndarray
) -> np.ndarray:
    """``(N, 3)`` test points uniform over the free floor at the UT height (rejection)."""
    lx, ly, _ = p.size
    c = POINT_WALL_CLEARANCE_M
    need = p.n_points
    got: list[np.ndarray] = []
    n_got = 0
    drawn = 0
    batch = _POINT_BATCH  # fixed, so the first points do not depend on how many are asked for
    while n_got < need:
        if drawn >= _POINT_ATTEMPTS * max(need, _POINT_BATCH):
            raise HallrayError(
                f"{p.profile}: cannot place {need} test points on the free floor "
                f"(found {n_got} after {drawn} draws); lower the density or the number of points"
            )
        xy = np.column_stack([rng.uniform(c, lx - c, batch), rng.uniform(c, ly - c, batch)])
        xy = _r_array(xy)
        drawn += batch
        ok = np.ones(batch, dtype=bool)
        if len(footprints):
            ok &= ~_near(footprints, xy, POINT_CLUTTER_CLEARANCE_M).any(axis=1)
        d_bs = np.hypot(xy[:, None, 0] - bs_xy[None, :, 0], xy[:, None, 1] - bs_xy[None, :, 1])
        ok &= (d_bs >= POINT_BS_CLEARANCE_M).all(axis=1)
        take = xy[ok][: need - n_got]
        got.append(take)
        n_got += len(take)
    xy = np.vstack(got) if got else np.zeros((0, 2))
    return np.column_stack([xy, np.full(len(xy), p.ut_height)])
