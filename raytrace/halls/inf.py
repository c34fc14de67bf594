"""Synthetic indoor-factory halls after 3GPP TR 38.901 (InF), and a check of their line of sight.

3GPP TR 38.901 (section 7.2, Table 7.2-4; LoS probability in Table 7.4.2-1) describes an indoor
factory by four sub-scenarios: clutter *sparse* (density r < 40 %, typical clutter size about
10 m: big machines) or *dense* (r >= 40 %, about 2 m: small machinery, shelves), base stations
*low* (below the effective clutter height h_c) or *high* (above it). Evaluations commonly use
{r, h_c, d_clutter} = {0.2, 2 m, 10 m} (sparse) and {0.6, 6 m, 2 m} (dense), base stations at
1.5 m (low) or 8 m (high) on a 20 m grid, D/2 from the walls, and devices (UT) at 1.5 m.

3GPP does not place clutter: it is a statistical model. :func:`generate_hall` realises it as
geometry, in the existing hall schema (``docs/hall.md``), so ``build-hall``, ``load_scene`` and the
tracer work on the result:

1. the floor, minus an aisle along the walls, is cut into *production rows* whose depth is uniform
   in ``[0.5, 1.5] d_clutter``, and every row into *cells* whose length is uniform in the same
   range (a brick pattern, like machines along lines);
2. a random subset of cells, chosen in a seeded random order, receives a box (the cell minus a
   small gap on every side, height h_c) until the boxes cover the fraction r of the hall floor;
   a box around or beside a low base station is trimmed on one side to leave it 0.5 m of room
   (a base station stands beside a machine, not inside it);
3. each box gets an ITU-R P.2040 material, mostly metal (default 80 % metal, 10 % wood,
   10 % concrete);
4. base stations on a grid of about ``bs_spacing`` (20 m) spacing, half a spacing from the walls,
   at 1.5 m (low) or 8 m (high, at most 0.5 m below the ceiling);
5. test points (UT) at 1.5 m drawn uniformly over the free floor, away from clutter and walls.

The layout (steps 1-3) and the points (step 5) use two independent random streams spawned from
the seed, so asking for more points leaves the clutter unchanged. Same arguments, same YAML and
GLB bytes.

The 3GPP LoS probability is ``P_LOS = exp(-d_2D / k)`` with ``k = -d_clutter / ln(1 - r)`` for
SL and DL, and ``k`` multiplied by ``(h_BS - h_UT) / (h_c - h_UT)`` for SH and DH
(:func:`los_probability_3gpp`). :func:`los_check` measures the LoS fraction the generated halls
really give (Embree segment tests, :meth:`raytrace.scene.model.Scene.occluded`) per distance bin; why
and where the two differ is in ``docs/inf.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..core.errors import HallrayError
from ..core.scale import check_size
from ..scene.model import Scene
from .spec.los import line_of_sight, los_note, tracer_scene
from .spec.model import ITU_MATERIALS, HallSpec
from .spec.parse import parse_hall_spec

#: Version of the generator's algorithm: a change of the layout rules bumps it (seeds then give
#: other halls). Stored in ``inf.json``.
GENERATOR_VERSION = 1

#: The four sub-scenarios with clutter: (dense clutter, high base stations).
PROFILES: dict[str, tuple[bool, bool]] = {
    "InF-SL": (False, False),
    "InF-DL": (True, False),
    "InF-SH": (False, True),
    "InF-DH": (True, True),
}
#: Clutter density at and above which the clutter is "dense" (TR 38.901 Table 7.2-4).
DENSE_THRESHOLD = 0.4
#: Default {r, h_c (m), d_clutter (m)}: the TR 38.901 evaluation values (Table 7.8-7).
SPARSE_DEFAULTS = {"density": 0.2, "clutter_height": 2.0, "clutter_size": 10.0}
DENSE_DEFAULTS = {"density": 0.6, "clutter_height": 6.0, "clutter_size": 2.0}
#: UT (device) height, m (TR 38.901 InF evaluation).
UT_HEIGHT_M = 1.5
#: Base-station heights, m: low (InF-SL, InF-DL) and high (InF-SH, InF-DH).
LOW_BS_HEIGHT_M = 1.5
HIGH_BS_HEIGHT_M = 8.0
#: A high base station stays at least this far below the ceiling, m.
CEILING_CLEARANCE_M = 0.5
#: Base-station grid spacing, m (TR 38.901: 18 BSs on a 20 m grid in a 120 m x 60 m hall).
BS_SPACING_M = 20.0
#: Default hall: the TR 38.901 InF evaluation hall, L x W x D in m.
DEFAULT_SIZE_M = (120.0, 60.0, 10.0)
#: Default number of test points.
DEFAULT_POINTS = 50
#: Aisle kept free of clutter along the walls, m.
WALL_AISLE_M = 1.0
#: Row depth and cell length are uniform in this range times d_clutter (mean d_clutter).
CELL_SIZE_RANGE = (0.5, 1.5)
#: Gap between a box and its cell border on every side: this fraction of the cell side, at most
#: :data:`MAX_GAP_M` (so neighbouring machines never share a face).
GAP_FRACTION = 0.025
MAX_GAP_M = 0.05
#: No clutter within this horizontal distance of a low base station, m.
BS_CLEARANCE_M = 0.5
#: A box trimmed around a base station is dropped when its shorter side falls below this
#: fraction of d_clutter.
MIN_BOX_SIDE_FRACTION = 0.2
#: Test points keep this horizontal distance from clutter, m ...
POINT_CLUTTER_CLEARANCE_M = 0.3
#: ... from the walls, m ...
POINT_WALL_CLEARANCE_M = 0.5
#: ... and from every base station, m.
POINT_BS_CLEARANCE_M = 1.0
#: Default clutter materials and their probabilities (ITU-R P.2040 names): mostly metal.
DEFAULT_MATERIALS: dict[str, float] = {"metal": 0.8, "wood": 0.1, "concrete": 0.1}
#: Coordinates in the YAML are rounded to this many decimals of a metre (1 mm).
ROUND_DECIMALS = 3
#: Achieved density may fall short of the requested one by at most this (absolute) before the
#: request counts as impossible.
DENSITY_TOL = 0.01
#: Draws of candidate points before giving up (times the number of points).
_POINT_ATTEMPTS = 200
#: Candidate points are drawn in batches of this size.
_POINT_BATCH = 256


# --------------------------------------------------------------------------------------------
# parameters
# --------------------------------------------------------------------------------------------


def canonical_profile(profile: str) -> str:
    """``"inf-sl"`` -> ``"InF-SL"``; raises :class:`HallrayError` for an unknown profile."""
    if isinstance(profile, str):
        for name in PROFILES:
            if profile.strip().lower() == name.lower():
                return name
    raise HallrayError(f"unknown profile {profile!r}; choose one of {', '.join(PROFILES)}")


def parse_size(text: str | Sequence[float]) -> tuple[float, float, float]:
    """``"42x46x8.8"`` (or a 3-sequence) -> ``(L, W, D)`` in m, all finite and positive."""
    if isinstance(text, str):
        parts = text.lower().replace(" ", "").split("x")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = []
        if len(vals) != 3:
            raise HallrayError(f"bad size {text!r}: expected LxWxH in metres, e.g. 42x46x8.8")
    else:
        try:
            vals = [float(v) for v in text]
        except (TypeError, ValueError):
            raise HallrayError(f"bad size {text!r}: expected [L, W, H] in metres") from None
        if len(vals) != 3:
            raise HallrayError(f"bad size {text!r}: expected [L, W, H] in metres")
    if not all(math.isfinite(v) and v > 0 for v in vals):
        raise HallrayError(f"bad size {text!r}: every dimension must be a positive number of m")
    check_size(max(vals), f"hall size {text if isinstance(text, str) else list(text)}")
    return (vals[0], vals[1], vals[2])


@dataclass(frozen=True)
class InFOptions:
    """The generator's options besides profile, size and seed (the keyword arguments of
    :func:`generate_hall`, :func:`resolve_params` and :func:`check_hall`). None means the
    profile's TR 38.901 default.

    Attributes
    ----------
    density : clutter density r, fraction of the floor covered; default 0.2 (sparse) / 0.6
        (dense); sparse profiles need ``0 <= r < 0.4``, dense ones ``0.4 <= r < 1``
    clutter_size : d_clutter, m; default 10 (sparse) / 2 (dense); mean row depth and cell length
    clutter_height : h_c, m; default 2 (sparse) / 6 (dense); above the UT, below the ceiling
    height_spread : s in [0, 1): box heights uniform in ``h_c [1 - s, 1 + s]`` (default 0)
    bs_height : h_BS, m; default 1.5 (low; must be below h_c) or min(8, D - 0.5) (high; above
        h_c)
    ut_height : h_UT of the test points, m (1.5)
    bs_spacing : grid spacing, m (20); ``max(2, round(L / spacing))`` base stations along x, the
        same along y, at the centres of an even split of the hall (D/2 from the walls)
    bs_grid : (nx, ny), overrides ``bs_spacing``
    n_points : number of test points (50)
    materials : {ITU material: weight} of the clutter (default 80 % metal, 10 % wood, 10 %
        concrete)
    """

    density: float | None = None
    clutter_size: float | None = None
    clutter_height: float | None = None
    height_spread: float = 0.0
    bs_height: float | None = None
    ut_height: float = UT_HEIGHT_M
    bs_spacing: float = BS_SPACING_M
    bs_grid: Sequence[int] | None = None
    n_points: int = DEFAULT_POINTS
    materials: Mapping[str, float] | None = None


@dataclass(frozen=True)
class InFParams:
    """The resolved parameters of one InF hall (lengths in m).

    Attributes
    ----------
    profile : str, ``InF-SL`` | ``InF-DL`` | ``InF-SH`` | ``InF-DH``
    size : (3,) float, hall interior L x W x D, m
    seed : int
    density : float, clutter density r (fraction of the floor covered), 0 <= r < 1
    clutter_size : float, typical clutter size d_clutter, m (mean row depth and cell length)
    clutter_height : float, effective clutter height h_c, m (all boxes, unless ``height_spread``)
    height_spread : float, box heights uniform in ``h_c * [1 - s, 1 + s]`` (default 0: all h_c)
    bs_height : float, h_BS, m
    ut_height : float, h_UT, m
    bs_grid : (2,) int, base stations along x and y
    n_points : int, test points
    materials : mapping material -> probability
    """

    profile: str
    size: tuple[float, float, float]
    seed: int
    density: float
    clutter_size: float
    clutter_height: float
    height_spread: float
    bs_height: float
    ut_height: float
    bs_grid: tuple[int, int]
    n_points: int
    materials: dict[str, float] = field(default_factory=dict)

    @property
    def dense(self) -> bool:
        return PROFILES[self.profile][0]

    @property
    def high(self) -> bool:
        return PROFILES[self.profile][1]

    @property
    def k_subsce_m(self) -> float:
        """The 3GPP decay distance k of ``P_LOS = exp(-d_2D / k)``, m (inf for r = 0)."""
        return los_decay_distance_m(
            self.density,
            self.clutter_size,
            high=self.high,
            bs_height_m=self.bs_height,
            ut_height_m=self.ut_height,
            clutter_height_m=self.clutter_height,
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["size"] = list(self.size)
        d["bs_grid"] = list(self.bs_grid)
        return d


def resolve_params(
    profile: str, size: str | Sequence[float] | None = None, seed: int = 0, **options: Any
) -> InFParams:
    """Fill in the TR 38.901 defaults of a profile and validate everything (one-line errors).

    ``options`` are the fields of :class:`InFOptions`; see :func:`generate_hall`.
    """
    opt = InFOptions(**options)
    name = canonical_profile(profile)
    dense, high = PROFILES[name]
    defaults = DENSE_DEFAULTS if dense else SPARSE_DEFAULTS
    lx, ly, lz = parse_size(DEFAULT_SIZE_M if size is None else size)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise HallrayError(f"seed must be a non-negative integer, got {seed!r}")
    r = _density(name, dense, _number(name, opt.density, "clutter density", defaults["density"]))
    d_c = _number(name, opt.clutter_size, "clutter size", defaults["clutter_size"])
    if d_c <= 0:
        raise HallrayError(f"{name}: clutter size must be > 0 m, got {d_c:g}")
    h_ut, h_c, spread, h_bs = _heights(name, high, lz, opt, defaults["clutter_height"])
    grid = _bs_grid(name, lx, ly, opt)
    n_points = opt.n_points
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 0:
        raise HallrayError(f"{name}: number of points must be an integer >= 0, got {n_points!r}")
    return InFParams(
        profile=name,
        size=(lx, ly, lz),
        seed=int(seed),
        density=r,
        clutter_size=d_c,
        clutter_height=h_c,
        height_spread=spread,
        bs_height=h_bs,
        ut_height=h_ut,
        bs_grid=grid,
        n_points=int(n_points),
        materials=_clutter_materials(name, opt.materials),
    )


def _number(name: str, value: Any, what: str, default: float) -> float:
    """``value`` (or ``default`` if None) as a finite float; a one-line error naming the profile."""
    v = default if value is None else value
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
        raise HallrayError(f"{name}: {what} must be a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise HallrayError(f"{name}: {what} must be finite, got {v!r}")
    return v


def _density(name: str, dense: bool, r: float) -> float:
    """The clutter density, checked against the profile's range (TR 38.901 Table 7.2-4)."""
    if dense and not DENSE_THRESHOLD <= r < 1.0:
        raise HallrayError(
            f"{name}: clutter density {r:g} out of range for dense clutter "
            f"({DENSE_THRESHOLD:g} <= r < 1); use InF-S{name[-1]} for sparse clutter"
        )
    if not dense and not 0.0 <= r < DENSE_THRESHOLD:
        raise HallrayError(
            f"{name}: clutter density {r:g} out of range for sparse clutter "
            f"(0 <= r < {DENSE_THRESHOLD:g}); use InF-D{name[-1]} for dense clutter"
        )
    return r


