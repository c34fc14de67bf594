"""Facets and edges that an end point sees only through an opaque convex solid.

A path with a segment from an end point ``E`` (a transmitter or a receiver) to a point on facet
``f`` (a reflection) or on edge ``w`` (a diffraction) is blocked when that segment passes through
an opaque solid ``C`` (metal: :func:`~raytrace.solver.context.opaque_objects`). Before this
module, each such candidate was built (the mixed stages' triples, their expansion over the other
ends, the exact tests) and then dropped by the opaque test, one Embree ray per segment: on the 2 m
grid over the hall, two thirds of the RD and DR candidates ended there.

Here a whole facet or edge is ruled out per end point, before any candidate through it is made.
The points ``p`` for which the segment ``E -> p`` passes through a convex set ``C'`` form a
convex set: ``p = E + s (c - E)`` with ``c`` in ``C'`` and ``s >= 1`` is closed under convex
combinations (``c`` becomes a weighted mean of the ``c_i``, in ``C'``). So when the segments from
``E`` to every corner of a facet (its triangles' vertices) or to both ends of an edge pass
through ``C'``, so do the segments to every point of the facet or edge. ``C'`` is ``C`` shrunk by
:data:`SHADOW_DEPTH_M` (its planes moved inwards), so each such segment passes within the
solid by at least that depth: a chord of at least twice :data:`~raytrace.solver.context.
OPAQUE_CHORD_M` through an opaque solid, for points within micrometres of the facet or edge
(the exact tests' tolerances) as well. Such a path is dropped either way: by the opaque test,
or, where that test leaves a segment to the crossing analysis (its first opaque hit is the
object under one of its ends, or one it only touches), by its power after it: through the
default opaque objects (metals, skin depth ~1 um) such a chord costs far more than the dynamic
range. These go before they are made. (With objects declared opaque by the caller that are not
(``opaque=``), a path through 2 mm of one that the opaque test let pass used to be kept; it is
now dropped, as the declaration asks.)

The candidate solid for a group is the first convex opaque solid that Embree reports on the rays
from the end to the group's points (not the group's own object); the proof itself is the planes'
(float64, :func:`raytrace.solver.kernels.shadowed_groups`). A facet or edge without a proof is
kept: the rule only prunes, and which paths are found does not depend on it.
"""

from __future__ import annotations

import numpy as np

from ..core.jit import carray
from ..core.kept import keep
from ..scene.model import Scene
from . import kernels
from . import reflection as refl
from .context import OPAQUE_CHORD_M, TraceContext
from .penetration import convex_plane_arrays

__all__ = ["SHADOW_DEPTH_M", "SHADOWS_KEPT", "reflecting_sides", "shadowed", "shadows_of",
           "triples_in_shadow"]

#: Depth (m) inside an opaque solid on every segment from an end to a facet or edge in its
#: shadow: the chord is then at least twice the one that makes the solid opaque.
SHADOW_DEPTH_M = OPAQUE_CHORD_M
#: End points per Embree query (its arrays hold this many times the scene's corner points).
ENDS_PER_QUERY = 256


def _groups(scene: Scene) -> tuple[np.ndarray, ...]:
    """The scene's points (P, 3) and their groups: each facet's corners, then each edge's ends,
    as ``g_start, g_count`` (G,) into ``g_point`` (flat indices into the points), and each
    group's own object (G,). Cached (``scene.caches.shadow_groups``)."""
    cached = scene.caches.shadow_groups
    if cached is not None:
        return cached
    fc, w = scene.facets, scene.wedges
    # each facet's distinct corners, in its order (sorted by coordinates), as one unique over
    # (facet, x, y, z) rows: a scanned machine has a facet per triangle, and a list of a
    # million per-facet uniques costs seconds
    # (a facet's triangles are contiguous, in facet order)
    owner = np.repeat(np.arange(len(fc), dtype=np.float64), 3 * fc.tri_count)
    rows = np.unique(np.column_stack([owner, fc.triangles.reshape(-1, 3)]), axis=0)
    n_corners = np.bincount(rows[:, 0].astype(np.int64), minlength=len(fc))
    ends = np.stack([w.start, w.end], axis=1).reshape(-1, 3)  # both ends of every edge
    flat = np.concatenate([rows[:, 1:], ends])
    points, g_point = np.unique(flat, axis=0, return_inverse=True)
    count = np.concatenate([n_corners, np.full(len(w), 2)]).astype(np.int64)
    start = (np.cumsum(count) - count).astype(np.int64)
    own = np.concatenate([fc.object, w.object if len(w) else np.zeros(0)]).astype(np.int64)
    cached = (carray(points), start, count, carray(g_point.reshape(-1), np.int64), own)
    scene.caches.shadow_groups = cached
    return cached


