"""Work over many links: chunks of receivers, run in this process or on worker processes.

A trace is independent per link, so the receivers are split into chunks that worker processes
trace on their own copy of the scene (spawned, not forked: Embree and the tracer's threads do not
survive a fork; a pickled :class:`~raytrace.scene.model.Scene` carries its arrays and rebuilds its
intersector). Results come back in chunk order, so what is computed does not depend on the number
of workers or the chunk size. :class:`ScenePool` is that machinery; the tracer
(:func:`raytrace.solver.tracer.trace`, :func:`raytrace.solver.tracer.trace_chunks`) uses it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from ..core.errors import TraceInputError
from ..scene.model import Scene

#: Links per chunk of receivers (bounds the candidate arrays of one trace to a few hundred MB).
CHUNK_LINKS = 256
#: Below this many links a trace stays in this process: a worker's start-up (imports, scene,
#: Embree) costs about a second, more than tracing a few hundred links.
PROCESS_MIN_LINKS = 1000

_SCENE: dict[str, Scene] = {}


def cpu_count() -> int:
    """Cores this process may use (its CPU affinity where the platform tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def resolve_workers(workers: int | None, n_chunks: int) -> int:
    """Worker processes to start: the request (default: every core), at most the cores and the
    chunks. Raises :class:`TraceInputError` for a request that is not a positive integer."""
    if workers is None:
        want = cpu_count()
    elif isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise TraceInputError(f"workers must be a positive integer, got {workers!r}")
    else:
        want = workers
    return max(1, min(want, cpu_count(), max(n_chunks, 1)))


def receiver_chunks(n_tx: int, n_rx: int, chunk_links: int | None = None) -> list[range]:
    """Consecutive ranges of receiver indices with at most ``chunk_links`` links each."""
    per = max(1, int(chunk_links or CHUNK_LINKS) // max(n_tx, 1))
    return [range(r0, min(n_rx, r0 + per)) for r0 in range(0, n_rx, per)]


def _init_worker(scene: Scene) -> None:
    _SCENE["scene"] = scene


def _call(fn: Callable[[Scene, Any], Any], item: Any) -> Any:
    return fn(_SCENE["scene"], item)


class ScenePool:
    """``fn(scene, item)`` for many items, in order, in this process or on worker processes that
    each hold a copy of ``scene``.

    Parameters
    ----------
    scene : Scene
    workers : int, processes (1: run in this process, no pool)

    ``fn`` must be a module-level function (it is sent to the workers by reference).
    """

    def __init__(self, scene: Scene, workers: int) -> None:
        self.scene, self.workers = scene, int(workers)
        self._pool: ProcessPoolExecutor | None = None
        if self.workers > 1:
            import multiprocessing

            self._pool = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=(scene,),
            )

    def map(self, fn: Callable[[Scene, Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """The results of ``fn(scene, item)``, in the order of ``items``."""
        if self._pool is None:
            for item in items:
                yield fn(self.scene, item)
            return
        futures = [self._pool.submit(_call, fn, item) for item in items]
        try:
            for fut in futures:
                yield fut.result()
        finally:
            for fut in futures:
                fut.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> ScenePool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
