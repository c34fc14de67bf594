"""The map: its cells in chunks, each traced, measured and positioned in this process, on
worker processes or on a Dask cluster, joined into the schema's arrays (:func:`compute_map`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from positioning.twin.fingerprint import FingerprintMap

from ...core.errors import HallrayError
from ...emulation.bands import get_band
from ...emulation.receivers.receiver import Receiver
from ...scene.facts import SceneFacts
from ...scene.metadata import SceneMetadata
from ...scene.model import Scene
from ...solver.parallel import (
    ScenePool,
    receiver_chunks,
    resolve_workers,
)
from .cells import chunk_seed, measure_cells, receiver_model_meta, stored_paths
from .grid import MapGrid, make_grid
from .settings import MapSettings


def _chunk_job(scene: Scene, job: tuple) -> dict[str, Any]:
    """Trace, measure and position one chunk of cells (in a worker or in this process)."""
    from ...solver.tracer import trace

    tx, cells, first, settings, receiver, threads = job
    t0 = time.perf_counter()
    # a job's trace stays in its process, on threads (raytrace.solver.parallel.in_job)
    paths = trace(scene, tx, cells, receiver.band.center_frequency_hz, settings.trace,
                  threads=threads)  # fmt: skip
    t1 = time.perf_counter()
    out = measure_cells(paths, receiver, chunk_seed(settings.seed, first), settings.draws,
                        settings.methods, stored_paths(settings))  # fmt: skip
    out["time_s"]["trace"] = t1 - t0
    out["n_paths"] = paths.n_paths
    return out


@dataclass(frozen=True)
class AccuracyMap:
    """A computed map: the schema's arrays (:attr:`fmap`) and the grid they lie on."""

    fmap: FingerprintMap
    grid: MapGrid


def compute_map(
    scene: Scene,
    settings: MapSettings,
    *,
    scene_name: str = "",
    bs_xyz: np.ndarray | None = None,
    bs_names: Sequence[str] | None = None,
    area_xy: np.ndarray | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool | Callable[[int], None] = False,
) -> AccuracyMap:
    """The accuracy map of ``scene`` (module docstring).

    Parameters
    ----------
    scene : Scene
    settings : MapSettings
    scene_name : str, recorded in the meta
    bs_xyz : (B, 3) float, m, optional, base stations (default: the scene's metadata)
    bs_names : sequence of str, optional (default BS1, BS2, ... for given positions)
    area_xy : (K, 2) float, m, optional, polygon for the cells (default :func:`area_polygon`)
    workers : int, optional, processes (default every core, at most one per chunk; 1: this one)
    scheduler : Dask scheduler address or ``distributed.Client``, optional: the chunks run on
        that cluster instead (as :func:`raytrace.studies.sweep.run_sweep`'s cells; the scene is
        sent to every worker once)
    progress : bool or callable, a tqdm bar over the cells, or a callback with cells done

    Returns
    -------
    AccuracyMap
    """
    t_start = time.perf_counter()
    settings.check()
    inputs = SceneMetadata.from_scene(scene)
    if bs_xyz is None:
        bs_xyz, bs_names = inputs.bs_xyz, inputs.bs_names
    bs_xyz = np.asarray(bs_xyz, dtype=float).reshape(-1, 3)
    if len(bs_xyz) == 0:
        raise HallrayError("the scene has no base stations (metadata['hallray']['base_stations'])")
    names = list(bs_names) if bs_names is not None else [f"BS{i + 1}" for i in range(len(bs_xyz))]
    facts = SceneFacts.of(scene, inputs.block)  # the walk's one visit to the scene's facts
    grid = make_grid(scene, settings, inputs.point_names, inputs.point_xyz, area_xy, facts)
    settings.check_grid(len(grid.cell_xyz), len(bs_xyz))
    band = get_band(settings.band)
    receiver = Receiver(settings.receiver, band)
    chunks = receiver_chunks(len(bs_xyz), len(grid.cell_xyz), settings.chunk_links)
    n_workers = resolve_workers(workers, len(chunks))
    threads = 1 if n_workers > 1 or scheduler is not None else None
    jobs = [(bs_xyz, grid.cell_xyz[c.start : c.stop], c.start, settings, receiver, threads)
            for c in chunks]  # fmt: skip
    if scheduler is not None:
        parts = _run_chunks_dask(scene, jobs, chunks, scheduler, progress)
        n_workers = 0  # recorded as "dask"
    else:
        parts = _run_chunks(scene, jobs, chunks, n_workers, progress)
    arrays = _join(parts, len(settings.methods))
    timing = {k: float(sum(p["time_s"][k] for p in parts)) for k in ("trace", "measure", "locate")}
    timing["total_wall"] = time.perf_counter() - t_start
    meta = _meta(facts, scene_name, settings, band, grid, n_workers, timing,
                 sum(p["n_paths"] for p in parts))  # fmt: skip
    if stored_paths(settings) > 0:
        meta["receiver_model"] = receiver_model_meta(receiver)
    fmap = FingerprintMap(
        cell_xyz=grid.cell_xyz, bs_xyz=bs_xyz, bs_names=np.array(names, dtype=str),
        methods=np.array(settings.methods, dtype=str), meta=meta, **arrays,
    )  # fmt: skip
    return AccuracyMap(fmap, grid)


