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
(the edges' kept on it) by box queries on the trees
(:func:`raytrace.scene.spatial.query_boxes`), not from walks of its beam. Nothing else changes:
line of sight, single reflections, single diffractions, penetrations, and every pair of large
facets and edges are the exact tracer's, and every path found is one the exact tracer finds, with
the same numbers (``tests/test_near.py``).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from ..scene import accel
from ..scene.spatial import SphereTree, query_boxes

__all__ = ["small_facets", "near_edges", "near_facets", "near_facet_pairs", "QUERY_BLOCK", "Recall", "recall"]

#: Facets queried per block while the lists are made: a block's hits are about a hundred per
#: facet before the filters (8 bytes each), and the lists keep int32.
QUERY_BLOCK = 1 << 14


def small_facets(facets, reach: float) -> np.ndarray:
    """(K,) bool: the facets whose bounding sphere's radius (:func:`raytrace.scene.accel.
    facet_spheres`, metres) is below ``reach`` (metres); none for ``reach == 0``."""
    return accel.facet_spheres(facets)[1] < reach


def _grown_boxes(facets, rows: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = accel.facet_boxes(facets, 0.0)
    return lo[rows] - reach, hi[rows] + reach


def near_edges(facets, tree: SphereTree, reach: float, small: np.ndarray) -> tuple[np.ndarray, ...]:
    """The edges of ``tree`` (a tree of edges, as :func:`raytrace.scene.accel.wedge_tree`) near
    each small facet: their boxes meet the facet's box grown by ``reach``, and for a one-sided
    facet (a closed solid's) some part is strictly in front of its plane (every path's rule:
    :func:`raytrace.solver.kernels.facet_wedge_pairs_tree` tests it again per end).

    Returns
    -------
    start : (K + 1,) int64, slots : (L,) int32: facet ``f``'s edges are the tree's leaf slots
        ``slots[start[f]:start[f + 1]]`` (positions in ``tree.order``); none for a large facet
    """
    k = len(facets)
    rows = np.flatnonzero(small)
    slot_of = np.empty(tree.size, np.int64)
    slot_of[tree.order] = np.arange(tree.size)
    counts = np.zeros(k + 1, np.int64)
    parts = []
    for b0 in range(0, len(rows), QUERY_BLOCK):
        f = rows[b0 : b0 + QUERY_BLOCK]
        offsets, hits = query_boxes(tree, *_grown_boxes(facets, f, reach))
        owner = np.repeat(f, np.diff(offsets))
        # an edge lies in its box: a part of it in front puts the box's farthest corner there
        keep = _some_part_in_front(facets, owner, tree.lo[hits], tree.hi[hits])
        owner, hits = owner[keep], hits[keep]
        counts[1:] += np.bincount(owner, minlength=k)[:k] if len(owner) else 0
        parts.append(slot_of[hits].astype(np.int32))
    start = np.cumsum(counts)
    slots = np.concatenate(parts) if parts else np.zeros(0, np.int32)
    return start, slots


def _some_part_in_front(facets, f: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: per (facet ``f``, box ``lo``, ``hi``): the facet is two-sided, or some corner
    of the box lies strictly in front of its plane (a necessary condition for an element in
    the box to have a part there)."""
    n = facets.normal[f]
    far = np.where(n > 0, hi, lo)  # the box's corner farthest along the normal
    ahead = np.einsum("ij,ij->i", far, n) - facets.offset[f] > accel.PLANE_TOL_M
    return ahead | facets.two_sided[f]


def near_facets(facets, reach: float, small: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The facets each facet may exchange a double reflection with in the approximate
    discovery: those whose boxes meet its box grown by ``reach``, where one of the two is small
    and the two face each other (:func:`raytrace.scene.accel.facing`, a condition of every
    double reflection, whatever the transmitter). Made once per scene, in blocks of
    :data:`QUERY_BLOCK` facets (a million-triangle hall's box hits are tens of millions).

    Returns
    -------
    start : (K + 1,) int64, partners : (L,) int32: facet ``f``'s are
        ``partners[start[f]:start[f + 1]]``, in increasing order
    """
    tree = accel.facet_tree(facets)
    k = len(facets)
    counts = np.zeros(k + 1, np.int64)
    parts = []
    for b0 in range(0, k, QUERY_BLOCK):
        f1 = np.arange(b0, min(k, b0 + QUERY_BLOCK))
        offsets, hits = query_boxes(tree, *_grown_boxes(facets, f1, reach))
        owner = np.repeat(f1, np.diff(offsets))
        keep = small[owner] | small[hits]
        owner, hits = owner[keep], hits[keep]
        keep = accel.facing(facets, owner, hits)
        owner, hits = owner[keep], hits[keep]
        order = np.lexsort((hits, owner))
        counts[1:] += np.bincount(owner, minlength=k)[:k] if len(owner) else 0
        parts.append(hits[order].astype(np.int32))
    start = np.cumsum(counts)
    return start, (np.concatenate(parts) if parts else np.zeros(0, np.int32))


def near_facet_pairs(lists: tuple[np.ndarray, np.ndarray],
                     first: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """The (first facet, second facet) pairs of :func:`near_facets`' ``lists`` whose first facet
    is one of ``first``, in blocks of :data:`QUERY_BLOCK` first facets, in (row, second facet)
    order.

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


def _first(p) -> dict:
    out: dict = {}
    for i in np.lexsort((p.delay_s, p.rx_index, p.tx_index)):
        out.setdefault((int(p.tx_index[i]), int(p.rx_index[i])), i)
    return out


def recall(exact, approx) -> Recall:
    """The recall of ``approx`` against ``exact`` (:class:`raytrace.Paths` of the same scene
    and links, e.g. the traces without and with :attr:`TraceConfig.facet_reach`)."""
    depth = max(exact.interaction.shape[1], approx.interaction.shape[1])
    ke, ka = _keys(exact, depth), _keys(approx, depth)
    found = np.isin(ke, ka)
    extra = int((~np.isin(ka, ke)).sum())
    fe, fa = _first(exact), _first(approx)
    same = sum(1 for link, i in fe.items() if link in fa and ke[i] == ka[fa[link]])
    return Recall(float(found.mean()) if len(ke) else 1.0, same / len(fe) if fe else 1.0,
                  len(ke), int(found.sum()), extra)  # fmt: skip
