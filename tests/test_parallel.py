"""Tracing in chunks of receivers, in this process or on worker processes: identical paths."""

from __future__ import annotations

import os
import pickle

import numpy as np
import pytest
from test_diffraction_paths import _cluttered_scene

from raytrace import TraceConfig, TraceInputError, trace
from raytrace.solver import parallel, tracer
from raytrace.solver.parallel import (
    MIN_CHUNK_LINKS,
    ScenePool,
    WorkerCrashError,
    close_pools,
    cpu_count,
    receiver_chunks,
    resolve_workers,
)
from raytrace.solver.tracer import trace_chunks

F_C = 3.775e9
#: The directory that holds this raytrace package (what a subprocess puts on PYTHONPATH).
CHECKOUT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(parallel.__file__))))


def _same(a, b) -> None:
    assert a.n_paths == b.n_paths
    for k in a.PER_PATH:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    np.testing.assert_array_equal(a.rx, b.rx)


@pytest.fixture(scope="module")
def scene_links():
    sc, tx, rx = _cluttered_scene(3)
    rng = np.random.default_rng(8)
    more = rng.uniform([-8, -8, 0.5], [8, 8, 4], (40, 3))
    rx = np.concatenate([rx, more[sc.inside_solid(more) < 0]])
    cfg = TraceConfig(max_reflections=2, max_penetrations=2, max_diffractions=1, max_interactions=2)
    return sc, tx, rx, cfg


def test_chunks_and_workers_give_the_same_paths_in_the_same_order(scene_links):
    sc, tx, rx, cfg = scene_links
    whole = trace(sc, tx, rx, F_C, cfg, threads=1)
    assert {"D", "RD", "DR", "RR"} <= set(whole.kind_label)
    for chunk in (1, 7, 64):  # one receiver, a few, all of them at once
        _same(whole, trace(sc, tx, rx, F_C, cfg, workers=1, chunk_links=chunk * len(tx)))
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2, chunk_links=5 * len(tx)))
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2))  # guided chunks, this process stealing


def test_reduced_chunks_come_in_order_with_global_indices(scene_links):
    sc, tx, rx, cfg = scene_links
    whole = trace(sc, tx, rx, F_C, cfg)
    counts = np.zeros(len(tx) * len(rx), dtype=int)
    seen = []
    for chunk, per_link in trace_chunks(sc, tx, rx, F_C, cfg, reduce=_paths_per_link,
                                        workers=1, chunk_links=3 * len(tx)):  # fmt: skip
        seen.extend(chunk)
        counts += per_link
    assert seen == list(range(len(rx)))
    np.testing.assert_array_equal(counts, np.bincount(whole.link, minlength=counts.size))


def _paths_per_link(paths):
    return np.bincount(paths.link, minlength=paths.n_links)


def test_worker_count_is_bounded_and_checked():
    assert resolve_workers(1000, 3) == min(cpu_count(), 3)
    assert resolve_workers(None, 1) == 1
    assert resolve_workers(2, 10) == min(2, cpu_count())
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(TraceInputError, match="workers must be a positive integer"):
            resolve_workers(bad, 4)
    chunks = receiver_chunks(4, 10, 12)  # 3 receivers (12 links) per chunk
    assert [list(c) for c in chunks] == [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9]]


