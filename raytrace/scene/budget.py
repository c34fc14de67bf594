"""Memory a scene will take, estimated before it is built or traced, against what the machine
(and the process's limit) can give: a scene too large stops with one line that names its size
and the estimate, instead of a numpy traceback or a machine swapping to death.

The estimates are linear in the triangles: since the scene layer and the tracer hold no array
whose size is a product of two scene counts (issue 36), memory is O(triangles + candidates +
paths). The coefficients are measured peaks (``tools/bench.py --scene-scale``; docs/tracing.md,
"Scene scale") with a margin: 2 cores, the bundled hall plus noisy metal spheres.

=============  ===========  ==========================
triangles      load peak    peak after the first trace
=============  ===========  ==========================
6 400          0.33 GB      0.37 GB
21 760         0.35 GB      0.68-0.74 GB
83 200         0.39-0.50 GB 1.7-2.6 GB
247 040        0.69 GB      2.9-3.0 GB
984 320        2.1 GB       5.3-6.6 GB
=============  ===========  ==========================
"""

from __future__ import annotations

import os
import resource

from ..core.errors import SceneError

__all__ = ["CHECK_MIN_TRIANGLES", "TRACE_BASE_B", "available_bytes", "load_bytes", "trace_bytes", "check_load", "check_trace"]

#: Traces of scenes below this many triangles are not estimated (they fit anywhere).
CHECK_MIN_TRIANGLES = 20_000
#: Load: the interpreter with numpy, trimesh, numba and Embree, bytes.
LOAD_BASE_B = 400e6
#: Load: bytes per triangle (measured 1.8 kB: trimesh's processing, facets, wedges, trees).
LOAD_PER_TRIANGLE_B = 2.5e3
#: Trace: bytes on top of the loaded scene, whatever its size: the kept second images (at most
#: 1 GiB, :data:`raytrace.solver.specular.SECOND_IMAGES_KEPT_BYTES`), an end's kept triples and
#: the chunks in flight. A flat 20 kB per triangle (the ratio at 83 200 triangles, where the
#: kept part dominates) asked 19.7 GB for the million-triangle hall, whose trace adds 4.5 GB:
#: a machine with 16 GB was refused a trace it could run.
TRACE_BASE_B = 2.5e9
#: Trace: bytes per triangle beyond that (the trace added, measured: 2.2 GB at 83 200
#: triangles, 2.3 GB at 247 040, 3.2-4.5 GB at 984 320 (exact or ``facet_reach``); trees,
#: Embree's build, the candidate lists of the ends, the approximate discovery's lists).
TRACE_PER_TRIANGLE_B = 5e3


def available_bytes() -> float:
    """Bytes this process may still allocate: the smaller of the machine's available memory
    (``MemAvailable``) and the headroom under the process's address-space limit
    (``RLIMIT_AS``, as ``ulimit -v`` or a batch system sets it). Infinite when neither is
    known."""
    avail = float("inf")
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = float(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        try:
            with open(f"/proc/{os.getpid()}/statm") as fh:
                used = float(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        except (OSError, ValueError):
            used = 0.0
        avail = min(avail, max(float(soft) - used, 0.0))
    return avail


def load_bytes(n_triangles: int) -> float:
    """Estimated peak bytes of loading a scene of ``n_triangles`` triangles."""
    return LOAD_BASE_B + LOAD_PER_TRIANGLE_B * n_triangles


def trace_bytes(n_triangles: int) -> float:
    """Estimated bytes a trace adds to a loaded scene of ``n_triangles`` triangles (at least
    30 % above every measured peak of the scale benchmark)."""
    return TRACE_BASE_B + TRACE_PER_TRIANGLE_B * n_triangles


def _gb(b: float) -> str:
    return f"{b / 1e9:.1f} GB"


def _refuse(need: float, have: float, n_triangles: int, name: str, doing: str) -> None:
    if need > have:
        raise SceneError(
            f"scene {name} has {n_triangles:,} triangles: {doing} needs about {_gb(need)}, "
            f"this process can allocate {_gb(have)}; free memory, raise the limit, or simplify "
            "the mesh (fewer triangles)"
        )


def check_load(n_triangles: int, name: str, available: float | None = None) -> None:
    """SceneError (one line) when loading ``n_triangles`` needs more than is available."""
    have = available_bytes() if available is None else available
    _refuse(load_bytes(n_triangles), have, n_triangles, name, "loading it")


def check_trace(n_triangles: int, name: str, available: float | None = None) -> None:
    """SceneError (one line) when a trace of the scene needs more than is available."""
    have = available_bytes() if available is None else available
    _refuse(trace_bytes(n_triangles), have, n_triangles, name, "tracing it")
