"""Arrays handed from a worker process to the process that started it through shared memory.

A worker's paths for a chunk of receivers are tens of megabytes (a 64-receiver chunk of the 2 m
grid: 23 MB). Sent back through the pool's result pipe, the worker waits in ``put`` until the
calling process has read them all, and the calling process reads and unpickles them on the core
it traces on: measured on 2 cores (docs/tracing.md, "A ninth round"), the worker idled 0.12-0.19
s of a 1.7 s trace and the calling lane traced 5 % slower. Here the worker writes the arrays into
a file in a tmpfs directory (:data:`SHM_DIR`, memory, not disk) and sends its name; the calling
process maps the file copy-on-write (no copy, no unpickling: the arrays are views of the pages
the worker wrote) and removes it at once, so the memory is freed with the last view. Where there
is no such directory (macOS, Windows) the arrays go through the pipe as before.

Files are named after the calling process (``hallray-<caller pid>-<worker pid>-<n>``); those a
calling process did not read (it stopped consuming a trace's chunks, or died) are removed when it
exits or closes its pools (:func:`remove_left_over`), and by the workers when they see it gone.
"""

from __future__ import annotations

import glob
import itertools
import mmap
import os
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The tmpfs directory the files go to (Linux); without it, arrays go through the result pipe.
SHM_DIR = "/dev/shm"
#: File name prefix, then the calling process's pid.
PREFIX = "hallray-"
#: Each array starts at a multiple of this many bytes in the file.
ALIGN = 64
#: A file is written only where the directory has this many times its size free.
FREE_FACTOR = 4

_COUNTER = itertools.count()
#: Mappings alive in this process (each holds a file descriptor: Python's mmap keeps a duplicate
#: of the file's, and a trace of thousands of chunks must not run out of them).
_MAPPED = [0]


def _unmapped() -> None:
    _MAPPED[0] -= 1


def max_mapped() -> int:
    """How many chunks may stay mapped at once: a quarter of this process's file descriptor
    limit, at most 256 (beyond, a chunk is read into memory instead: one copy)."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (ImportError, OSError, ValueError):
        return 64
    if soft == resource.RLIM_INFINITY or soft <= 0:
        return 256
    return max(0, min(256, soft // 4))


@dataclass(frozen=True)
class SharedArrays:
    """Arrays written to a file in shared memory by :func:`share`: its ``path``, ``size`` in
    bytes and ``layout``, per array its name, dtype string, shape and offset."""

    path: str
    size: int
    layout: tuple[tuple[str, str, tuple[int, ...], int], ...]

    def load(self) -> dict[str, np.ndarray]:
        """The arrays, as writable views of a private (copy-on-write) mapping of the file (or,
        with :func:`max_mapped` mappings alive already, a copy); the file is removed (its pages
        are freed with the last view)."""
        try:
            with open(self.path, "rb") as fh:
                buf: Any = b""
                if self.size and _MAPPED[0] < max_mapped():
                    buf = mmap.mmap(fh.fileno(), self.size, access=mmap.ACCESS_COPY)
                    _MAPPED[0] += 1
                    weakref.finalize(buf, _unmapped)
                elif self.size:
                    buf = np.empty(self.size, dtype=np.uint8)
                    fh.readinto(memoryview(buf))
        finally:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
        out = {}
        for name, dtype, shape, offset in self.layout:
            dt = np.dtype(dtype)
            count = int(np.prod(shape, dtype=np.int64))
            if count == 0:
                out[name] = np.empty(shape, dtype=dt)
                continue
            out[name] = np.frombuffer(buf, dtype=dt, count=count, offset=offset).reshape(shape)
        return out


def share(arrays: dict[str, np.ndarray], caller: int) -> SharedArrays | None:
    """Write ``arrays`` (C order) to a new file in :data:`SHM_DIR` for process ``caller``;
    None where that directory does not exist, has less than :data:`FREE_FACTOR` times their size
    free, or the file cannot be written (the caller then sends the arrays themselves)."""
    if not os.path.isdir(SHM_DIR):
        return None
    # leave room: a container's /dev/shm may be small (Docker's default is 64 MB)
    need = sum(np.asarray(a).nbytes + ALIGN for a in arrays.values())
    try:
        st = os.statvfs(SHM_DIR)
    except OSError:
        return None
    if st.f_bavail * st.f_frsize < FREE_FACTOR * need:
        return None
    path = os.path.join(SHM_DIR, f"{PREFIX}{caller}-{os.getpid()}-{next(_COUNTER)}")
    layout = []
    offset = 0
    try:
        with open(path, "wb") as fh:
            for name, a in arrays.items():
                a = np.ascontiguousarray(a)
                pad = -offset % ALIGN
                if pad:
                    fh.write(b"\0" * pad)
                    offset += pad
                layout.append((name, a.dtype.str, tuple(a.shape), offset))
                if a.nbytes:
                    fh.write(memoryview(a).cast("B"))
                    offset += a.nbytes
    except OSError:  # full or read-only: the pipe still works
        try:
            os.unlink(path)
        except OSError:
            pass
        return None
    return SharedArrays(path, offset, tuple(layout))


def remove_left_over(caller: int) -> None:
    """Remove the files written for process ``caller`` that it has not read."""
    for path in glob.glob(os.path.join(SHM_DIR, f"{PREFIX}{caller}-*")):
        try:
            os.unlink(path)
        except OSError:
            pass
