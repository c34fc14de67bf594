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

Modules: :mod:`.params` (sub-scenarios, options, the 3GPP LoS probability), :mod:`.layout`
(base stations, clutter, points), :mod:`.generator` (:func:`generate_hall`, the YAML),
:mod:`.los` (the LoS check).
"""

from .generator import check_hall, generate_hall, hall_yaml, split_spec
from .layout import bs_positions, place_clutter, place_points, round_coord
from .los import (
    LosSample,
    fit_decay_distance_m,
    los_check,
    los_sample,
    merge_samples,
    scene_from_spec,
    wilson_interval,
)
from .params import (
    BS_CLEARANCE_M,
    BS_SPACING_M,
    CEILING_CLEARANCE_M,
    CELL_SIZE_RANGE,
    DEFAULT_MATERIALS,
    DEFAULT_POINTS,
    DEFAULT_SIZE_M,
    DENSE_DEFAULTS,
    DENSE_THRESHOLD,
    DENSITY_TOL,
    GAP_FRACTION,
    GENERATOR_VERSION,
    HIGH_BS_HEIGHT_M,
    LOW_BS_HEIGHT_M,
    MAX_GAP_M,
    MIN_BOX_SIDE_FRACTION,
    POINT_BS_CLEARANCE_M,
    POINT_CLUTTER_CLEARANCE_M,
    POINT_WALL_CLEARANCE_M,
    PROFILES,
    ROUND_DECIMALS,
    SPARSE_DEFAULTS,
    UT_HEIGHT_M,
    WALL_AISLE_M,
    InFOptions,
    InFParams,
    canonical_profile,
    los_decay_distance_m,
    los_probability_3gpp,
    parse_size,
    resolve_params,
)

__all__ = [
    "BS_CLEARANCE_M",
    "BS_SPACING_M",
    "CEILING_CLEARANCE_M",
    "CELL_SIZE_RANGE",
    "DEFAULT_MATERIALS",
    "DEFAULT_POINTS",
    "DEFAULT_SIZE_M",
    "DENSE_DEFAULTS",
    "DENSE_THRESHOLD",
    "DENSITY_TOL",
    "GAP_FRACTION",
    "GENERATOR_VERSION",
    "HIGH_BS_HEIGHT_M",
    "LOW_BS_HEIGHT_M",
    "MAX_GAP_M",
    "MIN_BOX_SIDE_FRACTION",
    "POINT_BS_CLEARANCE_M",
    "POINT_CLUTTER_CLEARANCE_M",
    "POINT_WALL_CLEARANCE_M",
    "PROFILES",
    "ROUND_DECIMALS",
    "SPARSE_DEFAULTS",
    "UT_HEIGHT_M",
    "WALL_AISLE_M",
    "InFOptions",
    "InFParams",
    "LosSample",
    "bs_positions",
    "canonical_profile",
    "check_hall",
    "fit_decay_distance_m",
    "generate_hall",
    "hall_yaml",
    "los_check",
    "los_decay_distance_m",
    "los_probability_3gpp",
    "los_sample",
    "merge_samples",
    "parse_size",
    "place_clutter",
    "place_points",
    "resolve_params",
    "round_coord",
    "scene_from_spec",
    "split_spec",
    "wilson_interval",
]
