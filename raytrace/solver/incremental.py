"""Moving objects: forklifts on routes, snapshots of the hall, and the incremental retrace.

Forklift model (see ``docs/dynamics.md``): a closed box of the route's ``size`` (length along
the driving direction, width, height) and ``material`` (metal in the reference hall), lifted
``clearance_m`` above the floor plane z = 0 (so it never shares a plane with the floor) and
reaching up to the route's height. Its centre drives along the route's polyline of ``waypoints``
at constant ``speed``: around the closed polygon for ``mode: loop``, there and back for
``mode: back_and_forth``; t = 0 at the first waypoint. The box is turned to the driving
direction of the current polyline segment (it turns on the spot at a waypoint). Routes are read
from the scene metadata (``metadata["hallray"]["routes"]``, written by the hall builder), so any
scene file with routes works.

Incremental retrace (:class:`SnapshotTracer`): the static scene is traced once. A snapshot's
scene is the static objects followed by the forklift boxes (:mod:`raytrace.scene.dynamic`), so
static facet and wedge indices are unchanged. Its paths are

* the static paths none of whose segments comes near a forklift box, unchanged;
* the static paths with a segment through or near a box (analytic segment-box test, boxes grown
  by ``grow_m``), re-evaluated in the snapshot scene (:func:`raytrace.solver.tracer.reevaluate`: same
  vertices, new penetrations and fields);
* the paths that reflect or diffract on a forklift (:func:`raytrace.solver.tracer.trace` with
  ``involving=``).

This is exactly the full retrace of the snapshot: a path's vertices lie on the elements it
reflects or diffracts on, so a path on static elements only is one of the static candidates, and
adding objects only adds crossings to its segments; a segment that does not meet a box cannot
cross it. To stay exact whatever the materials, the static candidates are kept without the
power cut (``min_power_db = -inf``, geometry only) and the power cut of each band is applied when
fields are evaluated, so one geometric trace per snapshot serves every band. Only objects opaque in
every band (metal) are dropped in that geometric trace (:func:`raytrace.solver.tracer.opaque_objects`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.errors import SceneError
from ..core.jit import carray
from ..scene.dynamic import extend_scene, posed, yaw_rotations
from ..scene.model import Scene
from ..scene.motion import FORKLIFT_CLEARANCE_M, Route
from . import kernels
from .config import TraceConfig
from .paths import Paths
from .tracer import opaque_objects, reevaluate, trace

#: Default growth of the forklift boxes in the segment test, m: far above Embree's float32
#: resolution (~4e-6 m at 50 m) and the tracer's end margin (1e-4 m), so that no crossing that
#: Embree could report is missed.
AFFECTED_GROW_M = 1e-3


# --------------------------------------------------------------------------------------------
# routes
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# boxes
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Boxes:
    """Oriented boxes, structure of arrays.

    Attributes
    ----------
    centre : (B, 3) float, metres
    rotation : (B, 3, 3) float, columns = the box axes (length, width, height) in world frame
    half : (B, 3) float, half extents along those axes, metres
    """

    centre: np.ndarray
    rotation: np.ndarray
    half: np.ndarray

    def __len__(self) -> int:
        return int(self.centre.shape[0])

    def contains(self, points: np.ndarray, grow: float = 0.0) -> np.ndarray:
        """(n, B) bool: point n inside box b grown by ``grow`` metres."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        local = np.einsum("nbj,bjk->nbk", p[:, None, :] - self.centre[None], self.rotation)
        return np.all(np.abs(local) <= self.half[None] + grow, axis=2)


def segments_meet_boxes(
    a: np.ndarray, b: np.ndarray, boxes: Boxes, grow: float = AFFECTED_GROW_M
) -> np.ndarray:
    """Whether each segment ``a -> b`` meets any of the boxes grown by ``grow`` (slab test).

    Parameters
    ----------
    a, b : (S, 3) float, segment ends, metres
    boxes : Boxes
    grow : float, metres added to every half extent

    Returns
    -------
    (S,) bool
    """
    a = np.asarray(a, dtype=float).reshape(-1, 3)
    b = np.asarray(b, dtype=float).reshape(-1, 3)
    hit = np.zeros(len(a), dtype=bool)
    for k in range(len(boxes)):  # a handful of boxes; vectorised over segments
        h = boxes.half[k] + grow
        # segment in the box frame: x_local = R^T (x - c)
        pa = (a - boxes.centre[k]) @ boxes.rotation[k]
        d = (b - boxes.centre[k]) @ boxes.rotation[k] - pa
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-h - pa) / d
            t2 = (h - pa) / d
        flat = d == 0
        inside = np.abs(pa) <= h
        t_lo = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
        t_hi = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
        enter = np.maximum(t_lo.max(axis=1), 0.0)
        leave = np.minimum(t_hi.min(axis=1), 1.0)
        hit |= enter <= leave
    return hit


