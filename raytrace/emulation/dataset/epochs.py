"""The epochs of one scenario: the tracer and measurement models of its datasets
(:func:`scenario_group`) and their measurements over every epoch, in this process or in worker
processes forked from the preloaded fork server (:func:`measure_group`); the files do not
depend on the number of workers.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...scene.metadata import SceneMetadata
from ...scene.model import Scene
from ...solver.incremental import SnapshotTracer
from ...solver.paths import Paths
from ..bands import get_band
from ..measurement import Measurements, ToaModel, link_los, shared_paths
from ..receivers.receiver import PreparedLinks
from .config import DatasetConfig

#: the group of this worker process (set by its initializer, :func:`_init_worker`)
_WORKER: dict[str, Any] = {}
#: Receivers whose static epochs cost milliseconds (one noise draw on prepared paths): a static
#: group of these alone is measured in this process, whatever the workers.
CHEAP_STATIC = ("first-path", "first-lobe", "paper")
#: Fewest epochs for which a static group with a costlier receiver (search-back: ~40 ms per
#: epoch and band) is measured on worker processes: below it the pool's start-up (~1 s) and each
#: worker's own prepare outweigh the second core.
STATIC_POOL_EPOCHS = 100


@dataclass
class ScenarioGroup:
    """Datasets of one scenario (one measurement model each) computed in one pass over the
    epochs from one trace per snapshot."""

    scenario: str
    models: list[ToaModel]
    times_s: np.ndarray
    tracer: SnapshotTracer
    #: index of each dataset's carrier in the tracer's frequencies (receivers share a trace)
    freq_index: list[int]
    #: static scene: each dataset's receiver work on its paths, done once
    prepared: list[PreparedLinks] | None = None
    #: time.perf_counter() when the group's set-up began, and its seconds (the static trace)
    t_start: float = 0.0
    trace_s: float = 0.0

    def paths_of(self, paths: Sequence[Paths], k: int) -> Paths:
        """The paths of dataset ``k`` among the tracer's per-frequency ``paths``."""
        return paths[self.freq_index[k]]

    @property
    def static(self) -> bool:
        """Whether the scene never changes (every epoch measures the same paths)."""
        return self.scenario != "semi-dynamic"


def _group_state(g: ScenarioGroup) -> dict[str, Any]:
    tr = g.tracer
    return {
        "scenario": g.scenario,
        "models": g.models,
        "times_s": g.times_s,
        "scene": tr.scene,  # pickled without its Embree scene, rebuilt when unpickled
        "tx": tr.tx,
        "rx": tr.rx,
        "routes": tr.fleet.routes,
        "frequencies_hz": tr.frequencies_hz,
        "settings": tr.settings,
        "clearance_m": tr.fleet.clearance_m,
        "static_paths": tr.static_paths,
        "freq_index": g.freq_index,
    }


def _init_worker(state: dict[str, Any]) -> None:
    tracer = SnapshotTracer(
        state["scene"],
        state["tx"],
        state["rx"],
        state["routes"],
        state["frequencies_hz"],
        state["settings"],
        clearance_m=state["clearance_m"],
        static_paths=state["static_paths"],
        threads=1,
    )
    _WORKER["group"] = ScenarioGroup(
        state["scenario"], state["models"], state["times_s"], tracer, state["freq_index"]
    )


def _run_epochs(g: ScenarioGroup, epochs: Sequence[int]) -> tuple[list[Measurements], dict]:
    """Measurements of the given epochs for every dataset of the group, and the tracer's stage
    timings of this call."""
    tr = g.tracer
    tr.stats = {}
    if g.static:
        if g.prepared is None:
            g.prepared = _prepare_all(g, tr.static_paths)
        los = [link_los(p) for p in tr.static_paths]
        out = [
            m.measure(g.paths_of(tr.static_paths, k), epochs, g.prepared[k], los[g.freq_index[k]])
            for k, m in enumerate(g.models)
        ]
        return out, dict(tr.stats)
    parts: list[list[Measurements]] = [[] for _ in g.models]
    for e in epochs:
        paths = tr.paths_at(float(g.times_s[e]))  # one trace of the snapshot for all datasets
        prepared = _prepare_all(g, paths)
        los = [link_los(p) for p in paths]  # per band, for all its datasets
        for k, m in enumerate(g.models):
            parts[k].append(m.measure(g.paths_of(paths, k), [e], prepared[k], los[g.freq_index[k]]))
    return [Measurements.concatenate(p) for p in parts], dict(tr.stats)