def _heights(
    name: str, high: bool, lz: float, opt: InFOptions, default_clutter_height: float
) -> tuple[float, float, float, float]:
    """``(h_UT, h_c, height spread, h_BS)``, m: UT < clutter < ceiling, and the base station
    below the clutter (low) or between the tallest clutter and the ceiling (high)."""
    h_ut = _number(name, opt.ut_height, "UT height", UT_HEIGHT_M)
    if not 0 < h_ut < lz:
        raise HallrayError(f"{name}: UT height {h_ut:g} m must be inside the hall (0 .. {lz:g})")
    h_c = _number(name, opt.clutter_height, "clutter height", default_clutter_height)
    if not h_ut < h_c < lz:
        raise HallrayError(
            f"{name}: clutter height {h_c:g} m must be above the UT height {h_ut:g} m and below "
            f"the ceiling {lz:g} m"
        )
    spread = _number(name, opt.height_spread, "height spread", 0.0)
    if not 0.0 <= spread < 1.0:
        raise HallrayError(f"{name}: height spread must be in [0, 1), got {spread:g}")
    if high:
        h_bs = _number(
            name, opt.bs_height, "BS height", min(HIGH_BS_HEIGHT_M, lz - CEILING_CLEARANCE_M)
        )
        if not h_c < h_bs <= lz - CEILING_CLEARANCE_M:
            raise HallrayError(
                f"{name}: BS height {h_bs:g} m must be above the clutter height {h_c:g} m and at "
                f"least {CEILING_CLEARANCE_M:g} m below the ceiling {lz:g} m"
            )
        if h_c * (1.0 + spread) >= h_bs:
            raise HallrayError(
                f"{name}: the tallest clutter ({h_c * (1 + spread):g} m) must stay below the "
                f"BS height {h_bs:g} m; reduce the height spread"
            )
    else:
        h_bs = _number(name, opt.bs_height, "BS height", LOW_BS_HEIGHT_M)
        if not 0 < h_bs < h_c:
            raise HallrayError(
                f"{name}: BS height {h_bs:g} m must be above the floor and below the clutter "
                f"height {h_c:g} m (a low BS); use InF-{name[-2]}H for high base stations"
            )
    if h_c * (1.0 + spread) >= lz:
        raise HallrayError(
            f"{name}: clutter up to {h_c * (1 + spread):g} m does not fit below the ceiling"
        )
    return h_ut, h_c, spread, h_bs


