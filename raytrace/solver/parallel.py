"""Work over many links: chunks of receivers, run in this process and on worker processes.

A trace is independent per link, so the receivers are split into chunks that worker processes
trace on their own copy of the scene. Results come back in chunk order, so what is computed does
not depend on the number of workers or the chunk size. :class:`ScenePool` is that machinery; the
tracer (:func:`raytrace.solver.tracer.trace`, :func:`raytrace.solver.tracer.trace_chunks`) and the
accuracy map use it.

What a pool costs, and how it is kept small (measured in docs/tracing.md, "Where the time goes"):

* **Workers come from a fork server** with numpy and raytrace imported once (:data:`PRELOAD`); a
  worker is a fork of it, ready in tens of milliseconds, where a spawned interpreter spends half a
  second or more importing them. The fork server never imports Embree nor builds a scene, so its
  forks are safe (a fork of a process whose Embree or tracer threads are alive is not: that is
  why the workers are never forked from the caller; and Embree merely imported before a fork
  makes the fork trace 2x slower). Where there is no fork server (Windows) workers are spawned.
  The fork server loads BLAS with one thread (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``,
  ``MKL_NUM_THREADS`` at 1 in its environment): a worker is one lane, and BLAS's helper threads
  would spin on the other lanes' cores. Python has one fork server per interpreter, so a caller's
  own ``forkserver`` processes started after a pool get this setting and this ``PYTHONPATH`` too.
* **The pool outlives one call**: it is kept for the next call with the same scene (its pickled
  bytes, compared by digest) and as many workers or fewer, so a caller that traces many times
  (the accuracy map, reproduce-paper) starts it once. A call with another scene or more workers
  closes it and starts a new one; :func:`close_pools` closes it, and so does the end of the
  interpreter.
* **The scene is sent once per worker** as its pickled bytes (the arrays; the Embree scene is
  rebuilt in a few milliseconds, the facets and wedges are not recomputed; their derived caches
  are, once per worker, so that the bytes do not change when a trace fills them).
* **The calling process works too**: with ``workers=n`` there are ``n - 1`` worker processes, and
  this process takes the next chunk of the queue whenever it would otherwise wait, so it traces
  while the workers start and no core idles while it waits.
* **Guided chunks** (:func:`receiver_chunks` with ``lanes``): the last chunks are smaller, so the
  lanes finish together.
* **A worker's paths come back through shared memory** (:mod:`raytrace.solver.shared`): it writes
  them to a file in ``/dev/shm`` and sends the name, so it does not wait in the result pipe for
  this process to read them, and this process maps them instead of reading and unpickling them
  on the core it traces on.

A worker process that dies (killed, out of memory) makes the pool raise one
:class:`WorkerCrashError`; the broken pool is dropped and the next call starts a new one. The
other way round, a worker ends within about a second (:data:`CALLER_WATCH_S`) of the process
that started it, if that one dies without closing its pools (SIGKILL, the out-of-memory killer):
every pool's processes watch their caller (:func:`_watch_caller`; not on Windows).

* **Workers do not run the caller's script.** A fork-server or spawned process imports the
  parent's ``__main__`` first (``multiprocessing``'s rule), so a script that calls ``trace`` at
  its top level, without ``if __name__ == "__main__":``, would run again in every worker and
  start pools there. The jobs are raytrace functions, so workers are started with the parent's
  ``__main__`` hidden from them; only a pool whose jobs come from ``__main__`` (``main=True``,
  e.g. a ``reduce`` defined in the script) imports it, and then the script needs the guard.
"""

from __future__ import annotations

import atexit
import hashlib
import multiprocessing
import multiprocessing.context
import os
import pickle
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from hallray.workerenv import ONE_THREAD, environ_set

from ..core.errors import HallrayError, TraceInputError
from ..scene.model import Scene
from .shared import remove_left_over

