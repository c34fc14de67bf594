"""Every method on several datasets at once: :func:`evaluate_all` runs
:func:`~positioning.report.runs.evaluate` on worker processes, one group of datasets per worker.

A report's datasets are independent, and each is solved by the same code on the same numbers
wherever it runs, so the fixes do not depend on the number of workers (bit for bit:
tests/positioning/cli/test_pos_cli.py compares a report made with one and with two). Datasets
that use the same fingerprint map (the same band) go to the same worker, in the report's order:
the ``twin`` estimator re-synthesises its ToA raster around the fixes once per process and map
(:mod:`positioning.twin.lattice`), so the second dataset of a band only looks up most of it.

Workers are spawned (a fresh interpreter, the caller's ``sys.path``; never a fork of a caller
whose threads may hold locks) with BLAS and OpenMP on one thread each: a worker is one lane, and
BLAS's helper threads would spin on the other workers' cores. An error in a worker (bad input
found while solving) is raised here as it was raised there; an interruption or an error ends
the workers at once.
"""

from __future__ import annotations

import multiprocessing
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

from hallray.workerenv import ONE_THREAD, environ_set

from ..evaluation.integrity import ALERT_LIMIT_M
from ..io.dataset import ToaDataset
from .runs import DatasetResult, evaluate


def groups_by_map(
    params: Sequence[Mapping[str, Mapping[str, Any]]], workers: int
) -> list[list[int]]:
    """Indices of the datasets per worker: datasets with the same ``twin`` map together, in the
    report's order; without maps (or with fewer maps than workers), round-robin over
    ``workers`` groups. Never more groups than datasets."""
    keys = [str(dict(p.get("twin", {})).get("map", "")) for p in params]
    distinct = list(dict.fromkeys(keys))
    if len(distinct) >= workers and any(distinct):
        return [[i for i, k in enumerate(keys) if k == key] for key in distinct]
    n = max(1, min(workers, len(keys)))
    return [list(range(g, len(keys), n)) for g in range(n)]


def spawn_pool(processes: int) -> Any:
    """A ``multiprocessing`` pool of ``processes`` spawned workers, BLAS and OpenMP on one
    thread each (see the module docstring); the caller closes or terminates it."""
    ctx = multiprocessing.get_context("spawn")
    with environ_set(ONE_THREAD):  # inherited by the workers spawned now
        return ctx.Pool(processes)


def _evaluate_group(jobs: list[tuple]) -> list[DatasetResult]:
    """A worker's datasets, one after the other (the twin's map and raster kept between them)."""
    return [evaluate(ds, methods, params, height, outside=outside, alert_limit_m=limit)
            for ds, methods, params, height, outside, limit in jobs]  # fmt: skip


def _evaluate_in_worker(jobs: list[tuple]) -> tuple[list[DatasetResult], list[tuple]]:
    """:func:`_evaluate_group` in a worker, with the warnings it gave (message, category), for
    the caller to give again as its own (the command prints them as ``warning: ...`` lines)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = _evaluate_group(jobs)
    return out, [(str(w.message), w.category) for w in caught]


def evaluate_all(
    datasets: Sequence[ToaDataset],
    methods: Sequence[str],
    params: Sequence[Mapping[str, Mapping[str, Any]]],
    height: str | float = "true",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = ALERT_LIMIT_M,
    workers: int = 1,
) -> list[DatasetResult]:
    """:func:`~positioning.report.runs.evaluate` of every dataset (with its own ``params``), in
    the order of ``datasets``; on ``workers`` processes (1: in this one).

    Parameters
    ----------
    datasets : the datasets
    methods : method names (``METHOD+track`` for tracked rows)
    params : per dataset, the method parameters (e.g. the twin's map of its band)
    height, outside, alert_limit_m : as :func:`~positioning.report.runs.evaluate`
    workers : int >= 1, processes (at most one per group of datasets, :func:`groups_by_map`;
        a group is never split, more groups than workers queue)
    """
    jobs = [(ds, list(methods), dict(p), height, outside, alert_limit_m)
            for ds, p in zip(datasets, params, strict=True)]  # fmt: skip
    groups = groups_by_map(params, workers) if workers > 1 else []
    if len(groups) < 2:
        return _evaluate_group(jobs)
    pool = spawn_pool(min(workers, len(groups)))  # more groups (maps) wait for a worker
    done = False
    try:
        pending = [pool.apply_async(_evaluate_in_worker, ([jobs[i] for i in g],))
                   for g in groups]  # fmt: skip
        out: list[DatasetResult | None] = [None] * len(jobs)
        said: list[tuple] = []
        for g, res in zip(groups, pending, strict=True):
            results, caught = res.get()
            for i, r in zip(g, results, strict=True):
                out[i] = r
            said += caught
        done = True
    finally:
        if done:
            pool.close()
        else:  # an error or Ctrl-C: the other workers' results are not wanted
            pool.terminate()
        pool.join()
    for message, category in dict.fromkeys(said):  # each once, as the "default" filter does
        warnings.warn(message, category, stacklevel=2)
    return [r for r in out if r is not None]
