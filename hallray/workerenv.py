"""The environment that worker processes are started with (standard library only).

Both packages start worker processes (the tracer's fork server, the reports' spawned pool): a
worker is one lane, so it loads BLAS and OpenMP with one thread each (their helper threads
spin for about 0.1 s after each product they share, on the cores the other lanes work on), and
the variables are set only while the workers start: the caller's own settings stay.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

__all__ = ["ONE_THREAD", "environ_set"]

#: BLAS and OpenMP libraries on one thread each.
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def environ_set(values: Mapping[str, str]) -> Iterator[None]:
    """Within the block, ``os.environ`` holds ``values`` (what processes started in it
    inherit); afterwards each variable is as it was, unset where it was unset."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
