"""Tracing in chunks of receivers, in this process or on worker processes: identical paths."""

from __future__ import annotations

import numpy as np
import pytest
from test_diffraction_paths import _cluttered_scene

from raytrace import TraceConfig, TraceInputError, trace
from raytrace.solver.parallel import cpu_count, receiver_chunks, resolve_workers
from raytrace.solver.tracer import trace_chunks

F_C = 3.775e9


def _same(a, b) -> None:
    assert a.n_paths == b.n_paths
    for k in a._PER_PATH:
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