def _run_chunks(
    scene: Scene, jobs: list[tuple], chunks: list[range], n_workers: int,
    progress: bool | Callable[[int], None],
) -> list[dict[str, Any]]:  # fmt: skip
    """Every chunk's result, in chunk order, with a progress bar over the cells."""
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=chunks[-1].stop, desc="accuracy map", unit="cell")
    parts = []
    try:
        with ScenePool(scene, n_workers, preload=(__name__,)) as pool:
            for chunk, part in zip(chunks, pool.map(_chunk_job, jobs)):
                parts.append(part)
                if bar is not None:
                    bar.update(len(chunk))
                elif callable(progress):
                    progress(len(chunk))
    finally:
        if bar is not None:
            bar.close()
    return parts


def _run_chunks_dask(
    scene: Scene, jobs: list[tuple], chunks: list[range], scheduler: Any,
    progress: bool | Callable[[int], None],
) -> list[dict[str, Any]]:  # fmt: skip
    """:func:`_run_chunks` on a Dask cluster (the sweep's connection and allocator settings)."""
    from ..cluster import connect_dask, tune_malloc

    client, own = connect_dask(scheduler)
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=chunks[-1].stop, desc="accuracy map (dask)", unit="cell")
    try:
        client.run(tune_malloc)
        scene_f = client.scatter(scene, broadcast=True)
        futures = client.map(_chunk_job, [scene_f] * len(jobs), jobs, pure=False)
        parts = []
        for chunk, fut in zip(chunks, futures):
            parts.append(fut.result())
            if bar is not None:
                bar.update(len(chunk))
            elif callable(progress):
                progress(len(chunk))
        return parts
    finally:
        if bar is not None:
            bar.close()
        if own:
            client.close()


def _join(parts: list[dict[str, Any]], n_methods: int) -> dict[str, np.ndarray]:
    """The chunks' arrays joined along the cell axis."""
    out: dict[str, np.ndarray] = {}
    for key in ("los", "first_kind", "excess_m", "toa_s", "toa_std_s", "detected_fraction",
                "gdop"):  # fmt: skip
        out[key] = np.concatenate([p[key] for p in parts])
    for key in ("err_p90_m", "err_mean_m", "availability"):
        out[key] = np.concatenate([p[key].reshape(n_methods, -1) for p in parts], axis=1)
    if "path_delay_s" in parts[0]:
        for key in ("path_delay_s", "path_gain", "path_dir", "path_radius_m"):
            out[key] = np.concatenate([p[key] for p in parts])
    out["los"] = out["los"].astype(bool)
    out["first_kind"] = out["first_kind"].astype(str)
    return out


def _meta(
    facts: SceneFacts, scene_name: str, settings: MapSettings, band: Any, grid: MapGrid,
    n_workers: int, timing: dict[str, float], n_paths: int,
) -> dict[str, Any]:  # fmt: skip
    """The map's ``meta_json`` (docs/accuracy_map.md)."""
    from ...core.version import __version__

    return {
        "band": band.name,
        "frequency_hz": band.center_frequency_hz,
        "bandwidth_hz": band.bandwidth_hz,
        "receiver": settings.receiver,
        "step_m": settings.step_m,
        "height_m": float(grid.cell_xyz[0, 2]),
        "scene": scene_name,
        "scene_sha256": facts.sha256,
        "draws": settings.draws,
        "seed": settings.seed,
        "paths_per_link": stored_paths(settings),
        "noise_streams": "chunk c: ToaModel seed SeedSequence([seed, first cell of c]); "
        "epochs 0..draws-1",
        "chunk_links": settings.chunk_links,
        "clearance_m": settings.clearance_m,
        "service_area": grid.area_xy.tolist(),
        "grid": {
            "origin_xy": grid.origin_xy.tolist(),
            "step_m": grid.step_m,
            "shape": list(grid.shape),
            "cell_ij": "round((cell_xy - origin_xy) / step_m)",
        },
        "test_points": [
            {"name": n, "xyz": p.tolist(), "nearest_cell_m": float(d)}
            for n, p, d in zip(grid.test_names, grid.test_xyz, grid.test_distance_m)
        ],
        "positioning": "positioning.locate, 2D with the device height known, default parameters",
        "gdop": "horizontal, base stations the noiseless receiver detects (NaN below 3)",
        "trace": asdict(settings.trace),
        "version": __version__,
        "workers": n_workers if n_workers else "dask",
        "n_paths": int(n_paths),
        "timing_s": timing,
    }
