"""Path finding over many links: the tracer that runs the stages.

What is traced (Table I of the paper: each mechanism has its own limit, :class:`TraceConfig`):

* line of sight;
* specular reflections up to ``max_reflections`` (0, 1 or 2) by the image method over the
  scene's planar facets (:mod:`raytrace.solver.specular`);
* penetrations: every segment of every path may cross objects; each crossing is attenuated by
  the slab transmission of the crossed material (ITU-R P.2040 section 3) and delayed by its group
  delay; paths with more than ``max_penetrations`` crossings in all are dropped
  (:mod:`raytrace.solver.penetration`, :mod:`raytrace.solver.evaluate`);
* first-order edge diffraction (UTD), with reflections before and/or after it when
  ``max_interactions`` allows (:mod:`raytrace.solver.diffraction`).

The stages are independent: they run on a thread pool (their heavy parts, numpy on large
arrays and Embree, release the GIL) and their paths are joined in stage order, so the output does
not depend on the number of threads.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hallray.errors import brief
from hallray.units import frequency_problem

from ..core.errors import TraceInputError
from ..core.scale import MAX_SCENE_M, unit_hint
from ..scene.budget import CHECK_MIN_TRIANGLES, check_trace
from ..scene.model import Scene
from . import diffraction, specular
from .config import MIN_POWER_DB, TraceConfig
from .context import TraceContext, check_involving, opaque_objects
from .evaluate import candidates, evaluate
from .parallel import (
    ScenePool,
    auto_in_process,
    caller_pid,
    cpu_count,
    from_main,
    in_worker,
    receiver_chunks,
    resolve_workers,
)
from .paths import DIFFRACTION, Paths
from .shared import SharedArrays, share

__all__ = [
    "MIN_POWER_DB",
    "TraceConfig",
    "check_positions",
    "opaque_objects",
    "reevaluate",
    "trace",
]

#: Relative cost of the stages (the thread pool starts the costliest first, longest processing
#: time first). Second-order reflections go before the mixed stages: on the hall they are short
#: (so the order changes nothing there), on a scanned hall they cost as much as each of the two
#: parts of the RD and DR stages (11 s of 44 at 83 200 triangles), and started last they ran
#: alone on one thread.
_STAGE_COST = {
    "reflection-diffraction-reflection": 7,
    "2nd-order reflections": 6.5,
    "diffraction-reflection": 6,
    "reflection-diffraction": 5,
    "diffraction": 1,
}


def check_positions(
    scene: Scene, points: np.ndarray, what: str, *, strict: bool = False
) -> np.ndarray:
    """Validate transmitter or receiver positions: finite, at a sane scale, not inside a solid.

    The scene's bounding box is not where radio may go (a transmitter in front of a lone wall or
    above a floor is outside it): a point far from the box (more than half the box diagonal plus
    1 m) is only a warning. A point farther than :data:`~raytrace.core.scale.MAX_SCENE_M` from it
    is the scale rule's unit mistake and an error. ``strict`` is kept for compatibility and
    changes nothing. Raises :class:`TraceInputError` (:class:`~raytrace.core.scale.ScaleError`).

    Returns
    -------
    (n, 3) float array of the positions, metres
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
    dist = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
    i = int(np.argmax(dist))
    where = f"{what} {i} at {p[i].round(3).tolist()}"
    box = f"bounds {lo.round(2).tolist()} .. {hi.round(2).tolist()} m"
    if dist[i] > MAX_SCENE_M:  # the scale rule: a unit mistake, not a position
        raise TraceInputError(
            f"{where} is {dist[i]:,.0f} m outside the scene ({box}), beyond the "
            f"{MAX_SCENE_M / 1000:g} km a hall can span: {unit_hint(float(dist[i]))}"
        )
    far = dist > 0.5 * scene.extent + 1.0
    if far.any():
        warnings.warn(
            f"{int(far.sum())} {what}(s) far outside the scene, e.g. {where} is {dist[i]:.1f} m "
            f"from its {box}: check the coordinates (metres)",
            stacklevel=2,
        )
    inside = scene.inside_solid(p)
    if (inside >= 0).any():
        i = int(np.argmax(inside >= 0))
        raise TraceInputError(
            f"{what} {i} at {p[i].round(3).tolist()} is inside the solid "
            f"{scene.objects[inside[i]].name!r} (a closed mesh is a solid; to read it as a "
            "hollow shell of surfaces, as Sionna RT does, load it with surfaces=True, --surfaces)"
        )
    return p