def path_segments(paths: Paths) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The straight segments of every path between its ends and its reflection and diffraction
    vertices (penetration points lie on them).

    Returns
    -------
    a, b : (S, 3) float, segment ends, metres
    path : (S,) int, the path of each segment
    """
    kinds, pts, _ = paths.vertices()
    n, k = kinds.shape
    rx = paths.rx[paths.rx_index]
    chain = np.empty((n, k + 2, 3))
    chain[:, 0] = paths.tx[paths.tx_index]
    # compacted vertices first; empty slots and the end are the receiver (zero-length segments)
    chain[:, 1 : k + 1] = np.where((kinds > 0)[:, :, None], pts, rx[:, None, :])
    chain[:, k + 1] = rx
    n_seg = (kinds > 0).sum(axis=1) + 1
    valid = np.arange(k + 1)[None, :] < n_seg[:, None]
    path = np.broadcast_to(np.arange(n)[:, None], (n, k + 1))[valid]
    return chain[:, :-1][valid], chain[:, 1:][valid], path


# --------------------------------------------------------------------------------------------
# the fleet
# --------------------------------------------------------------------------------------------


class Fleet:
    """The forklifts of a set of routes: poses, boxes and their meshes at any time.

    Parameters
    ----------
    routes : sequence of Route
    clearance_m : float, height of the boxes' underside above the floor, metres
    """

    def __init__(self, routes: Sequence[Route], clearance_m: float = FORKLIFT_CLEARANCE_M):
        self.routes = list(routes)
        self.clearance_m = float(clearance_m)
        size = np.array([r.size for r in self.routes], dtype=float).reshape(-1, 3)
        if np.any(size[:, 2] <= self.clearance_m):
            raise SceneError("a forklift is not taller than its clearance above the floor")
        self.extent = np.column_stack([size[:, 0], size[:, 1], size[:, 2] - self.clearance_m])

    def __len__(self) -> int:
        return len(self.routes)

    @property
    def names(self) -> list[str]:
        return [r.name for r in self.routes]

    def poses(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Box centres (B, 3) metres and headings (B,) radians at time ``t_s``."""
        xy = np.zeros((len(self), 2))
        yaw = np.zeros(len(self))
        for i, r in enumerate(self.routes):  # a few routes
            p, h = r.pose(t_s)
            xy[i], yaw[i] = p[0], h[0]
        z = self.clearance_m + 0.5 * self.extent[:, 2]
        return np.column_stack([xy, z]), yaw

    def boxes(self, t_s: float) -> Boxes:
        """The boxes at time ``t_s``."""
        centre, yaw = self.poses(t_s)
        return Boxes(centre, yaw_rotations(yaw), 0.5 * self.extent)

    def template(self, materials: Any) -> Scene:
        """One closed box per forklift, centred at the origin, axis-aligned (length along x).

        Each box is processed on its own (the boxes overlap here) and the scenes are joined.
        """
        import trimesh

        out = None
        for i, r in enumerate(self.routes):
            box = Scene.from_meshes(
                [(r.name, trimesh.creation.box(extents=self.extent[i]), r.material)],
                materials,
                source="forklifts",
            )
            out = box if out is None else extend_scene(out, box)
        if out is None:
            raise SceneError("no forklift routes")
        return out

    def meshes(self, t_s: float) -> list[tuple[str, Any, str]]:
        """``(name, trimesh.Trimesh, material)`` of the boxes at ``t_s`` (world coordinates)."""
        import trimesh

        box = self.boxes(t_s)
        out = []
        for i, r in enumerate(self.routes):
            m = trimesh.creation.box(extents=self.extent[i])
            tf = np.eye(4)
            tf[:3, :3] = box.rotation[i]
            tf[:3, 3] = box.centre[i]
            m.apply_transform(tf)
            out.append((r.name, m, r.material))
        return out


