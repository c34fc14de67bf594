"""Path finding over many links: line of sight, reflections, penetrations (and diffraction).

What is traced (Table I of the paper: each mechanism has its own limit):

* line of sight;
* specular reflections up to ``max_reflections`` (0, 1 or 2) by the image method over the
  scene's planar facets;
* penetrations: every segment of every path may cross objects; each crossing is attenuated by
  the slab transmission of the crossed material (ITU-R P.2040 section 3); paths with more than
  ``max_penetrations`` crossings in all are dropped;
* first-order edge diffraction (UTD), with reflections before and/or after it when
  ``max_interactions`` allows (see :mod:`raytrace.physics.utd`).

Field model: isotropic antennas with vertical polarisation at both ends. The field vector is
tracked through every interaction in the TE/TM basis of the interaction's plane of incidence
(basis ``s = k_i x n``, ``p = s x k``), and the received amplitude is its projection on the
receive antenna's polarisation (vertical, made perpendicular to the arrival direction), so that
line of sight is exactly Friis: ``gain = lambda / (4 pi d) * exp(-j k d)``.
"""

from __future__ import annotations

import os
import threading
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..core.constants import C0
from ..core.errors import TraceInputError
from ..physics.materials import fresnel, slab, slab_group_delay
from ..scene import accel
from ..scene.model import Scene
from . import reflection as refl
from .paths import DIFFRACTION, PENETRATION, REFLECTION, Paths
from .penetration import segment_crossings

#: Paths whose power gain is below this (dB) carry no power (e.g. through metal) and are dropped.
MIN_POWER_DB = -250.0
#: Work is split into chunks of about this many candidate paths to bound memory.
CHUNK = 400_000
#: An object is opaque when its slab loss at normal incidence, through its sheet thickness (open
#: sheets) or through this chord (closed solids, m), is more than ``OPAQUE_MARGIN_DB`` below
#: ``min_power_db``: metals at these frequencies (skin depth ~1 um). A path that crosses an
#: opaque object is dropped by one Embree query before the crossing analysis.
OPAQUE_CHORD_M = 1e-3
#: dB of headroom for the other factors of a path (oblique incidence, diffraction coefficients).
OPAQUE_MARGIN_DB = 100.0


#: Relative cost of the stages on a hall-like scene (the thread pool starts the costliest first).
_STAGE_COST = {
    "diffraction-reflection": 6,
    "reflection-diffraction": 5,
    "reflection-diffraction-reflection": 7,
    "2nd-order reflections": 2,
    "diffraction": 1,
}


@dataclass(frozen=True)
class TraceConfig:
    """Tracer settings.

    Attributes
    ----------
    max_reflections : int, 0..2
    max_penetrations : int, >= 0, crossings in all along a path
    max_diffractions : int, 0 or 1
    max_interactions : int, reflections plus diffractions on one path (penetrations apart)
    min_power_db : float, paths weaker than this are dropped
    extrapolate : bool, allow materials outside their ITU-R P.2040 frequency range (warns)
    slab_delay : bool, a penetrated slab delays the path by its group delay
        (:func:`raytrace.physics.materials.slab_group_delay`), not only its phase
    """

    max_reflections: int = 2
    max_penetrations: int = 2
    max_diffractions: int = 1
    max_interactions: int = 2
    min_power_db: float = MIN_POWER_DB
    extrapolate: bool = False
    slab_delay: bool = True

    def validate(self) -> None:
        if not 0 <= self.max_reflections <= 2:
            raise TraceInputError(f"max_reflections must be 0, 1 or 2, got {self.max_reflections}")
        if self.max_penetrations < 0:
            raise TraceInputError(f"max_penetrations must be >= 0, got {self.max_penetrations}")
        if self.max_diffractions not in (0, 1):
            raise TraceInputError(f"max_diffractions must be 0 or 1, got {self.max_diffractions}")
        if self.max_interactions < 0:
            raise TraceInputError(f"max_interactions must be >= 0, got {self.max_interactions}")


