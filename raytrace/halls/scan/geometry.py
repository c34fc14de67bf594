"""Geometry of the reconstruction: plane frames and fits, raster masks to polygons and their
cleaning, triangulation, sheets, slabs and upright boxes (with the recursive split of a cluster
a box fits poorly). Metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .options import MIN_OBJECT_THICKNESS_M, RECT_FILL, TIDY_GRID_M, ScanOptions


def plane_frame(n: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origin (3,) and in-plane axes u, v (3,) of the plane ``n . x = d``: u along x for a
    horizontal plane, v vertical for any other, so outlines of upright objects are aligned."""
    n = n / np.linalg.norm(n)
    if abs(n[2]) > 0.9:
        u = np.array([1.0, 0.0, 0.0]) - n[0] * n
    else:
        v = np.array([0.0, 0.0, 1.0]) - n[2] * n
        v /= np.linalg.norm(v)
        u = np.cross(v, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return n * d, u, v


def reframe(poly: Any, old: tuple[np.ndarray, float], new: tuple[np.ndarray, float]) -> Any:
    """A polygon traced in the frame of plane ``old`` = (n, d), projected onto plane ``new`` and
    expressed in its frame (after a refit the plane moves a little)."""
    import shapely

    o0, u0, v0 = plane_frame(*old)
    o1, u1, v1 = plane_frame(*new)

    def move(ab: np.ndarray) -> np.ndarray:
        x = o0 + ab[:, :1] * u0 + ab[:, 1:] * v0
        return np.column_stack([(x - o1) @ u1, (x - o1) @ v1])

    out = shapely.transform(poly, move)
    return out if out.is_valid else shapely.make_valid(out)


def fit_plane(pts: np.ndarray, n_hint: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal on the side of ``n_hint``, offset) through points."""
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[2]
    if n @ n_hint < 0:
        n = -n
    return n, float(n @ c)


def polygons_from_mask(mask: np.ndarray, lo: np.ndarray, cell: float) -> list[Any]:
    """Shapely polygons (with holes) of a boolean raster (rows along v, columns along u) whose
    cell (i, j) has its centre at ``lo + (j + 0.5, i + 0.5) * cell``: marching squares at 0.5,
    which runs along the outer boundary of the occupied cells."""
    import contourpy
    import shapely

    m = np.pad(mask, 1).astype(float)
    xs = lo[0] + (np.arange(m.shape[1]) - 0.5) * cell
    ys = lo[1] + (np.arange(m.shape[0]) - 0.5) * cell
    gen = contourpy.contour_generator(xs, ys, m, fill_type="OuterOffset", corner_mask=False)
    points, offsets = gen.filled(0.5, 2.0)
    polys = []
    for pts, off in zip(points, offsets):
        rings = [pts[off[k] : off[k + 1]] for k in range(len(off) - 1)]
        if not rings or len(rings[0]) < 4:
            continue
        poly = shapely.Polygon(rings[0], [r for r in rings[1:] if len(r) >= 4])
        if not poly.is_valid:
            poly = shapely.make_valid(poly)
        polys.extend(polygon_parts(poly))
    return polys


def polygon_parts(geom: Any) -> list[Any]:
    """The polygons of a shapely geometry (Polygon, MultiPolygon, collection)."""
    if geom is None or geom.is_empty:
        return []
    if geom.geom_type == "Polygon":
        return [geom]
    if hasattr(geom, "geoms"):
        return [p for g in geom.geoms for p in polygon_parts(g)]
    return []


def clean_polygon(poly: Any, *, fill_all: bool, max_hole_area: float, simplify: float) -> Any:
    """Fill holes (all, or those smaller than ``max_hole_area``), simplify, make valid."""
    import shapely

    holes = (
        [] if fill_all else [h for h in poly.interiors if shapely.Polygon(h).area > max_hole_area]
    )
    out = shapely.Polygon(poly.exterior, holes)
    if simplify > 0:
        out = out.simplify(simplify, preserve_topology=True)
    if not out.is_valid:
        out = shapely.make_valid(out)
    return out


def _tidy(poly: Any) -> Any:
    """A polygon ready to triangulate: vertices on a 0.1 mm grid, nearly collinear vertices
    (within 0.1 mm) removed, so that no sliver triangle (which the scene loader would drop as
    degenerate, opening a closed slab) comes out."""
    import shapely

    out = shapely.set_precision(poly, TIDY_GRID_M)
    out = out.simplify(TIDY_GRID_M, preserve_topology=True)
    parts = polygon_parts(out)
    return max(parts, key=lambda p: p.area) if parts else shapely.Polygon()


def rectangle_fit(poly: Any, cell: float) -> Any:
    """The polygon's rectangle when it is one (raster outlines zig-zag by a cell along straight
    edges): the minimum rotated rectangle of the polygon opened by 1.5 cells (spurs gone), if
    the polygon fills at least RECT_FILL of it; otherwise the polygon itself."""
    if len(poly.interiors):
        return poly
    opened = poly.buffer(-1.5 * cell, join_style="mitre").buffer(1.5 * cell, join_style="mitre")
    if opened.is_empty or opened.geom_type != "Polygon":
        return poly
    rect = opened.minimum_rotated_rectangle
    if rect.geom_type != "Polygon" or poly.area < RECT_FILL * rect.area:
        return poly
    return rect


def _triangulate(poly: Any) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay triangulation of a polygon (with holes): vertices (V, 2) and
    counter-clockwise faces (F, 3), vertices shared (exactly the polygon's vertices)."""
    import shapely

    tris = shapely.constrained_delaunay_triangles(poly)
    coords = [np.asarray(t.exterior.coords)[:3] for t in polygon_parts(tris)]
    if not coords:
        return np.zeros((0, 2)), np.zeros((0, 3), dtype=np.int64)
    c = np.stack(coords)  # (F, 3, 2)
    verts, inv = np.unique(c.reshape(-1, 2), axis=0, return_inverse=True)
    faces = inv.reshape(-1, 3).astype(np.int64)
    # counter-clockwise in (u, v): the face normal is +n
    e1 = verts[faces[:, 1]] - verts[faces[:, 0]]
    e2 = verts[faces[:, 2]] - verts[faces[:, 0]]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    faces[cw] = faces[cw][:, ::-1]
    return verts, faces


