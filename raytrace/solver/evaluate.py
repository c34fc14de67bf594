"""The common back end of every stage: candidate paths -> visible paths with their fields.

A stage (:mod:`raytrace.solver.specular`, :mod:`raytrace.solver.diffraction`) proposes candidate
paths as vertex chains; :func:`evaluate` then

1. drops candidates with a segment through an opaque object (one Embree query),
2. finds what every segment crosses and drops paths over the penetration limit
   (:func:`raytrace.solver.penetration.segment_crossings`),
3. tracks the field vector through every interaction (:func:`path_fields`),
4. assembles the :class:`~raytrace.solver.paths.Paths` with their interaction sequences and drops
   those below the power cut.

Field model: isotropic antennas with vertical polarisation at both ends. The field vector is
tracked in the TE/TM basis of each interaction's plane of incidence (``s = k_i x n``,
``p = s x k``) and projected on the receive antenna's polarisation (vertical, made perpendicular
to the arrival direction), so that line of sight is exactly Friis:
``gain = lambda / (4 pi d) exp(-j k d)``. Penetrated slabs add their group delay to the path
delay when ``TraceConfig.slab_delay`` is on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..core.jit import carray
from ..core.vec import index, norm
from ..core.vec import rows as take_rows
from . import kernels
from .context import TraceContext
from .paths import DIFFRACTION, PENETRATION, REFLECTION, Paths
from .penetration import (
    CONTACT_TOL_MARGINS,
    Crossings,
    convex_plane_arrays,
    flat_sheet_arrays,
    segment_crossings,
)


class DiffractionOperator(NamedTuple):
    """What a diffraction does to the field at vertex ``j`` of n chains (a
    :data:`DiffractionModel`'s answer): ``[E_beta0, E_phi] = -D [E . beta0'_hat, E . phi'_hat]
    A`` where ``valid``, zero elsewhere, and an extra amplitude factor of the whole path.

    Attributes
    ----------
    d_matrix : (n, 2, 2) complex, sqrt(metres), the dyadic coefficient ``D``
        (:func:`raytrace.physics.utd.diffraction_matrix`)
    basis : (n, 4, 3) float, the ray-fixed unit vectors ``beta0'_hat, phi'_hat`` of the
        incident ray and ``beta0_hat, phi_hat`` of the diffracted one
    spreading : (n,) float, 1/sqrt(metres), ``A``
    valid : (n,) bool
    scale : (n,) float, the extra factor (the incident leg's spreading, 1/metres)
    """

    d_matrix: np.ndarray
    basis: np.ndarray
    spreading: np.ndarray
    valid: np.ndarray
    scale: np.ndarray


#: ``model(wedge (n,), chain (n, k+2, 3), j, seg_len (n, k+1)) -> DiffractionOperator``: the
#: diffraction at vertex ``j`` of each chain.
DiffractionModel = Callable[..., DiffractionOperator]


@dataclass(frozen=True)
class Candidates:
    """Candidate paths of one interaction sequence length ``k`` (structure of arrays, M paths).

    Attributes
    ----------
    t_idx, r_idx : (M,) int, transmitter and receiver
    verts : (M, k, 3) float, interaction points in order, metres
    elem : (M, k) int, facet of a reflection, wedge of a diffraction
    kinds : (M, k) int8, interaction codes (``REFLECTION``, ``DIFFRACTION``)
    chain : (M, k + 2, 3) float, tx, the vertices and rx, metres
    vobj : (M, k) int, object under each vertex
    """

    t_idx: np.ndarray
    r_idx: np.ndarray
    verts: np.ndarray
    elem: np.ndarray
    kinds: np.ndarray
    chain: np.ndarray
    vobj: np.ndarray

    def __len__(self) -> int:
        return int(self.t_idx.shape[0])

    @property
    def depth(self) -> int:
        """Number of vertices ``k`` (reflections and diffractions) of every candidate."""
        return int(self.verts.shape[1])

    @property
    def ends(self) -> np.ndarray:
        """(M * (k + 1), 2) int: object under each segment's start and end (-1: tx or rx)."""
        m = len(self)
        edge = np.full((m, 1), -1)
        chain_obj = np.concatenate([edge, self.vobj, edge], axis=1)
        return np.stack([chain_obj[:, :-1], chain_obj[:, 1:]], axis=2).reshape(-1, 2)

    def take(self, sel: np.ndarray) -> Candidates:
        """The candidates ``sel`` (indices or mask)."""
        sel = index(sel)
        return Candidates(*(take_rows(getattr(self, f), sel) for f in self.__dataclass_fields__))


def candidates(
    ctx: TraceContext,
    t_idx: np.ndarray,
    r_idx: np.ndarray,
    verts: np.ndarray,
    elem: np.ndarray,
    kinds: np.ndarray | None = None,
) -> Candidates:
    """Candidates from a stage's arrays (``kinds`` default: all reflections)."""
    m, k = verts.shape[0], verts.shape[1]
    kinds = np.full((m, k), REFLECTION, np.int8) if kinds is None else kinds
    chain = np.concatenate(
        [take_rows(ctx.tx, t_idx)[:, None], verts, take_rows(ctx.rx, r_idx)[:, None]], axis=1
    )
    # the object under each vertex (tx and rx: none), so segments ignore their own vertices
    if k:
        facet_obj = ctx.scene.facets.object[np.where(kinds == REFLECTION, elem, 0)]
        vobj = np.where(kinds == DIFFRACTION, ctx.wedge_object(elem), facet_obj)
    else:
        vobj = np.zeros((m, 0), int)
    return Candidates(t_idx, r_idx, verts, elem, kinds, chain, vobj)


def evaluate(
    ctx: TraceContext, cand: Candidates, diffraction: DiffractionModel | None = None
) -> Paths:
    """Check visibility and penetrations of candidate paths and compute their fields.

    Parameters
    ----------
    ctx : TraceContext
    cand : Candidates, from :func:`candidates` (a stage's vertex chains)
    diffraction : DiffractionModel applied at diffraction vertices
        (:func:`raytrace.solver.diffraction.field_model`)

    Returns
    -------
    Paths, in candidate order, without the blocked, over-limit and powerless ones.
    """
    depth = cand.depth + ctx.cfg.max_penetrations
    twice = same_point_twice(ctx, cand)
    if twice.any():
        ctx.count("paths_dropped_same_point", int(twice.sum()))
        cand = cand.take(~twice)
    blocked = blocked_by_opaque(ctx, cand)
    if blocked.any():
        ctx.count("paths_blocked_opaque", int(blocked.sum()))
        cand = cand.take(~blocked)
    if not len(cand):
        return Paths.empty(ctx.tx, ctx.rx, ctx.f, depth)
    cross, within = within_penetration_limit(ctx, cand)
    if not within.any():
        return Paths.empty(ctx.tx, ctx.rx, ctx.f, depth)
    # the fields of the few over the limit are computed with the rest and dropped: cheaper than
    # copying the rest out
    gain, delay_s = path_fields(ctx, cand, cross, diffraction)
    powered = 20 * np.log10(np.maximum(np.abs(gain), 1e-300)) >= ctx.cfg.min_power_db
    ctx.count("paths_dropped_no_power", int((within & ~powered).sum()))
    return assemble(ctx, cand, cross, delay_s, gain, np.flatnonzero(within & powered))


#: Candidates sampled to choose the order in which :func:`blocked_by_opaque` queries the segments.
ORDER_SAMPLE = 256


def same_point_twice(ctx: TraceContext, cand: Candidates) -> np.ndarray:
    """(M,) bool: candidates with two consecutive interactions on one object closer than the
    scene's margin: a reflection on a face at the very edge the path then diffracts at (or the
    reverse). On a clean mesh the edge lies in the face's plane and no such candidate is valid;
    on one whose welding gaps were closed (:func:`raytrace.scene.construction.weld_vertices`)
    the edge lies 1e-7 m off the plane and the reflection point just inside the face: the
    diffraction path again, not another one."""
    if cand.depth < 2:
        return np.zeros(len(cand), dtype=bool)
    gap = norm(cand.verts[:, 1:] - cand.verts[:, :-1])  # (M, k - 1)
    same = cand.vobj[:, 1:] == cand.vobj[:, :-1]
    return ((gap < ctx.scene.margin) & same).any(axis=1)


def blocked_by_opaque(ctx: TraceContext, cand: Candidates) -> np.ndarray:
    """(M,) bool: candidates with a segment that crosses an opaque object.

    Conservative: a segment whose first opaque hit is the object under one of its own ends (a ray
    grazing the face of the object it diffracts on, within float32 noise), or a solid it only
    touches (:func:`~raytrace.solver.penetration.touches`), is left to
    :func:`segment_crossings`, which records exactly what it crosses
    (:func:`raytrace.solver.kernels.opaque_blocks`).
    """
    m = len(cand)
    if not ctx.opaque.any() or m == 0:
        return np.zeros(m, dtype=bool)
    chain, margin = carray(cand.chain), ctx.scene.margin
    vobj, planes = carray(cand.vobj, np.int64), convex_plane_arrays(ctx.scene)
    sheets = flat_sheet_arrays(ctx.scene)
    blocked = np.zeros(m, dtype=bool)

    def blocks(live: np.ndarray, j: int) -> np.ndarray:
        # a hit on the object under either end of the segment is the vertex's own, and a
        # segment that only touches an opaque solid (lying in the plane of its face, or leaving
        # a vertex at a neighbour's corner, which Embree reports in one direction and not in the
        # other) is not blocked by it: both left to segment_crossings, which steps past touches
        # and records real crossings
        a, d, length, org, d32, reach = kernels.segment_rays(chain, live, j, margin)
        hit = ctx.scene.first_hit_among(ctx.opaque, org, d32, reach)
        return kernels.opaque_blocks(hit, live, j, vobj, a, d, length, *planes, *sheets,
                                     CONTACT_TOL_MARGINS * margin)  # fmt: skip

    # one segment at a time, the likeliest to be blocked first: the other segments of a blocked
    # candidate need no query. Each ray's answer is its own, so the order changes the work,
    # never the result. Every segment of a sample of the candidates is queried (their verdicts
    # are kept) and the segments go in the order of how often they blocked the sample, then of
    # their length: on the 2 m grid 18 % fewer rays than by length alone
    step = max(1, m // ORDER_SAMPLE)
    sample = np.arange(0, m, step)
    total = norm(chain[sample, 1:] - chain[sample, :-1]).sum(axis=0)
    rate = np.zeros(len(total))
    live = np.arange(m)
    if step > 1:
        verdict = np.array([blocks(sample, j) for j in range(len(total))])
        rate = verdict.mean(axis=1)
        blocked[sample] = verdict.any(axis=0)
        live = np.delete(live, sample)
    for j in np.lexsort((-total, -rate)):
        if len(live) == 0:
            break
        b = blocks(live, int(j))
        blocked[live[np.flatnonzero(b)]] = True
        live = live[np.flatnonzero(~b)]
    return blocked


def within_penetration_limit(ctx: TraceContext, cand: Candidates) -> tuple[Crossings, np.ndarray]:
    """The crossings of the candidates' segments (``M * (k + 1)`` rows, segment-major per path)
    and which candidates cross at most ``max_penetrations`` objects in all ((M,) bool). The
    others' penetration counts are set to zero, so that their fields can be computed with the
    rest's (and are dropped)."""
    m, k, kmax = len(cand), cand.depth, ctx.cfg.max_penetrations
    a = cand.chain[:, :-1].reshape(-1, 3)
    b = cand.chain[:, 1:].reshape(-1, 3)
    cross = segment_crossings(ctx.scene, a, b, kmax, cand.ends)
    ctx.count("segments_tested", len(a))
    ok = ~cross.exceeded.reshape(m, k + 1).any(axis=1)
    ok &= cross.count.reshape(m, k + 1).sum(axis=1) <= kmax
    if not ok.all():
        cross.count[np.repeat(~ok, k + 1)] = 0
    return cross, ok


def path_fields(
    ctx: TraceContext,
    cand: Candidates,
    cross: Crossings,
    diffraction: DiffractionModel | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Complex gain and delay of every candidate.

    The field vector starts vertically polarised, goes through each segment's penetrations (slab
    transmission, ITU-R P.2040 sec. 3) and each vertex's reflection (Fresnel or slab) or
    diffraction (``diffraction`` model), and is projected on the receive antenna. The
    diffraction operators are computed per vertex position for every path at once; the
    compiled loop :func:`raytrace.solver.kernels.path_gains` computes the other coefficients
    and applies them all, path by path.

    Returns
    -------
    gain : (M,) complex, field amplitude relative to the transmitted one
    delay_s : (M,) float, seconds: unfolded length over c, plus the slabs' group delays
    """
    m, k = len(cand), cand.depth
    n_pen = cross.object.shape[1]
    # diffractions, every vertex of one position in the chain at once (the operators of the
    # diffraction model, one row per diffraction, found by d_slot); the compiled loop computes
    # the other coefficients path by path
    d_slot = np.full((m, k), -1, dtype=np.int64)
    amp_scale = np.ones(m, dtype=complex)  # extra scalar factors (diffraction spreading)
    ops: list[DiffractionOperator] = []
    seg_len = None
    for j in range(k):
        is_d = np.flatnonzero(cand.kinds[:, j] == DIFFRACTION)
        if not len(is_d):
            continue
        if diffraction is None:
            raise RuntimeError("diffraction vertex without a diffraction model")
        if seg_len is None:
            seg_len = norm(cand.chain[:, 1:] - cand.chain[:, :-1])  # (m, k+1)
        op = diffraction(cand.elem[is_d, j], take_rows(cand.chain, is_d), j + 1,
                         take_rows(seg_len, is_d))  # fmt: skip
        d_slot[is_d, j] = sum(len(o.valid) for o in ops) + np.arange(len(is_d))
        amp_scale[is_d] *= op.scale
        ops.append(op)
    if len(ops) == 1:
        d_matrix, d_basis, d_amp, d_valid = ops[0][:4]
    else:  # (several diffraction positions, or none)
        d_matrix, d_basis, d_amp, d_valid = (
            np.concatenate([o[i] for o in ops]) if ops else np.zeros((0, *tail), dtype=dt)
            for i, tail, dt in ((0, (2, 2), complex), (1, (4, 3), float), (2, (), float),
                                (3, (), bool))
        )  # fmt: skip
    fc = ctx.scene.facets
    sheet = fc.two_sided
    return kernels.path_gains(
        carray(cand.chain), carray(cand.kinds, np.int8), carray(cand.elem, np.int64),
        carray(cross.count, np.int64).reshape(m, k + 1),
        carray(cross.normal).reshape(m, k + 1, n_pen, 3),
        carray(cross.object, np.int64).reshape(m, k + 1, n_pen),
        carray(cross.thickness).reshape(m, k + 1, n_pen), carray(ctx.obj_material, np.int64),
        carray(ctx.eta, complex), carray(ctx.eta_slope, complex), carray(ctx.thickness),
        carray(fc.normal), carray(fc.material, np.int64), carray(sheet, bool), d_slot,
        carray(d_matrix, complex), carray(d_basis), carray(d_amp), carray(d_valid, bool),
        amp_scale, float(ctx.f), float(ctx.k0), float(ctx.wavelength),
        bool(ctx.cfg.slab_delay), int(REFLECTION), int(DIFFRACTION),
    )  # fmt: skip


def assemble(
    ctx: TraceContext,
    cand: Candidates,
    cross: Crossings,
    delay_s: np.ndarray,
    gain: np.ndarray,
    rows: np.ndarray,
) -> Paths:
    """The :class:`Paths` of the evaluated candidates ``rows`` (int (N,), in order), with
    interaction sequences ordered along the path: the penetrations of segment ``j``, then
    vertex ``j``. Only those rows are copied."""
    m, k = len(cand), cand.depth
    count = cross.count.reshape(m, k + 1)
    n_pen = cross.object.shape[1]
    rows = carray(rows, np.int64)
    inter, pts, objs, elems = kernels.interaction_sequences(
        carray(count, np.int64), carray(cross.object, np.int64).reshape(m, k + 1, n_pen),
        carray(cross.point).reshape(m, k + 1, n_pen, 3), carray(cand.kinds, np.int8),
        carray(cand.verts), carray(cand.vobj, np.int64), carray(cand.elem, np.int64),
        k + ctx.cfg.max_penetrations, int(PENETRATION), rows,
    )  # fmt: skip
    t_idx, r_idx = cand.t_idx[rows].astype(np.int64), cand.r_idx[rows].astype(np.int64)
    kinds = take_rows(cand.kinds, rows)
    return Paths(
        tx=ctx.tx,
        rx=ctx.rx,
        frequency_hz=ctx.f,
        link=t_idx * len(ctx.rx) + r_idx,
        tx_index=t_idx,
        rx_index=r_idx,
        delay_s=delay_s[rows],
        gain=gain[rows],
        n_reflections=(kinds == REFLECTION).sum(axis=1).astype(np.int16),
        n_penetrations=take_rows(count, rows).sum(axis=1).astype(np.int16),
        n_diffractions=(kinds == DIFFRACTION).sum(axis=1).astype(np.int16),
        interaction=inter,
        points=pts,
        objects=objs,
        elements=elems,
    )
