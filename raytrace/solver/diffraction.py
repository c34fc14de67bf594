"""Diffraction stage of the tracer: candidate paths over wedges, pure and mixed with reflections.

What is traced (first-order diffraction, UTD field from :mod:`raytrace.physics.utd`):

* ``D``: tx -> edge -> rx, for every link and every wedge;
* ``RD``: tx -> facet -> edge -> rx, and ``DR``: tx -> edge -> facet -> rx, when
  ``max_reflections >= 1`` and ``max_interactions >= 2``;
* ``RDR``: tx -> facet -> edge -> facet -> rx, when ``max_reflections >= 2`` and
  ``max_interactions >= 3``.

Reflections are unfolded by images: for ``RD`` the diffraction point is Keller's point between
the image of the transmitter in the facet and the receiver, and the reflection point is where
the segment image -> diffraction point crosses the facet. Candidates (tx, facet, wedge) are pruned
exactly before receivers are considered: the transmitter on a reflecting side of the facet, the
edge (clipped to that side) projected from the image onto the facet's plane must meet the facet's
bounding box. Every segment is then checked with Embree (penetrations allowed up to the limit).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from functools import partial

import numpy as np

from ..core.jit import carray
from ..core.kept import keep as keep_bounded
from ..core.vec import cross as _cross
from ..core.vec import norm
from ..core.vec import rows as take_rows
from ..physics.utd import (
    KELLER_TOL_M,
    chain_diffraction,
    diffraction_valid,
    keller_points,
    wedge_frames,
)
from ..scene import accel
from ..scene.spatial import build_tree
from . import kernels, near, shadow
from . import reflection as refl
from .context import TraceContext
from .evaluate import Candidates, DiffractionModel, DiffractionOperator, candidates, evaluate
from .paths import DIFFRACTION, REFLECTION, Paths

#: Work is split into chunks of about this many candidates.
CHUNK = 300_000
#: The RD and DR stages of a large scene (one traced with the trees, not the tables of
#: :func:`raytrace.solver.kernels.use_tables`) are this many stages each, over every n-th end
#: point, for the stage threads to share.
LARGE_SCENE_PARTS = 2
#: Padding (m) of the visible part of an edge used to prune diffraction points before the exact
#: point-in-facet test: far above rounding, so the pruning never drops a valid path.
SPAN_PAD_M = 1e-6
#: A point is surely inside a wedge (its diffraction invalid whatever the diffraction point) when
#: its azimuth is inside the wedge's interior by more than this (rad) and it is farther than
#: :data:`INSIDE_MIN_RHO_M` from the edge line: far above the rounding of the azimuth computed
#: from another point of the edge (about 1e-14 m / rho) and the 1e-9 rad snap of
#: :func:`~raytrace.physics.utd.wedge_geometry`, so the pruning never drops a valid path.
INSIDE_MARGIN_RAD = 1e-6
#: See :data:`INSIDE_MARGIN_RAD`, metres.
INSIDE_MIN_RHO_M = 1e-3


def stages(ctx: TraceContext) -> list[tuple[str, Callable[[], list[Paths]]]]:
    """The diffraction stages allowed by the context's limits, as (name, callable) pairs."""
    out: list[tuple[str, Callable[[], list[Paths]]]] = [("diffraction", lambda: [_pure(ctx)])]
    cfg = ctx.cfg
    if cfg.max_reflections >= 1 and cfg.max_interactions >= 2:
        # on a large scene these two are most of a trace: each in parts (of its end points) so
        # that the stage threads share them
        fc, w = ctx.scene.facets, ctx.scene.wedges
        parts = 1 if kernels.use_tables(len(fc), len(w)) else LARGE_SCENE_PARTS
        for name, before, n_ends in (("reflection-diffraction", True, len(ctx.tx)),
                                     ("diffraction-reflection", False, len(ctx.rx))):
            n = max(1, min(parts, n_ends))
            out.extend((name, partial(_one_reflection, ctx, before, i, n)) for i in range(n))
    if cfg.max_reflections >= 2 and cfg.max_interactions >= 3:
        out.append(("reflection-diffraction-reflection", lambda: _two_reflections(ctx)))
    return out


