"""Arrays handed from a worker to its caller through a file in shared memory."""

from __future__ import annotations

import os

import numpy as np
import pytest
from test_parallel import F_C, _same, scene_links  # noqa: F401 (a fixture)

from raytrace import trace
from raytrace.solver import shared, tracer

needs_shm = pytest.mark.skipif(not os.path.isdir(shared.SHM_DIR), reason="no /dev/shm")


@needs_shm
def test_arrays_come_back_equal_writable_and_the_file_is_removed():
    rng = np.random.default_rng(2)
    arrays = {
        "kinds": rng.integers(0, 4, (7, 4)).astype(np.int8),
        "points": rng.normal(size=(7, 4, 3)),
        "gain": rng.normal(size=7) + 1j * rng.normal(size=7),
        "count": rng.integers(0, 9, 7).astype(np.int16),
        "empty": np.zeros((0, 4, 3)),
        "strided": rng.normal(size=(7, 6))[:, ::2],  # not contiguous: written in C order
    }
    handle = shared.share(arrays, os.getpid())
    assert handle is not None and os.path.exists(handle.path)
    assert all(offset % shared.ALIGN == 0 for *_, offset in handle.layout)
    got = handle.load()
    assert not os.path.exists(handle.path)
    assert list(got) == list(arrays)
    for k, a in arrays.items():
        assert got[k].dtype == a.dtype and got[k].shape == a.shape, k
        np.testing.assert_array_equal(got[k], a, err_msg=k)
    got["points"][0, 0, 0] = 42.0  # a private mapping: writable
    assert got["points"][0, 0, 0] == 42.0


def test_without_a_shared_memory_directory_the_arrays_go_as_they_are(tmp_path, monkeypatch):
    monkeypatch.setattr(shared, "SHM_DIR", str(tmp_path / "none"))
    assert shared.share({"a": np.arange(3)}, os.getpid()) is None


def test_left_over_files_of_one_caller_are_removed(tmp_path, monkeypatch):
    monkeypatch.setattr(shared, "SHM_DIR", str(tmp_path))
    mine = shared.share({"a": np.arange(3)}, 123)
    other = shared.share({"a": np.arange(3)}, 1234)
    shared.remove_left_over(123)
    assert not os.path.exists(mine.path) and os.path.exists(other.path)


@needs_shm
def test_a_workers_paths_come_through_shared_memory(scene_links, monkeypatch):  # noqa: F811
    """With two lanes the worker's chunks come as files (the calling process loads them), the
    paths are those of one thread, and no file is left behind."""
    sc, tx, rx, cfg = scene_links
    loads = []
    real = tracer._SharedPaths.load
    monkeypatch.setattr(tracer._SharedPaths, "load", lambda self: loads.append(1) or real(self))
    whole = trace(sc, tx, rx, F_C, cfg, threads=1)
    _same(whole, trace(sc, tx, rx, F_C, cfg, workers=2, chunk_links=3 * len(tx)))
    assert loads
    assert not [f for f in os.listdir(shared.SHM_DIR)
                if f.startswith(f"{shared.PREFIX}{os.getpid()}-")]  # fmt: skip


def test_a_full_or_small_shared_memory_falls_back_to_the_pipe(tmp_path, monkeypatch):
    """A file that cannot be written whole (the directory filled up meanwhile) is removed and
    None returned; a directory with too little room free is not written to at all."""
    monkeypatch.setattr(shared, "SHM_DIR", str(tmp_path))
    real_open = open

    class Full:
        def __init__(self, path, mode):
            self.fh = real_open(path, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, data):
            if len(data) > 8:
                raise OSError(28, "No space left on device")
            return self.fh.write(data)

    monkeypatch.setattr(shared, "open", Full, raising=False)
    assert shared.share({"a": np.arange(100.0)}, 7) is None
    assert not os.listdir(tmp_path)
    monkeypatch.undo()
    monkeypatch.setattr(shared, "SHM_DIR", str(tmp_path))
    free = os.statvfs(tmp_path)
    monkeypatch.setattr(shared, "FREE_FACTOR", free.f_bavail * free.f_frsize / 800 + 1)
    assert shared.share({"a": np.arange(100.0)}, 7) is None
    assert not os.listdir(tmp_path)


@needs_shm
def test_mappings_stay_within_a_budget_of_file_descriptors(monkeypatch):
    """Each mapping holds a file descriptor (Python's mmap keeps a duplicate), so past
    max_mapped() mappings alive a chunk is read into memory instead; a mapping's count goes when
    its last array does."""
    import gc

    monkeypatch.setattr(shared, "max_mapped", lambda: 1)
    start = shared._MAPPED[0]
    fds = len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else None
    a = np.arange(1000.0)
    got = [shared.share({"a": a}, os.getpid()).load()["a"] for _ in range(3)]
    for g in got:
        np.testing.assert_array_equal(g, a)
    assert shared._MAPPED[0] == start + 1
    if fds is not None:
        assert len(os.listdir("/proc/self/fd")) <= fds + 1
    del got, g
    gc.collect()
    assert shared._MAPPED[0] == start


def test_the_mapping_budget_is_a_quarter_of_the_descriptor_limit(monkeypatch):
    import resource

    for soft, want in ((1024, 256), (400, 100), (20000, 256), (2, 0)):
        monkeypatch.setattr(resource, "getrlimit", lambda _, s=soft: (s, 1 << 20))
        assert shared.max_mapped() == want