# --------------------------------------------------------------------------------------------
# incremental retrace
# --------------------------------------------------------------------------------------------


def _at_frequency(paths: Paths, frequency_hz: float) -> Paths:
    return dataclasses.replace(paths, frequency_hz=float(frequency_hz))


class PathSegments:
    """The segments of a path set with their bounding boxes, for repeated box tests."""

    def __init__(self, paths: Paths):
        self.n_paths = paths.n_paths
        self.a, self.b, self.path = path_segments(paths)
        self.lo = np.minimum(self.a, self.b)
        self.hi = np.maximum(self.a, self.b)

    def affected(self, boxes: Boxes, grow: float) -> np.ndarray:
        """(P,) bool: paths with a segment that meets a box grown by ``grow`` metres (the slab
        test of :func:`segments_meet_boxes`, after a bounding-box prefilter, compiled:
        :func:`raytrace.solver.kernels.paths_meeting_boxes`)."""
        half = np.ascontiguousarray(boxes.half + grow, dtype=float)
        ext = np.ascontiguousarray(np.einsum("bij,bj->bi", np.abs(boxes.rotation), half))
        return kernels.paths_meeting_boxes(
            self.a, self.b, self.lo, self.hi, self.path, self.n_paths,
            carray(boxes.centre), carray(boxes.rotation), half, ext,
        )  # fmt: skip


