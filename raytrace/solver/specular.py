"""Specular stages of the tracer: line of sight, first- and second-order reflections.

Image method over the scene's planar facets (a closed solid's facet reflects on its outward side,
an open sheet's on both): the candidates of each stage are vertex chains that
:func:`raytrace.solver.evaluate.evaluate` turns into paths (visibility, penetrations, fields).
These stages mirror the diffraction stages of :mod:`raytrace.solver.diffraction`; only the
tracer calls them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core.jit import carray
from ..core.kept import keep
from ..scene import accel
from ..scene.spatial import build_tree
from . import kernels, near, shadow
from . import reflection as refl
from .context import TraceContext
from .evaluate import candidates, evaluate
from .paths import Paths

#: Work is split into chunks of about this many candidate paths to bound memory.
CHUNK = 400_000


def stages(ctx: TraceContext) -> list[tuple[str, Callable[[], list[Paths]]]]:
    """The specular stages allowed by the context's limits, as (name, callable) pairs."""
    cfg = ctx.cfg
    out: list[tuple[str, Callable[[], list[Paths]]]] = []
    if ctx.facet_mask is None:  # line of sight involves no object
        out.append(("line of sight", lambda: line_of_sight(ctx)))
    if cfg.max_reflections >= 1 and cfg.max_interactions >= 1:
        out.append(("1st-order reflections", lambda: first_order(ctx)))
    if cfg.max_reflections >= 2 and cfg.max_interactions >= 2:
        out.append(("2nd-order reflections", lambda: second_order(ctx)))
    return out


def line_of_sight(ctx: TraceContext) -> list[Paths]:
    """Line of sight: every link, no vertex."""
    t_idx, r_idx = np.divmod(np.arange(len(ctx.tx) * len(ctx.rx)), len(ctx.rx))
    return [
        evaluate(
            ctx,
            candidates(
                ctx, t_idx, r_idx, np.zeros((len(t_idx), 0, 3)), np.zeros((len(t_idx), 0), int)
            ),
        )
    ]


def first_order(ctx: TraceContext) -> list[Paths]:
    """Single reflections: the image of the transmitter in every facet that both ends see on a
    reflecting side, through the receiver, crossing the facet."""
    fc = ctx.scene.facets
    # (a facet that an end sees only through an opaque solid reflects nothing of it)
    side_tx = shadow.reflecting_sides(ctx, ctx.tx)  # (T, K)
    side_rx = shadow.reflecting_sides(ctx, ctx.rx)  # (R, K)
    if kernels.use_tables(len(fc), len(ctx.scene.wedges)):
        ok_tkr = (side_tx[:, :, None] != 0) & (side_tx[:, :, None] == side_rx.T[None])
        if ctx.facet_mask is not None:
            ok_tkr &= ctx.facet_mask[None, :, None]
        t_idx, k_idx, r_idx = np.nonzero(ok_tkr)
    else:
        # the triples whose receiver is in the beam from the image through the facet (no
        # (transmitters x facets x receivers) table)
        centre, radius = accel.facet_spheres(fc)
        rx_centre = 0.5 * (ctx.rx.min(axis=0) + ctx.rx.max(axis=0))
        rx_radius = float(np.sqrt(((ctx.rx - rx_centre) ** 2).sum(axis=1)).max()) * (1 + 1e-9)
        chosen = np.ones(len(fc), bool) if ctx.facet_mask is None else ctx.facet_mask
        t_idx, k_idx, r_idx = kernels.first_order_candidates(
            carray(side_tx, np.int8), carray(side_rx, np.int8), carray(chosen, bool),
            carray(ctx.tx), carray(ctx.rx), carray(fc.normal), carray(fc.offset), carray(centre),
            carray(radius), *rx_centre, rx_radius + 1e-9, kernels.PRUNE)  # fmt: skip
    ctx.count("candidates_r1", len(t_idx))
    img = refl.mirror(ctx.tx[t_idx], fc.normal[k_idx], fc.offset[k_idx])
    u, p = refl.segment_plane_point(ctx.rx[r_idx], img, fc.normal[k_idx], fc.offset[k_idx])
    ok = (u > 0) & (u < 1)
    ok[ok] = accel.points_in_facets(p[ok], k_idx[ok], fc)
    return [
        evaluate(ctx, candidates(ctx, t_idx[ok], r_idx[ok], p[ok][:, None, :], k_idx[ok][:, None]))
    ]