def _prepare_all(g: ScenarioGroup, paths: Sequence[Paths]) -> list[PreparedLinks]:
    """Every dataset's receiver work on its band's ``paths``; the receivers of one band share
    the CIR and first paths they all derive from the paths (computed once, not per receiver)."""
    shared = [shared_paths(p) for p in paths]
    return [m.prepare(g.paths_of(paths, k), shared[g.freq_index[k]])
            for k, m in enumerate(g.models)]  # fmt: skip


def _run_chunk(epochs: Sequence[int]) -> tuple[list[Measurements], dict]:
    return _run_epochs(_WORKER["group"], epochs)


def _chunks(n: int, size: int) -> list[list[int]]:
    return [list(range(i, min(n, i + size))) for i in range(0, n, size)]


def measure_group(
    g: ScenarioGroup,
    workers: int,
    progress: Callable[[int], None] | None,
    sink: Callable[[list[Measurements]], None] | None = None,
) -> tuple[list[Measurements], dict]:
    """All epochs of a group: the measurements of each dataset, summed stage timings.

    ``sink``: called with each chunk's measurements (one per dataset, consecutive epochs, in
    order) instead of keeping them; the measurements returned are then ``[]``. A long dataset
    is streamed to its files this way, so that memory does not grow with its epochs.
    """
    n = len(g.times_s)
    parts: list[list[Measurements]] = [[] for _ in g.models]
    stats: dict[str, float] = {}

    def collect(res: tuple[list[Measurements], dict], n_done: int) -> None:
        measured, st = res
        if sink is not None:
            sink(measured)
        for k, m in enumerate(measured if sink is None else []):
            parts[k].append(m)
        for key, v in st.items():
            stats[key] = stats.get(key, 0.0) + v
        if progress is not None:
            progress(n_done)

    if workers <= 1 or n < 2 or _static_in_process(g, n):
        for chunk in _chunks(n, 10):
            collect(_run_epochs(g, chunk), len(chunk))
    else:
        # chunks of at most 10 epochs (~5 s of a semi-dynamic worker): the last chunk, which
        # one worker finishes while the other idles, is short
        size = max(1, min(10, n // (4 * workers)))
        chunks = _chunks(n, size)
        from ...solver.parallel import process_context, resolve_workers

        workers = resolve_workers(workers, len(chunks))  # never more than the cores, the chunks
        # forks of the preloaded fork server, never of this process: Embree's and the tracer's
        # threads do not survive a fork (raytrace.solver.parallel)
        ctx = process_context((__name__,))
        with ProcessPoolExecutor(
            max_workers=workers,
            mp_context=ctx,
            initializer=_init_worker,
            initargs=(_group_state(g),),
        ) as pool:
            # map keeps the order of the chunks: the files do not depend on the worker count
            for chunk, res in zip(chunks, pool.map(_run_chunk, chunks)):
                collect(res, len(chunk))
    return ([] if sink is not None else [Measurements.concatenate(p) for p in parts]), stats


def _static_in_process(g: ScenarioGroup, n: int) -> bool:
    """Whether a static group is measured in this process: its receivers are all cheap, or its
    epochs too few to pay for worker processes (each worker prepares the paths once itself; the
    files do not depend on where the epochs are measured: each draws from its own streams)."""
    if not g.static:
        return False
    return n < STATIC_POOL_EPOCHS or all(m.receiver.method in CHEAP_STATIC for m in g.models)


def scenario_group(
    scenario: str,
    configs: Sequence[DatasetConfig],
    scene: Scene,
    inputs: SceneMetadata,
    static_cache: dict[float, Paths],
) -> ScenarioGroup:
    """The tracer and measurement models of one scenario's datasets (the static scene's paths
    per carrier come from ``static_cache`` when another scenario traced them; new ones are
    added to it)."""
    t_start = time.perf_counter()
    routes = inputs.routes if scenario == "semi-dynamic" else []
    carriers = [get_band(c.band).center_frequency_hz for c in configs]
    freqs = list(dict.fromkeys(carriers))
    known = [static_cache.get(f) for f in freqs]
    tracer = SnapshotTracer(
        scene,
        inputs.bs_xyz,
        inputs.point_xyz,
        routes,
        freqs,
        configs[0].trace,
        clearance_m=configs[0].clearance_m,
        static_paths=None if any(p is None for p in known) else known,
    )
    static_cache.update(zip(freqs, tracer.static_paths))
    times = configs[0].times_s
    tracer.check_clear(times, inputs.bs_names, inputs.point_names)
    models = [c.model() for c in configs]
    index = [freqs.index(f) for f in carriers]
    return ScenarioGroup(scenario, models, times, tracer, index, t_start=t_start,
                         trace_s=time.perf_counter() - t_start)  # fmt: skip
