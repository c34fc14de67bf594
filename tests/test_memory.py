"""core.memory: large output arrays in small pages."""

from __future__ import annotations

import gc
import mmap
import sys
from pathlib import Path

import numpy as np
import pytest

from raytrace.core import memory
from raytrace.core.memory import fresh_empty

LINUX_THP = sys.platform.startswith("linux") and Path("/sys/kernel/mm/transparent_hugepage").exists()


def _mapping_of(addr: int) -> tuple[str, list[str]] | None:
    """The /proc/self/smaps header line and VmFlags of the mapping holding ``addr``."""
    header, found = None, False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        first = line.split(maxsplit=1)[0]
        if "-" in first and not first.endswith(":"):
            lo, hi = (int(x, 16) for x in first.split("-"))
            found, header = lo <= addr < hi, line
        elif found and first == "VmFlags:":
            return header, line.split()[1:]
    return None


def test_small_arrays_are_numpys_own():
    a = fresh_empty((10, 3), np.float64)
    assert a.shape == (10, 3) and a.dtype == np.float64 and a.base is None


@pytest.mark.parametrize("shape, dtype", [((700_000, 3), np.float64), (2_000_000, np.int32),
                                          ((300_000, 4, 3), np.float32)])  # fmt: skip
def test_large_arrays_are_writable_contiguous_mapped(shape, dtype):
    a = fresh_empty(shape, dtype)
    want = (shape,) if isinstance(shape, int) else shape
    assert a.shape == want and a.dtype == dtype
    assert a.flags.c_contiguous and a.flags.writeable and a.flags.aligned
    base = a
    while getattr(base, "base", None) is not None:
        base = base.base
    base = base.obj if isinstance(base, memoryview) else base
    assert isinstance(base, mmap.mmap) and len(base) == a.nbytes
    a[...] = 7
    assert np.all(a == 7)


@pytest.mark.skipif(not LINUX_THP, reason="transparent huge pages are Linux's")
def test_large_arrays_are_advised_small_pages_and_unmapped_with_the_array():
    a = fresh_empty((1_000_000, 3))  # 24 MB
    a[...] = 1.0
    addr = a.ctypes.data
    header, flags = _mapping_of(addr)
    assert "nh" in flags, header  # MADV_NOHUGEPAGE
    plain = np.empty((1_000_000, 3))  # numpy's own: advised huge pages
    plain[...] = 1.0
    assert "nh" not in _mapping_of(plain.ctypes.data)[1]
    del a
    gc.collect()
    m = _mapping_of(addr)
    assert m is None or "nh" not in m[1]  # the mapping went with its array


def test_falls_back_to_numpy_where_mapping_fails(monkeypatch):
    def refuse(*args, **kwargs):
        raise OSError("no room")

    monkeypatch.setattr(memory.mmap, "mmap", refuse)
    a = fresh_empty((1_000_000, 3))
    assert a.shape == (1_000_000, 3) and a.base is None


def test_zero_size_and_object_arrays():
    assert fresh_empty((0, 3)).shape == (0, 3)
    monkey = fresh_empty(10, object)
    assert monkey.dtype == object and monkey.base is None


def test_the_free_heap_is_given_back_after_a_large_load(tmp_path, monkeypatch):
    """glibc's malloc_trim is there on Linux, and load_scene calls it after a scene of at
    least budget.CHECK_MIN_TRIANGLES triangles only."""
    import trimesh

    import raytrace.scene.io as io
    from raytrace import load_scene
    from raytrace.scene.budget import CHECK_MIN_TRIANGLES

    assert memory.release_free_heap() is sys.platform.startswith("linux")
    calls = []
    monkeypatch.setattr(io, "release_free_heap", lambda: calls.append(1) or True)
    for sub, expected in ((2, 0), (5, 1)):  # 320 and 20 480 triangles
        mesh = trimesh.creation.icosphere(sub, 1.0)
        mesh.apply_translation([0.0, 0.0, 2.0])
        path = tmp_path / f"ball{sub}_metal.stl"
        mesh.export(path)
        calls.clear()
        scene = load_scene(path, cache=False)
        assert (len(scene.faces) >= CHECK_MIN_TRIANGLES) == bool(expected)
        assert len(calls) == expected