def check_positions(
    scene: Scene, points: np.ndarray, what: str, *, strict: bool = False
) -> np.ndarray:
    """Validate transmitter or receiver positions: finite, near the scene, not inside a solid.

    A point is outside the scene when it is farther from the scene's bounding box than half the
    box diagonal plus 1 m (a unit mistake, typically), or, with ``strict``, when it is outside
    the bounding box at all (what an enclosed hall wants). Raises :class:`TraceInputError`.
    """
    p = np.asarray(points, dtype=float)
    if p.ndim == 1:
        p = p.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise TraceInputError(f"{what} positions must be (n, 3), got shape {p.shape}")
    if len(p) == 0:
        raise TraceInputError(f"no {what} positions given")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise TraceInputError(f"{what} {int(np.argmax(bad))} has a NaN or infinite coordinate")
    lo, hi = scene.bounds
    slack = 1e-6 if strict else 0.5 * scene.extent + 1.0
    out = ((p < lo - slack) | (p > hi + slack)).any(axis=1)
    if out.any():
        i = int(np.argmax(out))
        raise TraceInputError(
            f"{what} {i} at {p[i].round(3).tolist()} is outside the scene "
            f"(bounds {lo.round(2).tolist()} .. {hi.round(2).tolist()} m)"
        )
    inside = scene.inside_solid(p)
    if (inside >= 0).any():
        i = int(np.argmax(inside >= 0))
        raise TraceInputError(
            f"{what} {i} at {p[i].round(3).tolist()} is inside the solid "
            f"{scene.objects[inside[i]].name!r}"
        )
    return p


def trace(
    scene: Scene,
    tx: np.ndarray,
    rx: np.ndarray,
    frequency_hz: float,
    max_reflections: int = 2,
    max_penetrations: int = 2,
    max_diffractions: int = 1,
    *,
    max_interactions: int = 2,
    min_power_db: float = MIN_POWER_DB,
    extrapolate: bool = False,
    slab_delay: bool = True,
    progress: bool | Callable[[int], None] = False,
    stats: dict[str, int] | None = None,
    involving: np.ndarray | list[int] | None = None,
    threads: int | None = None,
    opaque: np.ndarray | None = None,
) -> Paths:
    """Find every path between every transmitter and every receiver.

    Parameters
    ----------
    scene : Scene
    tx : (T, 3) float, transmitter positions, metres
    rx : (R, 3) float, receiver positions, metres
    frequency_hz : float
    max_reflections : int, 0..2
    max_penetrations : int, crossings of objects allowed along one path
    max_diffractions : int, 0 or 1
    max_interactions : int, reflections plus diffractions on one path
    min_power_db : float, weaker paths are dropped (metal blocks: its transmission is ~0)
    extrapolate : bool, allow materials outside their valid frequency range (warns)
    slab_delay : bool, add the group delay of penetrated slabs to the path delays (default True;
        False: free-space delays, the slab's phase only)
    progress : bool, show a progress bar over the mechanisms
    stats : dict, optional, filled with counters (candidates, segments tested, dropped paths)
        and each stage's wall time in microseconds (``time_us[<stage>]``; stages overlap on threads)
    involving : object indices, optional; only paths that reflect or diffract on at least one of
        these objects (no line of sight). With :func:`reevaluate`, this is how a snapshot with
        moving objects is traced without retracing the static scene.
    threads : int, optional, threads for the independent stages (default: all cores; 1 in a
        process pool's workers avoids oversubscription)
    opaque : (O,) bool, optional, objects that block: a path through one is dropped before the
        crossing analysis (default :func:`opaque_objects` at this frequency and power cut; give
        the objects opaque at every band when tracing geometry once for several bands with
        ``min_power_db=-inf``)

    Returns
    -------
    Paths, sorted by link, delay and kind.
    """
    cfg = TraceConfig(
        max_reflections,
        max_penetrations,
        max_diffractions,
        max_interactions,
        min_power_db,
        extrapolate,
        bool(slab_delay),
    )
    cfg.validate()
    f = float(frequency_hz)
    if not np.isfinite(f) or f <= 0:
        raise TraceInputError(f"frequency must be a positive number of Hz, got {frequency_hz}")
    tx = check_positions(scene, tx, "transmitter")
    rx = check_positions(scene, rx, "receiver")
    ctx = _Context(scene, tx, rx, f, cfg, involving, opaque)

    stages: list[tuple[str, Callable[[], list[Paths]]]] = []
    if involving is None:
        stages.append(("line of sight", ctx.los))
    if cfg.max_reflections >= 1 and cfg.max_interactions >= 1:
        stages.append(("1st-order reflections", ctx.reflections_1))
    if cfg.max_reflections >= 2 and cfg.max_interactions >= 2:
        stages.append(("2nd-order reflections", ctx.reflections_2))
    if cfg.max_diffractions >= 1 and cfg.max_interactions >= 1 and len(scene.wedges):
        from . import diffraction as diffraction_paths

        stages.extend(diffraction_paths.stages(ctx))

    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(stages), desc="tracing", unit="stage", leave=False)
    n_threads = (os.cpu_count() or 1) if threads is None else max(1, int(threads))
    results: list[list[Paths]] = []

    # The stages are independent; their heavy parts (numpy on large arrays, Embree) release the
    # GIL, so threads use the cores. Results are joined in stage order: output is deterministic.
    def report(name: str) -> None:
        if bar is not None:
            bar.set_postfix_str(name)
            bar.update(1)
        elif callable(progress):
            progress(1)

    if n_threads == 1 or len(stages) <= 1:
        for name, stage in stages:
            results.append(ctx.timed(name, stage))
            report(name)
    else:
        with ThreadPoolExecutor(max_workers=min(n_threads, len(stages))) as pool:
            # the costliest stages first, so the short ones fill in beside them
            order = sorted(range(len(stages)), key=lambda i: -_STAGE_COST.get(stages[i][0], 0))
            futures: list = [None] * len(stages)
            for i in order:
                futures[i] = pool.submit(ctx.timed, *stages[i])
            for (name, _), fut in zip(stages, futures):
                results.append(fut.result())
                report(name)
    parts = [p for r in results for p in r]
    if bar is not None:
        bar.close()
    if stats is not None:
        stats.update(ctx.stats)
    if not parts:
        return Paths.empty(
            tx, rx, f, cfg.max_reflections + cfg.max_penetrations + cfg.max_diffractions
        )
    return Paths.concatenate(parts).sorted()


