"""Steps 3-4 of the reconstruction: RANSAC planes, largest first, split into connected
pieces with their traced outlines (:func:`find_planes`), then slabs (bounding planes, closed,
extended to meet each other) and sheets (:func:`plane_elements`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.errors import HallrayError
from .element import Element
from .geometry import (
    clean_polygon,
    fit_plane,
    half_plane,
    plane_frame,
    polygon_parts,
    polygons_from_mask,
    rectangle_fit,
    reframe,
    sheet_mesh,
    slab_mesh,
)
from .options import (
    BOUNDING_OUTSIDE_FRACTION,
    EDGE_MIN_COS,
    MAX_GRID_CELLS,
    MAX_PLANE_MISSES,
    ORIENTATION_TOL_DEG,
    ScanOptions,
)


@dataclass
class PlanePiece:
    """A connected piece of one RANSAC plane ``n . x = d`` (unit normal towards the points, m):
    its outlines in the plane frame of :func:`plane_frame`, the indices of its points and
    whether every point of the cloud is on one side of it (floor, ceiling, outer walls)."""

    n: np.ndarray
    d: float
    polygons: list[Any]  # in the plane frame (u, v)
    members: np.ndarray  # point indices
    bounding: bool


def find_planes(pts: np.ndarray, nrm: np.ndarray, opt: ScanOptions, o3d: Any) -> list[PlanePiece]:
    """RANSAC planes, largest first, split into connected pieces (see the module docstring)."""
    rng = np.random.default_rng(opt.seed)
    o3d.utility.random.seed(int(opt.seed))
    pool = np.ones(len(pts), dtype=bool)
    pieces: list[PlanePiece] = []
    misses = 0
    n_planes = 0
    while n_planes < opt.max_planes and misses < MAX_PLANE_MISSES:
        idx = np.flatnonzero(pool)
        if len(idx) < opt.plane_min_points:
            break
        plane = _ransac_plane(pts, nrm, idx, opt, o3d, rng)
        if plane is None:
            break
        n, d, members, tried = plane
        if len(members) < opt.plane_min_points:
            # too small: take these points out of the search (they stay in the residual)
            pool[members] = False
            pool[tried] = False
            misses += 1
            continue
        pool[members] = False
        found = _split_plane(pts, nrm, members, n, d, opt)
        if not found:
            misses += 1
            continue
        misses = 0
        n_planes += 1
        pieces += _plane_pieces(pts, nrm, pool, (n, d), found, opt)
    # largest first (total polygon area)
    pieces.sort(key=lambda p: -sum(q.area for q in p.polygons))
    return pieces


def _ransac_plane(
    pts: np.ndarray,
    nrm: np.ndarray,
    idx: np.ndarray,
    opt: ScanOptions,
    o3d: Any,
    rng: np.random.Generator,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray] | None:
    """One RANSAC plane among the points ``idx`` still free: ``(n, d, members, tried)`` with
    the unit normal and offset of ``n . x = d`` after a least-squares refit, its inliers by
    distance and normal agreement, and RANSAC's own inliers (to take out of the search when the
    plane is too small); None when RANSAC returns no plane."""
    cos_tol = math.cos(math.radians(opt.plane_normal_deg))
    # RANSAC among the points whose normals share the pool's dominant orientation: a plane
    # then cannot collect inliers from the strips where it slices perpendicular surfaces
    pts_p, nrm_p = pts[idx], nrm[idx]
    cand = idx[np.abs(nrm_p @ _dominant_direction(nrm_p, cos_tol, rng)) >= cos_tol]
    if len(cand) < opt.plane_min_points:
        cand = idx
    if len(cand) > opt.ransac_sample:
        cand = np.unique(cand[rng.integers(0, len(cand), opt.ransac_sample)])
    sub_pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[cand]))
    model, ransac_inliers = sub_pcd.segment_plane(opt.plane_distance_m, 3, opt.ransac_iterations)
    n = np.asarray(model[:3], dtype=float)
    scale = np.linalg.norm(n)
    if not np.isfinite(scale) or scale == 0:
        return None
    n, d = n / scale, -float(model[3]) / scale
    members = idx
    for _ in range(2):  # inliers by distance and normal, then a least-squares refit
        near = np.abs(pts_p @ n - d) < opt.plane_distance_m
        near &= np.abs(nrm_p @ n) >= cos_tol
        members = idx[near]
        if len(members) < opt.plane_min_points:
            break
        n, d = fit_plane(pts[members], n)
    return n, d, members, cand[np.asarray(ransac_inliers, dtype=np.int64)]


def _plane_pieces(
    pts: np.ndarray,
    nrm: np.ndarray,
    pool: np.ndarray,
    traced: tuple[np.ndarray, float],
    found: list[tuple[np.ndarray, list[Any]]],
    opt: ScanOptions,
) -> list[PlanePiece]:
    """The pieces of one plane ``traced`` = (n, d) (the frame its outlines were traced in):
    oriented towards the bulk of the points, refitted, joined by their noise tail; one piece
    for a bounding plane. Takes their points out of ``pool`` (updated in place)."""
    cos_tol = math.cos(math.radians(opt.plane_normal_deg))
    n, d = traced
    # orient towards the bulk of the points; bounding if almost nothing lies beyond
    side = pts @ n - d
    if np.count_nonzero(side > 0) < np.count_nonzero(side < 0):
        n, d, side = -n, -d, -side
    outside = np.count_nonzero(side < -3.0 * opt.plane_distance_m)
    bounding = outside <= BOUNDING_OUTSIDE_FRACTION * len(pts)
    # the noise tail beyond the inlier distance (within twice it, over the piece) belongs
    # to the plane too: left alone it would make a ghost plane or flat objects beside it
    tail = np.flatnonzero(pool)
    tail = tail[np.abs(pts[tail] @ traced[0] - traced[1]) < 2.0 * opt.plane_distance_m]
    tail = tail[np.abs(nrm[tail] @ traced[0]) >= cos_tol]
    tails = [_inside_polygons(pts[tail], traced, ps, opt.grid_cell_m) for _, ps in found]
    if bounding:
        mem = np.concatenate([m for m, _ in found])
        n_b, d_b = fit_plane(pts[mem], n)
        polys = [reframe(p, traced, (n_b, d_b)) for _, ps in found for p in ps]
        mem = np.union1d(mem, tail[np.logical_or.reduce(tails)])
        pool[mem] = False
        return [PlanePiece(n_b, d_b, polys, mem, True)]
    out = []
    for (mem, polys), in_tail in zip(found, tails):
        n_p, d_p = fit_plane(pts[mem], n)
        polys = [reframe(p, traced, (n_p, d_p)) for p in polys]
        mem = np.union1d(mem, tail[in_tail])
        pool[mem] = False
        out.append(PlanePiece(n_p, d_p, polys, mem, False))
    return out


def _inside_polygons(
    pts: np.ndarray, plane: tuple[np.ndarray, float], polys: Sequence[Any], grow: float
) -> np.ndarray:
    """(n,) bool, points whose projection on the plane (n, d) falls in the polygons (in the
    plane's frame) grown by ``grow`` m."""
    import shapely

    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    origin, u, v = plane_frame(*plane)
    region = shapely.unary_union(list(polys)).buffer(grow, join_style="mitre")
    rel = pts - origin
    return np.asarray(shapely.contains_xy(region, rel @ u, rel @ v), dtype=bool)


def _dominant_direction(
    normals: np.ndarray, cos_tol: float, rng: np.random.Generator
) -> np.ndarray:
    """The unit direction (up to sign) shared by the most normals within ``acos(cos_tol)``,
    among 64 of the normals themselves, scored on at most 20 000 of them."""
    m = normals[rng.integers(0, len(normals), min(len(normals), 20_000))]
    cand = m[rng.integers(0, len(m), 64)]
    score = (np.abs(m @ cand.T) >= cos_tol).sum(axis=0)
    return cand[int(np.argmax(score))]


def _split_plane(
    pts: np.ndarray,
    nrm: np.ndarray,
    members: np.ndarray,
    n: np.ndarray,
    d: float,
    opt: ScanOptions,
) -> list[tuple[np.ndarray, list[Any]]]:
    """Connected pieces (>= min area) of a plane's inliers: (point indices, outline polygons in
    the frame of (n, d)). Rasterise at ``grid_cell_m``, close gaps, label 8-connected pieces,
    trace the outlines along the cells' boundary and pull them in by the expected overshoot
    (half a cell, less half the point spacing, plus the points' noise: their RMS distance to
    the plane)."""
    from scipy import ndimage

    noise = min(float(np.sqrt(np.mean((pts[members] @ n - d) ** 2))), 0.5 * opt.plane_distance_m)
    cell = float(opt.grid_cell_m)
    grid, ij, lo = _plane_raster(pts, nrm, members, n, d, opt)
    labels, n_lab = ndimage.label(grid, structure=np.ones((3, 3), dtype=bool))
    if n_lab == 0:
        return []
    counts = np.bincount(labels.ravel(), minlength=n_lab + 1)
    min_cells = max(opt.plane_min_area_m2 / cell**2, 1.0)
    point_label = labels[ij[:, 1], ij[:, 0]]
    out = []
    slices = ndimage.find_objects(labels)
    for k in range(1, n_lab + 1):
        if counts[k] < min_cells:
            continue
        sl = slices[k - 1]
        sub_lo = lo + np.array([sl[1].start, sl[0].start]) * cell
        # the outline runs on average half a cell beyond the outermost points, which lie half a
        # point spacing inside the true edge plus about one noise deviation outside it
        spacing = math.sqrt(counts[k] * cell * cell / max(np.count_nonzero(point_label == k), 1))
        shrink = noise + 0.5 * max(0.0, cell - spacing)
        polys = _piece_outlines(labels[sl] == k, sub_lo, shrink, opt)
        if polys and sum(p.area for p in polys) >= opt.plane_min_area_m2:
            out.append((members[point_label == k], polys))
    return out


def _plane_raster(
    pts: np.ndarray,
    nrm: np.ndarray,
    members: np.ndarray,
    n: np.ndarray,
    d: float,
    opt: ScanOptions,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The occupancy raster of a plane's inliers in its frame (rows along v, columns along u,
    cells of ``grid_cell_m``): the inliers' cells, the edge band (below) and gaps closed.
    Returns the raster, the inliers' cells (m, 2) as (column, row), and the (u, v) of the
    raster's corner, m."""
    from scipy import ndimage

    origin, u, v = plane_frame(n, d)
    rel = pts[members] - origin
    uv = np.column_stack([rel @ u, rel @ v])
    cell = float(opt.grid_cell_m)
    r = int(math.ceil(opt.close_gaps_m / (2.0 * cell)))
    r_edge = int(math.ceil(float(opt.normal_radius_m) / cell))
    pad = r + r_edge + 2
    lo = uv.min(axis=0) - pad * cell
    ij = np.floor((uv - lo) / cell).astype(np.int64)
    shape = (int(ij[:, 1].max()) + pad + 1, int(ij[:, 0].max()) + pad + 1)
    if shape[0] * shape[1] > MAX_GRID_CELLS:
        raise HallrayError(
            f"a plane of {shape[1] * cell:.0f} m x {shape[0] * cell:.0f} m is too large for "
            f"outline cells of {cell} m; are the coordinates in metres? (else use a larger voxel)"
        )
    grid = np.zeros(shape, dtype=bool)
    grid[ij[:, 1], ij[:, 0]] = True
    # near the edges the normals are blurred (they mix both faces), so the normal test leaves a
    # band of about one normal radius out: there, points near the plane count unless their
    # normals are clean perpendicular ones (a floor running past the foot of a face), which
    # brings the outline out to the true edge
    near = np.flatnonzero(
        (np.abs(pts @ n - d) < opt.plane_distance_m) & (np.abs(nrm @ n) >= EDGE_MIN_COS)
    )
    rel_n = pts[near] - origin
    ij_n = np.floor((np.column_stack([rel_n @ u, rel_n @ v]) - lo) / cell).astype(np.int64)
    ok = (ij_n >= 0).all(axis=1) & (ij_n[:, 1] < shape[0]) & (ij_n[:, 0] < shape[1])
    edge = np.zeros(shape, dtype=bool)
    edge[ij_n[ok, 1], ij_n[ok, 0]] = True
    yy, xx = np.mgrid[-r_edge : r_edge + 1, -r_edge : r_edge + 1]
    grid |= edge & ndimage.binary_dilation(grid, structure=xx**2 + yy**2 <= r_edge * r_edge)
    if r > 0:
        yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
        grid = ndimage.binary_closing(grid, structure=xx**2 + yy**2 <= r * r)
    return grid, ij, lo


def _piece_outlines(mask: np.ndarray, lo: np.ndarray, shrink: float, opt: ScanOptions) -> list:
    """Outline polygons of one connected piece of a plane raster (corner ``lo`` (2,) m): traced,
    small holes filled, simplified, snapped to a rectangle when it is one, pulled in by
    ``shrink`` m; parts under a quarter of the smallest plane area dropped."""
    cell = float(opt.grid_cell_m)
    polys = []
    for poly in polygons_from_mask(mask, lo, cell):
        poly = clean_polygon(
            poly, fill_all=False, max_hole_area=opt.max_hole_area_m2, simplify=opt.simplify_m
        )
        poly = rectangle_fit(poly, cell)
        shrunk = poly.buffer(-shrink, join_style="mitre")
        polys.extend(q for q in polygon_parts(shrunk) if q.area >= 0.25 * opt.plane_min_area_m2)
    return polys


def plane_elements(pieces: list[PlanePiece], pts: np.ndarray, opt: ScanOptions) -> list[Element]:
    """Elements of the plane pieces: bounding planes closed, grown, cut where they meet and
    extruded outward; the others open sheets."""
    elements = []
    for i, piece in enumerate(pieces):
        frame = plane_frame(piece.n, piece.d)
        if piece.bounding:
            polys = _bounding_polygons(pieces, i, opt)
        else:
            polys = piece.polygons
        counts = _points_per_polygon(pts[piece.members], (piece.n, piece.d), polys)
        for poly, count in zip(polys, counts):
            if piece.bounding and opt.wall_thickness_m > 0:
                mesh = slab_mesh(poly, *frame, -opt.wall_thickness_m * piece.n)
                closed = True
            else:
                mesh = sheet_mesh(poly, *frame)
                closed = False
            if len(mesh.faces):
                elements.append(
                    Element(
                        "plane", mesh, closed, count, piece.n, piece.d,
                        piece.bounding, poly.area, poly, frame,
                    )
                )  # fmt: skip
    return elements


def _bounding_polygons(pieces: list[PlanePiece], i: int, opt: ScanOptions) -> list[Any]:
    """The outline of bounding plane ``i`` in its frame: holes filled (unseen floor under
    machines), grown by ``snap_m``, cut where the other bounding planes meet it, unseen strips
    along it filled; its polygons (no holes) of at least a quarter of the smallest plane area."""
    import shapely

    piece = pieces[i]
    origin, u, v = plane_frame(piece.n, piece.d)
    tol = math.sin(math.radians(ORIENTATION_TOL_DEG))
    seen = shapely.unary_union(
        [
            clean_polygon(p, fill_all=True, max_hole_area=0.0, simplify=opt.simplify_m)
            for p in piece.polygons
        ]
    )
    grown = seen.buffer(opt.snap_m, join_style="mitre")
    region = shapely.box(*grown.bounds)
    horizontal_i = abs(piece.n[2]) > 0.5
    for j, other in enumerate(pieces):
        if j == i or not other.bounding:
            continue
        g = np.array([other.n @ u, other.n @ v])
        if np.linalg.norm(g) < tol:
            continue  # parallel
        # which one runs through the joint: horizontal planes pass under/over vertical ones,
        # between two vertical planes the earlier (larger) one
        horizontal_j = abs(other.n[2]) > 0.5
        through = horizontal_i if horizontal_i != horizontal_j else i < j
        d_cut = other.d - (opt.wall_thickness_m if through else 0.0)
        c0 = float(other.n @ origin - d_cut)
        region = region.intersection(half_plane(g, c0, region.bounds))
    geom = grown.intersection(region)
    # strips the scanner could not see (floor under racks along a wall, a wall behind
    # them): parts of the region left uncovered in which no disc of radius hidden_fill_m fits
    missing = polygon_parts(region.difference(geom))
    hidden = [m for m in missing if m.buffer(-opt.hidden_fill_m).is_empty]
    if hidden:
        geom = shapely.unary_union([geom, *hidden])
    geom = geom.simplify(opt.simplify_m, preserve_topology=True)
    return [
        shapely.Polygon(p.exterior)  # no holes in a bounding plane
        for p in polygon_parts(geom)
        if p.area >= 0.25 * opt.plane_min_area_m2
    ]


def _points_per_polygon(
    pts: np.ndarray, plane: tuple[np.ndarray, float], polys: Sequence[Any]
) -> list[int]:
    """How many of a piece's points each of its polygons explains (the nearest polygon in the
    plane; all of them when there is one polygon)."""
    import shapely

    if len(polys) <= 1:
        return [len(pts)] * len(polys)
    origin, u, v = plane_frame(*plane)
    rel = pts - origin
    xy = shapely.points(rel @ u, rel @ v)
    dist = np.stack([shapely.distance(p, xy) for p in polys])
    return np.bincount(np.argmin(dist, axis=0), minlength=len(polys)).tolist()