class SnapshotTracer:
    """Paths of every link in every snapshot of a scene with moving forklifts.

    Parameters
    ----------
    scene : Scene, the static scene (without forklifts)
    tx : (T, 3) float, transmitter positions, metres
    rx : (R, 3) float, receiver positions, metres
    routes : sequence of Route (may be empty: every snapshot is the static scene)
    frequencies_hz : sequence of float, the bands' carriers; one path set per frequency
    settings : TraceConfig
    clearance_m : float, forklift underside above the floor, metres
    grow_m : float, growth of the boxes in the affected-path test, metres
    static_paths : list of Paths, optional, a previous :attr:`static_paths` of the same inputs
        (skips the static traces, e.g. in worker processes)
    threads : int, optional, threads of each :func:`trace` call (1 in a process pool's workers)

    Attributes
    ----------
    static_paths : list of Paths, per frequency: ``trace`` of the static scene
    moving_objects : (B,) int, object indices of the forklifts in a snapshot scene
    stats : dict, accumulated seconds per stage and counters of :meth:`paths_at`
    """

    def __init__(
        self,
        scene: Scene,
        tx: np.ndarray,
        rx: np.ndarray,
        routes: Sequence[Route],
        frequencies_hz: Sequence[float],
        settings: TraceConfig | None = None,
        *,
        clearance_m: float = FORKLIFT_CLEARANCE_M,
        grow_m: float = AFFECTED_GROW_M,
        static_paths: Sequence[Paths] | None = None,
        threads: int | None = None,
    ):
        self.scene = scene
        self.tx = np.asarray(tx, dtype=float).reshape(-1, 3)
        self.rx = np.asarray(rx, dtype=float).reshape(-1, 3)
        self.frequencies_hz = [float(f) for f in frequencies_hz]
        if not self.frequencies_hz:
            raise SceneError("no frequency to trace")
        self.settings = settings or TraceConfig()
        self.threads = threads
        self.fleet = Fleet(routes, clearance_m)
        self.grow_m = max(float(grow_m), 10.0 * scene.margin)
        self.template = self.fleet.template(scene.materials) if len(self.fleet) else None
        n0 = len(scene.objects)
        self.moving_objects = np.arange(n0, n0 + len(self.fleet))
        if static_paths is None:
            static_paths = [
                self._trace(scene, f, self.settings.min_power_db) for f in self.frequencies_hz
            ]
        elif len(static_paths) != len(self.frequencies_hz):
            raise SceneError("one static path set per frequency is needed")
        self.static_paths = list(static_paths)
        self._segments = [PathSegments(p) for p in self.static_paths]
        self._opaque: list[np.ndarray] | None = None  # per frequency, over a snapshot's objects
        self.stats: dict[str, float] = {}

    # -- helpers --------------------------------------------------------------------------
    def _trace(self, scene: Scene, frequency_hz: float, min_power_db: float, **kw: Any) -> Paths:
        cfg = self.settings.replace(min_power_db=min_power_db)
        return trace(scene, self.tx, self.rx, frequency_hz, cfg, threads=self.threads, **kw)

    def _tick(self, key: str, t0: float) -> float:
        now = time.perf_counter()
        self.stats[key] = self.stats.get(key, 0.0) + (now - t0)
        return now

    # -- snapshots ------------------------------------------------------------------------
    def boxes_at(self, t_s: float) -> Boxes:
        """The forklift boxes at ``t_s``."""
        return self.fleet.boxes(t_s)

    def scene_at(self, t_s: float) -> Scene:
        """The snapshot scene at ``t_s``: static objects, then one box per forklift."""
        if self.template is None:
            return self.scene
        box = self.fleet.boxes(t_s)
        return extend_scene(self.scene, posed(self.template, box.rotation, box.centre))

    def paths_at(self, t_s: float, scene: Scene | None = None) -> list[Paths]:
        """Paths of every link at time ``t_s``, per frequency, by the incremental retrace.

        Parameters
        ----------
        t_s : float, seconds
        scene : Scene, optional, ``scene_at(t_s)`` if already built

        Returns
        -------
        list of Paths (one per frequency), sorted like :func:`trace`'s
        """
        if self.template is None:
            return list(self.static_paths)
        t0 = time.perf_counter()
        snap = self.scene_at(t_s) if scene is None else scene
        boxes = self.fleet.boxes(t_s)
        t0 = self._tick("scene_s", t0)
        affected = [seg.affected(boxes, self.grow_m) for seg in self._segments]
        t0 = self._tick("affected_s", t0)
        # paths on the forklifts: geometry once (no power cut), fields per frequency below.
        # Objects opaque in every band block in the geometric trace too (what they block carries
        # no power in any band).
        cut = self.settings.min_power_db
        if self._opaque is None:
            # every snapshot has the same objects and materials: computed once
            self._opaque = [opaque_objects(snap, f, cut) for f in self.frequencies_hz]
        opaque = self._opaque
        common = np.logical_and.reduce(opaque)
        new = self._trace(
            snap, self.frequencies_hz[0], -np.inf, involving=self.moving_objects, opaque=common
        )
        t0 = self._tick("involving_s", t0)
        out = []
        for k, (f, static, aff) in enumerate(zip(self.frequencies_hz, self.static_paths, affected)):
            if k == 0 and np.array_equal(opaque[0], common):
                # the new paths' fields are already those of this frequency: only the power cut
                # (the tracer's own expression) remains
                power_db = 20 * np.log10(np.maximum(np.abs(new.gain), 1e-300))
                parts = [
                    reevaluate(snap, static.select(aff), self.settings),
                    new.select(power_db >= cut),
                ]
            else:
                redo = Paths.concatenate([static.select(aff), new])
                parts = [reevaluate(snap, _at_frequency(redo, f), self.settings)]
            out.append(Paths.concatenate([static.select(~aff), *parts]).sorted())
            self.stats["affected_paths"] = self.stats.get("affected_paths", 0) + int(aff.sum())
        self._tick("reevaluate_s", t0)
        self.stats["snapshots"] = self.stats.get("snapshots", 0) + 1
        self.stats["new_paths"] = self.stats.get("new_paths", 0) + new.n_paths
        return out

    def full_retrace(self, t_s: float, scene: Scene | None = None) -> list[Paths]:
        """The same paths by tracing the snapshot scene from scratch (the reference; slow)."""
        snap = self.scene_at(t_s) if scene is None else scene
        return [self._trace(snap, f, self.settings.min_power_db) for f in self.frequencies_hz]

    def check_clear(self, times: np.ndarray, names_tx: Sequence[str], names_rx: Sequence[str]):
        """Raise :class:`SceneError` if a transmitter or receiver is inside a forklift at any of
        ``times`` (the tracer cannot place an antenna inside a solid)."""
        if not len(self.fleet):
            return
        pts = np.vstack([self.tx, self.rx])
        names = list(names_tx) + list(names_rx)
        for t in np.asarray(times, dtype=float):
            inside = self.fleet.boxes(float(t)).contains(pts, self.scene.margin)
            if inside.any():
                i, k = np.argwhere(inside)[0]
                raise SceneError(
                    f"{names[i]} is inside forklift '{self.fleet.names[k]}' at t = {t:g} s"
                )
