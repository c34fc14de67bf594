"""The InF hall generator: :func:`generate_hall` realises a 3GPP sub-scenario as a hall
description in the hall schema (docs/hall.md), from two random streams of the seed (the layout,
the points), and its YAML (:func:`hall_yaml`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..spec.los import line_of_sight, los_note
from ..spec.parse import parse_hall_spec
from .layout import bs_positions, place_clutter, place_points, round_coord
from .params import GENERATOR_VERSION, WALL_AISLE_M, InFParams, resolve_params


def _layout(
    p: InFParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Base stations, clutter footprints, heights, materials and points of a hall."""
    layout_ss, points_ss = np.random.SeedSequence(p.seed).spawn(2)
    rng_layout = np.random.default_rng(layout_ss)
    rng_points = np.random.default_rng(points_ss)
    bs = bs_positions(p)
    footprints, heights, mats = place_clutter(rng_layout, p, bs[:, :2])
    pts = place_points(rng_points, p, footprints, bs[:, :2])
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
            "min": [round_coord(fp[0]), round_coord(fp[1]), 0.0],
            "size": [round_coord(fp[2] - fp[0]), round_coord(fp[3] - fp[1]), round_coord(hgt)],
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
        "hall": {
            "size": [round_coord(lx), round_coord(ly), round_coord(lz)],
            "material": "concrete",
            "wall_thickness": 0.3,
        },
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
            "min": [round_coord(WALL_AISLE_M), round_coord(WALL_AISLE_M)],
            "max": [round_coord(lx - WALL_AISLE_M), round_coord(ly - WALL_AISLE_M)],
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
