"""Dask clusters for the studies: connecting to a scheduler (:func:`connect_dask`) and the
allocator setting of Dask's workers that halves the tracer's speed (:func:`tune_malloc`). Sweeps
(:mod:`raytrace.studies.sweep`) and accuracy maps (:mod:`raytrace.studies.accuracy_map`) run
their work on a cluster through these.
"""

from __future__ import annotations

import sys
from typing import Any

from ..core.errors import HallrayError

#: Seconds to wait for a Dask scheduler before giving up.
CONNECT_TIMEOUT_S = 10.0
#: glibc ``mallopt`` settings for Dask workers (see :func:`tune_malloc`): large temporaries from
#: the heap below 32 MiB, heap top trimmed beyond 128 MiB.
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 128 * 1024 * 1024


def tune_malloc() -> bool:
    """Undo the allocator setting Dask's nanny gives its workers, which halves the tracer's speed.

    Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (to return memory to the OS
    quickly). Setting it switches off glibc's dynamic mmap threshold, so every numpy temporary
    above 128 KiB becomes a fresh ``mmap`` whose pages fault in again: a trace took 2.3x as long
    in a Dask worker as in a plain process. This sets ``M_MMAP_THRESHOLD`` and
    ``M_TRIM_THRESHOLD`` through ``mallopt`` (glibc only; elsewhere it does nothing).

    Returns
    -------
    bool, whether the settings were applied
    """
    import ctypes
    import ctypes.util

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    return bool(
        mallopt(m_mmap_threshold, MMAP_THRESHOLD_BYTES)
        and mallopt(m_trim_threshold, TRIM_THRESHOLD_BYTES)
    )


def connect_dask(scheduler: Any) -> tuple[Any, bool]:
    """Connect to a Dask cluster (sweeps' cells and accuracy maps' chunks run there).

    Parameters
    ----------
    scheduler : str or ``distributed.Client``, a scheduler address (``tcp://host:8786``) or a
        client already connected

    Returns
    -------
    (client, own) : the client, and whether it was made here (the caller closes it then)

    Raises
    ------
    HallrayError
        dask.distributed is not installed, or the scheduler does not answer within
        :data:`CONNECT_TIMEOUT_S`.
    """
    try:
        from distributed import Client
    except ImportError:
        raise HallrayError(
            "--scheduler needs dask.distributed: pip install 'hallray[cluster]' "
            "(or 'dask[distributed]')"
        ) from None
    if isinstance(scheduler, Client):
        return scheduler, False
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s"), True
    except (OSError, TimeoutError, ValueError) as exc:
        raise HallrayError(
            f"cannot connect to the Dask scheduler {scheduler!r}: {str(exc).splitlines()[0]}"
        ) from None
