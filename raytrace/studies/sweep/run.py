"""Running a sweep: the missing cells in this process, on a local process pool or on a Dask
cluster, each result written as it comes, then the tables and ``OUT/sweep.json``
(:func:`run_sweep`).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hallray.safe_output import MARKER, write_marker

from ...core.errors import HallrayError
from ...core.fileio import write_atomic
from ..cluster import connect_dask, tune_malloc
from .cell import run_cell
from .config import PIPELINE_VERSION, Cell, SweepConfig, canonical, load_sweep_config
from .files import read_cell_result, write_cell_result, write_tables


@dataclass
class SweepReport:
    """What :func:`run_sweep` did."""

    out_dir: Path
    n_cells: int
    computed: list[str]
    skipped: list[str]
    failed: dict[str, str]
    wall_s: float
    results: dict[str, dict[str, Any]]
    mode: str

    @property
    def cells_per_minute(self) -> float:
        return 60.0 * len(self.computed) / self.wall_s if self.wall_s > 0 else math.nan


def _execute_local(
    tasks: list[dict[str, Any]], workers: int
) -> Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]]:
    """Yield ``(task, result, error)`` as cells finish, in this process or on a process pool."""
    if not tasks:
        return
    if workers <= 1:
        for t in tasks:
            try:
                yield t, run_cell({**t, "threads": None}), None
            except HallrayError as exc:
                yield t, None, str(exc)
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from ...solver.parallel import cpu_count, process_context

    # forks of the preloaded fork server, never of this process: Embree's threads (alive here once
    # it has traced anything) do not survive a fork, and a child's first scene build could wait
    # for them forever (raytrace.solver.parallel)
    workers = min(workers, len(tasks), cpu_count())  # never more than usable cores or cells
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=process_context((__name__,)))
    futures: dict[Any, dict[str, Any]] = {}
    seen: set[Any] = set()
    try:
        futures = {pool.submit(run_cell, t): t for t in tasks}
        for fut in as_completed(futures):
            seen.add(fut)
            t = futures[fut]
            try:
                yield t, fut.result(), None
            except Exception as exc:  # a worker's error, reported per cell  # noqa: BLE001
                yield t, None, f"{type(exc).__name__}: {exc}".splitlines()[0]
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: stop the running cells now, keep finished ones
        done = [f for f in futures if f.done() and f not in seen and not f.cancelled()]
        _stop_pool(pool)
        for fut in done:
            if fut.exception() is None:
                yield futures[fut], fut.result(), None
        raise
    except BaseException:  # the consumer stopped (or failed): do not wait for running cells
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True, cancel_futures=True)


def _stop_pool(pool: Any) -> None:
    """Cancel a process pool's pending cells and terminate its running ones at once (waiting
    for them is what made Ctrl-C take tens of seconds)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=5)


def _execute_dask(
    tasks: list[dict[str, Any]], client: Any, own: bool
) -> Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]]:
    """The same on a Dask distributed cluster; closes the client if ``own``."""
    from distributed import as_completed

    try:
        if not tasks:
            return
        client.run(tune_malloc)  # see tune_malloc: the workers' allocator setting costs 2x
        futures = client.map(
            run_cell, tasks, key=[f"hallray-cell-{t['key']}" for t in tasks], pure=False
        )
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        for fut in as_completed(futures):
            t = by_key[fut.key]
            try:
                yield t, fut.result(), None
            except Exception as exc:  # noqa: BLE001 -- a worker's error, reported per cell
                yield t, None, f"{type(exc).__name__}: {exc}".splitlines()[0]
            finally:
                fut.release()
    finally:
        if own:
            client.close()


#: The name a sweep directory's marker records (:func:`hallray.safe_output.write_marker`).
SWEEP_COMMAND = "run-sweep"


def _output_dir(cfg: SweepConfig, out_dir: str | os.PathLike[str] | None) -> Path:
    """The sweep's output directory (:func:`default_output` if not given), checked by the one
    output rule (:func:`hallray.safe_output.check_output`: not an input, the working directory,
    ...): new, empty, or this sweep's own (its marker or, from before markers, its
    ``sweep.json``), never a directory with other content (a dataset, another sweep)."""
    from hallray.safe_output import check_output, foreign_reason

    out = Path(out_dir) if out_dir is not None else default_output(cfg)
    real = check_output(out, inputs=[cfg.source or None], directory=True, what="output")
    if real.is_dir() and any(real.iterdir()):
        reason = foreign_reason(real, SWEEP_COMMAND)
        if reason is not None and (real / "sweep.json").is_file():
            reason = None  # a sweep written before the markers
        if reason is None:
            try:
                name = json.loads((real / "sweep.json").read_text(encoding="utf-8")).get("name")
            except (OSError, ValueError, AttributeError):
                name = cfg.name
            if name != cfg.name:
                reason = f"holds the sweep {name!r}, not {cfg.name!r}"
        if reason is not None:
            raise HallrayError(
                f"output {out} is not empty and {reason}: a sweep writes into a new or empty "
                "directory, or resumes its own; choose another -o"
            )
    return out


