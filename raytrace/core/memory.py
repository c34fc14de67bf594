"""Large output arrays in small pages, so that their first writes do not wait on the kernel.

numpy advises the kernel to back arrays of 4 MiB and more with transparent huge pages
(``madvise(MADV_HUGEPAGE)``). Where the kernel's THP defrag setting is ``madvise`` (a common
default, and this project's CI machine), a first write into such an array may stall while the
kernel compacts memory to find a free 2 MiB page. For the join of a large trace's chunks (the 1 m
grid's 2.75 million paths, 600 MB, the serial step after a pool's work) that made the join
0.39-0.77 s from one run to the next, against 0.16-0.22 s in 4 KiB pages written by the same two
threads (docs/tracing.md, "An eleventh round"). :func:`fresh_empty` gives an array in a private
anonymous mapping advised ``MADV_NOHUGEPAGE``; elsewhere (no such advice, or a failed mapping) it
is ``np.empty``. The mapping is unmapped when the last array viewing it is freed.
"""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["SMALL_PAGES_BYTES", "fresh_empty", "release_free_heap"]

#: Arrays from this size up are mapped in small pages (numpy's own huge-page threshold).
SMALL_PAGES_BYTES = 1 << 22


def fresh_empty(shape: tuple[int, ...] | int, dtype: np.dtype | type = np.float64) -> np.ndarray:
    """An uninitialised, writable, C-contiguous array like ``np.empty(shape, dtype)``.

    Parameters
    ----------
    shape : int or tuple of int
    dtype : numpy dtype (not an object dtype)

    Returns
    -------
    array : ndarray of ``shape`` and ``dtype``; from :data:`SMALL_PAGES_BYTES` up, a view of an
        anonymous mapping advised ``MADV_NOHUGEPAGE`` (its ``base`` chain ends in a view of the mapping)
    """
    dt = np.dtype(dtype)
    shape = (int(shape),) if np.ndim(shape) == 0 else tuple(int(s) for s in shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
    advice = getattr(mmap, "MADV_NOHUGEPAGE", None)
    if nbytes < SMALL_PAGES_BYTES or advice is None or dt.hasobject:
        return np.empty(shape, dtype=dt)
    try:
        buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    except (OSError, ValueError, AttributeError):  # no anonymous mappings here, or no room
        return np.empty(shape, dtype=dt)
    try:
        buf.madvise(advice)
    except OSError:  # a kernel without transparent huge pages refuses the advice: nothing to undo
        pass
    return np.frombuffer(buf, dtype=dt).reshape(shape)


def release_free_heap() -> bool:
    """Give the C heap's free memory back to the operating system (glibc's ``malloc_trim``;
    elsewhere nothing), after a step whose temporaries are gone.

    Loading a million-triangle mesh peaks at 2.9 GB in trimesh's processing and leaves 0.6 GB
    of freed heap that glibc keeps: the next step does not reuse most of it (numpy's large
    arrays are mapped afresh), and the first trace of that hall with ``facet_reach`` peaked at
    8.25 GB after an uncached load against 6.23 GB with the heap trimmed (docs/scene.md).

    Returns
    -------
    bool, whether the C library had the call
    """
    import ctypes
    import ctypes.util
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return False
    trim(0)
    return True