def test_guided_chunks_cover_the_receivers_in_order_and_shrink():
    for n_tx, n_rx, lanes in ((4, 429, 2), (3, 50, 2), (1, 1000, 16), (4, 3, 8)):
        chunks = receiver_chunks(n_tx, n_rx, None, lanes)
        assert [r for c in chunks for r in c] == list(range(n_rx))
        sizes = [len(c) for c in chunks]
        least = min(max(1, MIN_CHUNK_LINKS // n_tx), -(-n_rx // lanes))
        if len(sizes) <= lanes:  # a small trace: larger chunks last (the calling process's)
            sizes = sizes[::-1]
        assert all(a >= b for a, b in zip(sizes, sizes[1:]))  # they only shrink
        # the first is a full chunk, or 1/(2 lanes) of the receivers when that is less
        assert sizes[0] == min(n_rx, 256 // n_tx, max(least, -(-n_rx // (2 * lanes))))
        assert max(sizes) * n_tx <= 256
        assert all(k >= least for k in sizes[:-1])  # none below the floor but the remainder
        assert sizes[-1] <= least or len(sizes) == 1  # the last ones are small
    # a trace smaller than one chunk still gives every lane a share (the hall on 2 lanes), the
    # larger one to the calling process, which takes the last chunk
    assert [len(c) for c in receiver_chunks(4, 23, None, 2)] == [11, 12]
    assert [len(c) for c in receiver_chunks(4, 25, None, 4)] == [4, 7, 7, 7]
    assert [len(c) for c in receiver_chunks(4, 3, None, 8)] == [1, 1, 1]
    # a larger trace keeps its guided order (the small chunks last)
    sizes = [len(c) for c in receiver_chunks(4, 429, None, 2)]
    assert len(sizes) > 2 and sizes == sorted(sizes, reverse=True)
    # one lane, or a given chunk size: fixed chunks as before
    assert receiver_chunks(4, 10, None, 1) == receiver_chunks(4, 10)
    assert receiver_chunks(4, 10, 12, 8) == receiver_chunks(4, 10, 12)


def _pid(scene, item):
    import time

    time.sleep(0.05)
    return item, os.getpid(), parallel.in_job()


def test_a_small_map_leaves_the_last_item_to_the_calling_process(scene_links, monkeypatch):
    """No more items than lanes: the calling process takes the last item (receiver_chunks puts
    the larger chunk there; a worker also sends its paths back), a worker the first, whether
    the feeder thread has handed out the first item when the caller looks or not (it is made
    late here, then left alone)."""
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    import time

    sc = scene_links[0]
    run = parallel._Feeder._run

    def late(self):
        time.sleep(0.3)
        run(self)

    for slow in (True, False):
        with monkeypatch.context() as mp:
            if slow:
                mp.setattr(parallel._Feeder, "_run", late)
            with ScenePool(sc, 2) as pool:
                out = list(pool.map(_pid, range(2)))
        assert [i for i, _, _ in out] == [0, 1]
        assert out[1][1] == os.getpid() and out[0][1] != os.getpid()


def test_pool_is_kept_for_the_same_scene_and_renewed_for_another(scene_links):
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    sc, tx, rx, cfg = scene_links
    close_pools()
    with ScenePool(sc, 2) as pool:
        first = list(pool.map(_pid, range(30)))
    ex = parallel._KEPT["executor"]
    with ScenePool(sc, 2) as pool:  # the same scene again: the same worker processes
        second = list(pool.map(_pid, range(30)))
    assert parallel._KEPT["executor"] is ex
    # in order, every item run as a job; both this process and the worker worked
    for out in (first, second):
        assert [i for i, _, _ in out] == list(range(30))
        assert all(job for _, _, job in out)
    workers = {p for _, p, _ in first + second} - {os.getpid()}
    assert len(workers) == 1
    assert os.getpid() in {p for _, p, _ in second}
    other, _, _ = _cluttered_scene(4)
    with ScenePool(other, 2) as pool:  # another scene: a new pool
        third = list(pool.map(_pid, range(30)))
    assert parallel._KEPT["executor"] is not ex
    assert not workers & {p for _, p, _ in third}
    close_pools()
    assert not parallel._KEPT
    # a closed pool is started again on demand, and traces as before
    whole = trace(sc, tx, rx, F_C, cfg, threads=1)
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2, chunk_links=4 * len(tx)))
    close_pools()


def test_a_small_trace_goes_over_every_lane(scene_links):
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    sc, tx, rx, cfg = scene_links
    assert len(tx) * len(rx) < 256  # less than one fixed chunk
    chunks = [c for c, _ in trace_chunks(sc, tx, rx, F_C, cfg, workers=2)]
    assert len(chunks) >= 2 and [r for c in chunks for r in c] == list(range(len(rx)))


def test_a_traced_scene_pickles_to_the_same_bytes_and_keeps_its_pool(scene_links):
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    sc, tx, rx, cfg = scene_links
    fresh = pickle.loads(pickle.dumps(sc))
    before = pickle.dumps(fresh)
    close_pools()
    trace(fresh, tx, rx, F_C, cfg, workers=2)  # fills the scene's derived caches
    assert fresh.facets.cache and fresh.wedges.cache
    assert pickle.dumps(fresh) == before  # caches stay behind: the same digest
    ex = parallel._KEPT["executor"]
    trace(fresh, tx, rx, F_C, cfg, workers=2)
    assert parallel._KEPT["executor"] is ex  # the same worker processes
    close_pools()


def _die_in_worker(scene, item):
    import time

    if parallel._SCENE.get("worker"):
        os._exit(3)
    time.sleep(1.0)  # this process is slow: the worker takes the first item
    return item


def test_a_dead_worker_is_one_clear_error_and_the_next_pool_works(scene_links):
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    sc, tx, rx, cfg = scene_links
    close_pools()
    with pytest.raises(WorkerCrashError, match="worker process died"):
        with ScenePool(sc, 2) as pool:
            list(pool.map(_die_in_worker, range(4)))
    assert not parallel._KEPT  # the broken pool was dropped
    whole = trace(sc, tx, rx, F_C, cfg, threads=1)
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2, chunk_links=4 * len(tx)))
    close_pools()