def _bs_grid(name: str, lx: float, ly: float, opt: InFOptions) -> tuple[int, int]:
    """Base stations along x and y: ``opt.bs_grid``, else from ``opt.bs_spacing``."""
    if opt.bs_grid is None:
        spacing = _number(name, opt.bs_spacing, "BS spacing", BS_SPACING_M)
        if spacing <= 0:
            raise HallrayError(f"{name}: BS spacing must be > 0 m, got {spacing:g}")
        return (max(2, round(lx / spacing)), max(2, round(ly / spacing)))
    grid = list(opt.bs_grid)
    if len(grid) != 2 or not all(
        isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1 for n in grid
    ):
        raise HallrayError(f"{name}: bs_grid must be two integers >= 1, got {opt.bs_grid!r}")
    return (int(grid[0]), int(grid[1]))


def _clutter_materials(name: str, materials: Mapping[str, float] | None) -> dict[str, float]:
    """ITU material -> probability (the weights normalised)."""
    mats = dict(DEFAULT_MATERIALS if materials is None else materials)
    if not mats:
        raise HallrayError(f"{name}: give at least one clutter material")
    for m, w in mats.items():
        if m not in ITU_MATERIALS:
            raise HallrayError(
                f"{name}: unknown clutter material {m!r} (ITU-R P.2040: {', '.join(ITU_MATERIALS)})"
            )
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not w >= 0:
            raise HallrayError(f"{name}: weight of material {m!r} must be >= 0, got {w!r}")
    total = float(sum(mats.values()))
    if total <= 0:
        raise HallrayError(f"{name}: clutter material weights sum to zero")
    return {m: float(w) / total for m, w in mats.items()}


