"""The approximate discovery of :attr:`raytrace.solver.config.TraceConfig.facet_reach`: what a
small facet may exchange a reflection with in a path of several interactions.

A scanned or tessellated machine has facets of 1-3 cm. Exactly, the beam from an end's image
through each of them is walked across the whole scene's edges (reflection-diffraction) and
facets (double reflection): on a million-triangle hall that is most of the trace, and its slope
against the triangle count is above 1. The paths those far walks find are few: on the 83 200-
triangle benchmark hall, the paths with a reflection in a small facet whose neighbour on the path
lies more than 5 cm from it are 0.12 % of all paths (docs/tracing.md), and a facet much smaller
than its first Fresnel zone (tens of centimetres at 3-30 GHz and metres of range) does not
reflect specularly anyway.

So with ``facet_reach = r > 0`` a facet whose bounding sphere's radius is below ``r`` (a *small*
facet) reflects, in a path of more than one reflection or diffraction, only toward or from the
edges and facets next to it on the path whose bounding boxes come within ``r`` of its own box
(per axis: the boxes grown by ``r`` meet). Its candidates come from lists made once per scene
(kept on it) by box queries on the trees in one compiled pass (:func:`_near_runs`), not from
walks of its beam. Nothing else changes: line of sight, single reflections, single diffractions,
penetrations, and every pair of large facets and edges are the exact tracer's, and every path
found is one the exact tracer finds, with the same numbers (``tests/test_near.py``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from ..core.jit import carray, kernel
from ..scene import accel
from ..scene.accel import facet_sees
from ..scene.spatial import SphereTree

__all__ = ["small_facets", "near_edges", "near_facets", "near_facet_pairs", "QUERY_BLOCK",
           "LIST_BUFFER", "Recall", "recall"]

#: First facets per block of :func:`near_facet_pairs` (a hundred partners each at most, 16 bytes
#: per pair as the caller takes them).
QUERY_BLOCK = 1 << 14
#: Values per buffer while the lists are made (int32: 16 MB).
LIST_BUFFER = 1 << 22


def small_facets(facets, reach: float) -> np.ndarray:
    """(K,) bool: the facets whose bounding sphere's radius (:func:`raytrace.scene.accel.
    facet_spheres`, metres) is below ``reach`` (metres); none for ``reach == 0``."""
    return accel.facet_spheres(facets)[1] < reach


@kernel("Tuple((i8, i8))(i8[::1], f8[:, ::1], f8[:, ::1], i8[::1], i8[::1], i8[::1], i8[::1], "
        "f8[:, ::1], f8[:, ::1], i8[::1], f8[:, ::1], f8[:, ::1], f8, b1, b1[::1], f8[:, ::1], "
        "f8[::1], b1[::1], f8[:, ::1], i8[::1], i8[::1], f8, i8, i8[::1], i4[::1])")
def _near_runs(order, node_lo, node_hi, left, right, start, count, lo, hi, rows, f_lo, f_hi, reach,
               facets_mode, small, normal, offset, two_sided, corners, c_start, c_count, tol, q0,
               counts, out):  # fmt: skip
    """The lists of :func:`near_edges` (``facets_mode`` False: the tree is of edges, the values
    leaf slots) or :func:`near_facets` (True: the tree is the facets', the values facets) for
    the facets ``rows`` (increasing) from ``q0`` on, in one pass: the tree's elements whose box
    (``lo``, ``hi``) meets the facet's box grown by ``reach``, filtered, written into ``out``
    until it is full and counted in ``counts[f + 1]``. Returns ``(q, m)``: the first row not
    done and the values written (a row's values are never split)."""
    cap = len(out)
    stack = np.empty(256, np.int64)
    m = 0
    for q in range(q0, len(rows)):
        m_q = m
        f = rows[q]
        qlx, qly, qlz = f_lo[f, 0] - reach, f_lo[f, 1] - reach, f_lo[f, 2] - reach
        qhx, qhy, qhz = f_hi[f, 0] + reach, f_hi[f, 1] + reach, f_hi[f, 2] + reach
        nx, ny, nz, off = normal[f, 0], normal[f, 1], normal[f, 2], offset[f]
        one_sided = not two_sided[f]
        top = 0
        stack[0] = 0
        while top >= 0:
            node = stack[top]
            top -= 1
            if not (node_lo[node, 0] <= qhx and qlx <= node_hi[node, 0]
                    and node_lo[node, 1] <= qhy and qly <= node_hi[node, 1]
                    and node_lo[node, 2] <= qhz and qlz <= node_hi[node, 2]):  # fmt: skip
                continue
            if left[node] >= 0:
                top += 1
                stack[top] = right[node]
                top += 1
                stack[top] = left[node]
                continue
            for k in range(start[node], start[node] + count[node]):
                e = order[k]
                if not (lo[e, 0] <= qhx and qlx <= hi[e, 0] and lo[e, 1] <= qhy
                        and qly <= hi[e, 1] and lo[e, 2] <= qhz and qlz <= hi[e, 2]):  # fmt: skip
                    continue
                if facets_mode:
                    # one of the two small, and facing each other (accel.facing)
                    if e == f or not (small[f] or small[e]):
                        continue
                    if not facet_sees(corners, c_start[f], c_count[f], normal[e, 0],
                                      normal[e, 1], normal[e, 2], offset[e], two_sided[e], tol):
                        continue  # fmt: skip
                    if not facet_sees(corners, c_start[e], c_count[e], nx, ny, nz, off,
                                      two_sided[f], tol):  # fmt: skip
                        continue
                    value = e
                else:
                    # an edge lies in its box: a part in front of a one-sided facet puts the
                    # box's corner farthest along the normal there
                    if one_sided:
                        cx = hi[e, 0] if nx > 0 else lo[e, 0]
                        cy = hi[e, 1] if ny > 0 else lo[e, 1]
                        cz = hi[e, 2] if nz > 0 else lo[e, 2]
                        if not cx * nx + cy * ny + cz * nz - off > tol:
                            continue
                    value = k
                if m == cap:
                    return q, m_q  # full: the caller takes a new buffer for this row
                out[m] = value
                m += 1
        counts[f + 1] = m - m_q
    return len(rows), m


def _lists(facets, tree: SphereTree, rows: np.ndarray, reach: float, facets_mode: bool,
           small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """CSR lists of :func:`_near_runs` over ``rows``: ``start`` (K + 1,) int64 and the values
    (L,) int32, in buffers of :data:`LIST_BUFFER` values taken as they fill."""
    k = len(facets)
    counts = np.zeros(k + 1, np.int64)
    f_lo, f_hi = accel.facet_boxes(facets, 0.0)
    verts = carray(facets.triangles.reshape(-1, 3))
    c_start = carray(3 * (np.cumsum(facets.tri_count) - facets.tri_count), np.int64)
    fixed = (carray(tree.order, np.int64), carray(tree.node_lo), carray(tree.node_hi),
             carray(tree.left, np.int64), carray(tree.right, np.int64),
             carray(tree.start, np.int64), carray(tree.count, np.int64), carray(tree.lo),
             carray(tree.hi), carray(rows, np.int64), carray(f_lo), carray(f_hi), float(reach),
             facets_mode, carray(small, bool), carray(facets.normal), carray(facets.offset),
             carray(facets.two_sided, bool), verts, c_start,
             carray(3 * facets.tri_count, np.int64), accel.PLANE_TOL_M)  # fmt: skip
    parts = []
    q, cap = 0, LIST_BUFFER
    while q < len(rows) and tree.size:
        out = np.empty(cap, np.int32)
        q_next, m = _near_runs(*fixed, q, counts, out)
        parts.append(out[:m].copy() if 2 * m < cap else out[:m])
        if q_next == q and m == 0:
            cap *= 2  # one row's values do not fit: a larger buffer for it
        q = q_next
    values = np.concatenate(parts) if len(parts) > 1 else (parts[0] if parts else
                                                           np.zeros(0, np.int32))  # fmt: skip
    return np.cumsum(counts), values


def near_edges(facets, tree: SphereTree, reach: float, small: np.ndarray) -> tuple[np.ndarray, ...]:
    """The edges of ``tree`` (a tree of edges, as :func:`raytrace.scene.accel.wedge_tree`) near
    each small facet: their boxes meet the facet's box grown by ``reach``, and for a one-sided
    facet (a closed solid's) some part may be strictly in front of its plane (every path's rule:
    :func:`raytrace.solver.kernels.facet_wedge_pairs_tree` tests it again per end).

    Returns
    -------
    start : (K + 1,) int64, slots : (L,) int32: facet ``f``'s edges are the tree's leaf slots
        ``slots[start[f]:start[f + 1]]`` (positions in ``tree.order``); none for a large facet
    """
    return _lists(facets, tree, np.flatnonzero(small), reach, False, small)


def near_facets(facets, reach: float, small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The facets each facet may exchange a double reflection with in the approximate
    discovery: those whose boxes meet its box grown by ``reach``, where one of the two is small
    and the two face each other (:func:`raytrace.scene.accel.facing`, a condition of every
    double reflection, whatever the transmitter). Made once per scene.

    Returns
    -------
    start : (K + 1,) int64, partners : (L,) int32: facet ``f``'s are
        ``partners[start[f]:start[f + 1]]``
    """
    return _lists(facets, accel.facet_tree(facets), np.arange(len(facets)), reach, True, small)


def near_facet_pairs(lists: tuple[np.ndarray, np.ndarray],
                     first: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """The (first facet, second facet) pairs of :func:`near_facets`' ``lists`` whose first facet
    is one of ``first``, in blocks of :data:`QUERY_BLOCK` first facets, in row order.

    Yields
    ------
    a : (P,) int, rows of ``first``; f2 : (P,) int, second facets
    """
    start, partners = lists
    for b0 in range(0, len(first), QUERY_BLOCK):
        f1 = first[b0 : b0 + QUERY_BLOCK]
        counts = start[f1 + 1] - start[f1]
        a = np.repeat(np.arange(b0, b0 + len(f1)), counts)
        # each row's run of partners: its start, plus the position within the run
        at = np.repeat(start[f1] - (np.cumsum(counts) - counts), counts) + np.arange(counts.sum())
        yield a, partners[at].astype(np.int64)


class Recall(NamedTuple):
    """How much of an exact trace an approximate one finds (:func:`recall`).

    Attributes
    ----------
    paths : float, the fraction of the exact trace's paths found (the same link and the same
        interactions on the same scene elements)
    first_arrivals : float, the fraction of links whose first-arriving exact path is also the
        approximate trace's first (links with a path)
    n_exact, n_found, n_extra : int, the exact trace's paths, those of them found, and paths
        found that the exact trace does not have (0 for :attr:`TraceConfig.facet_reach`)
    """

    paths: float
    first_arrivals: float
    n_exact: int
    n_found: int
    n_extra: int


def _keys(p, depth: int) -> np.ndarray:
    """One row per path: link, interaction codes, objects and elements (padded to ``depth``
    interactions), as one opaque value each (comparable, hashable)."""
    pad = ((0, 0), (0, depth - p.interaction.shape[1]))
    rows = np.column_stack([p.tx_index, p.rx_index, np.pad(p.interaction, pad),
                            np.pad(p.objects, pad, constant_values=-1),
                            np.pad(p.elements, pad, constant_values=-1)])  # fmt: skip
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    return rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()


def _first(p, n_rx: int) -> tuple[np.ndarray, np.ndarray]:
    """Each link with a path (``tx * n_rx + rx``, increasing) and its first-arriving path."""
    order = np.lexsort((p.delay_s, p.rx_index, p.tx_index))
    link = p.tx_index[order].astype(np.int64) * n_rx + p.rx_index[order]
    first = np.r_[True, link[1:] != link[:-1]] if len(link) else np.zeros(0, bool)
    return link[first], order[first]


def recall(exact, approx) -> Recall:
    """The recall of ``approx`` against ``exact`` (:class:`raytrace.Paths` of the same scene
    and links, e.g. the traces without and with :attr:`TraceConfig.facet_reach`)."""
    depth = max(exact.interaction.shape[1], approx.interaction.shape[1])
    ke, ka = _keys(exact, depth), _keys(approx, depth)
    found = np.isin(ke, ka)
    extra = int((~np.isin(ka, ke)).sum())
    n_rx = int(max(exact.rx_index.max(initial=-1), approx.rx_index.max(initial=-1))) + 1
    (le, ie), (la, ia) = _first(exact, n_rx), _first(approx, n_rx)
    _, je, ja = np.intersect1d(le, la, assume_unique=True, return_indices=True)
    same = int((ke[ie[je]] == ka[ia[ja]]).sum())
    return Recall(float(found.mean()) if len(ke) else 1.0, same / len(le) if len(le) else 1.0,
                  len(ke), int(found.sum()), extra)  # fmt: skip