def reevaluate(
    scene: Scene,
    paths: Paths,
    *,
    max_penetrations: int = 2,
    min_power_db: float = MIN_POWER_DB,
    extrapolate: bool = False,
    slab_delay: bool = True,
) -> Paths:
    """Recompute visibility, penetrations and fields of given paths in another scene.

    The paths keep their reflection and diffraction vertices and elements (facet and wedge
    indices), so ``scene`` must index those elements as the scene they were traced in did; a
    scene built from the same objects followed by more objects does. Paths that now cross more
    objects than allowed, or carry no power, are dropped.

    Parameters
    ----------
    scene : Scene
    paths : Paths, from :func:`trace`
    max_penetrations, min_power_db, extrapolate, slab_delay : as in :func:`trace`

    Returns
    -------
    Paths, sorted like :func:`trace`'s.
    """
    cfg = TraceConfig(2, max_penetrations, 1, 3, min_power_db, extrapolate, bool(slab_delay))
    ctx = _Context(scene, paths.tx, paths.rx, paths.frequency_hz, cfg, None)
    kinds, pts, elem = paths.vertices()
    depth = max(kinds.shape[1], 1) + max_penetrations
    parts = [Paths.empty(paths.tx, paths.rx, paths.frequency_hz, depth)]
    if paths.n_paths:
        from . import diffraction as diffraction_paths

        # one group per interaction sequence, so the back end sees rectangular arrays
        seq, group = np.unique(kinds, axis=0, return_inverse=True)
        for g, pattern in enumerate(seq):
            sel = np.flatnonzero(group.reshape(-1) == g)
            k = int((pattern > 0).sum())
            has_d = bool((pattern == DIFFRACTION).any())
            parts.append(
                ctx.finish(
                    paths.tx_index[sel],
                    paths.rx_index[sel],
                    pts[sel, :k],
                    elem[sel, :k],
                    kinds=kinds[sel, :k],
                    diffraction=diffraction_paths.field_model(ctx) if has_d else None,
                )
            )
    return Paths.concatenate(parts).sorted()


