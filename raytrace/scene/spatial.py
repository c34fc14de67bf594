"""A bounding-volume hierarchy over spheres and boxes, for the pairwise relations of a scene.

Every pairwise relation the tracer needs between scene elements (which facets of another object
may cover an edge, which facets a reflection through a facet can reach, which edges a reflection
can reach) was a dense (elements x elements) matrix before; a hall of 10^5 triangles asked for
tens of gigabytes. Here each relation is a query on a tree: the cost grows with the candidates
found, not with the product of the counts.

Why not Embree: embreex exposes ray queries only (intersect, occluded). The queries here are
cones (every ray from a point through a facet's bounding sphere), boxes and spheres against the
elements' bounding volumes, which no ray query answers. The tree is built once per element set
(sorted by size class, then along a Morton curve, and cut where the classes and the curve's
cells are, so that every node is compact in space and holds elements of one size) and walked by compiled loops that write their hits into buffers grown on demand.

Each element has an axis-aligned box (``lo``, ``hi``) and a bounding sphere (``centre``,
``radius``) given by the caller; a node holds the box and a bounding sphere of all its elements.
The node tests are conservative (a node is skipped only when no element of it can meet the
query), the element tests are those of the query, so a query returns exactly what a scan of
all elements with the same element test would return (tests: ``tests/test_spatial.py``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from ..core.jit import carray, inline, kernel

__all__ = ["sphere_in_beam", "sphere_ahead", "LEAF_SIZE", "SphereTree", "build_tree", "query_boxes",
           "query_beams", "query_beams_grouped"]

#: Elements per leaf at most.
LEAF_SIZE = 8


class SphereTree(NamedTuple):
    """A bounding-volume hierarchy over N elements (:func:`build_tree`); node 0 is the root.

    Attributes
    ----------
    order : (N,) int, the elements in leaf order (a leaf holds ``order[start:start + count]``)
    lo, hi : (N, 3) float, each element's box, metres (in the caller's element order)
    centre : (N, 3) float, each element's bounding sphere's centre, metres
    radius : (N,) float, metres
    node_lo, node_hi : (M, 3) float, each node's box, metres
    node_centre : (M, 3) float, node_radius : (M,) float: a sphere around every element sphere
    left, right : (M,) int, children (-1 for a leaf)
    start, count : (M,) int, a leaf's run of ``order`` (count 0 for an inner node)
    """

    order: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    node_lo: np.ndarray
    node_hi: np.ndarray
    node_centre: np.ndarray
    node_radius: np.ndarray
    left: np.ndarray
    right: np.ndarray
    start: np.ndarray
    count: np.ndarray

    @property
    def size(self) -> int:
        """N, the number of elements."""
        return len(self.order)

    @property
    def nbytes(self) -> int:
        """Bytes held by the tree's arrays."""
        return int(sum(x.nbytes for x in self))


#: Bits per axis of the Morton codes; the 4 bits above them hold the element's size class.
MORTON_BITS = 19


