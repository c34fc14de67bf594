"""The parameters of an InF hall: the four 3GPP sub-scenarios (sparse or dense clutter, low
or high base stations) and their evaluation values, the options of a generated hall resolved
and checked (:func:`resolve_params`), and the 3GPP LoS probability they imply
(:func:`los_probability_3gpp`, TR 38.901 Table 7.4.2-1). Lengths in metres.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from hallray.errors import brief
from hallray.limits import check_size

from ...core.errors import HallrayError
from ...core.scale import check_extent
from ..spec.model import ITU_MATERIALS

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


def canonical_profile(profile: str) -> str:
    """``"inf-sl"`` -> ``"InF-SL"``; raises :class:`HallrayError` for an unknown profile."""
    if isinstance(profile, str):
        for name in PROFILES:
            if profile.strip().lower() == name.lower():
                return name
    raise HallrayError(f"unknown profile {brief(profile)}; choose one of {', '.join(PROFILES)}")


def parse_size(text: str | Sequence[float]) -> tuple[float, float, float]:
    """``"42x46x8.8"`` (or a 3-sequence) -> ``(L, W, D)`` in m, all finite and positive."""
    if isinstance(text, str):
        parts = text.lower().replace(" ", "").split("x")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = []
        if len(vals) != 3:
            raise HallrayError(f"bad size {brief(text)}: expected LxWxH in metres, e.g. 42x46x8.8")
    else:
        try:
            vals = [float(v) for v in text]
        except (TypeError, ValueError):
            raise HallrayError(f"bad size {brief(text)}: expected [L, W, H] in metres") from None
        if len(vals) != 3:
            raise HallrayError(f"bad size {brief(text)}: expected [L, W, H] in metres")
    if not all(math.isfinite(v) and v > 0 for v in vals):
        raise HallrayError(f"bad size {brief(text)}: every dimension must be a positive number of m")
    check_extent(vals, f"hall size {brief(text) if isinstance(text, str) else list(vals)}")
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
        raise HallrayError(f"seed must be a non-negative integer, got {brief(seed)}")
    r = _density(name, dense, _number(name, opt.density, "clutter density", defaults["density"]))
    d_c = _number(name, opt.clutter_size, "clutter size", defaults["clutter_size"])
    if d_c <= 0:
        raise HallrayError(f"{name}: clutter size must be > 0 m, got {d_c:g}")
    h_ut, h_c, spread, h_bs = _heights(name, high, lz, opt, defaults["clutter_height"])
    grid = _bs_grid(name, lx, ly, opt)
    n_points = opt.n_points
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 0:
        raise HallrayError(f"{name}: number of points must be an integer >= 0, got {brief(n_points)}")
    # the size limits, before any layout work
    check_size("points", int(n_points), f"{name}: {int(n_points)} points")
    check_size("base stations", float(grid[0]) * float(grid[1]), f"{name}: base-station grid {grid[0]}x{grid[1]}")
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
        raise HallrayError(f"{name}: {what} must be a number, got {brief(v)}")
    v = float(v)
    if not math.isfinite(v):
        raise HallrayError(f"{name}: {what} must be finite, got {brief(v)}")
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
        raise HallrayError(f"{name}: bs_grid must be two integers >= 1, got {brief(opt.bs_grid)}")
    return (int(grid[0]), int(grid[1]))


def _clutter_materials(name: str, materials: Mapping[str, float] | None) -> dict[str, float]:
    """ITU material -> probability (the weights normalised)."""
    mats = dict(DEFAULT_MATERIALS if materials is None else materials)
    if not mats:
        raise HallrayError(f"{name}: give at least one clutter material")
    for m, w in mats.items():
        if m not in ITU_MATERIALS:
            raise HallrayError(
                f"{name}: unknown clutter material {brief(m)} (ITU-R P.2040: {', '.join(ITU_MATERIALS)})"
            )
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not w >= 0:
            raise HallrayError(f"{name}: weight of material {brief(m)} must be >= 0, got {brief(w)}")
    total = float(sum(mats.values()))
    if total <= 0:
        raise HallrayError(f"{name}: clutter material weights sum to zero")
    return {m: float(w) / total for m, w in mats.items()}


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