class _Context:
    """Per-call state shared by the path stages: scene, links, material constants."""

    def __init__(
        self,
        scene: Scene,
        tx: np.ndarray,
        rx: np.ndarray,
        f: float,
        cfg: TraceConfig,
        involving: np.ndarray | list[int] | None = None,
        opaque: np.ndarray | None = None,
    ):
        self.scene, self.tx, self.rx, self.f, self.cfg = scene, tx, rx, f, cfg
        # which facets / wedges may take part (all, unless restricted to some objects)
        if involving is None:
            self.facet_mask = None
            self.wedge_mask = None
        else:
            objs = np.zeros(len(scene.objects), dtype=bool)
            objs[np.asarray(involving, dtype=np.int64)] = True
            self.facet_mask = objs[scene.facets.object]
            self.wedge_mask = objs[scene.wedges.object] if len(scene.wedges) else np.zeros(0, bool)
        self.k0 = 2 * np.pi * f / C0
        self.wavelength = C0 / f
        with warnings.catch_warnings():
            if cfg.extrapolate:
                warnings.simplefilter("default")
            self.eta = np.array(
                [
                    scene.materials[m].permittivity(f, extrapolate=cfg.extrapolate)
                    for m in scene.material_names
                ],
                dtype=complex,
            )
            self.eta_slope = np.array(
                [
                    scene.materials[m].permittivity_slope(f, extrapolate=cfg.extrapolate)
                    for m in scene.material_names
                ],
                dtype=complex,
            )
        self.thickness = scene.material_thickness()
        self.obj_material = scene.object_material
        self.obj_closed = scene.object_closed
        if opaque is None:
            self.opaque = opaque_objects(scene, f, cfg.min_power_db, eta=self.eta)
        else:
            self.opaque = np.asarray(opaque, dtype=bool).reshape(-1)
            if self.opaque.shape != (len(scene.objects),):
                raise TraceInputError(
                    f"opaque must have one flag per object ({len(scene.objects)}), "
                    f"got {self.opaque.shape[0]}"
                )
        self.stats: dict[str, int] = {}
        self._lock = threading.Lock()

    def timed(self, name: str, stage: Callable[[], list[Paths]]) -> list[Paths]:
        """Run a stage and record its wall time (microseconds) as ``time_us[<name>]``."""
        t0 = time.perf_counter()
        out = stage()
        self.count(f"time_us[{name}]", int((time.perf_counter() - t0) * 1e6))
        return out

    def count(self, key: str, n: int) -> None:
        with self._lock:
            self.stats[key] = self.stats.get(key, 0) + int(n)

    # -- stages -------------------------------------------------------------------------------
    def los(self) -> list[Paths]:
        t_idx, r_idx = np.divmod(np.arange(len(self.tx) * len(self.rx)), len(self.rx))
        return [
            self.finish(t_idx, r_idx, np.zeros((len(t_idx), 0, 3)), np.zeros((len(t_idx), 0), int))
        ]

    def reflections_1(self) -> list[Paths]:
        fc = self.scene.facets
        side_tx = refl.reflecting_side(fc, self.tx)  # (T, K)
        side_rx = refl.reflecting_side(fc, self.rx)  # (R, K)
        ok_tkr = (side_tx[:, :, None] != 0) & (side_tx[:, :, None] == side_rx.T[None])
        if self.facet_mask is not None:
            ok_tkr &= self.facet_mask[None, :, None]
        t_idx, k_idx, r_idx = np.nonzero(ok_tkr)
        self.count("candidates_r1", len(t_idx))
        img = refl.mirror(self.tx[t_idx], fc.normal[k_idx], fc.offset[k_idx])
        u, p = refl.segment_plane_point(self.rx[r_idx], img, fc.normal[k_idx], fc.offset[k_idx])
        ok = (u > 0) & (u < 1)
        ok[ok] = accel.points_in_facets(p[ok], k_idx[ok], fc)
        return [self.finish(t_idx[ok], r_idx[ok], p[ok][:, None, :], k_idx[ok][:, None])]

    def reflections_2(self) -> list[Paths]:
        fc = self.scene.facets
        pairs = accel.facing_pairs(fc)
        if self.facet_mask is not None:
            pairs = pairs & (self.facet_mask[:, None] | self.facet_mask[None, :])
        side_rx = refl.reflecting_side(fc, self.rx)  # (R, K)
        centre, radius = accel.facet_spheres(fc)
        out: list[Paths] = []
        for t in range(len(self.tx)):
            side_t = refl.reflecting_side(fc, self.tx[t : t + 1])[0]  # (K,)
            f1 = np.flatnonzero(side_t != 0)
            img1 = refl.mirror(
                np.broadcast_to(self.tx[t], (len(f1), 3)), fc.normal[f1], fc.offset[f1]
            )
            # only first facets with some partner, and side tests only on possible partners
            rows = pairs[f1].any(axis=1)
            f1, img1 = f1[rows], img1[rows]
            cols = np.flatnonzero(pairs[f1].any(axis=0))
            # first images on a reflecting side of the second facet (exact necessary condition)
            side_img = refl.reflecting_side(fc, img1, cols)  # (len(f1), len(cols))
            a, jc = np.nonzero((side_img != 0) & pairs[f1][:, cols])
            f2 = cols[jc]
            # beam test: the second facet must meet the rays from the first image through the
            # first facet (bounding spheres: a necessary condition)
            beam = refl.cone_reaches(img1[a], centre[f1[a]], radius[f1[a]], centre[f2], radius[f2])
            a, f2, jc = a[beam], f2[beam], jc[beam]
            i1, f1a = a, f1[a]
            if len(f1a) == 0:
                continue
            img2 = refl.mirror(img1[i1], fc.normal[f2], fc.offset[f2])
            s_img = side_img[i1, jc]
            # receivers on the same side of the second facet as the first image, inside the
            # beam from the second image through the second facet
            step = max(1, CHUNK // max(len(self.rx), 1))
            for c0 in range(0, len(f1a), step):
                sl = slice(c0, c0 + step)
                ok_qr = side_rx.T[f2[sl]] == s_img[sl, None]
                ok_qr &= refl.cone_reaches(
                    img2[sl, None, :],
                    centre[f2[sl], None, :],
                    radius[f2[sl], None],
                    self.rx[None],
                    0.0,
                )
                q, r_idx = np.nonzero(ok_qr)
                self.count("candidates_r2", len(q))
                q = q + c0
                ff1, ff2 = f1a[q], f2[q]
                u2, p2 = refl.segment_plane_point(
                    self.rx[r_idx], img2[q], fc.normal[ff2], fc.offset[ff2]
                )
                ok = (u2 > 0) & (u2 < 1)
                ok[ok] = accel.points_in_facets(p2[ok], ff2[ok], fc)
                q, r_idx, ff1, ff2, p2 = q[ok], r_idx[ok], ff1[ok], ff2[ok], p2[ok]
                u1, p1 = refl.segment_plane_point(p2, img1[i1[q]], fc.normal[ff1], fc.offset[ff1])
                ok = (u1 > 0) & (u1 < 1)
                ok[ok] = accel.points_in_facets(p1[ok], ff1[ok], fc)
                # the second reflection point must be on the side of the first facet that the
                # transmitter is on
                s2 = refl.signed_distance(p2[ok], fc.normal[ff1[ok]], fc.offset[ff1[ok]])
                ok[ok] = np.sign(s2) == side_t[ff1[ok]]
                if ok.any():
                    verts = np.stack([p1[ok], p2[ok]], axis=1)
                    fac = np.stack([ff1[ok], ff2[ok]], axis=1)
                    out.append(self.finish(np.full(int(ok.sum()), t), r_idx[ok], verts, fac))
        return out

    # -- common back end ----------------------------------------------------------------------
    def finish(
        self,
        t_idx: np.ndarray,
        r_idx: np.ndarray,
        verts: np.ndarray,
        facet: np.ndarray,
        kinds: np.ndarray | None = None,
        diffraction: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> Paths:
        """Check visibility and penetrations of candidate paths and compute their fields.

        Parameters
        ----------
        t_idx, r_idx : (M,) int
        verts : (M, k, 3) float, interaction points in order, metres
        facet : (M, k) int, facet of each reflection (or wedge index of a diffraction)
        kinds : (M, k) int8, interaction codes (default: all reflections)
        diffraction : callable applied at diffraction vertices (see diffraction_paths)
        """
        sc = self.scene
        m, k = verts.shape[0], verts.shape[1]
        kinds = np.full((m, k), REFLECTION, np.int8) if kinds is None else kinds
        if m == 0:
            return Paths.empty(self.tx, self.rx, self.f, k + self.cfg.max_penetrations)
        chain = np.concatenate([self.tx[t_idx][:, None], verts, self.rx[r_idx][:, None]], axis=1)
        kmax = self.cfg.max_penetrations
        # the object under each vertex (tx and rx: none), so segments ignore their own vertices
        vobj = np.where(
            kinds == DIFFRACTION,
            self._wedge_object(facet),
            sc.facets.object[np.where(kinds == REFLECTION, facet, 0)]
            if k
            else np.zeros((m, 0), int),
        )
        chain_obj = np.concatenate([np.full((m, 1), -1), vobj, np.full((m, 1), -1)], axis=1)
        ends = np.stack([chain_obj[:, :-1], chain_obj[:, 1:]], axis=2).reshape(-1, 2)
        blocked = self._blocked_by_opaque(chain, ends)
        if blocked.any():
            self.count("paths_blocked_opaque", int(blocked.sum()))
            sel = np.flatnonzero(~blocked)
            t_idx, r_idx, verts, facet, kinds, chain, vobj = (
                x[sel] for x in (t_idx, r_idx, verts, facet, kinds, chain, vobj)
            )
            ends = ends.reshape(m, k + 1, 2)[sel].reshape(-1, 2)
            m = len(sel)
            if m == 0:
                return Paths.empty(self.tx, self.rx, self.f, k + kmax)
        a = chain[:, :-1].reshape(-1, 3)
        b = chain[:, 1:].reshape(-1, 3)
        cr = segment_crossings(sc, a, b, kmax, ends)
        self.count("segments_tested", len(a))
        seg_count = cr.count.reshape(m, k + 1)
        n_pen = seg_count.sum(axis=1)
        ok = ~cr.exceeded.reshape(m, k + 1).any(axis=1) & (n_pen <= kmax)
        if not ok.all():
            sel = np.flatnonzero(ok)
            idx2 = (sel[:, None] * (k + 1) + np.arange(k + 1)[None]).reshape(-1)
            t_idx, r_idx, verts, facet, kinds, chain, vobj = (
                t_idx[sel],
                r_idx[sel],
                verts[sel],
                facet[sel],
                kinds[sel],
                chain[sel],
                vobj[sel],
            )
            seg_count, n_pen = seg_count[sel], n_pen[sel]
            cr = type(cr)(*(getattr(cr, f)[idx2] for f in cr.__dataclass_fields__))
            m = len(sel)
        if m == 0:
            return Paths.empty(self.tx, self.rx, self.f, k + kmax)

        seg = chain[:, 1:] - chain[:, :-1]  # (m, k+1, 3)
        seg_len = np.linalg.norm(seg, axis=2)
        dirs = seg / np.maximum(seg_len, 1e-300)[:, :, None]
        total = seg_len.sum(axis=1)

        # field vector: vertical polarisation perpendicular to the departure direction
        e = _vertical_pol(dirs[:, 0]).astype(complex)
        pen_obj = cr.object.reshape(m, k + 1, -1)
        pen_nrm = cr.normal.reshape(m, k + 1, -1, 3)
        pen_th = cr.thickness.reshape(m, k + 1, -1)
        amp_scale = np.ones(m, dtype=complex)  # extra scalar factors (diffraction spreading)
        slab_delay = np.zeros(m)  # group delay of the penetrated slabs, s
        for j in range(k + 1):
            for s in range(pen_obj.shape[2]):
                has = seg_count[:, j] > s
                if has.any():
                    o = pen_obj[has, j, s]
                    mat = self.obj_material[o]
                    cos_i = np.abs(np.einsum("ij,ij->i", pen_nrm[has, j, s], dirs[has, j]))
                    _, _, t_te, t_tm = slab(self.eta[mat], cos_i, pen_th[has, j, s], self.f)
                    if self.cfg.slab_delay:
                        slab_delay[has] += slab_group_delay(
                            self.eta[mat], cos_i, pen_th[has, j, s], self.eta_slope[mat]
                        )
                    e[has] = _apply_te_tm(
                        e[has], dirs[has, j], dirs[has, j], pen_nrm[has, j, s], t_te, t_tm
                    )
            if j < k:
                is_r = kinds[:, j] == REFLECTION
                if is_r.any():
                    fidx = facet[is_r, j]
                    nrm = self.scene.facets.normal[fidx]
                    mat = self.scene.facets.material[fidx]
                    cos_i = np.abs(np.einsum("ij,ij->i", nrm, dirs[is_r, j]))
                    r_te, r_tm = self._reflection(mat, cos_i, self.scene.facets.two_sided[fidx])
                    e[is_r] = _apply_te_tm(
                        e[is_r], dirs[is_r, j], dirs[is_r, j + 1], nrm, r_te, r_tm
                    )
                is_d = kinds[:, j] == DIFFRACTION
                if is_d.any():
                    if diffraction is None:
                        raise RuntimeError("diffraction vertex without a diffraction model")
                    e_d, scale = diffraction(
                        facet[is_d, j], chain[is_d], j + 1, e[is_d], seg_len[is_d]
                    )
                    e[is_d] = e_d
                    amp_scale[is_d] *= scale
        a_rx = _vertical_pol(dirs[:, -1])
        proj = np.einsum("ij,ij->i", e, a_rx)
        has_d = (kinds == DIFFRACTION).any(axis=1)
        # free-space spreading over the unfolded length (diffracted paths carry their own)
        spread = np.where(has_d, 1.0, self.wavelength / (4 * np.pi * total))
        gain = spread * amp_scale * np.exp(-1j * self.k0 * total) * proj
        power_db = 20 * np.log10(np.maximum(np.abs(gain), 1e-300))
        keep = power_db >= self.cfg.min_power_db
        self.count("paths_dropped_no_power", int((~keep).sum()))

        # interaction sequence: penetrations of segment j, then vertex j
        depth = k + kmax
        inter = np.zeros((m, depth), np.int8)
        pts = np.full((m, depth, 3), np.nan)
        objs = np.full((m, depth), -1, np.int64)
        elems = np.full((m, depth), -1, np.int64)
        pen_pts = cr.point.reshape(m, k + 1, -1, 3)
        pos = np.zeros(m, dtype=np.int64)
        rows = np.arange(m)
        vert_obj = vobj
        for j in range(k + 1):
            for s in range(pen_obj.shape[2]):
                has = seg_count[:, j] > s
                r = rows[has]
                inter[r, pos[has]] = PENETRATION
                pts[r, pos[has]] = pen_pts[has, j, s]
                objs[r, pos[has]] = pen_obj[has, j, s]
                pos[has] += 1
            if j < k:
                inter[rows, pos] = kinds[:, j]
                pts[rows, pos] = verts[:, j]
                objs[rows, pos] = vert_obj[:, j]
                elems[rows, pos] = facet[:, j]
                pos += 1
        n_r = (kinds == REFLECTION).sum(axis=1).astype(np.int16)
        n_d = (kinds == DIFFRACTION).sum(axis=1).astype(np.int16)
        n_rx = len(self.rx)
        paths = Paths(
            tx=self.tx,
            rx=self.rx,
            frequency_hz=self.f,
            link=t_idx * n_rx + r_idx,
            tx_index=t_idx.astype(np.int64),
            rx_index=r_idx.astype(np.int64),
            delay_s=total / C0 + slab_delay,
            gain=gain,
            n_reflections=n_r,
            n_penetrations=n_pen.astype(np.int16),
            n_diffractions=n_d,
            interaction=inter,
            points=pts,
            objects=objs,
            elements=elems,
        )
        return paths.select(keep)

    def _blocked_by_opaque(self, chain: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(M,) bool: paths with a segment that crosses an opaque object.

        Parameters
        ----------
        chain : (M, k + 2, 3) float, path vertices from transmitter to receiver, metres
        ends : (M * (k + 1), 2) int, object under each segment's start and end (-1 for none)

        Conservative: a segment whose first opaque hit is the object under one of its own ends
        (a ray grazing the face of the object it diffracts on, within float32 noise) is left to
        :func:`segment_crossings`, which records exactly what it crosses.
        """
        m = chain.shape[0]
        if not self.opaque.any() or m == 0:
            return np.zeros(m, dtype=bool)
        a = chain[:, :-1].reshape(-1, 3)
        v = chain[:, 1:].reshape(-1, 3) - a
        length = np.linalg.norm(v, axis=1)
        d = np.divide(v, length[:, None], out=np.zeros_like(v), where=length[:, None] > 0)
        margin = self.scene.margin
        hit = self.scene.first_hit_among(self.opaque, a + margin * d, d, length - 2 * margin)
        blocked = (hit >= 0) & (hit != ends[:, 0]) & (hit != ends[:, 1])
        return blocked.reshape(m, -1).any(axis=1)

    def _wedge_object(self, idx: np.ndarray) -> np.ndarray:
        w = self.scene.wedges
        if len(w) == 0:
            return np.full(idx.shape, -1)
        return w.object[np.clip(idx, 0, len(w) - 1)]

    def _reflection(
        self, mat: np.ndarray, cos_i: np.ndarray, two_sided: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """TE/TM reflection coefficients: a closed solid's face is a half-space interface
        (Fresnel); an open sheet is a slab of its material's thickness (ITU-R P.2040 sec. 3)."""
        eta = self.eta[mat]
        r_te, r_tm, _, _ = fresnel(eta, cos_i)
        r_te = np.asarray(r_te, dtype=complex).copy()
        r_tm = np.asarray(r_tm, dtype=complex).copy()
        if two_sided.any():
            s_te, s_tm, _, _ = slab(
                eta[two_sided], cos_i[two_sided], self.thickness[mat[two_sided]], self.f
            )
            r_te[two_sided] = s_te
            r_tm[two_sided] = s_tm
        return r_te, r_tm


def opaque_objects(
    scene: Scene,
    frequency_hz: float,
    min_power_db: float = MIN_POWER_DB,
    *,
    eta: np.ndarray | None = None,
    extrapolate: bool = False,
) -> np.ndarray:
    """(O,) bool: objects through which no path can carry power above ``min_power_db``.

    An object is opaque when its slab loss (ITU-R P.2040 eqs. 37-39 via :func:`slab`) at normal
    incidence, through its sheet thickness (open sheets) or :data:`OPAQUE_CHORD_M` (closed
    solids), is below ``min_power_db - OPAQUE_MARGIN_DB``: metals, whose skin depth is about a
    micrometre. A chord through a metal solid shorter than that (a ray grazing a corner by
    less than a millimetre) is blocked too, which is what the edge's diffraction accounts for.

    Parameters
    ----------
    scene : Scene
    frequency_hz : float
    min_power_db : float
    eta : (n_materials,) complex, optional, relative permittivity of each used material at the
        frequency (computed when not given)
    extrapolate : bool, allow materials outside their valid frequency range

    Returns
    -------
    (O,) bool
    """
    if eta is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            eta = np.array(
                [
                    scene.materials[m].permittivity(frequency_hz, extrapolate=extrapolate)
                    for m in scene.material_names
                ],
                dtype=complex,
            )
    mat = scene.object_material
    if len(mat) == 0:
        return np.zeros(0, dtype=bool)
    th = np.where(scene.object_closed, OPAQUE_CHORD_M, scene.material_thickness()[mat])
    _, _, t_te, t_tm = slab(eta[mat], np.ones(len(mat)), th, frequency_hz)
    amp = np.maximum(np.abs(t_te), np.abs(t_tm))
    loss_db = 20 * np.log10(np.maximum(amp, 1e-300))
    return loss_db < min_power_db - OPAQUE_MARGIN_DB


def _vertical_pol(direction: np.ndarray) -> np.ndarray:
    """Unit vector of a vertically polarised antenna's field for a ray along ``direction``:
    z made perpendicular to the ray (x for a vertical ray)."""
    z = np.array([0.0, 0.0, 1.0])
    v = z[None, :] - direction[:, 2:3] * direction
    n = np.linalg.norm(v, axis=1)
    vertical = n < 1e-9
    if vertical.any():
        x = np.array([1.0, 0.0, 0.0])
        v[vertical] = x - direction[vertical, 0:1] * direction[vertical]
        n[vertical] = np.linalg.norm(v[vertical], axis=1)
    return v / n[:, None]


def _apply_te_tm(
    e: np.ndarray,
    k_in: np.ndarray,
    k_out: np.ndarray,
    normal: np.ndarray,
    c_te: np.ndarray,
    c_tm: np.ndarray,
) -> np.ndarray:
    """Field after an interaction with TE/TM coefficients.

    Basis: ``s = k_in x n`` (TE, perpendicular to the plane of incidence), ``p = s x k`` on each
    side (TM). With this basis the P.2040 coefficients (R_TM -> +1 for a perfect conductor) map
    the field directly; at normal incidence any ``s`` perpendicular to ``k_in`` serves.

    Parameters
    ----------
    e : (n, 3) complex, incident field vector
    k_in, k_out : (n, 3) float, unit propagation directions before and after
    normal : (n, 3) float, unit surface normal
    c_te, c_tm : (n,) complex
    """
    s = np.cross(k_in, normal)
    ns = np.linalg.norm(s, axis=1)
    normal_inc = ns < 1e-9
    if normal_inc.any():
        # any direction perpendicular to k_in
        helper = np.where(np.abs(k_in[normal_inc, 0:1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        s[normal_inc] = np.cross(k_in[normal_inc], helper)
        ns[normal_inc] = np.linalg.norm(s[normal_inc], axis=1)
    s = s / ns[:, None]
    p_in = np.cross(s, k_in)
    p_out = np.cross(s, k_out)
    es = np.einsum("ij,ij->i", e, s)
    ep = np.einsum("ij,ij->i", e, p_in)
    return (c_te * es)[:, None] * s + (c_tm * ep)[:, None] * p_out