def sheet_mesh(poly: Any, origin: np.ndarray, u: np.ndarray, v: np.ndarray) -> Any:
    """An open, flat mesh of a polygon lying in the plane (origin, u, v)."""
    import trimesh

    v2, f = _triangulate(_tidy(poly))
    v3 = origin + v2[:, :1] * u + v2[:, 1:] * v
    return trimesh.Trimesh(v3, f, process=True)


def slab_mesh(poly: Any, origin: np.ndarray, u: np.ndarray, v: np.ndarray, t: np.ndarray) -> Any:
    """A closed slab: the polygon in the plane (origin, u, v) extruded by the vector ``t``."""
    import trimesh

    poly = _tidy(poly)
    v2, f = _triangulate(poly)
    top = origin + v2[:, :1] * u + v2[:, 1:] * v
    nv = len(v2)
    faces = [f[:, ::-1], f + nv]  # base faces away from t, the far cap towards t (fixed below)
    lookup = {tuple(p): i for i, p in enumerate(v2)}
    rings = [poly.exterior, *poly.interiors]
    for ring in rings:
        rc = np.asarray(ring.coords)[:-1]
        idx = np.array([lookup[tuple(p)] for p in rc])
        a, b = idx, np.roll(idx, -1)
        faces.append(np.column_stack([a, b, b + nv]))
        faces.append(np.column_stack([a, b + nv, a + nv]))
    mesh = trimesh.Trimesh(np.vstack([top, top + t]), np.vstack(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def half_plane(g: np.ndarray, c0: float, bounds: tuple[float, float, float, float]) -> Any:
    """The half-plane ``g . x + c0 >= 0`` clipped to a generous square around ``bounds``."""
    import shapely

    x0, y0, x1, y1 = bounds
    size = 10.0 * max(x1 - x0, y1 - y0, 1.0) + 100.0
    gn = g / np.linalg.norm(g)
    p0 = -c0 * g / (g @ g)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    p0 = p0 + (centre - p0) - ((centre - p0) @ gn) * gn  # foot of the centre on the line
    tdir = np.array([-gn[1], gn[0]])
    corners = [
        p0 - size * tdir,
        p0 + size * tdir,
        p0 + size * tdir + size * gn,
        p0 - size * tdir + size * gn,
    ]
    return shapely.Polygon(corners)


def _box_mesh(rect_xy: np.ndarray, z0: float, z1: float) -> Any:
    """Closed upright box over a rectangle (4, 2) from z0 to z1."""
    import trimesh

    v = np.vstack(
        [np.column_stack([rect_xy, np.full(4, z0)]), np.column_stack([rect_xy, np.full(4, z1)])]
    )
    f = np.array(
        [
            [0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7],
            [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
            [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7],
        ]
    )  # fmt: skip
    mesh = trimesh.Trimesh(v, f, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def _upright_box(pts: np.ndarray, min_thickness: float) -> tuple[np.ndarray, float, float]:
    """Minimum-area rectangle of the points seen from above (4, 2), grown to ``min_thickness``,
    and the z range."""
    import shapely

    z0, z1 = float(pts[:, 2].min()), float(pts[:, 2].max())
    if z1 - z0 < min_thickness:
        zc = 0.5 * (z0 + z1)
        z0, z1 = zc - 0.5 * min_thickness, zc + 0.5 * min_thickness
    hull = shapely.MultiPoint(pts[:, :2]).convex_hull
    rect = hull.minimum_rotated_rectangle if hull.geom_type == "Polygon" else None
    if rect is None or rect.geom_type != "Polygon":
        # collinear or a single point: a thin rectangle along the points' main direction
        xy = pts[:, :2]
        c = xy.mean(axis=0)
        d = xy - c
        if np.allclose(d, 0):
            axis = np.array([1.0, 0.0])
        else:
            axis = np.linalg.svd(d, full_matrices=False)[2][0]
        s = d @ axis
        lo_, hi_ = min(s.min(), -0.5 * min_thickness), max(s.max(), 0.5 * min_thickness)
        perp = np.array([-axis[1], axis[0]]) * 0.5 * min_thickness
        corners = np.array(
            [
                c + lo_ * axis - perp,
                c + hi_ * axis - perp,
                c + hi_ * axis + perp,
                c + lo_ * axis + perp,
            ]
        )
        return corners, z0, z1
    corners = np.asarray(rect.exterior.coords)[:4]
    # grow thin sides to min_thickness
    e1, e2 = corners[1] - corners[0], corners[3] - corners[0]
    c = corners.mean(axis=0)
    out = []
    l1, l2 = np.linalg.norm(e1), np.linalg.norm(e2)
    a1 = e1 / l1 * max(l1, min_thickness) / 2
    a2 = e2 / l2 * max(l2, min_thickness) / 2
    for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        out.append(c + s1 * a1 + s2 * a2)
    return np.array(out), z0, z1


def _fit_box_sides(
    pts: np.ndarray, rect: np.ndarray, noise: float, thick: float
) -> tuple[np.ndarray, float, float]:
    """An upright box in the frame of ``rect`` (4, 2) with each side at the median of the points
    within four noise deviations of the outermost one: on a scanned face that is the face
    itself (the outermost points lie about two deviations beyond it), at an edge seen only
    from one side about the edge. Returns the footprint (4, 2) and the z range, no side
    shorter than ``thick``."""
    c = rect.mean(axis=0)
    e1, e2 = rect[1] - rect[0], rect[3] - rect[0]
    a1, a2 = e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)
    coords = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2, pts[:, 2]])
    band = 4.0 * max(noise, 0.005)
    lo, hi = np.empty(3), np.empty(3)
    for k in range(3):
        x = coords[:, k]
        lo[k] = np.median(x[x < x.min() + band])
        hi[k] = np.median(x[x > x.max() - band])
        if hi[k] - lo[k] < thick:
            mid = 0.5 * (lo[k] + hi[k])
            lo[k], hi[k] = mid - 0.5 * thick, mid + 0.5 * thick
    corners = [c + lo[0] * a1 + lo[1] * a2, c + hi[0] * a1 + lo[1] * a2]
    corners += [c + hi[0] * a1 + hi[1] * a2, c + lo[0] * a1 + hi[1] * a2]
    return np.array(corners), float(lo[2]), float(hi[2])


def _height_fill(
    pts: np.ndarray, frame: tuple[np.ndarray, np.ndarray, np.ndarray], cell: float
) -> float:
    """How much of an upright box the points explain: the volume under their height map (the
    highest point per footprint cell) over the box volume. ``frame`` is (centre (2,), axis a1
    (2,), axis a2 (2,)) of the box footprint. Cells without points count as empty, also when
    enclosed: a fence around a robot cell is not a solid block (a cabinet seen only from its
    sides comes out as its sides, which block the same rays)."""
    c, a1, a2 = frame
    st = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2])
    z0, z1 = pts[:, 2].min(), pts[:, 2].max()
    lo = st.min(axis=0)
    ij = np.floor((st - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), pts[:, 2])
    height = np.where(np.isfinite(top), top, z0) - z0
    extent = (st.max(axis=0) - lo).clip(min=cell)
    box = extent[0] * extent[1] * max(z1 - z0, cell)
    return float(min(1.0, height.sum() * cell * cell / box))