def shadowed(scene: Scene, opaque: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The facets and edges each end point sees only through an opaque convex solid.

    Parameters
    ----------
    scene : Scene
    opaque : (O,) bool, the objects that block
    ends : (E, 3) float, metres

    Returns
    -------
    facets : (E, K) bool, every segment from the end to the facet crosses an opaque solid
    wedges : (E, W) bool, the same for the edges
    """
    n_k, n_w = len(scene.facets), len(scene.wedges)
    ends = carray(ends).reshape(-1, 3)
    normal, offset, count = convex_plane_arrays(scene)
    solid = np.asarray(opaque, dtype=bool) & (count > 0)
    if not solid.any() or len(ends) == 0:
        return np.zeros((len(ends), n_k), dtype=bool), np.zeros((len(ends), n_w), dtype=bool)
    points, start, n_p, g_point, own = _groups(scene)
    out = np.zeros((len(ends), len(start)), dtype=bool)
    for e0 in range(0, len(ends), ENDS_PER_QUERY):  # (E, P, 3) arrays of bounded size
        block = ends[e0 : e0 + ENDS_PER_QUERY]
        d = points[None, :, :] - block[:, None, :]  # (e, P, 3)
        length = np.sqrt(np.einsum("epc,epc->ep", d, d))
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = d / length[..., None]
        origin = np.broadcast_to(block[:, None, :], d.shape).reshape(-1, 3)
        hit = scene.first_hit_among(solid, origin, unit.reshape(-1, 3), length.reshape(-1))
        out[e0 : e0 + len(block)] = kernels.shadowed_groups(
            carray(block), points, carray(hit.reshape(length.shape), np.int64), start, n_p,
            g_point, own, normal, offset, count, float(SHADOW_DEPTH_M))  # fmt: skip
    return out[:, :n_k], out[:, n_k:]


#: Transmitter sets whose shadows are kept per scene: a grid is traced in chunks of receivers
#: against the same few transmitters.
SHADOWS_KEPT = 16


def _kept_or_new(ctx: TraceContext, ends: np.ndarray, which: str) -> tuple[np.ndarray, ...]:
    """:func:`shadowed` of the ends; the transmitters' kept on the scene (per position and
    opaque objects, ``scene.caches.kept_shadows``) for the next trace with the same ones."""
    if which != "tx":
        return shadowed(ctx.scene, ctx.opaque, ends)
    kept = ctx.scene.caches.kept_shadows
    key = (carray(ends).tobytes(), np.asarray(ctx.opaque, dtype=bool).tobytes())
    found = kept.get(key)
    if found is None:
        found = keep(kept, key, shadowed(ctx.scene, ctx.opaque, ends), SHADOWS_KEPT)
    return found


def shadows_of(ctx: TraceContext, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shadowed` for a trace's transmitters or receivers (``ends`` is ``ctx.tx`` or
    ``ctx.rx``; other end sets are computed each time), with its opaque objects: computed once
    per trace and end set. Nothing is in shadow with the pruning off (:data:`kernels.PRUNE`),
    nor in a trace restricted to some objects (``involving``: a snapshot's moving objects, whose
    few candidates cost less than the shadows' rays; 0.040 -> 0.074 s per snapshot of the hall
    with them).

    Returns
    -------
    facets : (E, K) bool, read-only
    wedges : (E, W) bool, read-only
    """
    which = "tx" if ends is ctx.tx else "rx" if ends is ctx.rx else None
    with ctx.shadows_lock:  # (the stages run on threads: one computes, the others wait for it)
        found = ctx.shadows.get(which) if which is not None else None
        if found is None:
            if kernels.PRUNE and ctx.facet_mask is None:
                found = _kept_or_new(ctx, ends, which)
            else:
                found = (np.zeros((len(ends), len(ctx.scene.facets)), dtype=bool),
                         np.zeros((len(ends), len(ctx.scene.wedges)), dtype=bool))  # fmt: skip
            for x in found:
                x.setflags(write=False)
            if which is not None:
                ctx.shadows[which] = found
    return found