def check_distinct(tx: np.ndarray, rx: np.ndarray, tol_m: float = 1e-6) -> None:
    """Refuse a transmitter and a receiver at one position (no direction, no path length).

    tx : (T, 3), rx : (R, 3) float, metres; tol_m : closer than this is "the same", m.
    Memory: one (T, chunk) block at a time.
    """
    for start in range(0, len(rx), 65536):
        block = rx[start : start + 65536]
        d = np.linalg.norm(tx[:, None, :] - block[None, :, :], axis=2)
        if (d < tol_m).any():
            t, r = np.argwhere(d < tol_m)[0]
            raise TraceInputError(
                f"transmitter {int(t)} and receiver {int(start + r)} are at the same position "
                f"{tx[t].round(3).tolist()}: a link needs two distinct ends"
            )


def trace(
    scene: Scene,
    tx: np.ndarray,
    rx: np.ndarray,
    frequency_hz: float,
    config: TraceConfig | None = None,
    *,
    progress: bool | Callable[[int], None] = False,
    stats: dict[str, int] | None = None,
    involving: np.ndarray | list[int] | None = None,
    threads: int | None = None,
    opaque: np.ndarray | None = None,
    workers: int | None = None,
    chunk_links: int | None = None,
) -> Paths:
    """Find every path between every transmitter and every receiver.

    Parameters
    ----------
    scene : Scene
    tx : (T, 3) float, transmitter positions, metres
    rx : (R, 3) float, receiver positions, metres
    frequency_hz : float, Hz
    config : TraceConfig, optional, the limits (default ``TraceConfig()``: 2 reflections, 2
        penetrations, 1 diffraction, 2 interactions, slab group delays on)
    progress : bool or callable, a progress bar over the stages (or chunks), or a callback
    stats : dict, optional, filled with counters (candidates, segments tested, dropped paths)
        and each stage's time in microseconds (``time_us[<stage>]``; summed over chunks, and
        overlapping on threads); a trace in chunks also gives the time each kind of lane spent
        on its chunks (``busy_us[caller]``: this process, ``busy_us[workers]``: the worker
        processes together), against which their idle time shows
    involving : object indices, optional; only paths that reflect or diffract on at least one of
        these objects (no line of sight). With :func:`reevaluate`, this is how a snapshot with
        moving objects is traced without retracing the static scene.
    threads : int, optional, threads for the independent stages of one trace in this process
        (default: as many as the cores this process may use, its CPU affinity)
    opaque : (O,) bool, optional, objects that block: a path through one is dropped before the
        crossing analysis (default :func:`opaque_objects` at this frequency and power cut; give
        the objects opaque at every band when tracing geometry once for several bands with
        ``min_power_db=-inf``)
    workers : int, optional, lanes over chunks of receivers (:func:`trace_chunks`): this process
        and ``workers - 1`` worker processes. Default
        (:func:`~raytrace.solver.parallel.auto_in_process`): this process alone, its stages on
        threads, below :data:`~raytrace.solver.parallel.PROCESS_MIN_LINKS` links (unless the
        kept pool for this scene is already running) or inside a pool's job; every core from
        there on. The paths do not depend on it.
    chunk_links : int, optional, links per chunk (default: guided chunks of at most
        :data:`~raytrace.solver.parallel.CHUNK_LINKS` links, smaller at the end)

    Returns
    -------
    Paths, in their canonical order (:meth:`Paths.sorted`).
    """
    cfg, f, tx, rx = _checked(scene, tx, rx, frequency_hz, config)
    if involving is not None:
        involving = check_involving(scene, involving)
    if (
        workers is None
        and chunk_links is None
        and auto_in_process(len(tx) * len(rx), scene, len(rx))
    ):
        return _trace_links(scene, tx, rx, f, cfg, progress, stats, involving, threads, opaque)
    chunks = _chunked(scene, tx, rx, f, cfg, None, workers, chunk_links, progress, stats,
                      involving, opaque, threads)  # fmt: skip
    return join_chunks([paths for _, paths in chunks], len(tx))


#: Joins of at least this many paths copy on several threads (:meth:`Paths.concatenate`).
JOIN_THREADS_PATHS = 200_000