#: Links per chunk of receivers (bounds the candidate arrays of one trace to a few hundred MB).
CHUNK_LINKS = 256
#: Smallest guided chunk, links (a chunk has a fixed cost of about 70 ms of CPU on the hall: 16
#: links per chunk cost 35 % more than 256, 64 links 5 %).
MIN_CHUNK_LINKS = 64
#: With ``workers=None``, a trace of fewer links stays in this process, on threads over its
#: stages, unless it fills :data:`AUTO_MIN_LANES` lanes. Measured on 2 cores (hall, a kept pool,
#: docs/tracing.md): threads and 2 lanes tie at 92 and 256 links, 2 lanes win from 412 links on
#: (1.42 s against 1.71 s), and the first pool of an interpreter (0.28 s) is repaid by about 500.
PROCESS_MIN_LINKS = 500
#: ... or from this many lanes of :data:`MIN_CHUNK_LINKS` links on as many cores: threads over the
#: stages cannot go beyond about 2.1x (the costliest stage is 47 % of a trace), 6 lanes can.
AUTO_MIN_LANES = 6
#: Modules the fork server imports once, so that its forks (the workers) start with them. Never
#: embreex (nor trimesh, which imports it): Embree imported before the fork makes every fork
#: trace about 2x slower (2 workers on the 2 m grid: 10.9 s against 5.5 s); each worker imports
#: it itself (tests/test_parallel.py checks that these modules do not).
PRELOAD = ("numpy", "raytrace")


class WorkerCrashError(HallrayError):
    """A worker process died while tracing (killed, out of memory, a crash in native code)."""


_SCENE: dict[str, Any] = {}  # in a worker: its scene, and that it is a worker
_STATE: dict[str, Any] = {}  # in the caller: whether the fork server was started
_LOCK = threading.Lock()
#: The one kept pool: {"key": (scene digest, processes), "executor": ProcessPoolExecutor}.
_KEPT: dict[str, Any] = {}
#: Set in a worker and while this process runs a job: traces inside a job stay in-process.
_IN_JOB = threading.local()