# --------------------------------------------------------------------------------------------
# the 3GPP LoS probability
# --------------------------------------------------------------------------------------------


def los_decay_distance_m(
    density: float,
    clutter_size_m: float,
    *,
    high: bool = False,
    bs_height_m: float = LOW_BS_HEIGHT_M,
    ut_height_m: float = UT_HEIGHT_M,
    clutter_height_m: float = 2.0,
) -> float:
    """TR 38.901 Table 7.4.2-1 InF: ``k_subsce = -d_clutter / ln(1 - r)`` (SL, DL), times
    ``(h_BS - h_UT) / (h_c - h_UT)`` for SH and DH. Metres; ``inf`` for r = 0."""
    if density <= 0.0:
        return math.inf
    k = -clutter_size_m / math.log1p(-density)
    if high:
        k *= (bs_height_m - ut_height_m) / (clutter_height_m - ut_height_m)
    return k


def los_probability_3gpp(d2d_m: np.ndarray | float, k_m: float) -> np.ndarray:
    """``P_LOS = exp(-d_2D / k)`` (TR 38.901 Table 7.4.2-1, InF-SL/DL/SH/DH).

    Parameters
    ----------
    d2d_m : (n,) float, horizontal BS-UT distance, m
    k_m : float, decay distance from :func:`los_decay_distance_m`, m

    Returns
    -------
    (n,) float in (0, 1]
    """
    d = np.asarray(d2d_m, dtype=float)
    if math.isinf(k_m):
        return np.ones_like(d)
    return np.exp(-d / k_m)