def field_model(ctx: TraceContext) -> DiffractionModel:
    """The callback the tracer's back end applies at a diffraction vertex
    (:func:`raytrace.physics.utd.chain_diffraction`: the unfolded source and receiver, images
    for mixed paths, are recovered from the chain, straight on either side of the edge once
    unfolded; the faces reflect as the materials' interfaces, or slabs for open sheets)."""
    w = ctx.scene.wedges
    frame = _wedge_frame(ctx).utd

    def apply(wedge, chain, j, seg_len):
        two = ~ctx.obj_closed[w.object[wedge]]
        dif = chain_diffraction(frame, wedge, chain, j, seg_len, ctx.f, ctx.eta, ctx.thickness,
                                w.material[wedge], two)  # fmt: skip
        # incident spreading of the unfolded incident leg; the phase of the whole path is applied
        # by the back end
        scale = np.where(dif.valid, ctx.wavelength / (4 * np.pi * dif.s_in), 0.0)
        return DiffractionOperator(dif.d_matrix, dif.basis, dif.spreading, dif.valid, scale)

    return apply


class _WedgeFrame:
    """Per wedge, what :func:`_surely_inside` needs, as contiguous component arrays: the
    edge-fixed axes ``t0`` and ``n0`` of :func:`~raytrace.physics.utd.wedge_geometry` (3, W),
    the start's coordinates along them (W,) m, ``cos``/``sin`` of the exterior angle ``n pi`` and
    whether the interior is a sector narrower than pi (``1 <= n < 2``, the wedges pruned)."""

    def __init__(self, w) -> None:
        self.utd = wedge_frames(w.direction, w.normal0, w.normal1, w.face0_dir)
        _, t0, n0, _, n = self.utd
        self.t0, self.n0 = np.ascontiguousarray(t0.T), np.ascontiguousarray(n0.T)
        self.t_start = np.einsum("ij,ij->i", w.start, t0)
        self.n_start = np.einsum("ij,ij->i", w.start, n0)
        self.cos_n, self.sin_n = np.cos(n * np.pi), np.sin(n * np.pi)
        # the azimuth about the edge does not depend on the diffraction point as long as the
        # edge's direction is that of end - start: prune only wedges where it is, to 1e-10 m
        drift = norm(_cross(w.direction, w.end - w.start))
        self.prunable = (n >= 1.0) & (n < 2.0 - 1e-6) & (drift < 1e-10)
        #: the frame as :mod:`raytrace.solver.kernels` takes it
        self.kernel_args = (self.t0, self.n0, self.t_start, self.n_start, self.cos_n, self.sin_n,
                            np.ascontiguousarray(self.prunable), np.sin(INSIDE_MARGIN_RAD) ** 2,
                            INSIDE_MIN_RHO_M**2)  # fmt: skip


def _wedge_frame(ctx: TraceContext) -> _WedgeFrame:
    """The scene's :class:`_WedgeFrame` (cached on the wedges)."""
    w = ctx.scene.wedges
    cached = w.cache.get("utd_frame")
    if cached is None:
        cached = w.cache["utd_frame"] = _WedgeFrame(w)
    return cached


def _surely_inside(fr: _WedgeFrame, wi: np.ndarray, px, py, pz) -> np.ndarray:
    """Whether points (components ``px, py, pz``) are inside wedges ``wi`` by a margin: a
    diffraction with a source or receiver there is never valid. Broadcasts.

    With ``x, y`` the point's coordinates along ``t0, n0`` from the edge (azimuth ``phi``
    measured from face 0), the interior ``n pi < phi < 2 pi`` of a wedge with ``1 <= n < 2`` is
    where ``y < 0`` and ``r sin(phi - n pi) = cos(n pi) y - sin(n pi) x > 0``; both must hold by
    ``sin`` :data:`INSIDE_MARGIN_RAD` times ``r``, at ``r`` above :data:`INSIDE_MIN_RHO_M`
    (:func:`raytrace.solver.kernels.surely_inside`).
    """
    wi, px, py, pz = np.broadcast_arrays(wi, px, py, pz)
    flat = [carray(x, t).reshape(-1)
            for x, t in ((wi, np.int64), (px, float), (py, float), (pz, float))]  # fmt: skip
    return kernels.surely_inside(*fr.kernel_args, *flat).reshape(wi.shape)


def _valid_geometry(ctx: TraceContext, wedge, src, dst, point) -> np.ndarray:
    """:func:`~raytrace.physics.utd.wedge_geometry`'s ``valid`` of diffractions at wedges
    ``wedge`` (frames cached per wedge)."""
    return diffraction_valid(_wedge_frame(ctx).utd.take(wedge), src, dst, point)