def cpu_count() -> int:
    """Cores this process may use (its CPU affinity where the platform tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def in_worker() -> bool:
    """Whether this code runs in a worker process of a :class:`ScenePool`."""
    return bool(_SCENE.get("worker"))


def in_job() -> bool:
    """Whether this code runs inside a pool's job (in a worker process of any pool, or a chunk
    this process took): a trace there must not start processes of its own by default."""
    import multiprocessing

    return (
        bool(_SCENE.get("worker"))
        or getattr(_IN_JOB, "depth", 0) > 0
        or multiprocessing.parent_process() is not None
    )


def resolve_workers(workers: int | None, n_chunks: int) -> int:
    """Lanes to run (this process and ``lanes - 1`` workers): the request (default: every core),
    at most the cores and the chunks. Raises :class:`TraceInputError` for a request that is not a
    positive integer."""
    if workers is None:
        want = 1 if in_job() else cpu_count()
    elif isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise TraceInputError(f"workers must be a positive integer, got {workers!r}")
    else:
        want = workers
    return max(1, min(want, cpu_count(), max(n_chunks, 1)))


def auto_in_process(n_links: int, scene: Scene | None = None, n_rx: int = 0) -> bool:
    """The rule of ``workers=None``: whether a trace of ``n_links`` links stays in this process
    (its stages on threads) rather than going over every core in chunks.

    It stays in this process inside a pool's job (:func:`in_job`), on one core, and when it has
    fewer than :data:`PROCESS_MIN_LINKS` links unless it fills :data:`AUTO_MIN_LANES` lanes of
    :data:`MIN_CHUNK_LINKS` links (``min(cores, n_links // MIN_CHUNK_LINKS) >= AUTO_MIN_LANES``),
    or unless the kept pool of every core is already there for ``scene`` (:func:`pool_is_kept`)
    and there are at least two receivers: the pool's start is what the threshold pays for, and
    with it running, lanes beat stage threads from 8 links on (hall, 2 cores: 92 links in 0.39 s
    against 0.47 s). On the 2-core development machine this is: processes from 500 links on; on
    6 cores or more, from 384 links on; from 2 receivers on once a trace has started the pool.
    """
    if in_job() or cpu_count() == 1:
        return True
    lanes = min(cpu_count(), n_links // MIN_CHUNK_LINKS)
    if n_links >= PROCESS_MIN_LINKS or lanes >= AUTO_MIN_LANES:
        return False
    return not (scene is not None and n_rx >= 2 and pool_is_kept(scene, cpu_count()))


def pool_is_kept(scene: Scene, workers: int, main: bool = False) -> bool:
    """Whether the kept pool (module description) is the one ``ScenePool(scene, workers, main=
    main)`` would use: the same scene (by the digest of its bytes), at least as many processes
    (a broken pool is dropped, so a kept one has not failed)."""
    with _LOCK:
        key = _KEPT.get("key")
    if key is None or key[1] < workers - 1 or key[2] != bool(main):
        return False
    return key[0] == _digest(pickle.dumps(scene, protocol=pickle.HIGHEST_PROTOCOL))


def _digest(blob: bytes) -> bytes:
    """What the kept pool is found by: a digest of the pickled scene."""
    return hashlib.blake2b(blob, digest_size=16).digest()


def receiver_chunks(
    n_tx: int, n_rx: int, chunk_links: int | None = None, lanes: int = 1
) -> list[range]:
    """Consecutive ranges of receiver indices with at most ``chunk_links`` links each.

    With ``chunk_links=None`` and several ``lanes``, the chunks are guided: each takes at most
    ``1 / (2 lanes)`` of the receivers still left (at least :data:`MIN_CHUNK_LINKS` links, or
    ``1 / lanes`` of all the receivers when that is less, so that a small trace still gives every
    lane a share: the hall's 23 receivers on 2 lanes are 11 + 12, not 7 + 16), so the last chunks
    are small and the lanes finish together. A trace of no more chunks than lanes has its larger
    chunks last: the first go to the worker processes, which also send their paths back, the
    last to the calling process (:meth:`ScenePool.map`). The chunks never change what is traced.
    """
    per = max(1, int(chunk_links or CHUNK_LINKS) // max(n_tx, 1))
    if chunk_links is not None or lanes <= 1:
        return [range(r0, min(n_rx, r0 + per)) for r0 in range(0, n_rx, per)]
    least = min(max(1, MIN_CHUNK_LINKS // max(n_tx, 1)), -(-n_rx // lanes))
    sizes, r0 = [], 0
    while r0 < n_rx:
        left = n_rx - r0
        sizes.append(min(per, left, max(least, -(-left // (2 * lanes)))))
        r0 += sizes[-1]
    if len(sizes) <= lanes:
        sizes.reverse()
    out, r0 = [], 0
    for size in sizes:
        out.append(range(r0, r0 + size))
        r0 += size
    return out


#: Where this raytrace is (the checkout the fork server and the workers must import).
_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _init_worker(blob: bytes, origin: str) -> None:
    here = _PACKAGE
    if here != origin:
        raise RuntimeError(f"worker imports raytrace from {here}, the caller from {origin}")
    _SCENE["scene"] = pickle.loads(blob)
    _SCENE["worker"] = True


def _call(fn: Callable[[Scene, Any], Any], item: Any) -> Any:
    return fn(_SCENE["scene"], item)


def process_context(preload: Sequence[str] = (), main: bool = False) -> Any:
    """The multiprocessing context for worker processes: the fork server, started now if it is
    not running, importing :data:`PRELOAD` and ``preload`` in the background (spawn where there
    is no fork server). ``preload`` counts only for the first call of the interpreter. Its
    processes do not import the caller's ``__main__`` unless ``main`` (module docstring), and
    end when this process is gone (:func:`_watch_caller`)."""
    with _LOCK:
        ctx = _context(preload)
    return _wrapped(ctx, main)


def _context(preload: Sequence[str]) -> Any:
    """:func:`process_context` (the caller holds the lock)."""
    import multiprocessing

    # the fork server is started as `python -c`, which puts the working directory first on its
    # sys.path (Python 3.11's fork server does not take this process's sys.path): run from a
    # source checkout with the package installed elsewhere, it would import the checkout's
    # raytrace. PYTHONSAFEPATH (3.11+) drops that entry; older Pythons spawn, which does
    # take this process's sys.path.
    if "forkserver" not in multiprocessing.get_all_start_methods() or sys.version_info < (3, 11):
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    if not _STATE.get("forkserver_started"):
        from multiprocessing import forkserver

        ctx.set_forkserver_preload(list(dict.fromkeys([*PRELOAD, *preload])))
        # the fork server imports raytrace from where this process does (not another checkout)
        root = os.path.dirname(_PACKAGE)
        old = os.environ.get("PYTHONPATH")
        # and loads BLAS with one thread (hallray.workerenv; docs/tracing.md, "A twelfth round")
        env = {"PYTHONPATH": root if not old else root + os.pathsep + old, "PYTHONSAFEPATH": "1",
               **ONE_THREAD}  # fmt: skip
        with environ_set(env):
            forkserver.ensure_running()
        _STATE["forkserver_started"] = True
    return ctx


_MAIN_LOCK = threading.Lock()


class _MainHidden:
    """While entered, ``__main__`` has neither ``__file__`` nor ``__spec__`` (so a process
    started meanwhile by ``multiprocessing`` is not told to import it)."""

    def __enter__(self) -> None:
        _MAIN_LOCK.acquire()
        main = sys.modules.get("__main__")
        self._saved = {}
        if main is not None:
            for k in ("__file__", "__spec__"):
                if k in main.__dict__:
                    self._saved[k] = main.__dict__[k]
            main.__dict__.pop("__file__", None)
            if "__spec__" in main.__dict__:
                main.__dict__["__spec__"] = None

    def __exit__(self, *exc: object) -> None:
        main = sys.modules.get("__main__")
        if main is not None:
            main.__dict__.update(self._saved)
        _MAIN_LOCK.release()


def _hiding_main(popen: Callable[[Any], Any]) -> Any:
    """A process class's ``_Popen`` that launches with ``__main__`` hidden (:class:`_MainHidden`)
    unless the process is to import it (``_hide_main`` False)."""

    def _Popen(process_obj: Any) -> Any:
        if not getattr(process_obj, "_hide_main", True):
            return popen(process_obj)
        with _MainHidden():
            return popen(process_obj)

    return staticmethod(_Popen)


#: Seconds between a worker's checks that the process that started it is still there.
CALLER_WATCH_S = 1.0


def _caller_token(pid: int) -> Any:
    """Something that identifies the running process ``pid`` (None: it is gone): its start time
    where /proc tells it (a zombie counts as gone, and a new process with the same pid differs),
    else whether a signal can be sent to it; on Windows always True (not watched there)."""
    if os.name == "nt":  # os.kill(pid, 0) would terminate it there: no watch on Windows
        return True
    if not os.path.isdir("/proc/self"):  # no /proc (macOS): whether it can be signalled
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except OSError:  # it exists but belongs to someone else, or the platform says no more
            pass
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
    except OSError:
        return None
    fields = stat[stat.rindex(b")") + 2 :].split()  # after "pid (comm) ": state, ppid, ...
    return None if fields[0] in (b"Z", b"X") else fields[19]  # field 22: start time


def _watch_caller(pid: int, period_s: float = CALLER_WATCH_S) -> None:
    """In a worker: end this process when the process that started the pool is gone.

    A worker waits on its pool's queue, whose pipe its siblings also hold open, so a caller that
    dies without closing the pool (SIGKILL, the out-of-memory killer) would leave its workers
    (a fork server's children, not the caller's) waiting for ever, each with its copy of the
    scene and its memory."""
    token = _caller_token(pid)
    if token is None:
        os._exit(0)

    def watch() -> None:
        import time

        while True:
            time.sleep(period_s)
            if _caller_token(pid) != token:
                remove_left_over(pid)  # the chunks it will not read
                os._exit(0)

    threading.Thread(target=watch, name="caller-watch", daemon=True).start()


class _Watched:
    """Mixin of a worker process class: records the starting process, and in the worker watches
    it (:func:`_watch_caller`)."""

    _hide_main = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[call-arg]
        self._caller = os.getpid()

    def run(self) -> None:
        _STATE["caller"] = self._caller
        _watch_caller(self._caller)
        super().run()  # type: ignore[misc]


class _Contexted:
    """Mixin of a multiprocessing context whose processes (``_process``, a :class:`_Watched`
    class) import the parent's ``__main__`` only if the context was made with ``main``."""

    _process: type

    def __init__(self, main: bool = False) -> None:
        super().__init__()
        self._main = bool(main)

    def Process(self, *args: Any, **kwargs: Any) -> Any:  # noqa: N802 (multiprocessing's name)
        process = self._process(*args, **kwargs)
        process._hide_main = not self._main
        return process


class _SpawnProcess(_Watched, multiprocessing.context.SpawnProcess):
    _Popen = _hiding_main(multiprocessing.context.SpawnProcess._Popen)


class _SpawnContext(_Contexted, multiprocessing.context.SpawnContext):
    _process = _SpawnProcess


if hasattr(multiprocessing.context, "ForkServerContext"):  # not on Windows

    class _ForkServerProcess(_Watched, multiprocessing.context.ForkServerProcess):
        _Popen = _hiding_main(multiprocessing.context.ForkServerProcess._Popen)

    class _ForkServerContext(_Contexted, multiprocessing.context.ForkServerContext):
        _process = _ForkServerProcess


def _wrapped(ctx: Any, main: bool) -> Any:
    """The multiprocessing context like ``ctx`` (fork server or spawn) whose processes watch this
    one (:func:`_watch_caller`) and start without importing the parent's ``__main__`` unless
    ``main``."""
    if ctx.get_start_method() == "forkserver":
        return _ForkServerContext(main)
    return _SpawnContext(main)


def from_main(fn: object) -> bool:
    """True if ``fn`` (or the function a ``functools.partial`` wraps) is defined in the
    caller's ``__main__`` (a worker must import it)."""
    return getattr(getattr(fn, "func", fn), "__module__", None) == "__main__"


def close_pools() -> None:
    """Stop the kept worker processes (called at the end of the interpreter)."""
    with _LOCK:
        ex = _KEPT.pop("executor", None)
        _KEPT.clear()
    if ex is not None:
        ex.shutdown(wait=True, cancel_futures=True)
    # the chunks' files in shared memory that this process did not read (a trace stopped)
    remove_left_over(os.getpid())


atexit.register(close_pools)


def caller_pid() -> int | None:
    """In a worker: the pid of the process that started its pool (None elsewhere)."""
    return _STATE.get("caller")


def _executor(
    blob: bytes, processes: int, preload: Sequence[str], main: bool = False
) -> ProcessPoolExecutor:
    """The kept pool for this scene and number of processes, started if it is not there
    (``main``: its workers import the caller's ``__main__``)."""
    key = (_digest(blob), processes, bool(main))
    with _LOCK:
        kept = _KEPT.get("key")
        # a kept pool with more processes serves fewer lanes as well (ScenePool hands out at most
        # lanes - 1 items at a time): a small trace after a big one keeps the big one's workers
        if kept is not None and kept[0] == key[0] and kept[2] == key[2] and kept[1] >= processes:
            return _KEPT["executor"]
        old = _KEPT.pop("executor", None)
        if old is not None:
            old.shutdown(wait=False, cancel_futures=True)
        ex = ProcessPoolExecutor(
            max_workers=processes,
            mp_context=_wrapped(_context(preload), main),
            initializer=_init_worker,
            initargs=(blob, _PACKAGE),
        )
        _KEPT.update(key=key, executor=ex)
        return ex


def _drop(ex: ProcessPoolExecutor) -> None:
    """Forget a broken pool (the next call starts a new one)."""
    with _LOCK:
        if _KEPT.get("executor") is ex:
            _KEPT.clear()
    # the other workers may still be alive, blocked on a queue left dirty: stop them now
    for proc in list((getattr(ex, "_processes", None) or {}).values()):
        proc.terminate()
    ex.shutdown(wait=False, cancel_futures=True)


class _Feeder:
    """Hands the items of one :meth:`ScenePool.map` to the workers in order, one per worker at a
    time, so that the rest stay in one queue that this process takes from too."""

    def __init__(
        self, pool: ProcessPoolExecutor, fn: Callable[[Scene, Any], Any], items: list, lanes: int
    ) -> None:
        from collections import deque

        self._pool, self._fn, self._items = pool, fn, items
        self._left = deque(range(len(items)))
        self._futures: dict[int, Future] = {}
        self._cond = threading.Condition()
        self._slots = threading.Semaphore(max(lanes - 1, 1))
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="scenepool-feeder", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self._slots.acquire()
            with self._cond:
                if self._stopped or not self._left:
                    return
                i = self._left.popleft()
            try:
                fut = self._pool.submit(_call, self._fn, self._items[i])
            except Exception as exc:  # noqa: BLE001  broken, or shut down under us: its result
                fut = Future()
                fut.set_exception(exc if isinstance(exc, BrokenProcessPool)
                                  else BrokenProcessPool(f"{type(exc).__name__}: {exc}"))  # fmt: skip
            fut.add_done_callback(lambda _: self._slots.release())
            with self._cond:
                self._futures[i] = fut
                self._cond.notify_all()

    def future(self, i: int, wait: bool = False) -> Future | None:
        """Item ``i``'s future once it was handed to a worker (``wait``: until it is)."""
        with self._cond:
            if wait:
                self._cond.wait_for(lambda: i in self._futures)
            return self._futures.get(i)

    def take_next(self, last: bool = False) -> int | None:
        """The next item no worker has been given, or the last one (None: there is none left)."""
        with self._cond:
            if not self._left:
                return None
            return self._left.pop() if last else self._left.popleft()

    def stop(self) -> None:
        """Hand out nothing more (items already with the workers run to their end)."""
        with self._cond:
            self._stopped = True
            self._left.clear()
        self._slots.release()
        self._thread.join()


class ScenePool:
    """``fn(scene, item)`` for many items, in order, on ``workers`` lanes: this process and
    ``workers - 1`` worker processes that each hold a copy of ``scene``.

    Parameters
    ----------
    scene : Scene
    workers : int, lanes (1: this process alone, no worker process)
    preload : sequence of str, optional, more modules for the fork server to import (only
        before it has started: the first pool of the interpreter)
    main : bool, the workers import the caller's ``__main__`` (needed when ``fn`` or what the
        items carry is defined there; the script then needs ``if __name__ == "__main__":``).
        Default False: a script that traces at its top level is not run again in the workers.

    ``fn`` must be a module-level function (it is sent to the workers by reference). The worker
    processes are kept after :meth:`close` for the next pool with the same scene and as many
    workers or fewer (see the module's description); :func:`close_pools` stops them.
    """

    def __init__(
        self, scene: Scene, workers: int, preload: Sequence[str] = (), main: bool = False
    ) -> None:
        self.scene, self.workers, self.main = scene, int(workers), bool(main)
        self._pool: ProcessPoolExecutor | None = None
        if self.workers > 1:
            blob = pickle.dumps(scene, protocol=pickle.HIGHEST_PROTOCOL)
            self._pool = _executor(blob, self.workers - 1, preload, self.main)

    def map(self, fn: Callable[[Scene, Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """The results of ``fn(scene, item)``, in the order of ``items``.

        All lanes take the items in order from one queue: a feeder thread hands the next one to
        a worker as soon as it is free, and this process takes the next one whenever the result
        it must yield next is not there yet (it traces while the workers start, and the small
        guided chunks at the end go to whichever lane is free). With no more items than lanes,
        this process takes the last item only. Raises :class:`WorkerCrashError` if
        a worker process dies; an exception raised by ``fn`` is raised as it is.
        """
        items = list(items)
        if self._pool is not None and from_main(fn) and not self.main:
            raise TypeError(
                f"{fn.__qualname__} is defined in __main__: the workers need "  # type: ignore[attr-defined]
                "ScenePool(..., main=True) to import it"
            )
        if self._pool is None:
            for item in items:
                yield self._here(fn, item)
            return
        feed = _Feeder(self._pool, fn, items, self.workers)
        done: dict[int, Any] = {}
        # no more items than lanes (a small trace): this process takes the last one and leaves
        # the others to the workers, whatever the feeder has handed out yet (receiver_chunks
        # puts the larger chunks last: a worker also sends its paths back)
        last = len(items) <= self.workers
        try:
            for i in range(len(items)):
                while i not in done:
                    fut = feed.future(i)
                    if fut is not None and fut.done():
                        break
                    # the next result is not there: work meanwhile
                    j = None if last and done else feed.take_next(last)
                    if j is None:
                        fut = feed.future(i, wait=True)
                        break
                    done[j] = self._here(fn, items[j])
                if i in done:
                    yield done.pop(i)
                    continue
                try:
                    result = fut.result()
                except BrokenProcessPool as exc:
                    _drop(self._pool)
                    raise WorkerCrashError(
                        f"a worker process died while tracing (killed, out of memory or a crash "
                        f"in native code): {exc}"
                    ) from None
                yield result
        finally:
            feed.stop()

    def _here(self, fn: Callable[[Scene, Any], Any], item: Any) -> Any:
        """``fn(scene, item)`` in this process, marked as a job (no nested pool)."""
        _IN_JOB.depth = getattr(_IN_JOB, "depth", 0) + 1
        try:
            return fn(self.scene, item)
        finally:
            _IN_JOB.depth -= 1

    def close(self) -> None:
        """Release the pool (its worker processes are kept for the next one, see above)."""
        self._pool = None

    def __enter__(self) -> ScenePool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