def _inner_workers(scene, item):
    return resolve_workers(None, 10), parallel.auto_in_process(10**6)


def test_the_auto_rule_by_links_and_cores(monkeypatch):
    monkeypatch.setattr(parallel, "cpu_count", lambda: 2)
    assert parallel.auto_in_process(92) and parallel.auto_in_process(499)
    assert not parallel.auto_in_process(500)
    monkeypatch.setattr(parallel, "cpu_count", lambda: 16)
    assert parallel.auto_in_process(383) and not parallel.auto_in_process(384)
    monkeypatch.setattr(parallel, "cpu_count", lambda: 1)
    assert parallel.auto_in_process(10**6)


def test_cores_are_those_the_process_may_use(monkeypatch):
    """A process restricted to one core (taskset, a container's cpuset) counts one, not the
    machine's cores; without an affinity call, the machine's."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 64)
    assert cpu_count() == 1

    def unsupported(pid):
        raise OSError("no affinity here")

    monkeypatch.setattr(os, "sched_getaffinity", unsupported, raising=False)
    assert cpu_count() == 64


@pytest.fixture
def stage_pools(monkeypatch):
    """The thread counts of the stage thread pools the tracer starts, in order."""
    started = []

    class Counting(tracer.ThreadPoolExecutor):
        def __init__(self, max_workers=None, **kw):
            started.append(max_workers)
            super().__init__(max_workers=max_workers, **kw)

    monkeypatch.setattr(tracer, "ThreadPoolExecutor", Counting)
    return started


def test_stage_threads_follow_the_usable_cores(scene_links, monkeypatch, stage_pools):
    """A trace's stages run on one thread where the process may use one core (more threads would
    only contend for the GIL), and on threads where it may use several: the same paths."""
    sc, tx, rx, cfg = scene_links
    started = stage_pools
    monkeypatch.setattr(tracer, "cpu_count", lambda: 1)
    one = trace(sc, tx, rx[:3], F_C, cfg, workers=1)
    assert started == []
    monkeypatch.setattr(tracer, "cpu_count", lambda: 2)
    two = trace(sc, tx, rx[:3], F_C, cfg, workers=1)
    assert started == [2]
    _same(one, two)


def test_one_lane_in_chunks_keeps_the_threads_asked_for(scene_links, monkeypatch, stage_pools):
    """``threads`` holds for a trace in chunks on one lane too (not only below the chunking
    threshold): ``threads=1`` starts no stage thread, the default one per usable core, in every
    chunk; the same paths."""
    sc, tx, rx, cfg = scene_links
    started = stage_pools
    monkeypatch.setattr(tracer, "cpu_count", lambda: 2)
    one = trace(sc, tx, rx[:6], F_C, cfg, workers=1, threads=1, chunk_links=2 * len(tx))
    assert started == []
    every = trace(sc, tx, rx[:6], F_C, cfg, workers=1, chunk_links=2 * len(tx))
    assert started == [2, 2, 2]
    _same(one, every)


def _blas_helpers(scene, item):
    """In a lane: its pid, its BLAS thread setting, and the threads a shared product started."""

    def threads() -> int:
        return len(os.listdir("/proc/self/task"))

    before = threads()
    a = np.ones((600, 600))
    _ = a @ a  # large enough for BLAS to share it among helper threads, where it has any
    return os.getpid(), os.environ.get("OPENBLAS_NUM_THREADS"), threads() - before


def test_worker_processes_load_blas_with_one_thread(scene_links):
    """numpy's BLAS helper threads spin for about 0.1 s after each product they share, on the
    cores the other lanes trace on: the workers (one lane each) load BLAS with one thread, so
    that a product starts none; this process keeps its own setting."""
    if cpu_count() < 2 or not os.path.isdir("/proc/self/task"):
        pytest.skip("needs two cores and /proc")
    mine = os.environ.get("OPENBLAS_NUM_THREADS")
    with ScenePool(scene_links[0], 2) as pool:
        out = list(pool.map(_blas_helpers, range(2)))
    worker = [r for r in out if r[0] != os.getpid()]
    assert worker, "no item went to the worker"
    for _, setting, started in worker:
        assert setting == "1"
        assert started == 0
    assert os.environ.get("OPENBLAS_NUM_THREADS") == mine


def test_each_lane_reports_the_time_it_spent_on_its_chunks(scene_links):
    """``busy_us[caller]`` and ``busy_us[workers]``: each lane's time on its chunks, within the
    trace's wall time (the rest is idle or the join); a trace in this process alone has no
    worker lane."""
    import time

    sc, tx, rx, cfg = scene_links
    st: dict = {}
    trace(sc, tx, rx, F_C, cfg, workers=1, chunk_links=3 * len(tx), stats=st)
    assert st["busy_us[caller]"] > 0 and "busy_us[workers]" not in st
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    st = {}
    t0 = time.perf_counter()
    trace(sc, tx, rx, F_C, cfg, workers=2, chunk_links=3 * len(tx), stats=st)
    wall_us = (time.perf_counter() - t0) * 1e6
    assert 0 < st["busy_us[caller]"] <= wall_us and 0 < st["busy_us[workers]"] <= wall_us
    # a lane's stages run inside its chunks
    stages = sum(v for k, v in st.items() if k.startswith("time_us["))
    assert stages <= st["busy_us[caller]"] + st["busy_us[workers]"]


def test_a_running_pool_takes_small_traces(scene_links, monkeypatch):
    if cpu_count() < 2:
        pytest.skip("needs two cores")
    sc, tx, rx, cfg = scene_links
    close_pools()
    assert parallel.auto_in_process(len(tx) * 3, sc, 3)  # no pool: stage threads
    whole = trace(sc, tx, rx, F_C, cfg, threads=1)
    ScenePool(sc, cpu_count()).close()  # starts the kept pool of every core
    assert parallel.pool_is_kept(sc, cpu_count())
    assert not parallel.pool_is_kept(sc, cpu_count(), main=True)
    assert not parallel.auto_in_process(len(tx) * 3, sc, 3)
    assert parallel.auto_in_process(len(tx), sc, 1)  # one receiver: one chunk anyway
    ex = parallel._KEPT["executor"]
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2))  # fewer lanes: the same pool serves
    assert parallel._KEPT["executor"] is ex
    other, _, _ = _cluttered_scene(4)
    assert not parallel.pool_is_kept(other, cpu_count())
    assert parallel.auto_in_process(len(tx) * 3, other, 3)
    lanes = []
    monkeypatch.setattr(tracer, "_chunked", _recording(tracer._chunked, lanes))
    _same(whole, trace(sc, tx, rx, F_C, cfg))
    assert lanes == [None]  # went over the lanes, workers=None
    close_pools()


def _recording(fn, calls):
    def wrapped(*args):
        calls.append(args[6])  # ``workers``
        return fn(*args)

    return wrapped


def test_work_inside_a_job_stays_in_its_process(scene_links):
    sc = scene_links[0]
    assert list(ScenePool(sc, 1).map(_inner_workers, range(2))) == [(1, True)] * 2
    assert resolve_workers(None, 10) == min(cpu_count(), 10)


def test_the_fork_server_preload_does_not_import_embree():
    # Embree imported before the fork makes every worker trace about 2x slower
    import subprocess
    import sys

    mods = [*parallel.PRELOAD, "raytrace.studies.accuracy_map", "raytrace.emulation.dataset",
            "raytrace.studies.sweep"]  # fmt: skip
    code = f"import sys\nfor m in {mods!r}: __import__(m)\nprint('embreex' in sys.modules)"
    root = os.path.dirname(os.path.dirname(os.path.abspath(parallel.__file__)))
    env = {**os.environ, "PYTHONPATH": os.path.dirname(root)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True, timeout=120).stdout  # fmt: skip
    assert out.split()[-1] == "False"


def test_workers_import_the_callers_raytrace_not_the_working_directorys(tmp_path):
    """Run from a directory holding another ``raytrace`` (a source checkout beside an installed
    package, as `pip install . && reproduce-paper` in the checkout does): the workers import the
    caller's package, not the working directory's."""
    import subprocess
    import sys

    root = CHECKOUT
    cwd = tmp_path / "checkout"
    cwd.mkdir()
    # the same code under another path: it imports, but is not the caller's package
    (cwd / "raytrace").symlink_to(os.path.join(root, "raytrace"), target_is_directory=True)
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    script = bin_ / "run.py"
    script.write_text(
        "from raytrace import TraceConfig, trace\n"
        "from raytrace.scene.io import load_scene\n"
        "from raytrace.scene.metadata import SceneMetadata\n"
        "if __name__ == '__main__':\n"
        "    sc = load_scene('hall')\n"
        "    m = SceneMetadata.from_scene(sc, require=True)\n"
        "    cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=0)\n"
        "    a = trace(sc, m.bs_xyz, m.point_xyz, 3.775e9, cfg, threads=1)\n"
        "    b = trace(sc, m.bs_xyz, m.point_xyz, 3.775e9, cfg, workers=2, chunk_links=16)\n"
        "    assert a.n_paths == b.n_paths > 0\n"
        "    print('ok', b.n_paths)\n"
    )
    env = {**os.environ, "PYTHONPATH": root}
    env.pop("PYTHONSAFEPATH", None)
    out = subprocess.run([sys.executable, str(script)], cwd=cwd, capture_output=True, text=True,
                         env=env, timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")


def test_a_script_that_traces_at_its_top_level_runs_once(tmp_path):
    """A script without ``if __name__ == "__main__":`` (a notebook-style script): the workers
    do not run it again (multiprocessing would import the parent's __main__ in every worker,
    which would trace and start pools there), nor do those of ``process_context()`` (the
    dataset and sweep pools). Its top-level print happens once."""
    import subprocess
    import sys

    root = CHECKOUT
    script = tmp_path / "plain.py"
    script.write_text(
        "from raytrace import TraceConfig, trace\n"
        "from raytrace.scene.io import load_scene\n"
        "from raytrace.scene.metadata import SceneMetadata\n"
        "print('top level')\n"
        "sc = load_scene('hall')\n"
        "m = SceneMetadata.from_scene(sc, require=True)\n"
        "cfg = TraceConfig(max_reflections=1, max_penetrations=0, max_diffractions=0)\n"
        "a = trace(sc, m.bs_xyz, m.point_xyz, 3.775e9, cfg, threads=1)\n"
        "b = trace(sc, m.bs_xyz, m.point_xyz, 3.775e9, cfg, workers=2, chunk_links=16)\n"
        "assert a.n_paths == b.n_paths > 0\n"
        "import os\n"
        "from concurrent.futures import ProcessPoolExecutor\n"
        "from raytrace.solver.parallel import process_context\n"
        "with ProcessPoolExecutor(1, mp_context=process_context()) as ex:\n"
        "    assert ex.submit(os.getpid).result() != os.getpid()\n"
        "print('ok', b.n_paths)\n"
    )
    env = {**os.environ, "PYTHONPATH": root}
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                         text=True, env=env, timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.count("top level") == 1
    assert "ok" in out.stdout


def test_a_job_from_main_needs_a_pool_that_imports_main(scene_links):
    """A job function defined in __main__ cannot reach workers that do not import it: a
    one-line TypeError names the fix instead of a worker crash."""
    sc = scene_links[0]

    def job(scene, item):
        return item

    job.__module__ = "__main__"
    with pytest.raises(TypeError, match="main=True"), parallel.ScenePool(sc, 2) as pool:
        list(pool.map(job, range(3)))


def test_a_threaded_join_equals_the_serial_one(scene_links, monkeypatch):
    """Joining chunks on several threads (large traces) gives the same arrays as one thread, and
    trace() with the threaded join forced gives the same paths; its outputs are mapped in small
    pages (core.memory) from the first byte here."""
    import raytrace.solver.tracer as tracer_mod
    from raytrace.core import memory
    from raytrace.solver.paths import Paths

    sc, tx, rx, cfg = scene_links
    parts = [p for _, p in trace_chunks(sc, tx, rx, F_C, cfg, workers=1,
                                        chunk_links=3 * len(tx))]  # fmt: skip
    pieces = [p.select(slice(0, p.n_paths // 2)) for p in parts]
    pieces += [p.select(slice(p.n_paths // 2, None)) for p in parts]
    one = Paths.concatenate(pieces)
    monkeypatch.setattr(memory, "SMALL_PAGES_BYTES", 1)
    for threads in (2, 3, 8):
        many = Paths.concatenate(pieces, threads=threads)
        for k in Paths.PER_PATH:
            np.testing.assert_array_equal(getattr(many, k), getattr(one, k))
    monkeypatch.setattr(tracer_mod, "JOIN_THREADS_PATHS", 1)
    _same(trace(sc, tx, rx, F_C, cfg, threads=1),
          trace(sc, tx, rx, F_C, cfg, workers=1, chunk_links=5 * len(tx)))  # fmt: skip


def test_workers_end_when_their_caller_is_killed(tmp_path):
    """A caller killed without closing its pools (SIGKILL, the out-of-memory killer): its worker
    processes (children of the fork server, waiting on the pool's queue) end within seconds, both
    the trace pool's and those of ``process_context()`` (the dataset and sweep pools), and remove
    the files in shared memory written for it."""
    import signal
    import subprocess
    import sys
    import time

    if cpu_count() < 2 or os.name == "nt":
        pytest.skip("needs two cores and SIGKILL")
    root = CHECKOUT
    script = tmp_path / "stay.py"
    script.write_text(
        "import os, sys, time\n"
        "from concurrent.futures import ProcessPoolExecutor\n"
        "from raytrace.scene.io import load_scene\n"
        "from raytrace.solver.parallel import ScenePool, process_context\n"
        "if __name__ == '__main__':\n"
        "    pool = ScenePool(load_scene('hall'), 2)\n"
        "    other = ProcessPoolExecutor(1, mp_context=process_context())\n"
        "    pids = [pool._pool.submit(os.getpid).result(), other.submit(os.getpid).result()]\n"
        "    print(*pids, flush=True)\n"
        "    time.sleep(120)\n"
    )
    env = {**os.environ, "PYTHONPATH": root}
    proc = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path, stdout=subprocess.PIPE,
                            text=True, env=env)  # fmt: skip
    from raytrace.solver import shared

    # a chunk's file in shared memory that the caller will never read
    unread = os.path.join(shared.SHM_DIR, f"{shared.PREFIX}{proc.pid}-0-0")
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert len(workers) == 2 and proc.pid not in workers
        if os.path.isdir(shared.SHM_DIR):
            with open(unread, "wb") as fh:
                fh.write(b"paths")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    left = set(workers)
    deadline = time.monotonic() + 10 * parallel.CALLER_WATCH_S + 5
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = {p for p in left if parallel._caller_token(p) is not None}
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"worker processes {sorted(left)} outlived their killed caller"
    assert not os.path.exists(unread), "the workers left their killed caller's file behind"


def test_a_process_is_told_apart_from_a_gone_one():
    assert parallel._caller_token(os.getpid()) == parallel._caller_token(os.getpid()) is not None
    assert parallel._caller_token(2**30) is None  # above any pid_max: no such process


def test_without_proc_a_process_is_found_by_signal(monkeypatch):
    """Where there is no /proc (macOS) the caller is looked up by signal, not taken for gone
    (which would end every worker at once)."""
    if os.name == "nt":
        pytest.skip("not watched on Windows")
    real = os.path.isdir
    monkeypatch.setattr(os.path, "isdir", lambda p: False if p == "/proc/self" else real(p))
    assert parallel._caller_token(os.getpid()) is True
    assert parallel._caller_token(2**30) is None