def _codes(centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The sort keys of the elements: their size class (log2 of the scene's extent over the
    radius, 16 classes) above a Morton code of the centre (:data:`MORTON_BITS` per axis over the
    centres' bounding box). The tree's first cuts separate the size classes, so that a wall of the
    hall and the millimetre facets of a scanned machine are never in one node: a node's box is
    that of elements of one size, and a small query meets few large boxes."""
    lo = centre.min(axis=0)
    span = np.maximum(centre.max(axis=0) - lo, 1e-300)
    top = 2**MORTON_BITS - 1
    q = np.clip(((centre - lo) / span * top).astype(np.int64), 0, top)
    code = np.zeros(len(centre), dtype=np.int64)
    for bit in range(MORTON_BITS):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    extent = float(np.max(span)) + 2.0 * float(radius.max(initial=0.0))
    with np.errstate(divide="ignore"):
        size = np.floor(np.log2(extent / np.maximum(radius, 1e-300)))
    size = np.clip(size, 0, 15).astype(np.int64)
    return code | (size << (3 * MORTON_BITS))


@kernel("Tuple((i8[::1], i8[::1], i8[::1], i8[::1], i8))(i8[::1], i8)")
def _split(codes, leaf_size):
    """The node structure of a tree over elements sorted by Morton ``codes``: each node's run is
    cut where the highest bit that differs between its first and last code turns on (so a node
    is a cell of the Morton curve, compact in space), or at its middle where all its codes are
    equal, until it holds at most ``leaf_size``. Children are created after their parent, so
    iterating nodes backwards visits children first."""
    n = len(codes)
    cap = max(1, 2 * n)  # a binary tree with at most n leaves has fewer than 2 n nodes
    left = np.full(cap, -1, np.int64)
    right = np.full(cap, -1, np.int64)
    start = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    run_s = np.zeros(cap, np.int64)
    run_n = np.zeros(cap, np.int64)
    stack = np.zeros(256, np.int64)  # one pending sibling per level: depth <= 63 + log2(n)
    m = 1
    run_s[0], run_n[0] = 0, n
    top = 0
    stack[0] = 0
    while top >= 0:
        node = stack[top]
        top -= 1
        s, c = run_s[node], run_n[node]
        if c <= leaf_size:
            start[node], count[node] = s, c
            continue
        first, last = codes[s], codes[s + c - 1]
        if first == last:
            half = c // 2
        else:
            x = first ^ last
            bit = 62
            while (x >> bit) & 1 == 0:
                bit -= 1
            # the first code of the run with that bit set (binary search: the run is sorted)
            a, b = s, s + c - 1
            while a < b:
                mid = (a + b) // 2
                if (codes[mid] >> bit) & 1:
                    b = mid
                else:
                    a = mid + 1
            half = a - s
        a, b = m, m + 1
        m += 2
        run_s[a], run_n[a] = s, half
        run_s[b], run_n[b] = s + half, c - half
        left[node], right[node] = a, b
        top += 1
        stack[top] = b
        top += 1
        stack[top] = a
    return left[:m].copy(), right[:m].copy(), start[:m].copy(), count[:m].copy(), m


@kernel("void(i8[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], i8[::1], i8[::1], i8[::1], "
        "i8[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1])")
def _bounds(order, lo, hi, centre, radius, left, right, start, count, node_lo, node_hi,
            node_centre, node_radius):  # fmt: skip
    """Each node's box (bottom-up from the leaves) and a sphere around its elements' spheres
    (centred on the box, radius from the elements themselves: tighter than merging the
    children's spheres). Each element is visited once per level."""
    m = len(left)
    # the boxes, children before parents
    for node in range(m - 1, -1, -1):
        if left[node] < 0:
            for d in range(3):
                node_lo[node, d] = np.inf
                node_hi[node, d] = -np.inf
            for k in range(start[node], start[node] + count[node]):
                e = order[k]
                for d in range(3):
                    node_lo[node, d] = min(node_lo[node, d], lo[e, d], centre[e, d] - radius[e])
                    node_hi[node, d] = max(node_hi[node, d], hi[e, d], centre[e, d] + radius[e])
        else:
            a, b = left[node], right[node]
            for d in range(3):
                node_lo[node, d] = min(node_lo[a, d], node_lo[b, d])
                node_hi[node, d] = max(node_hi[a, d], node_hi[b, d])
    # each node's run of elements, then the radius about the box's centre
    run_s = np.zeros(m, np.int64)
    run_e = np.zeros(m, np.int64)
    for node in range(m - 1, -1, -1):
        if left[node] < 0:
            run_s[node], run_e[node] = start[node], start[node] + count[node]
        else:
            run_s[node], run_e[node] = run_s[left[node]], run_e[right[node]]
    for node in range(m):
        cx = 0.5 * (node_lo[node, 0] + node_hi[node, 0])
        cy = 0.5 * (node_lo[node, 1] + node_hi[node, 1])
        cz = 0.5 * (node_lo[node, 2] + node_hi[node, 2])
        r = 0.0
        for k in range(run_s[node], run_e[node]):
            e = order[k]
            dx, dy, dz = centre[e, 0] - cx, centre[e, 1] - cy, centre[e, 2] - cz
            r = max(r, np.sqrt(dx * dx + dy * dy + dz * dz) + radius[e])
        node_centre[node, 0], node_centre[node, 1], node_centre[node, 2] = cx, cy, cz
        node_radius[node] = r * (1 + 1e-12) + 1e-12


def build_tree(lo: np.ndarray, hi: np.ndarray, centre: np.ndarray, radius: np.ndarray,
               leaf_size: int = LEAF_SIZE) -> SphereTree:  # fmt: skip
    """A tree over elements with boxes and bounding spheres.

    Parameters
    ----------
    lo, hi : (N, 3) float, each element's axis-aligned box, metres
    centre : (N, 3) float, each element's bounding sphere's centre, metres
    radius : (N,) float, metres
    leaf_size : int, elements per leaf at most

    Returns
    -------
    SphereTree
    """
    lo, hi, centre = carray(lo).reshape(-1, 3), carray(hi).reshape(-1, 3), carray(centre).reshape(-1, 3)
    radius = carray(radius).reshape(-1)
    n = len(centre)
    if not (len(lo) == len(hi) == len(radius) == n):
        raise ValueError("lo, hi, centre and radius must describe the same elements")
    if leaf_size < 1:
        raise ValueError(f"leaf_size must be at least 1, got {leaf_size}")
    codes = _codes(centre, radius) if n else np.zeros(0, np.int64)
    order = np.argsort(codes, kind="stable")
    left, right, start, count, m = _split(carray(codes[order], np.int64), int(leaf_size))
    node_lo, node_hi = np.empty((m, 3)), np.empty((m, 3))
    node_centre, node_radius = np.empty((m, 3)), np.empty(m)
    order = carray(order, np.int64)
    if n:
        _bounds(order, lo, hi, centre, radius, left, right, start, count, node_lo, node_hi,
                node_centre, node_radius)  # fmt: skip
    else:
        node_lo[:], node_hi[:] = np.inf, -np.inf
        node_centre[:], node_radius[:] = 0.0, -1.0
    return SphereTree(order, lo, hi, centre, radius, node_lo, node_hi, node_centre, node_radius,
                      left, right, start, count)  # fmt: skip


# -- queries ----------------------------------------------------------------------------------
@inline
def _boxes_meet(alx, aly, alz, ahx, ahy, ahz, blx, bly, blz, bhx, bhy, bhz):
    """Closed boxes overlap (touching counts)."""
    return (alx <= bhx and blx <= ahx and aly <= bhy and bly <= ahy and alz <= bhz
            and blz <= ahz)  # fmt: skip


_TREE = ("i8[::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, ::1], i8[::1], i8[::1], i8[::1], "
         "i8[::1]")


@kernel(f"Tuple((i8, i8))({_TREE}, f8[:, ::1], f8[:, ::1], i8, i8[::1], i8[::1], i8)")
def _query_boxes(order, node_lo, node_hi, lo, hi, left, right, start, count, q_lo, q_hi, q0,
                 offsets, hits, base):  # fmt: skip
    """The elements whose box meets each query box from query ``q0`` on, written into ``hits``
    until it is full (:func:`_collect`)."""
    nq, cap = q_lo.shape[0], len(hits)
    stack = np.empty(256, np.int64)
    m = 0
    for q in range(q0, nq):
        m_q = m
        qlx, qly, qlz = q_lo[q, 0], q_lo[q, 1], q_lo[q, 2]
        qhx, qhy, qhz = q_hi[q, 0], q_hi[q, 1], q_hi[q, 2]
        top = 0
        stack[0] = 0
        while top >= 0:
            node = stack[top]
            top -= 1
            if not _boxes_meet(node_lo[node, 0], node_lo[node, 1], node_lo[node, 2],
                               node_hi[node, 0], node_hi[node, 1], node_hi[node, 2],
                               qlx, qly, qlz, qhx, qhy, qhz):  # fmt: skip
                continue
            if left[node] >= 0:
                top += 1
                stack[top] = right[node]
                top += 1
                stack[top] = left[node]
                continue
            for k in range(start[node], start[node] + count[node]):
                e = order[k]
                if _boxes_meet(lo[e, 0], lo[e, 1], lo[e, 2], hi[e, 0], hi[e, 1], hi[e, 2],
                               qlx, qly, qlz, qhx, qhy, qhz):  # fmt: skip
                    if m == cap:
                        return q, m_q  # full: the caller grows the buffer, query q again
                    hits[m] = e
                    m += 1
        offsets[q + 1] = base + m
    return nq, m


def _collect(run: Any, nq: int, first_cap: int) -> tuple[np.ndarray, np.ndarray]:
    """Run a query kernel over ``nq`` queries into buffers of bounded size: ``run(q0, offsets,
    hits, base)`` answers queries from ``q0`` until ``hits`` is full and returns ``(q, m)``, the
    first query not answered and the hits written before it. A compiled loop that reallocates
    its own output in the loop pays numba's reference counts on every iteration (twice the
    cost here), so the buffers are the caller's: each full buffer is kept and a new one, twice
    as large, takes the next queries. Returns the CSR ``offsets`` (nq + 1,) and ``hits``."""
    offsets = np.zeros(nq + 1, np.int64)
    parts = []
    q, base, cap = 0, 0, max(1024, first_cap)
    while True:
        hits = np.empty(cap, np.int64)
        q_next, m = run(q, offsets, hits, base)
        parts.append(hits[:m])
        base += m
        if q_next >= nq:
            break
        if q_next == q and m == 0:
            cap *= 2  # one query's hits do not fit: a larger buffer for it
        q = q_next
    return offsets, (np.concatenate(parts) if len(parts) > 1 else parts[0].copy())


def _tree_args(tree: SphereTree) -> tuple[np.ndarray, ...]:
    return (tree.order, tree.node_lo, tree.node_hi, tree.lo, tree.hi, tree.left, tree.right,
            tree.start, tree.count)  # fmt: skip


def query_boxes(tree: SphereTree, q_lo: np.ndarray, q_hi: np.ndarray) -> tuple[np.ndarray, ...]:
    """The elements whose box meets each query box (closed boxes: touching counts).

    Parameters
    ----------
    q_lo, q_hi : (Q, 3) float, the query boxes, metres

    Returns
    -------
    offsets : (Q + 1,) int; hits : (H,) int, the elements of query q are
        ``hits[offsets[q]:offsets[q + 1]]``, in the tree's leaf order
    """
    q_lo, q_hi = carray(q_lo).reshape(-1, 3), carray(q_hi).reshape(-1, 3)
    if tree.size == 0:
        return np.zeros(len(q_lo) + 1, np.int64), np.zeros(0, np.int64)
    args = _tree_args(tree)
    return _collect(lambda q0, off, hits, base: _query_boxes(*args, q_lo, q_hi, q0, off, hits,
                                                             base),
                    len(q_lo), 16 * len(q_lo))  # fmt: skip


@inline
def sphere_in_beam(ax, ay, az, ux, uy, uz, cos_a, sin_a, inside, cx, cy, cz, radius):
    """The beam (apex ``a``, unit axis ``u``, half-angle cosine and sine; ``inside``: the apex
    is inside the sphere the beam is cast through, every direction is in it) can meet the sphere
    (centre ``c``, ``radius``): the angle between the axis and the centre is at most the
    half-angle plus the sphere's angular radius (:func:`raytrace.solver.reflection.beam_reaches`
    times ``|c - a|``, without a division), a necessary condition."""
    if inside:
        return True
    vx, vy, vz = cx - ax, cy - ay, cz - az
    dt2 = vx * vx + vy * vy + vz * vz
    r2 = radius * radius
    if dt2 <= r2:
        return True
    dot = ux * vx + uy * vy + uz * vz
    dt = np.sqrt(dt2)
    return dot >= cos_a * np.sqrt(dt2 - r2) - sin_a * min(radius, dt) - 1e-7 * dt


@inline
def sphere_ahead(nx, ny, nz, off, side, cx, cy, cz, radius):
    """Some of the sphere is strictly on the ``side`` (+1, -1; 0: either) of the plane
    ``n . x = off``."""
    s = nx * cx + ny * cy + nz * cz - off
    if side > 0:
        return s > -radius
    if side < 0:
        return s < radius
    return True


_BEAMS = "f8[:, ::1], f8[:, ::1], f8[::1], f8[::1], b1[::1], f8[:, ::1], f8[::1], i1[::1]"


@kernel(f"Tuple((i8, i8))({_TREE}, f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], {_BEAMS}, i8, "
        "i8[::1], i8[::1], i8)")
def _query_beams(order, node_lo, node_hi, lo, hi, left, right, start, count, node_centre,
                 node_radius, centre, radius, apex, axis, cos_a, sin_a, inside, plane_n,
                 plane_off, side, q0, offsets, hits, base):  # fmt: skip
    """The elements whose sphere each beam can reach beyond its plane, from query ``q0`` on,
    written into ``hits`` until it is full (:func:`_collect`, :func:`query_beams`)."""
    nq, cap = apex.shape[0], len(hits)
    stack = np.empty(256, np.int64)
    m = 0
    for q in range(q0, nq):
        m_q = m
        ax, ay, az = apex[q, 0], apex[q, 1], apex[q, 2]
        ux, uy, uz = axis[q, 0], axis[q, 1], axis[q, 2]
        ca, sa, ins = cos_a[q], sin_a[q], inside[q]
        nx, ny, nz, off, sd = plane_n[q, 0], plane_n[q, 1], plane_n[q, 2], plane_off[q], side[q]
        top = 0
        stack[0] = 0
        while top >= 0:
            node = stack[top]
            top -= 1
            cx, cy, cz = node_centre[node, 0], node_centre[node, 1], node_centre[node, 2]
            r = node_radius[node]
            if not sphere_ahead(nx, ny, nz, off, sd, cx, cy, cz, r):
                continue
            if not sphere_in_beam(ax, ay, az, ux, uy, uz, ca, sa, ins, cx, cy, cz, r):
                continue
            if left[node] >= 0:
                top += 1
                stack[top] = right[node]
                top += 1
                stack[top] = left[node]
                continue
            for k in range(start[node], start[node] + count[node]):
                e = order[k]
                ex, ey, ez, er = centre[e, 0], centre[e, 1], centre[e, 2], radius[e]
                if not sphere_ahead(nx, ny, nz, off, sd, ex, ey, ez, er):
                    continue
                if not sphere_in_beam(ax, ay, az, ux, uy, uz, ca, sa, ins, ex, ey, ez, er):
                    continue
                if m == cap:
                    return q, m_q
                hits[m] = e
                m += 1
        offsets[q + 1] = base + m
    return nq, m


def query_beams(tree: SphereTree, apex: np.ndarray, axis: np.ndarray, cos_a: np.ndarray,
                sin_a: np.ndarray, inside: np.ndarray, plane_normal: np.ndarray | None = None,
                plane_offset: np.ndarray | None = None,
                side: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The elements whose bounding sphere each beam can reach (a necessary condition), and
    that have some part strictly on a side of a plane (optional).

    A beam is every ray from ``apex`` within the half-angle of ``axis``
    (:func:`raytrace.solver.reflection.beam`); with ``inside`` every direction is in it.

    Parameters
    ----------
    apex, axis : (Q, 3) float, metres and unit vectors
    cos_a, sin_a : (Q,) float, cosine and sine of the half-angle
    inside : (Q,) bool
    plane_normal : (Q, 3) float, plane_offset : (Q,) float, side : (Q,) int, optional: only
        elements whose sphere reaches strictly to ``side`` (+1 the normal's side, -1 the other,
        0 either) of the plane ``normal . x = offset``

    Returns
    -------
    offsets : (Q + 1,) int; hits : (H,) int, in the CSR form of :func:`query_boxes`
    """
    apex, axis = carray(apex).reshape(-1, 3), carray(axis).reshape(-1, 3)
    nq = len(apex)
    if plane_normal is None:
        plane_normal, plane_offset, side = np.zeros((nq, 3)), np.zeros(nq), np.zeros(nq, np.int8)
    if tree.size == 0:
        return np.zeros(nq + 1, np.int64), np.zeros(0, np.int64)
    args = (*_tree_args(tree), tree.node_centre, tree.node_radius, tree.centre, tree.radius,
            apex, axis, carray(cos_a).reshape(-1), carray(sin_a).reshape(-1),
            carray(inside, bool).reshape(-1), carray(plane_normal).reshape(-1, 3),
            carray(plane_offset).reshape(-1), carray(side, np.int8).reshape(-1))
    return _collect(lambda q0, off, hits, base: _query_beams(*args, q0, off, hits, base), nq,
                    16 * nq)  # fmt: skip


def query_beams_grouped(*args, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """:func:`query_beams` as (query, element) pairs: ``(q_idx, e_idx)``, (H,) int each, in
    query order."""
    offsets, hits = query_beams(*args, **kwargs)
    q_idx = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    return q_idx, hits