def join_chunks(parts: list[Paths], n_tx: int) -> Paths:
    """The paths of chunks of consecutive receivers, in order, as one set in canonical order.

    Each chunk is in canonical order (by link ``tx * R + rx``, then ...) and holds whole links,
    so the whole is, per transmitter, each chunk's slice of that transmitter in chunk order:
    slices are views, and the arrays are copied once (the serial step after a pool's work).
    """
    bounds = [np.searchsorted(p.tx_index, np.arange(n_tx + 1)) for p in parts]
    pieces = [p.select(slice(b[t], b[t + 1])) for t in range(n_tx) for p, b in zip(parts, bounds)]
    n = sum(p.n_paths for p in parts)
    # a large join copies on all cores it may use (it is the serial step after the pool's work)
    threads = min(cpu_count(), 8) if n >= JOIN_THREADS_PATHS else 1
    return Paths.concatenate(pieces, threads=threads)


def trace_chunks(
    scene: Scene,
    tx: np.ndarray,
    rx: np.ndarray,
    frequency_hz: float,
    config: TraceConfig | None = None,
    *,
    reduce: Callable[[Paths], Any] | None = None,
    workers: int | None = None,
    chunk_links: int | None = None,
    progress: bool | Callable[[int], None] = False,
    stats: dict[str, int] | None = None,
    involving: np.ndarray | list[int] | None = None,
    opaque: np.ndarray | None = None,
) -> Iterator[tuple[range, Any]]:
    """Trace chunks of receivers (on worker processes) and yield each chunk's result in order.

    Each chunk is traced on its own (a link's paths do not depend on the other links); the paths
    of a chunk carry the global transmitter and receiver indices. With ``reduce``, a worker
    returns ``reduce(paths)`` instead of the paths, so that memory stays bounded by one chunk
    however many receivers there are.

    Parameters
    ----------
    scene, tx, rx, frequency_hz, config, involving, opaque : as in :func:`trace`
    reduce : callable, optional, a module-level function ``reduce(paths) -> result`` (it is sent to
        the workers by reference)
    workers : int, optional, lanes: this process and ``workers - 1`` worker processes (default
        every core, 1 inside a pool's job; at most one per chunk)
    chunk_links : int, optional, links per chunk (default: guided chunks of at most
        :data:`~raytrace.solver.parallel.CHUNK_LINKS` links, smaller at the end)
    progress : bool or callable, a progress bar over the chunks, or a callback per chunk
    stats : dict, optional, counters summed over the chunks

    Yields
    ------
    (receivers, result) : the chunk's receiver indices (a range) and its Paths or reduced result
    """
    cfg, f, tx, rx = _checked(scene, tx, rx, frequency_hz, config)
    if involving is not None:
        involving = check_involving(scene, involving)
    yield from _chunked(scene, tx, rx, f, cfg, reduce, workers, chunk_links, progress, stats,
                        involving, opaque)  # fmt: skip


def _chunked(
    scene: Scene,
    tx: np.ndarray,
    rx: np.ndarray,
    f: float,
    cfg: TraceConfig,
    reduce: Callable[[Paths], Any] | None,
    workers: int | None,
    chunk_links: int | None,
    progress: bool | Callable[[int], None],
    stats: dict[str, int] | None,
    involving: np.ndarray | list[int] | None,
    opaque: np.ndarray | None,
    threads: int | None = None,
) -> Iterator[tuple[range, Any]]:
    """:func:`trace_chunks` on validated input (``threads``: as in :func:`trace`, for chunks
    traced on one lane; with several, each lane traces on one thread)."""
    # guided chunks give every lane a share even of a trace smaller than one fixed chunk
    n_chunks = len(rx) if chunk_links is None else len(receiver_chunks(len(tx), len(rx), chunk_links))
    n_workers = resolve_workers(workers, n_chunks)
    chunks = receiver_chunks(len(tx), len(rx), chunk_links, n_workers)
    n_workers = min(n_workers, len(chunks))
    jobs = [(tx, rx, c, f, cfg, involving, opaque, reduce, n_workers > 1, threads) for c in chunks]
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(rx) * len(tx), desc="tracing", unit="link", leave=False)
    try:
        with ScenePool(scene, n_workers, main=from_main(reduce)) as pool:
            for chunk, (result, chunk_stats) in zip(chunks, pool.map(_trace_job, jobs)):
                if isinstance(result, _SharedPaths):
                    result = result.load()
                if stats is not None:
                    for key, v in chunk_stats.items():
                        stats[key] = stats.get(key, 0) + v
                if bar is not None:
                    bar.update(len(chunk) * len(tx))
                elif callable(progress):
                    progress(1)
                yield chunk, result
    finally:
        if bar is not None:
            bar.close()