def _done_and_todo(
    cells: Sequence[Cell], out: Path, limit: int | None
) -> tuple[dict[str, dict[str, Any]], list[Cell]]:
    """Stored results of the finished cells, and the cells to compute (at most ``limit``)."""
    results: dict[str, dict[str, Any]] = {}
    todo: list[Cell] = []
    for cell in cells:
        res = read_cell_result(out, cell)
        if res is None:
            todo.append(cell)
        else:
            results[cell.key] = res
    if limit is not None:
        todo = todo[: max(0, int(limit))]
    return results, todo


def _collect(
    runner: Iterable[tuple[dict[str, Any], dict[str, Any] | None, str | None]],
    out: Path,
    results: dict[str, dict[str, Any]],
    computed: list[str],
    failed: dict[str, str],
    tick: Callable[[int], None],
) -> None:
    """Write each finished cell (:func:`write_cell_result`), add it to ``results`` and its key
    to ``computed`` (a failure to ``failed``, key -> error) as it comes, then call ``tick(cells
    finished or failed)``: an interruption leaves them telling what was done."""
    for task, result, error in runner:
        if result is not None:
            write_cell_result(out, result)
            result.pop("_files", None)
            results[task["key"]] = result
            computed.append(task["key"])
        else:
            failed[task["key"]] = error or "unknown error"
        tick(len(computed) + len(failed))


def _write_summary(
    out: Path,
    cfg: SweepConfig,
    results: Mapping[str, Any],
    last_run: Mapping[str, Any],
) -> None:
    """``OUT/sweep.json``: the config, every cell's key and state, what the last run did."""
    cells = cfg.cells()
    summary = {
        "name": cfg.name,
        "description": cfg.description,
        "source": cfg.source,
        "grid": canonical(cfg.grid),
        "fixed": canonical(cfg.fixed),
        "methods": cfg.methods,
        "pipeline_version": PIPELINE_VERSION,
        "datasets": cfg.datasets,
        "n_cells": len(cells),
        "n_finished": len(results),
        "last_run": dict(last_run),
        "cells": [{"index": c.index, "key": c.key, "done": c.key in results} for c in cells],
    }
    write_atomic(out / "sweep.json", (json.dumps(summary, indent=1) + "\n").encode())


def run_sweep(
    config: SweepConfig | str | os.PathLike[str] | Mapping[str, Any],
    out_dir: str | os.PathLike[str] | None = None,
    *,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool | Callable[[int, int], None] = False,
    limit: int | None = None,
) -> SweepReport:
    """Run (or resume) a sweep; write one file per cell and the results tables.

    Parameters
    ----------
    config : SweepConfig, a config file or a mapping
    out_dir : output directory (default: the config's ``output``, else ``<config stem>-sweep``
        beside the config file, else ``sweep-<name>``)
    workers : processes of the local pool (default: the cores this process may use; 1 = in
        this process)
    scheduler : Dask scheduler address (``tcp://host:8786``) or a ``distributed.Client``; when
        given, cells run on that cluster and ``workers`` is ignored
    progress : True for a tqdm bar on stderr, or a callable ``(done, total)``
    limit : compute at most this many missing cells (then stop, as if interrupted)

    Returns
    -------
    SweepReport
    """
    cfg = config if isinstance(config, SweepConfig) else load_sweep_config(config)
    out = _output_dir(cfg, out_dir)
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, int) or workers < 1
    ):
        raise HallrayError(f"workers must be an integer >= 1, got {workers!r}")
    cells = cfg.cells()
    results, todo = _done_and_todo(cells, out, limit)
    skipped = list(results)
    # connect before writing anything: an unreachable scheduler leaves no output behind
    dask_client = connect_dask(scheduler) if scheduler is not None and todo else None
    out.mkdir(exist_ok=True)
    if not (out / MARKER).exists():
        write_marker(out, SWEEP_COMMAND, listed=False)  # resumable: never replaced, only resumed
    from ...solver.parallel import cpu_count

    n_workers = workers if workers is not None else cpu_count()
    mode = "dask" if scheduler is not None else ("local" if n_workers <= 1 else f"pool:{n_workers}")
    tasks = [c.task() for c in todo]
    bar = None
    if progress is True and tasks:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), desc=f"sweep {cfg.name}", unit="cell", file=sys.stderr)

    def tick(n_done: int) -> None:
        if bar is not None:
            bar.update(1)
        elif callable(progress):
            progress(n_done, len(tasks))

    t0 = time.perf_counter()
    runner = (
        _execute_dask(tasks, *dask_client)
        if dask_client is not None
        else _execute_local(tasks, n_workers)
    )
    computed: list[str] = []
    failed: dict[str, str] = {}
    try:
        _collect(runner, out, results, computed, failed, tick)
    finally:
        if bar is not None:
            bar.close()
        wall = time.perf_counter() - t0
        write_tables(out, cfg, results)
        last_run = {
            "mode": mode,
            "computed": len(computed),
            "skipped": len(skipped),
            "failed": failed,
            "wall_s": wall,
        }
        _write_summary(out, cfg, results, last_run)
    return SweepReport(out, len(cells), computed, skipped, failed, wall, results, mode)


def default_output(cfg: SweepConfig) -> Path:
    """Where a sweep writes when no ``-o`` is given (see :func:`run_sweep`)."""
    if cfg.output:
        base = Path(cfg.source).parent if cfg.source else Path.cwd()
        return base / cfg.output
    if cfg.source:
        src = Path(cfg.source)
        return src.parent / f"{src.stem}-sweep"
    return Path.cwd() / f"sweep-{cfg.name}"