def reflecting_sides(ctx: TraceContext, ends: np.ndarray) -> np.ndarray:
    """(E, K) int8: :func:`raytrace.solver.reflection.reflecting_side` of the trace's ``ends``
    (``ctx.tx`` or ``ctx.rx``), 0 where the end sees the facet only through an opaque solid
    (:func:`shadows_of`): a facet in shadow reflects nothing of that end."""
    side = refl.reflecting_side(ctx.scene.facets, ends)
    side[shadows_of(ctx, ends)[0]] = 0
    return side


#: Ray origins for the triples' candidate solids are moved this far along the ray (m), off the
#: facet a reflection point lies on (the proof itself is the planes').
_RAY_START_M = 1e-4


def triples_in_shadow(scene: Scene, opaque: np.ndarray, end: np.ndarray, f_idx: np.ndarray,
                      w_idx: np.ndarray, img: np.ndarray, t_lo: np.ndarray,
                      t_hi: np.ndarray) -> np.ndarray:  # fmt: skip
    """Which (end, facet, edge) triples of one end point have every candidate blocked by an
    opaque convex solid: on the segment from the end to the reflection point, or on the one from
    the reflection point to the edge (:func:`raytrace.solver.kernels.shadowed_triples`). Four
    Embree rays per triple find the candidate solids; the tracer asks only for the transmitters'
    triples, which a scene keeps for its next trace.

    Parameters
    ----------
    end : (3,) float, metres
    f_idx, w_idx : (M,) int, facets and edges
    img : (M, 3) float, the end's image in each facet, metres
    t_lo, t_hi : (M,) float, the part of each edge a diffraction point lies in, metres from its
        start (:func:`raytrace.solver.kernels.facet_wedge_pairs`)

    Returns
    -------
    (M,) bool
    """
    m = len(f_idx)
    normal, offset, count = convex_plane_arrays(scene)
    solid = np.asarray(opaque, dtype=bool) & (count > 0)
    if m == 0 or not solid.any():
        return np.zeros(m, dtype=bool)
    fc, w = scene.facets, scene.wedges
    length, unit = w.length[w_idx], w.direction[w_idx]
    n, off = fc.normal[f_idx], fc.offset[f_idx]
    lo, hi = np.clip(t_lo, 0.0, length), np.clip(t_hi, 0.0, length)
    # a diffraction point lies on the end's side of the facet's plane (the exact tests' rule; the
    # padded span may reach behind it): the span is cut where the edge meets the plane, so that
    # its projection from the image, the reflection points' range, is a bounded segment
    side = np.sign(refl.signed_distance(np.broadcast_to(end, (m, 3)), n, off))
    s_lo = side * refl.signed_distance(w.start[w_idx] + lo[:, None] * unit, n, off)
    s_hi = side * refl.signed_distance(w.start[w_idx] + hi[:, None] * unit, n, off)
    with np.errstate(invalid="ignore", divide="ignore"):
        cut = lo + (hi - lo) * s_lo / (s_lo - s_hi)  # where the edge meets the plane
    lo = np.where(s_lo < 0, cut, lo)
    hi = np.where(s_hi < 0, cut, hi)
    ahead = (s_lo >= 0) | (s_hi >= 0)  # some of the span in front (else no candidate: no proof)
    d_lo = w.start[w_idx] + lo[:, None] * unit
    d_hi = w.start[w_idx] + hi[:, None] * unit
    # the reflection points' range: the span's ends projected from the image onto the plane
    r_lo = refl.segment_plane_point(img, d_lo, n, off)[1]
    r_hi = refl.segment_plane_point(img, d_hi, n, off)[1]
    a = np.concatenate([np.broadcast_to(end, (m, 3)), np.broadcast_to(end, (m, 3)), r_lo, r_hi])
    b = np.concatenate([r_lo, r_hi, d_lo, d_hi])
    d = b - a
    dist = np.sqrt(np.einsum("nc,nc->n", d, d))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = d / dist[:, None]
    reach = np.where(np.isfinite(dist), dist - _RAY_START_M, 0.0)
    hit = scene.first_hit_among(solid, a + _RAY_START_M * u, u, reach)
    return ahead & kernels.shadowed_triples(
        carray(end).reshape(3), carray(d_lo), carray(d_hi), carray(r_lo), carray(r_hi),
        carray(fc.object[f_idx], np.int64), carray(w.object[w_idx], np.int64),
        carray(hit.reshape(4, m).T, np.int64), normal, offset, count,
        float(SHADOW_DEPTH_M))  # fmt: skip