def _trace_job(scene: Scene, job: tuple) -> tuple[Any, dict[str, int]]:
    """One chunk of :func:`trace_chunks` (in a worker or in this process), with the time its
    lane spent on it (``busy_us[workers]`` or ``busy_us[caller]``, microseconds)."""
    t0 = time.perf_counter()
    tx, rx, chunk, f, cfg, involving, opaque, reduce, in_pool, threads = job
    stats: dict[str, int] = {}
    part = _trace_links(scene, tx, rx[chunk.start : chunk.stop], f, cfg, False, stats, involving,
                        1 if in_pool else threads, opaque)  # fmt: skip
    paths = part.with_receivers(rx, chunk.start)
    out: Any = paths if reduce is None else reduce(paths)
    if reduce is None and in_worker():
        out = _SharedPaths.of(paths)
    lane = "busy_us[workers]" if in_worker() else "busy_us[caller]"
    stats[lane] = int(round((time.perf_counter() - t0) * 1e6))
    return out, stats


@dataclass(frozen=True)
class _SharedPaths:
    """A worker's paths, their arrays in a file in shared memory (:mod:`raytrace.solver.shared`:
    the worker does not wait for this process to read them through the result pipe)."""

    arrays: SharedArrays
    tx: np.ndarray
    rx: np.ndarray
    frequency_hz: float

    @classmethod
    def of(cls, paths: Paths) -> _SharedPaths | Paths:
        """The paths' handle, or the paths themselves where there is no shared memory."""
        caller = caller_pid()
        arrays = None if caller is None else share(
            {k: getattr(paths, k) for k in Paths.PER_PATH}, caller
        )
        if arrays is None:
            return paths
        return cls(arrays, paths.tx, paths.rx, paths.frequency_hz)

    def load(self) -> Paths:
        return Paths(tx=self.tx, rx=self.rx, frequency_hz=self.frequency_hz, **self.arrays.load())


def _checked(
    scene: Scene, tx: np.ndarray, rx: np.ndarray, frequency_hz: float, config: TraceConfig | None
) -> tuple[TraceConfig, float, np.ndarray, np.ndarray]:
    """The config, frequency and positions of a trace, validated (:class:`TraceInputError`)."""
    cfg = TraceConfig() if config is None else config
    if not isinstance(cfg, TraceConfig):
        raise TraceInputError(f"config must be a TraceConfig, got {type(cfg).__name__}")
    try:
        f = float(frequency_hz)
    except (TypeError, ValueError):
        raise TraceInputError(f"frequency must be a number of Hz, got {brief(frequency_hz)}") from None
    if not np.isfinite(f) or f <= 0:
        raise TraceInputError(f"frequency must be a positive number of Hz, got {frequency_hz}")
    problem = frequency_problem(f)  # the scale rule: 3.5 "Hz" is 3.5 GHz in the wrong unit
    if problem is not None:
        raise TraceInputError(f"frequency {problem}")
    tx = check_positions(scene, tx, "transmitter")
    rx = check_positions(scene, rx, "receiver")
    check_distinct(tx, rx)
    if len(scene.faces) >= CHECK_MIN_TRIANGLES:  # a small scene's trace fits anywhere
        check_trace(len(scene.faces), Path(scene.source).name or "in memory")
    return cfg, f, tx, rx


def _trace_links(
    scene: Scene,
    tx: np.ndarray,
    rx: np.ndarray,
    f: float,
    cfg: TraceConfig,
    progress: bool | Callable[[int], None],
    stats: dict[str, int] | None,
    involving: np.ndarray | list[int] | None,
    threads: int | None,
    opaque: np.ndarray | None,
) -> Paths:
    """Every path of the links ``tx x rx`` (validated) in this process: the stages on threads."""
    ctx = TraceContext(scene, tx, rx, f, cfg, involving, opaque)
    stages = specular.stages(ctx)
    if cfg.max_diffractions >= 1 and cfg.max_interactions >= 1 and len(scene.wedges):
        stages.extend(diffraction.stages(ctx))
    results = _run_stages(ctx, stages, progress, threads)
    if stats is not None:
        for key, v in ctx.stats.items():
            stats[key] = stats.get(key, 0) + v
    parts = [p for r in results for p in r]
    if not parts:
        depth = cfg.max_reflections + cfg.max_penetrations + cfg.max_diffractions
        return Paths.empty(tx, rx, f, depth)
    return Paths.concatenate(parts).sorted()