# --------------------------------------------------------------------------------------------
# layout
# --------------------------------------------------------------------------------------------


def _r(x: float) -> float:
    """Round to :data:`ROUND_DECIMALS` (a plain float with a short repr, -0.0 normalised)."""
    return float(round(float(x), ROUND_DECIMALS)) + 0.0


def _r_array(a: np.ndarray) -> np.ndarray:
    """:func:`_r` elementwise (Python's decimal-correct rounding, not ``np.round``'s scaling,
    so that 11.514 stays 11.514 and prints short in the YAML)."""
    a = np.asarray(a, dtype=float)
    return np.array([_r(v) for v in a.ravel()], dtype=float).reshape(a.shape)


def _bs_positions(p: InFParams) -> np.ndarray:
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


def _place_clutter(
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


def _points(
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


# --------------------------------------------------------------------------------------------
# the generator
# --------------------------------------------------------------------------------------------


def _layout(
    p: InFParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Base stations, clutter footprints, heights, materials and points of a hall."""
    layout_ss, points_ss = np.random.SeedSequence(p.seed).spawn(2)
    rng_layout = np.random.default_rng(layout_ss)
    rng_points = np.random.default_rng(points_ss)
    bs = _bs_positions(p)
    footprints, heights, mats = _place_clutter(rng_layout, p, bs[:, :2])
    pts = _points(rng_points, p, footprints, bs[:, :2])
    return bs, footprints, heights, mats, pts


def check_hall(
    profile: str, size: str | Sequence[float] | None = None, seed: int = 0, **options: Any
) -> InFParams:
    """Validate the arguments of :func:`generate_hall` and lay the hall out (clutter and points,
    milliseconds) without building it: raises the same one-line errors, including clutter or
    points that cannot be placed. Returns the resolved parameters."""
    options.pop("los_notes", None)
    p = resolve_params(profile, size, seed, **options)
    _layout(p)
    return p


def generate_hall(
    profile: str,
    size: str | Sequence[float] | None = None,
    seed: int = 0,
    *,
    los_notes: bool = True,
    **options: Any,
) -> dict[str, Any]:
    """A synthetic InF hall as a hall-spec mapping (the YAML schema of ``docs/hall.md``).

    Parameters
    ----------
    profile : ``InF-SL``, ``InF-DL``, ``InF-SH`` or ``InF-DH`` (case-insensitive)
    size : ``"LxWxH"`` or (3,) float, m; default the TR 38.901 hall 120 x 60 x 10 m
    seed : int >= 0; the same arguments give the same hall (byte for byte once written)
    los_notes : write each point's LoS status into its note: per base station LoS, or the first
        object blocking the segment (:func:`raytrace.halls.spec.line_of_sight`, Embree)
    **options : the fields of :class:`InFOptions` (density, clutter_size, clutter_height,
        height_spread, bs_height, ut_height, bs_spacing, bs_grid, n_points, materials)

    Returns
    -------
    dict
        The hall spec (``schema_version, name, description, hall, objects, base_stations,
        points, area_of_interest``) plus ``"_inf"``: the resolved :class:`InFParams` as a dict
        and the achieved density (remove it, or use :func:`split_spec`, before YAML-dumping for
        ``build-hall``; :func:`hall_yaml` does).

    Raises
    ------
    HallrayError
        Unknown profile, bad size, density out of range for the profile, heights inconsistent
        with it, clutter that cannot be placed, points that cannot be placed.
    """
    p = resolve_params(profile, size, seed, **options)
    bs, footprints, heights, mats, pts = _layout(p)
    lx, ly, _ = p.size
    covered = (footprints[:, 2] - footprints[:, 0]) * (footprints[:, 3] - footprints[:, 1])
    achieved = float(np.sum(covered)) / (lx * ly)
    spec = _hall_mapping(p, achieved, bs, _clutter_objects(footprints, heights, mats), pts)
    hall = parse_hall_spec(spec)  # the generated hall must pass the schema's own validation
    if los_notes and hall.points and hall.base_stations:
        los = line_of_sight(hall, max_blockers=1)
        for entry in spec["points"]:
            entry["note"] = f"UT drop; {los_note(los[entry['name']])}"
    spec["_inf"] = {
        "generator_version": GENERATOR_VERSION,
        "params": p.to_dict(),
        "k_subsce_m": p.k_subsce_m,
        "achieved_density": achieved,
        "n_clutter": len(spec["objects"]),
    }
    return spec


def _clutter_objects(
    footprints: np.ndarray, heights: np.ndarray, mats: Sequence[str]
) -> list[dict[str, Any]]:
    """The clutter boxes as hall-spec objects ``clutter_0001, ...`` standing on the floor."""
    width = max(4, len(str(len(footprints))))
    return [
        {
            "name": f"clutter_{k + 1:0{width}d}",
            "type": "box",
            "material": mat,
            "min": [_r(fp[0]), _r(fp[1]), 0.0],
            "size": [_r(fp[2] - fp[0]), _r(fp[3] - fp[1]), _r(hgt)],
        }
        for k, (fp, hgt, mat) in enumerate(zip(footprints, heights, mats, strict=True))
    ]


def _hall_mapping(
    p: InFParams,
    achieved: float,
    bs: np.ndarray,
    objects: list[dict[str, Any]],
    pts: np.ndarray,
) -> dict[str, Any]:
    """The hall spec mapping (without the ``_inf`` block): name, description, shell, clutter,
    base stations ``BS1, ...``, points ``P01, ...`` and the area inside the wall aisle."""
    lx, ly, lz = p.size
    pw = max(2, len(str(len(pts))))
    dense = "dense" if p.dense else "sparse"
    high = "high" if p.high else "low"
    spec: dict[str, Any] = {
        "schema_version": 1,
        "name": f"{p.profile.lower()}-seed{p.seed}",
        "description": (
            f"3GPP TR 38.901 {p.profile} synthetic hall ({dense} clutter, {high} base stations), "
            f"seed {p.seed}: r = {achieved:.3f} (asked {p.density:g}), d_clutter = "
            f"{p.clutter_size:g} m, h_c = {p.clutter_height:g} m, h_BS = {p.bs_height:g} m, "
            f"h_UT = {p.ut_height:g} m; generated by raytrace.halls.inf v{GENERATOR_VERSION}"
        ),
        "hall": {"size": [_r(lx), _r(ly), _r(lz)], "material": "concrete", "wall_thickness": 0.3},
        "objects": objects,
        "base_stations": [
            {"name": f"BS{k + 1}", "xyz": [float(c) for c in xyz]} for k, xyz in enumerate(bs)
        ],
        "points": [
            {"name": f"P{k + 1:0{pw}d}", "xyz": [float(c) for c in xyz], "note": "UT drop"}
            for k, xyz in enumerate(pts)
        ],
    }
    if lx > 2 * WALL_AISLE_M and ly > 2 * WALL_AISLE_M:
        spec["area_of_interest"] = {
            "min": [_r(WALL_AISLE_M), _r(WALL_AISLE_M)],
            "max": [_r(lx - WALL_AISLE_M), _r(ly - WALL_AISLE_M)],
        }
    return spec


def split_spec(spec: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(hall spec without "_inf", the "_inf" block)`` of a :func:`generate_hall` result."""
    hall = {k: v for k, v in spec.items() if k != "_inf"}
    return hall, dict(spec.get("_inf", {}))


def hall_yaml(spec: Mapping[str, Any]) -> str:
    """The hall spec as YAML text (the ``_inf`` block left out), deterministic."""
    import yaml

    hall, info = split_spec(spec)
    params = info.get("params", {})
    head = "# synthetic indoor-factory hall (3GPP TR 38.901 InF), made by make-hall"
    if params:
        size = "x".join(f"{v:g}" for v in params["size"])
        head += f": --profile {params['profile']} --size {size} --seed {params['seed']}"
    body = yaml.safe_dump(hall, sort_keys=False, default_flow_style=None, width=100)
    return head + "\n" + body


# --------------------------------------------------------------------------------------------
# scene and LoS
# --------------------------------------------------------------------------------------------


def scene_from_spec(spec: HallSpec | Mapping[str, Any]) -> Scene:
    """The tracer's :class:`Scene` of a hall spec or of a :func:`generate_hall` mapping, built
    in memory (:func:`raytrace.halls.spec.tracer_scene`)."""
    hall = spec if isinstance(spec, HallSpec) else parse_hall_spec(split_spec(spec)[0])
    return tracer_scene(hall)


@dataclass
class LosSample:
    """Line-of-sight samples of one or more halls of one configuration.

    Attributes
    ----------
    d2d_m : (L,) float, horizontal BS-UT distance of each link, m
    los : (L,) bool, segment BS -> UT clear (Embree, :meth:`Scene.occluded`)
    k_3gpp_m : float, the 3GPP decay distance of the configuration, m
    label : str
    n_halls : int
    """

    d2d_m: np.ndarray
    los: np.ndarray
    k_3gpp_m: float
    label: str = ""
    n_halls: int = 1

    @property
    def n_links(self) -> int:
        return int(self.d2d_m.size)

    @property
    def los_fraction(self) -> float:
        return float(np.mean(self.los)) if self.los.size else math.nan

    @property
    def los_fraction_3gpp(self) -> float:
        """Expected fraction under TR 38.901 for the same distances."""
        return float(np.mean(los_probability_3gpp(self.d2d_m, self.k_3gpp_m)))

    def fit_k_m(self) -> float:
        """Maximum-likelihood k of ``P = exp(-d / k)`` for these samples, m (inf if all LoS,
        0 if none)."""
        return fit_decay_distance_m(self.d2d_m, self.los)

    def bins(self, width_m: float = 5.0) -> list[dict[str, float]]:
        """Per distance bin ``[lo, hi)``: links, LoS fraction (with its Wilson 95 % interval)
        and the 3GPP expectation (mean P_LOS over the bin's links)."""
        if self.d2d_m.size == 0:
            return []
        top = float(np.max(self.d2d_m))
        edges = np.arange(0.0, top + width_m, width_m)
        which = np.clip(np.digitize(self.d2d_m, edges) - 1, 0, len(edges) - 2)
        p3 = los_probability_3gpp(self.d2d_m, self.k_3gpp_m)
        rows = []
        for b in range(len(edges) - 1):
            sel = which == b
            n = int(sel.sum())
            if n == 0:
                continue
            k = int(self.los[sel].sum())
            lo, hi = wilson_interval(k, n)
            rows.append(
                {
                    "d_lo_m": float(edges[b]),
                    "d_hi_m": float(edges[b + 1]),
                    "n": n,
                    "n_los": k,
                    "los_fraction": k / n,
                    "ci_lo": lo,
                    "ci_hi": hi,
                    "p_los_3gpp": float(np.mean(p3[sel])),
                }
            )
        return rows

    def summary(self, width_m: float = 5.0) -> dict[str, Any]:
        k_fit = self.fit_k_m()
        return {
            "label": self.label,
            "n_halls": self.n_halls,
            "n_links": self.n_links,
            "los_fraction": self.los_fraction,
            "los_fraction_3gpp": self.los_fraction_3gpp,
            "k_3gpp_m": self.k_3gpp_m,
            "k_fit_m": k_fit,
            "bins": self.bins(width_m),
        }


def wilson_interval(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (95 % for the default z)."""
    if n == 0:
        return (math.nan, math.nan)
    phat = k / n
    den = 1.0 + z * z / n
    centre = (phat + z * z / (2 * n)) / den
    half = z * math.sqrt(phat * (1 - phat) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def fit_decay_distance_m(d2d_m: np.ndarray, los: np.ndarray) -> float:
    """Maximum-likelihood ``k`` of ``P(LoS | d) = exp(-d / k)`` from samples, m.

    The log-likelihood ``-sum_LoS d / k + sum_NLoS ln(1 - exp(-d / k))`` is concave in
    ``1 / k``; it is maximised on a bracket in ``log k``. Returns ``inf`` when every sample is
    LoS and ``0`` when none is.
    """
    from scipy.optimize import minimize_scalar

    d = np.asarray(d2d_m, dtype=float)
    y = np.asarray(los, dtype=bool)
    if d.size == 0:
        return math.nan
    if y.all():
        return math.inf
    if not y.any():
        return 0.0
    d = np.maximum(d, 1e-6)

    def nll(log_k: float) -> float:
        k = math.exp(log_k)
        return float(np.sum(d[y]) / k - np.sum(np.log(-np.expm1(-d[~y] / k))))

    res = minimize_scalar(
        nll, bounds=(math.log(1e-3), math.log(1e6)), method="bounded", options={"xatol": 1e-6}
    )
    return float(math.exp(res.x))


def los_sample(scene: Scene, hall: HallSpec, k_3gpp_m: float, label: str = "") -> LosSample:
    """LoS of every base station -> point link of a hall (Embree segment tests)."""
    bs = hall.base_station_xyz
    pts = hall.point_xyz
    o = np.repeat(bs, len(pts), axis=0)
    e = np.tile(pts, (len(bs), 1))
    los = ~scene.occluded(o, e)
    d2d = np.hypot(e[:, 0] - o[:, 0], e[:, 1] - o[:, 1])
    return LosSample(d2d, los, k_3gpp_m, label=label)


def merge_samples(samples: Sequence[LosSample], label: str = "") -> LosSample:
    """One sample from several halls of the same configuration (same k)."""
    if not samples:
        raise HallrayError("no LoS samples to merge")
    return LosSample(
        np.concatenate([s.d2d_m for s in samples]),
        np.concatenate([s.los for s in samples]),
        samples[0].k_3gpp_m,
        label=label or samples[0].label,
        n_halls=sum(s.n_halls for s in samples),
    )


def los_check(
    profile: str,
    seeds: Sequence[int] | int = 5,
    size: str | Sequence[float] | None = None,
    *,
    n_points: int = 200,
    **kwargs: Any,
) -> LosSample:
    """Generate one hall per seed and pool the LoS of all their BS -> point links.

    ``seeds`` is a list of seeds or a count (seeds 0 .. n-1). Other keyword arguments go to
    :func:`generate_hall`.
    """
    seed_list = list(range(seeds)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not seed_list:
        raise HallrayError("give at least one seed")
    samples = []
    for s in seed_list:
        spec = generate_hall(profile, size, s, n_points=n_points, los_notes=False, **kwargs)
        hall = parse_hall_spec(split_spec(spec)[0])
        samples.append(los_sample(scene_from_spec(hall), hall, spec["_inf"]["k_subsce_m"]))
    return merge_samples(samples, label=canonical_profile(profile))