def _pure(ctx: TraceContext) -> Paths:
    w = ctx.scene.wedges
    n_t, n_r, n_w = len(ctx.tx), len(ctx.rx), len(w)
    parts = []
    ctx.count("candidates_d", n_t * n_w * n_r)
    frame, w_all = _wedge_frame(ctx), np.arange(n_w)[:, None]
    # a transmitter or receiver surely inside the wedge: never a valid diffraction (pruning)
    open_t = ~_surely_inside(frame, w_all, *ctx.tx.T[:, None, :])  # (W, T)
    open_r = ~_surely_inside(frame, w_all, *ctx.rx.T[:, None, :])  # (W, R)
    if not kernels.PRUNE:
        open_t[:] = True
    # an edge seen from the transmitter or the receiver only through an opaque solid (shadow)
    open_t &= ~shadow.shadows_of(ctx, ctx.tx)[1].T
    open_r &= ~shadow.shadows_of(ctx, ctx.rx)[1].T
    if ctx.wedge_mask is not None:
        open_t &= ctx.wedge_mask[:, None]
    # Keller's point must lie on the edge (padded): tested per (transmitter, wedge) and
    # receiver before it is computed, in (transmitter, wedge, receiver) order
    w_idx, t_idx = np.nonzero(open_t)
    order = np.lexsort((w_idx, t_idx))
    w_idx, t_idx = w_idx[order], t_idx[order]
    start_c, unit_c, length = _edge_lines(ctx)
    ts, rho_s = _along_and_off(ctx.tx.T[:, t_idx], start_c[:, w_idx], unit_c[:, w_idx])
    tr_w, rho_w = _along_and_off(ctx.rx.T[:, None, :], start_c[..., None], unit_c[..., None])
    lo = np.full(len(w_idx), -SPAN_PAD_M)
    hi = length[w_idx] + SPAN_PAD_M
    step = max(1, CHUNK // max(n_r, 1))
    for c0 in range(0, len(w_idx), step):
        q, r_idx = kernels.expand_over_others(ts, rho_s, lo, hi, w_idx, tr_w, rho_w, open_r, c0,
                                              min(len(w_idx), c0 + step), kernels.PRUNE)  # fmt: skip
        t_idx_q, w_idx_q = t_idx[q], w_idx[q]
        parts.append(_pure_candidates(ctx, t_idx_q, w_idx_q, r_idx))
    return Paths.concatenate(parts) if parts else Paths.empty(ctx.tx, ctx.rx, ctx.f, 1)


def _edge_lines(ctx: TraceContext) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges' starts and unit vectors as components (3, W), and lengths (W,), metres: the
    same arithmetic as :func:`~raytrace.physics.utd.keller_points` (cached on the wedges)."""
    w = ctx.scene.wedges
    cached = w.cache.get("edge_lines")
    if cached is None:
        v = w.end - w.start
        length = norm(v)
        with np.errstate(divide="ignore", invalid="ignore"):
            unit = v / length[:, None]
        cached = w.cache["edge_lines"] = (np.ascontiguousarray(w.start.T),
                                          np.ascontiguousarray(unit.T), length)  # fmt: skip
    return cached


def _pure_candidates(
    ctx: TraceContext, t_idx: np.ndarray, w_idx: np.ndarray, r_idx: np.ndarray
) -> Paths:
    """D paths of (transmitter, wedge, receiver) candidates: Keller's points on the edges,
    valid diffractions, then :func:`evaluate`."""
    w = ctx.scene.wedges
    kp = keller_points(take_rows(ctx.tx, t_idx), take_rows(ctx.rx, r_idx),
                       take_rows(w.start, w_idx), take_rows(w.end, w_idx))  # fmt: skip
    ok = np.flatnonzero(kp.on_edge)
    t_idx, w_idx, r_idx, pt = t_idx[ok], w_idx[ok], r_idx[ok], take_rows(kp.point, ok)
    ok = np.flatnonzero(_valid_geometry(ctx, w_idx, take_rows(ctx.tx, t_idx),
                                        take_rows(ctx.rx, r_idx), pt))  # fmt: skip
    t_idx, w_idx, r_idx, pt = t_idx[ok], w_idx[ok], r_idx[ok], take_rows(pt, ok)
    kinds = np.full((len(t_idx), 1), DIFFRACTION, np.int8)
    cand = candidates(ctx, t_idx, r_idx, pt[:, None, :], w_idx[:, None], kinds=kinds)
    return evaluate(ctx, cand, diffraction=field_model(ctx))


class _PairGeometry:
    """What :func:`_facet_wedge_pairs` reuses for every end point: facet spheres, normals,
    offsets and boxes, wedge groups by object with their spheres, and each edge's sphere."""

    def __init__(self, ctx: TraceContext) -> None:
        fc, w, c = ctx.scene.facets, ctx.scene.wedges, carray
        self.f_centre, self.f_radius = accel.facet_spheres(fc)
        order, start, count, centre, radius = accel.wedge_groups(w)
        lo, hi = accel.facet_boxes(fc, ctx.scene.margin)
        self.g_order, self.g_start = c(order, np.int64), c(start, np.int64)
        self.facets = (c(fc.normal), c(fc.offset), c(lo), c(hi))
        self.groups = (self.g_order, self.g_start, c(count, np.int64), c(centre), c(radius))
        length = np.einsum("ij,ij->i", w.end - w.start, w.direction)
        half = 0.5 * w.length * (1 + 1e-9) + 1e-9
        self.wedges = (c(w.start), c(w.end), c(0.5 * (w.start + w.end)), c(half), c(length))

    @staticmethod
    def of(ctx: TraceContext) -> _PairGeometry:
        """The scene's pair geometry (cached on its wedges, per scene margin)."""
        key = ("pair_geometry", float(ctx.scene.margin))
        cached = ctx.scene.wedges.cache.get(key)
        if cached is None or cached[0] is not ctx.scene.facets:
            cached = ctx.scene.wedges.cache[key] = (ctx.scene.facets, _PairGeometry(ctx))
        return cached[1]


def _facet_wedge_pairs(
    ctx: TraceContext, ends: np.ndarray, mixed_rdr: bool = False, keep: bool = False
) -> tuple[np.ndarray, ...]:
    """(end point, facet, wedge) triples where a reflection in the facet can reach the edge:
    every chunk of :func:`_triple_chunks` joined (the RDR stage joins the two sides' triples by
    wedge).

    Returns
    -------
    e_idx, f_idx, w_idx : (M,) int
    image : (M, 3) float, the end's image in the facet, metres
    t_lo, t_hi : (M,) float, metres from the wedge's start: the part of the edge seen from the
        image through the facet's bounding box, padded by :data:`SPAN_PAD_M`. A diffraction
        point of this reflection lies in it (necessary condition).
    """
    parts = list(_triple_chunks(ctx, ends, mixed_rdr, keep))
    if not parts:
        return tuple(x[:0] for x in _pair_buffers(0)[:-1])
    return tuple(np.concatenate(x) for x in zip(*parts))


def _triple_chunks(
    ctx: TraceContext, ends: np.ndarray, mixed_rdr: bool = False, keep: bool = False,
    only: np.ndarray | None = None,
) -> Iterator[tuple[np.ndarray, ...]]:
    """The (end point, facet, wedge) triples of :func:`_facet_wedge_pairs`, in chunks of about
    :data:`TRIPLE_CHUNK`: the ends' own chunks (:func:`_end_chunks`) joined in order until a
    chunk holds that many, so that a small scene's ends make one batch (each batch pays the
    stages' fixed costs: one per end was 35 % of the hall's trace) and a large one's stay
    bounded."""
    held: list[tuple[np.ndarray, ...]] = []
    n = 0
    for chunk in _end_chunks(ctx, ends, mixed_rdr, keep, only):
        held.append(chunk)
        n += len(chunk[0])
        if n >= TRIPLE_CHUNK:
            yield _joined(held)
            held, n = [], 0
    if held:
        yield _joined(held)


def _joined(chunks: list[tuple[np.ndarray, ...]]) -> tuple[np.ndarray, ...]:
    return chunks[0] if len(chunks) == 1 else tuple(np.concatenate(a) for a in zip(*chunks))


def _end_chunks(
    ctx: TraceContext, ends: np.ndarray, mixed_rdr: bool = False, keep: bool = False,
    only: np.ndarray | None = None,
) -> Iterator[tuple[np.ndarray, ...]]:
    """The (end point, facet, wedge) triples of :func:`_facet_wedge_pairs`, one end at a time,
    each end's in chunks of at most about :data:`TRIPLE_CHUNK` (the triples of a wall and every
    edge of a scanned machine are millions, and the stages expand and test each chunk before
    the next).

    ``ends`` are transmitters (for RD) or receivers (for DR); ``mixed_rdr`` keeps every pair (the
    restriction to some objects is applied to the joined RDR triples instead). Exact necessary
    conditions, cheapest first: the bounding sphere of a group of edges (a node of the edges'
    tree; with :data:`raytrace.solver.kernels.EXHAUSTIVE`, an object's edges) must reach the
    end's side of the facet plane and the beam from the end's image through the facet's bounding
    sphere; per edge, the same with the edge's own sphere; the image must not be inside the
    wedge; then the edge, clipped to the end's side and projected from the image onto the
    facet's plane, must meet the facet's (slightly grown) bounding box
    (:func:`raytrace.solver.kernels.facet_wedge_pairs_tree`). With ``keep`` (the transmitters),
    an end's triples, when at most :data:`KEEP_MAX_TRIPLES`, are kept on the scene for the next
    trace with the same end, restriction and pruning (:data:`END_PAIRS_KEPT`), the ones every
    path of which an opaque solid blocks dropped first. With ``only`` (int indices of ``ends``),
    those ends' triples only (``ends`` stays the trace's own, whose shadows are computed once).
    """
    fc = ctx.scene.facets
    side = shadow.reflecting_sides(ctx, ends)  # (E, K), none in a facet in the end's shadow
    geo = _PairGeometry.of(ctx)
    if ctx.facet_mask is not None and not mixed_rdr:
        # only pairs with the wedge or the facet on a chosen object (a group is one object's)
        f_chosen = np.ascontiguousarray(ctx.facet_mask, dtype=bool)
        g_chosen = np.ascontiguousarray(ctx.wedge_mask[geo.g_order[geo.g_start]], dtype=bool)
    else:
        f_chosen = np.ones(len(fc), dtype=bool)
        g_chosen = np.ones(len(geo.g_start), dtype=bool)
    tables = kernels.use_tables(len(fc), len(ctx.scene.wedges)) and not ctx.cfg.facet_reach
    if tables:
        fixed = (*geo.facets[:2], f_chosen, *geo.facets[2:], *geo.groups, g_chosen, *geo.wedges,
                 *_wedge_frame(ctx).kernel_args, accel.PLANE_TOL_M, SPAN_PAD_M, kernels.PRUNE)  # fmt: skip
    else:
        fixed = _wedge_walks(ctx, geo, None if f_chosen.all() else f_chosen)
    taken = range(len(ends)) if only is None else only
    if not keep:
        for e in taken:
            yield from _end_triples(fc, geo, fixed, ends[e], side[e], e, tables)
        return
    kept = ctx.scene.wedges.cache.setdefault("end_pairs", {})
    mask = (None if ctx.facet_mask is None or mixed_rdr
            else (ctx.facet_mask.tobytes(), ctx.wedge_mask.tobytes()))  # fmt: skip
    for e in taken:
        key = (ends[e].tobytes(), side[e].tobytes(), mask, kernels.PRUNE, float(ctx.scene.margin),
               ctx.opaque.tobytes(), ctx.cfg.facet_reach)
        found = kept.get(key)
        if found is None:
            found = yield from _kept_triples(ctx, fc, geo, fixed, ends[e], side[e], e, tables)
            if found is None:  # too many to keep: streamed already
                continue
            keep_bounded(kept, key, found, END_PAIRS_KEPT)
        if len(found[0]):
            yield (np.full(len(found[0]), e), *found)


def _kept_triples(ctx: TraceContext, fc, geo: _PairGeometry, fixed: tuple, end: np.ndarray,
                  side_e: np.ndarray, e: int, tables: bool):  # fmt: skip
    """A transmitter's triples to keep (a generator): gathered while they are at most
    :data:`KEEP_MAX_TRIPLES`, then returned (without the end index, read-only) for the caller
    to keep and yield; beyond that, every chunk is yielded as it comes and None returned."""
    held: list[tuple[np.ndarray, ...]] = []
    n = 0
    chunks = _end_triples(fc, geo, fixed, end, side_e, e, tables)
    for chunk in chunks:
        held.append(chunk)
        n += len(chunk[0])
        if n > KEEP_MAX_TRIPLES:
            yield from held
            yield from chunks
            return None
    found = (tuple(np.concatenate(x) for x in zip(*held)) if held
             else tuple(x[:0] for x in _pair_buffers(0)[:-1]))  # fmt: skip
    found = found[1:]
    if kernels.PRUNE and ctx.facet_mask is None:
        # triples whose every path is blocked by an opaque solid (shadow.py)
        keep = ~shadow.triples_in_shadow(ctx.scene, ctx.opaque, end, *found)
        found = tuple(x[keep] for x in found)
    found = tuple(x.copy() for x in found)
    for x in found:
        x.setflags(write=False)
    return found


#: End points (transmitters) whose (facet, wedge) triples are kept per scene: a grid is traced
#: in chunks of receivers against the same few transmitters.
END_PAIRS_KEPT = 16
#: Rows of the triples' buffers per end point to start with (they double when full; an end of
#: the hall has about 7 000 triples).
PAIRS_PER_END = 8192
#: Triples of one end in one chunk of :func:`_triple_chunks` (64 bytes each), about.
TRIPLE_CHUNK = 1 << 20
#: A transmitter's triples are kept for the next trace only when at most this many (an end of
#: the hall has about 7 000; one of a hall with scanned machines, millions: streamed).
KEEP_MAX_TRIPLES = 1 << 19


def _pair_buffers(n: int) -> tuple:
    """Empty output buffers of :func:`raytrace.solver.kernels.facet_wedge_pairs` for ``n``
    triples (end, facet, wedge, image, span lo, hi), and 0 rows written."""
    i = lambda: np.empty(n, dtype=np.int64)  # noqa: E731
    return i(), i(), i(), np.empty((n, 3)), np.empty(n), np.empty(n), 0


def _end_triples(fc, geo: _PairGeometry, fixed: tuple, end: np.ndarray, side_e: np.ndarray,
                 e: int, tables: bool) -> Iterator[tuple[np.ndarray, ...]]:  # fmt: skip
    """End point ``e``'s triples (:func:`_triple_chunks`), in chunks: by the scan of
    :func:`raytrace.solver.kernels.facet_wedge_pairs` (``tables``) or the trees' walks."""
    f_ok = np.flatnonzero(side_e != 0)
    sgn = side_e[f_ok].astype(float)
    nrm, off = fc.normal[f_ok], fc.offset[f_ok]
    h_f = np.abs(end @ nrm.T - off)  # the end's distance from each plane
    img_f = end - 2.0 * (sgn * h_f)[:, None] * nrm
    # the beam from the image through each facet's bounding sphere
    f_beam = refl.beam(img_f, geo.f_centre[f_ok], geo.f_radius[f_ok])
    c = np.ascontiguousarray
    per_facet = (f_ok, sgn, h_f, c(img_f.T), c(f_beam.axis.T), f_beam.cos_a, f_beam.sin_a,
                 f_beam.apex_inside)  # fmt: skip
    if tables:
        *arrays, m = kernels.facet_wedge_pairs(*per_facet, *fixed, e, *_pair_buffers(PAIRS_PER_END))
        if m:
            yield tuple(x[:m] for x in arrays)
        return
    walks, tail = fixed
    for leaves, asks, lists in walks:
        active = np.ones(len(f_ok), dtype=bool) if asks is None else c(asks[f_ok])
        # the approximate discovery (solver/near.py): the small facets take their own lists
        walked = active if lists is None else active & ~lists[0][f_ok]
        yield from _streamed(partial(kernels.facet_wedge_pairs_tree, *per_facet, walked,
                                     *geo.facets, *leaves, *tail, e), len(f_ok))  # fmt: skip
        if lists is not None:
            yield from _streamed(partial(kernels.facet_wedge_pairs_near, *per_facet,
                                         active & lists[0][f_ok], *geo.facets, *lists[1:],
                                         *leaves[6:], *tail, e), len(f_ok))  # fmt: skip


def _streamed(run, n: int) -> Iterator[tuple[np.ndarray, ...]]:
    """The triples of a walk kernel over ``n`` facets (``run(*buffers, j)`` fills the buffers
    with whole facets from ``j`` on and returns the rows written and the next facet), in chunks:
    buffers that double when one facet's triples do not fit, up to :data:`TRIPLE_CHUNK`."""
    j, rows = 0, PAIRS_PER_END
    while j < n:
        *arrays, _ = _pair_buffers(rows)
        m, j_next = run(*arrays, j)
        if m:
            yield tuple(x[:m] for x in arrays)
        if j_next < n:
            # full: larger buffers next (one facet's triples never split), up to a chunk
            rows = 2 * rows if m == 0 else min(2 * rows, max(rows, TRIPLE_CHUNK))
        j = j_next


def _wedge_walks(ctx: TraceContext, geo: _PairGeometry,
                 f_chosen: np.ndarray | None) -> tuple[list, tuple]:  # fmt: skip
    """The trees of edges a facet's beam walks in :func:`_end_triples`
    (:class:`raytrace.solver.kernels.EdgeLeaves`: the scene's, or for a scene with moving
    objects the static scene's and the moving objects'; cached), each with the facets that ask
    it (None: all); with ``f_chosen`` (K,) bool (a trace of some objects only) the chosen facets
    ask every tree and the others one over the chosen edges only. And what the kernel takes
    after the edges (the wedge frame's scalars, tolerances, pruning)."""
    w = ctx.scene.wedges
    frame = _wedge_frame(ctx).kernel_args
    forest = accel.wedge_forest(w)
    cached = w.cache.get("edge_leaves")
    if cached is None or cached[0] is not forest:
        leaves = [kernels.edge_leaves(tree, np.arange(tree.size) + first, geo.wedges, frame)
                  for tree, first in forest]  # fmt: skip
        cached = w.cache["edge_leaves"] = (forest, leaves)
    reach = ctx.cfg.facet_reach
    small = near.small_facets(ctx.scene.facets, reach) if reach else None

    def lists(tree, kept: int | None):
        # the approximate discovery's lists of a tree: kept on the scene for the forest's tree
        # number ``kept`` (while its tree and the facets are the same), made again for a
        # restricted trace's tree of the chosen edges (kept None)
        if small is None or not small.any():
            return None
        fc = ctx.scene.facets
        key = ("near_edges", float(reach), kept)
        found = w.cache.get(key) if kept is not None else None
        if found is None or found[0] is not tree or found[1] is not fc:
            found = (tree, fc, (small, *near.near_edges(fc, tree, reach, small)))
            if kept is not None:
                w.cache[key] = found
        return found[2]

    walks = ([(leaves, f_chosen, lists(tree, i))
              for i, (leaves, (tree, _)) in enumerate(zip(cached[1], forest))]
             if len(w) else [])  # fmt: skip
    if len(w) and f_chosen is not None:
        chosen = np.flatnonzero(ctx.wedge_mask)
        if len(chosen):
            a, b = w.start[chosen], w.end[chosen]
            tree = build_tree(np.minimum(a, b), np.maximum(a, b), 0.5 * (a + b),
                              0.5 * w.length[chosen] * (1 + 1e-9) + 1e-9)  # fmt: skip
            walks.append((kernels.edge_leaves(tree, chosen, geo.wedges, frame), ~f_chosen,
                          lists(tree, None)))
    tail = (*frame[7:], accel.PLANE_TOL_M, SPAN_PAD_M, kernels.PRUNE)
    return walks, tail


def _one_reflection(ctx: TraceContext, before: bool, part: int = 0, parts: int = 1) -> list[Paths]:
    """RD (``before=True``: reflection at the transmitter's side) or DR paths, one chunk of
    (end, facet, wedge) triples at a time (:func:`_triple_chunks`); of the end points (the
    transmitters for RD) ``part``, ``part + parts``, ... only."""
    fc, w = ctx.scene.facets, ctx.scene.wedges
    ends, others = (ctx.tx, ctx.rx) if before else (ctx.rx, ctx.tx)
    side_e = carray(refl.reflecting_side(fc, ends), np.int8)
    # Keller's point in scalar form (see keller_points): t = ts + (td - ts) rho_s / (rho_s + rho_d)
    # with the end's image (ts, rho_s) per triple and the other end (td, rho_d) per wedge, so
    # that the expansion over the other ends is a cheap (triples, others) pass
    start_c, dir_c = w.start.T, w.direction.T
    td_w, rho_w = _along_and_off(
        others.T[:, None, :], start_c[..., None], dir_c[..., None]
    )  # (W, O)
    # the other end inside the wedge: never a valid diffraction
    o_xyz = others.T[:, None, :]  # (3, 1, O)
    open_w = ~_surely_inside(_wedge_frame(ctx), np.arange(len(w))[:, None], *o_xyz)
    # or seeing the edge only through an opaque solid
    open_w &= ~shadow.shadows_of(ctx, others)[1].T
    fr = _wedge_frame(ctx).utd
    fixed = (carray(others), carray(td_w), carray(rho_w), carray(open_w, bool), carray(w.start),
             carray(w.direction), carray(w.end), carray(fc.normal), carray(fc.offset), side_e,
             *accel.facet_test_arrays(fc), accel.BARY_TOL, accel.RECT_INSIDE_M, KELLER_TOL_M,
             carray(fr.edge_dir), carray(fr.face0_tangent), carray(fr.normal_0), carray(fr.n),
             before, kernels.PRUNE)  # fmt: skip
    out = []
    tx, rx = carray(ctx.tx), carray(ctx.rx)
    facet_obj = carray(fc.object, np.int64)
    wedge_obj = carray(w.object if len(w) else np.zeros(0), np.int64)
    n_o = len(others)
    step = max(1, CHUNK // max(n_o, 1))
    only = None if parts == 1 else np.arange(part, len(ends), parts)
    for e_idx, f_idx, w_idx, img, t_lo, t_hi in _triple_chunks(ctx, ends, keep=before, only=only):
        triples = (carray(e_idx, np.int64), carray(f_idx, np.int64), carray(w_idx, np.int64),
                   carray(img), carray(t_lo), carray(t_hi))  # fmt: skip
        for c0 in range(0, len(e_idx), step):
            # the pruned pairs' exact tests, one pair at a time: Keller's point on the edge and
            # on the end's side of the facet, the reflection point on the facet, a valid
            # diffraction
            q, o_idx, pts, n_pairs = kernels.reflection_edge_points(
                c0, min(len(e_idx), c0 + step), *triples, *fixed
            )  # fmt: skip
            ctx.count("candidates_rd" if before else "candidates_dr", n_pairs)
            if not len(q):
                continue
            cand = Candidates(*kernels.mixed_candidates(q, o_idx, pts, *triples[:3], tx, rx,
                                                         facet_obj, wedge_obj, before,
                                                         REFLECTION, DIFFRACTION))  # fmt: skip
            out.append(evaluate(ctx, cand, diffraction=field_model(ctx)))
    return out


def _along_and_off(
    p: np.ndarray, start: np.ndarray, direction: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Position along edge lines (m from ``start``) of the foot of points, and their distance
    from the lines (m) (:func:`raytrace.solver.kernels.prune.along_and_off`, which only prunes,
    within :data:`SPAN_PAD_M`); components first: (3, ...) arrays, broadcasting over the rest."""
    shape = np.broadcast_shapes(p.shape, start.shape, direction.shape)
    rows = [carray(np.moveaxis(np.broadcast_to(x, shape), 0, -1)).reshape(-1, 3)
            for x in (p, start, direction)]  # fmt: skip
    t, rho = kernels.along_and_off_rows(*rows)
    return t.reshape(shape[1:]), rho.reshape(shape[1:])


def _two_reflections(ctx: TraceContext) -> list[Paths]:
    """RDR paths: a reflection on each side of the edge (the two pruned sets joined on the wedge)."""
    fc, w = ctx.scene.facets, ctx.scene.wedges
    t_e, t_f, t_w, t_img, t_lo, t_hi = _facet_wedge_pairs(ctx, ctx.tx, mixed_rdr=True, keep=True)
    r_e, r_f, r_w, r_img, r_lo, r_hi = _facet_wedge_pairs(ctx, ctx.rx, mixed_rdr=True)
    side_t = refl.reflecting_side(fc, ctx.tx)
    side_r = refl.reflecting_side(fc, ctx.rx)
    out = []
    order = np.argsort(r_w, kind="stable")
    r_w_sorted = r_w[order]
    starts = np.searchsorted(r_w_sorted, t_w, side="left")
    ends = np.searchsorted(r_w_sorted, t_w, side="right")
    counts = ends - starts
    a = np.repeat(np.arange(len(t_w)), counts)
    b = order[
        np.repeat(starts, counts)
        + (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))
    ]
    # the diffraction point lies in the part of the edge seen through both facets
    keep = np.maximum(t_lo[a], r_lo[b]) <= np.minimum(t_hi[a], r_hi[b])
    if ctx.facet_mask is not None:
        keep &= ctx.facet_mask[t_f[a]] | ctx.wedge_mask[t_w[a]] | ctx.facet_mask[r_f[b]]
    a, b = a[keep], b[keep]
    ctx.count("candidates_rdr", len(a))
    for c0 in range(0, len(a), CHUNK):
        ia, ib = a[c0 : c0 + CHUNK], b[c0 : c0 + CHUNK]
        ww = t_w[ia]
        kp = keller_points(t_img[ia], r_img[ib], w.start[ww], w.end[ww])
        ok = kp.on_edge
        dpt = kp.point
        f1, f2 = t_f[ia], r_f[ib]
        s1 = refl.signed_distance(dpt, fc.normal[f1], fc.offset[f1])
        s2 = refl.signed_distance(dpt, fc.normal[f2], fc.offset[f2])
        ok &= (np.sign(np.where(ok, s1, 0)) == side_t[t_e[ia], f1]) & (
            np.sign(np.where(ok, s2, 0)) == side_r[r_e[ib], f2]
        )
        u1, p1 = refl.segment_plane_point(t_img[ia], dpt, fc.normal[f1], fc.offset[f1])
        u2, p2 = refl.segment_plane_point(r_img[ib], dpt, fc.normal[f2], fc.offset[f2])
        ok &= (u1 > 0) & (u1 < 1) & (u2 > 0) & (u2 < 1)
        ok[ok] = accel.points_in_facets(p1[ok], f1[ok], fc)
        ok[ok] = accel.points_in_facets(p2[ok], f2[ok], fc)
        ok[ok] = _valid_geometry(ctx, ww[ok], t_img[ia][ok], r_img[ib][ok], dpt[ok])
        if ok.any():
            n = int(ok.sum())
            out.append(
                evaluate(
                    ctx,
                    candidates(
                        ctx,
                        t_e[ia][ok],
                        r_e[ib][ok],
                        np.stack([p1[ok], dpt[ok], p2[ok]], axis=1),
                        np.stack([f1[ok], ww[ok], f2[ok]], axis=1),
                        kinds=np.repeat(
                            np.array([[REFLECTION, DIFFRACTION, REFLECTION]], np.int8), n, axis=0
                        ),
                    ),
                    diffraction=field_model(ctx),
                )
            )
    return out