def _run_stages(
    ctx: TraceContext,
    stages: list[tuple[str, Callable[[], list[Paths]]]],
    progress: bool | Callable[[int], None],
    threads: int | None,
) -> list[list[Paths]]:
    """Each stage's paths, in stage order, computed on up to ``threads`` threads."""
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(stages), desc="tracing", unit="stage", leave=False)

    def report(name: str) -> None:
        if bar is not None:
            bar.set_postfix_str(name)
            bar.update(1)
        elif callable(progress):
            progress(1)

    # the cores this process may use (its affinity: taskset, a container's cpuset), not the
    # machine's: more threads than cores only contend for the GIL
    n_threads = cpu_count() if threads is None else max(1, int(threads))
    results: list[list[Paths]] = []
    try:
        if n_threads == 1 or len(stages) <= 1:
            for name, stage in stages:
                results.append(ctx.timed(name, stage))
                report(name)
            return results
        with ThreadPoolExecutor(max_workers=min(n_threads, len(stages))) as pool:
            # the costliest stages first, so the short ones fill in beside them
            order = sorted(range(len(stages)), key=lambda i: -_STAGE_COST.get(stages[i][0], 0))
            futures: list = [None] * len(stages)
            for i in order:
                futures[i] = pool.submit(ctx.timed, *stages[i])
            for (name, _), fut in zip(stages, futures):
                results.append(fut.result())
                report(name)
        return results
    finally:
        if bar is not None:
            bar.close()


def reevaluate(scene: Scene, paths: Paths, config: TraceConfig | None = None) -> Paths:
    """Recompute visibility, penetrations and fields of given paths in another scene.

    The paths keep their reflection and diffraction vertices and elements (facet and wedge
    indices), so ``scene`` must index those elements as the scene they were traced in did; a
    scene built from the same objects followed by more objects does. Paths that now cross more
    objects than ``config.max_penetrations``, or carry less power than ``config.min_power_db``,
    are dropped (the reflection, diffraction and interaction limits do not apply: the vertices are
    given).

    Parameters
    ----------
    scene : Scene
    paths : Paths, from :func:`trace`
    config : TraceConfig, optional (default ``TraceConfig()``)

    Returns
    -------
    Paths, sorted like :func:`trace`'s.
    """
    cfg = TraceConfig() if config is None else config
    ctx = TraceContext(scene, paths.tx, paths.rx, paths.frequency_hz, cfg, None)
    kinds, pts, elem = paths.vertices()
    depth = max(kinds.shape[1], 1) + cfg.max_penetrations
    parts = [Paths.empty(paths.tx, paths.rx, paths.frequency_hz, depth)]
    # one group per interaction sequence, so the back end sees rectangular arrays
    seq, group = _unique_rows(kinds)
    for g, pattern in enumerate(seq if paths.n_paths else []):
        sel = np.flatnonzero(group.reshape(-1) == g)
        k = int((pattern > 0).sum())
        model = diffraction.field_model(ctx) if (pattern == DIFFRACTION).any() else None
        parts.append(
            evaluate(
                ctx,
                candidates(
                    ctx,
                    paths.tx_index[sel],
                    paths.rx_index[sel],
                    pts[sel, :k],
                    elem[sel, :k],
                    kinds=kinds[sel, :k],
                ),
                diffraction=model,
            )  # fmt: skip
        )
    return Paths.concatenate(parts).sorted()


def _unique_rows(kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(kinds, axis=0, return_inverse=True)`` for small non-negative integer codes
    (``kinds`` (n, k)): each row read as one integer in base ``max + 1``, whose order is the
    rows' lexicographic order (numpy's unique over rows sorts a void view: 6 ms for the 3 000
    paths of a forklift snapshot)."""
    if kinds.size == 0 or kinds.shape[1] == 0:
        return np.unique(kinds, axis=0, return_inverse=True)
    base = int(kinds.max()) + 1
    code = np.zeros(len(kinds), dtype=np.int64)
    for j in range(kinds.shape[1]):
        code = code * base + kinds[:, j]
    _, first, group = np.unique(code, return_index=True, return_inverse=True)
    return kinds[first], group