def second_order(ctx: TraceContext) -> list[Paths]:
    """Double reflections: images of images over the facet pairs that can exchange a reflection,
    found by beam queries on the facets' trees (:func:`_second_images`), pruned by beams through
    the facets' bounding spheres, one transmitter at a time (the transmitter's side kept on the
    scene), the candidates of all transmitters evaluated together."""
    fc = ctx.scene.facets
    # (no second reflection in a facet the receiver sees only through an opaque solid)
    side_rx = shadow.reflecting_sides(ctx, ctx.rx)  # (R, K)
    rx_centre = 0.5 * (ctx.rx.min(axis=0) + ctx.rx.max(axis=0))
    rx_radius = float(np.sqrt(((ctx.rx - rx_centre) ** 2).sum(axis=1)).max()) * (1 + 1e-9) + 1e-9
    side_rx, rx = carray(side_rx, np.int8), carray(ctx.rx)
    normal, offset = carray(fc.normal), carray(fc.offset)
    facet_tests = (*accel.facet_test_arrays(fc), accel.BARY_TOL, accel.RECT_INSIDE_M)
    out: list[Paths] = []
    # candidates that passed the exact tests, evaluated together (all transmitters' few in one
    # pass) once there are CHUNK of them and at the end
    found: list[tuple[np.ndarray, ...]] = []

    def flush() -> None:
        out.append(evaluate(ctx, candidates(ctx, *(np.concatenate(x) for x in zip(*found)))))
        found.clear()

    shadow_tx = shadow.shadows_of(ctx, ctx.tx)[0]
    for t in range(len(ctx.tx)):
        # the last transmitter's images go first (unless kept): a million-triangle hall's are
        # 1.7 GB, and two transmitters' at once were the trace's peak
        f1a = f2 = receiver_args = exact_args = None
        _, _, _, f1a, f2, _, _, receiver_args, exact_args = _second_images(
            ctx, t, shadow_tx[t], (side_rx, rx))
        if len(f1a) == 0:
            continue
        # receivers on the same side of the second facet as the first image, inside the
        # beam from the second image through the second facet; unfolded at the second
        # reflection, the path is straight from the first image to the receiver's mirror image
        # in the second facet, through the first facet. Second images whose beam misses the
        # receivers' bounding sphere are skipped whole.
        # the exact tests follow in the same pass: the segment receiver -> second image
        # crosses the second facet, the segment from there to the first image crosses the
        # first facet, and the second reflection point is on the transmitter's side of the
        # first facet (kernels.second_order_candidates)
        step = max(1, CHUNK // max(len(ctx.rx), 1))
        for c0 in range(0, len(f1a), step):
            q, r_idx, pts, n_pairs = kernels.second_order_candidates(
                c0, min(len(f1a), c0 + step), *receiver_args[:2], side_rx, *receiver_args[2:],
                rx, *rx_centre, rx_radius, kernels.PRUNE, *exact_args[:4], normal, offset,
                exact_args[4], *facet_tests, True,
            )  # fmt: skip
            ctx.count("candidates_r2", n_pairs)
            if len(q):
                found.append((np.full(len(q), t), r_idx, pts.reshape(-1, 2, 3),
                              np.stack([f1a[q], f2[q]], axis=1)))  # fmt: skip
                if sum(len(x[0]) for x in found) >= CHUNK:
                    flush()
    if found:
        flush()
    return out


#: Transmitters whose second images :func:`second_order` keeps per scene: a grid is traced in
#: chunks of receivers against the same few transmitters, and these do not depend on them.
SECOND_IMAGES_KEPT = 16
#: ... and at most this many bytes of them, the oldest dropped first (a transmitter's take
#: about 1.8 kB per facet of a scanned hall, 0.44 GB at 247 040 triangles: a million-triangle
#: hall's are made again per trace rather than held between traces).
SECOND_IMAGES_KEPT_BYTES = 1 << 30


def _second_images(ctx: TraceContext, t: int, in_shadow: np.ndarray,
                   receivers: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, ...]:  # fmt: skip
    """Transmitter ``t``'s side of double reflections (cached on the facets, per transmitter
    position, facet restriction, facets in its shadow (``in_shadow`` (K,) bool: no first
    reflection there) and :data:`raytrace.solver.kernels.PRUNE`).

    With ``receivers`` (``side_rx`` (R, K) int8, ``rx`` (R, 3), C-contiguous), pairs too many
    to keep (:func:`_kept_bytes` beyond :data:`SECOND_IMAGES_KEPT_BYTES`, or beyond one
    transmitter's share of it, 1 / :data:`SECOND_IMAGES_KEPT`, with ``facet_reach``) are made
    for these receivers only: the pairs that can reach none of them
    (:func:`raytrace.solver.kernels.second_pairs_reaching`) are dropped before they are sorted,
    mirrored and given beams, and the result is not kept. On a million-triangle hall that was
    most of a transmitter's tens of millions of pairs, for the same candidates.

    Returns
    -------
    side_t : (K,) int8, the transmitter's reflecting side of every facet
    img1 : (F1, 3) float, its images in the first facets, metres
    i1 : (M,) int, rows of ``img1``; f1, f2 : (M,) int, first and second facets
    img2 : (M, 3) float, the second images, metres
    s_img : (M,) int8, the side of the second facet the first image is on
    receiver_args : tuple, the per-image arguments of
        :func:`raytrace.solver.kernels.second_order_candidates` (``f2``, ``s_img``, the beams
        from the second images through the second facets, per pair, and from the first images
        through the first facets, per first image), around ``side_rx``
    exact_args : tuple, the arguments of its exact tests (``img1``, ``i1``, ``f1``, ``img2``,
        ``side_t``, writable copies)
    """
    fc = ctx.scene.facets
    mask = None if ctx.facet_mask is None else ctx.facet_mask.tobytes()
    reach = ctx.cfg.facet_reach
    key = (ctx.tx[t].tobytes(), mask, np.packbits(in_shadow).tobytes(), kernels.PRUNE, reach)
    kept = fc.cache.setdefault("second_images", {})
    found = kept.get(key)
    if found is not None:
        return found
    centre, radius = accel.facet_spheres(fc)
    side_t = refl.reflecting_side(fc, ctx.tx[t : t + 1])[0]  # (K,)
    f1 = np.flatnonzero((side_t != 0) & ~in_shadow)
    img1 = refl.mirror(np.broadcast_to(ctx.tx[t], (len(f1), 3)), fc.normal[f1], fc.offset[f1])
    # the second facets: those whose sphere the rays from the first image through the first
    # facet's sphere can reach, with some part on the transmitter's side of the first facet
    # (a query on the facets' trees, output-sensitive: no (facets x facets) table)
    b1 = refl.beam(img1, centre[f1], radius[f1])
    # (for the paths of some objects only: a first facet on them, or a second one)
    tables = kernels.use_tables(len(fc), len(ctx.scene.wedges)) and not reach
    if reach:  # the approximate discovery (solver/near.py)
        a, f2, s_img = _near_second_facets(fc, f1, b1, side_t[f1], ctx.facet_mask, reach)
    elif tables:  # the (facets x facets) table
        a, f2 = _table_pairs(fc, f1, ctx.facet_mask)
        # the pairs that can exchange a reflection (facing each other, not the same plane),
        # the first image on a reflecting side of the second facet (exact necessary conditions)
        s_img = refl.side_of(fc, img1[a], f2)
        ok = (s_img != 0) & accel.facing(fc, f1[a], f2)
        a, f2, s_img = a[ok], f2[ok], s_img[ok]
        # beam test: the second facet must meet the rays from the first image through the
        # first facet (bounding spheres: a necessary condition)
        beam = refl.cone_reaches(img1[a], centre[f1[a]], radius[f1[a]], centre[f2], radius[f2])
        a, f2, s_img = a[beam], f2[beam], s_img[beam]
    else:  # the trees' beam queries, the same conditions in one compiled pass
        a, f2, s_img = _second_facets(fc, f1, b1, side_t[f1], ctx.facet_mask)
    # the approximate discovery is for the largest scenes: a transmitter's images are kept
    # only within its share of the kept bytes, so that its first trace neither sorts nor
    # holds pairs that reach no receiver (1 GiB kept was the million-triangle trace's peak)
    limit = SECOND_IMAGES_KEPT_BYTES // (SECOND_IMAGES_KEPT if reach else 1)
    if (not tables and receivers is not None and kernels.PRUNE
            and _kept_bytes(len(a), len(f1), len(fc)) > limit):  # fmt: skip
        reaching = kernels.second_pairs_reaching(
            carray(a, np.int64), carray(f2, np.int64), carray(s_img, np.int8), carray(img1),
            carray(b1.axis), carray(b1.cos_a), carray(b1.apex_inside, bool), carray(fc.normal),
            carray(fc.offset), carray(centre), carray(radius), *receivers, PAIRS_SLACK,
        )  # fmt: skip
        a, f2, s_img = a[reaching], f2[reaching], s_img[reaching]
        key = None  # this trace's receivers' only: not kept
    order = np.lexsort((f2, a))  # in (first image, second facet) order, as a table would give
    c = lambda x, t=np.float64: np.array(x, dtype=t, order="C", copy=True)  # noqa: E731
    a, f2, s_img = c(a[order], np.int64), c(f2[order], np.int64), c(s_img[order], np.int8)
    img2 = c(refl.mirror(img1[a], fc.normal[f2], fc.offset[f2]))
    b2 = refl.beam(img2, centre[f2], radius[f2])
    # the beams through the first facets stay one per first image (b1; the kernel reads row a):
    # per pair, with the second facets' planes, they were most of what was kept
    img1, f1a, side_t = c(img1), c(f1[a], np.int64), c(side_t, np.int8)
    # own writable arrays (the kernel's signature takes writable arrays; it writes none), kept
    # behind read-only views
    receiver_args = (f2, s_img, img2, c(b2.axis), c(b2.cos_a), c(b2.apex_inside, bool),
                     c(b2.sin_a), c(b1.apex), c(b1.axis), c(b1.cos_a),
                     c(b1.apex_inside, bool))  # fmt: skip
    # and for its exact tests: the images, which first image and first facet, the side
    exact_args = (img1, a, f1a, img2, side_t)
    found = tuple(x.view() for x in (side_t, img1, a, f1a, f2, img2, s_img))
    for x in found:
        x.setflags(write=False)
    if key is None:
        return (*found, receiver_args, exact_args)
    return keep(kept, key, (*found, receiver_args, exact_args), SECOND_IMAGES_KEPT,
                SECOND_IMAGES_KEPT_BYTES)


#: Lowered from the beams' cosines in :func:`raytrace.solver.kernels.second_pairs_reaching`, so
#: that its rounding never drops a pair the receivers' exact tests accept (those use 1e-7 already;
#: the rounding of a cosine is about 1e-16).
PAIRS_SLACK = 1e-9


def _kept_bytes(n_pairs: int, n_first: int, n_facets: int) -> int:
    """Bytes of a transmitter's second images as :func:`_second_images` keeps them
    (:func:`raytrace.core.kept.nbytes`): per pair the row, both facets, the second image and its
    beam (8 + 8 + 8 + 1 + 24 + 24 + 8 + 1 + 8), per first image the image and its beam (24 + 24 +
    24 + 8 + 1), per facet the transmitter's side."""
    return 90 * n_pairs + 81 * n_first + n_facets


def _second_facets(fc, f1: np.ndarray, b1: refl.Beam, side1: np.ndarray, mask: np.ndarray | None,
                   forest: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(row of ``f1``, second facet, side of the first image) of the pairs of facets that can
    exchange a reflection from the first images ``b1.apex`` (:func:`_second_images`): the beam
    queries of :func:`raytrace.scene.accel.beam_facets` (with ``mask`` (K,) bool, a trace of
    some objects only: the pairs with a chosen facet), then their exact necessary conditions in
    one compiled pass (:func:`raytrace.solver.kernels.second_facets`). The first facets go in
    blocks of :data:`SECOND_FACETS_BLOCK`: a transmitter of a million-triangle hall has tens of
    millions of queried pairs, of which the conditions keep a few per cent, and the query's
    arrays of all of them at once were gigabytes. The pairs are the same (the caller sorts
    them). With ``forest`` (trees as :func:`raytrace.scene.accel.beam_facets` takes them, and
    the facet of each of their elements), those trees' facets only."""
    parts = []
    facet_args = _facet_args(fc)
    for r0 in range(0, len(f1), SECOND_FACETS_BLOCK):
        rows = slice(r0, r0 + SECOND_FACETS_BLOCK)
        b = refl.Beam(*(x[rows] for x in b1))
        f1_b = f1[rows]
        a, f2 = accel.beam_facets(fc, b, fc.normal[f1_b], fc.offset[f1_b], side1[rows], mask,
                                  None if mask is None else mask[f1_b],
                                  None if forest is None else forest[0])  # fmt: skip
        if forest is not None:
            f2 = forest[1][f2]
        parts.append(_pair_conditions(a, f2, f1_b, b, facet_args, r0))
    return _joined_pairs(parts)


def _facet_args(fc) -> tuple:
    """The facets' arrays :func:`raytrace.solver.kernels.second_facets` takes after the pairs
    (spheres, planes, sides, corners and each facet's run of them), made once per call of the
    callers below, not once per block."""
    c = carray
    centre, radius = accel.facet_spheres(fc)
    starts = c(3 * (np.cumsum(fc.tri_count) - fc.tri_count), np.int64)
    return (c(centre), c(radius), c(fc.normal), c(fc.offset), c(fc.two_sided, bool),
            c(fc.triangles.reshape(-1, 3)), starts, c(3 * fc.tri_count, np.int64),
            accel.PLANE_TOL_M)  # fmt: skip


def _pair_conditions(a: np.ndarray, f2: np.ndarray, f1: np.ndarray, b1: refl.Beam,
                     facet_args: tuple, r0: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The pairs (row ``a`` of ``f1`` and ``b1``, second facet ``f2``) that pass the exact
    necessary conditions of :func:`raytrace.solver.kernels.second_facets` (``facet_args`` of
    :func:`_facet_args`), with the rows shifted by ``r0``, and the side of the second facet the
    first image is on."""
    c = carray
    s_img = kernels.second_facets(
        c(a, np.int64), c(f2, np.int64), c(b1.apex), c(b1.axis), c(b1.cos_a), c(b1.sin_a),
        c(b1.apex_inside, bool), c(f1, np.int64), *facet_args,
    )  # fmt: skip
    ok = s_img != 0
    return a[ok] + r0, f2[ok], s_img[ok]


def _joined_pairs(parts: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int8)
    a, f2, s_img = (np.concatenate(x) for x in zip(*parts))
    return a, f2, s_img


def _near_second_facets(fc, f1: np.ndarray, b1: refl.Beam, side1: np.ndarray,
                        mask: np.ndarray | None, reach: float) -> tuple[np.ndarray, ...]:  # fmt: skip
    """:func:`_second_facets` in the approximate discovery (:mod:`raytrace.solver.near`): the
    pairs of two large facets from the beam queries of the large first facets on a tree of the
    large facets (with ``mask``, on every facet, the small second facets then dropped), and
    the pairs with a small facet from the lists of facets within ``reach``; the same exact
    conditions on both. Rows of ``f1``, in no particular order (the caller sorts them)."""
    small = near.small_facets(fc, reach)
    large = np.flatnonzero(~small[f1])
    b_large = refl.Beam(*(x[large] for x in b1))
    forest = None if mask is not None else _large_forest(fc, reach, small)
    a, f2, s_img = _second_facets(fc, f1[large], b_large, side1[large], mask, forest)
    keep = ~small[f2]
    parts = [(large[a[keep]], f2[keep], s_img[keep])]
    key = ("near_facets", float(reach))
    lists = fc.cache.get(key)
    if lists is None:
        lists = fc.cache[key] = near.near_facets(fc, reach, small)
    facet_args = _facet_args(fc)
    b1 = refl.Beam(*(carray(x, bool if x.dtype == bool else np.float64) for x in b1))
    for a, f2 in near.near_facet_pairs(lists, f1):
        if mask is not None:
            chosen = mask[f1[a]] | mask[f2]
            a, f2 = a[chosen], f2[chosen]
        parts.append(_pair_conditions(a, f2, f1, b1, facet_args))
    return _joined_pairs(parts)


def _large_forest(fc, reach: float, small: np.ndarray) -> tuple[tuple, np.ndarray]:
    """A tree over the facets that are not small (cached per ``reach``) as
    :func:`raytrace.scene.accel.beam_facets` takes trees, and those facets' indices."""
    key = ("large_tree", float(reach))
    cached = fc.cache.get(key)
    if cached is None:
        large = np.flatnonzero(~small)
        lo, hi = accel.facet_boxes(fc, 0.0)
        centre, radius = accel.facet_spheres(fc)
        tree = build_tree(lo[large], hi[large], centre[large], radius[large])
        cached = fc.cache[key] = (((tree, 0),), large)
    return cached


#: First facets per block of :func:`_second_facets` (a block's queried pairs are about a
#: hundred per first facet on a scanned hall: 16 bytes each, and as many again sorting them).
SECOND_FACETS_BLOCK = 1 << 15


def _table_pairs(fc, f1: np.ndarray, mask: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(row of ``f1``, second facet) pairs of the facets' pair table
    (:func:`raytrace.scene.accel.facing_pairs`, restricted to pairs with a chosen facet): the
    exhaustive path of :data:`raytrace.solver.kernels.EXHAUSTIVE`, for small scenes."""
    pairs = accel.facing_pairs(fc)[f1]
    if mask is not None:
        pairs = pairs & (mask[f1][:, None] | mask[None, :])
    return np.nonzero(pairs)