def box_decomposition(
    pts: np.ndarray, opt: ScanOptions, noise: float, depth: int = 0
) -> list[tuple[Any, int]]:
    """Upright boxes for a cluster: one box, or, when it explains the points poorly (a height-map
    fill below ``box_fill``), the cluster cut in two where the two child boxes are smallest
    (along either footprint axis or in height), recursively up to ``max_box_depth`` levels.
    Returns (box mesh, number of points) pairs; sibling boxes do not overlap."""
    thick = max(MIN_OBJECT_THICKNESS_M, 0.5 * opt.voxel_size_m)
    rect, z0, z1 = _upright_box(pts, thick)
    whole = [(_box_mesh(*_fit_box_sides(pts, rect, noise, thick)), len(pts))]
    if depth >= opt.max_box_depth or len(pts) < 2 * opt.object_min_points:
        return whole
    c = rect.mean(axis=0)
    e1, e2 = rect[1] - rect[0], rect[3] - rect[0]
    a1, a2 = e1 / np.linalg.norm(e1), e2 / np.linalg.norm(e2)
    if _height_fill(pts, (c, a1, a2), float(opt.grid_cell_m)) >= opt.box_fill:
        return whole
    coords = np.column_stack([(pts[:, :2] - c) @ a1, (pts[:, :2] - c) @ a2, pts[:, 2]])
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    parent = float(np.prod((hi - lo).clip(min=thick)))
    best: tuple[float, np.ndarray] | None = None
    for axis in range(3):
        for q in np.linspace(0.0, 1.0, 18)[1:-1]:
            left = coords[:, axis] < lo[axis] + q * (hi[axis] - lo[axis])
            n_left = int(left.sum())
            if min(n_left, len(pts) - n_left) < opt.object_min_points:
                continue
            vol = 0.0
            for side in (left, ~left):
                sub = coords[side]
                vol += float(np.prod((sub.max(axis=0) - sub.min(axis=0)).clip(min=thick)))
            if best is None or vol < best[0]:
                best = (vol, left)
    if best is None or best[0] > 0.9 * parent:
        return whole
    left = best[1]
    return box_decomposition(pts[left], opt, noise, depth + 1) + box_decomposition(
        pts[~left], opt, noise, depth + 1
    )
