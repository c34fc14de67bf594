"""The datasets of a scene: :func:`make_datasets` traces it once per snapshot for all bands
and receivers of a scenario, measures every epoch and writes each dataset's files, staged
(no half-written output).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterable, Sequence
from contextlib import nullcontext
from pathlib import Path
from typing import Any

from hallray.limits import check_size
from hallray.safe_output import output_dir

from ...core.errors import HallrayError, SceneError
from ...scene.facts import SceneFacts
from ...scene.io import load_scene
from ...scene.metadata import SceneMetadata
from ...scene.model import Scene
from ...solver.config import TraceConfig
from ...solver.paths import Paths
from ..bands import get_band
from ..channel.budget import LinkBudget
from ..channel.cfr import PrsSettings
from ..measurement import Measurements
from ..receivers.first_lobe import FirstLobeSettings
from ..receivers.receiver import DEFAULT_TOA_METHOD
from .config import SCENARIOS, DatasetConfig
from .epochs import ScenarioGroup, measure_group, scenario_group
from .files import DATASET_COMMAND, DatasetStream


def _dataset_configs(
    datasets: Iterable[tuple[str, str]],
    methods: Sequence[str],
    **settings: Any,
) -> list[DatasetConfig]:
    """One config per requested (scenario, band, receiver), in request order, duplicates
    dropped; each validated (one-line :class:`HallrayError`)."""
    triples = list(dict.fromkeys((str(s), str(b), m) for s, b in datasets for m in methods))
    if not triples:
        raise HallrayError("no dataset requested")
    configs = [
        DatasetConfig(s, b, toa_method=m, **settings)  # type: ignore[arg-type]
        for s, b, m in triples
    ]
    for c in configs:
        c.validate()
    return configs


def _open_scene(scene: str | os.PathLike[str] | Scene) -> Scene:
    return scene if isinstance(scene, Scene) else load_scene(scene)


def _measure_with_progress(
    g: ScenarioGroup, workers: int, progress: bool, sink: Any = None
) -> tuple[list[Measurements], dict]:
    """:func:`measure_group` (its chunks to ``sink``), with a tqdm bar on stderr if
    ``progress``."""
    if not progress:
        return measure_group(g, workers, None, sink)
    from tqdm import tqdm

    names = ", ".join(dict.fromkeys(m.receiver.band.name for m in g.models))
    with tqdm(
        total=len(g.times_s), desc=f"{g.scenario} ({names})", unit="epoch", file=sys.stderr
    ) as bar:
        return measure_group(g, workers, bar.update, sink)


def _write_group(
    g: ScenarioGroup,
    configs: Sequence[DatasetConfig],
    scene: tuple[Scene, SceneMetadata, SceneFacts],
    tmp: Path,
    out: Path,
    subdirectories: bool,
    first_method: str,
    workers: int,
    progress: bool,
) -> list[dict[str, Any]]:
    """Measure a scenario's datasets (``configs``, the group's order) and write each into its
    directory under ``tmp`` (``out`` once committed); their summaries."""
    t_static = g.trace_s
    fleet = g.tracer.fleet if g.scenario == "semi-dynamic" else None
    sc, inputs, facts = scene
    dirs = []
    for cfg in configs:
        name = f"{cfg.scenario}-{get_band(cfg.band).name}"
        if cfg.toa_method != first_method:
            name += f"-{cfg.toa_method}"
        dirs.append(tmp / name if subdirectories else tmp)
    # each dataset's toa.csv is written while its epochs are measured: memory does not grow
    # with the epochs (the bytes are those of dataset_parts on all the measurements)
    streams = [DatasetStream(d, sc, cfg, inputs=inputs, facts=facts, fleet=fleet)
               for d, cfg in zip(dirs, configs)]  # fmt: skip
    try:
        _, stats = _measure_with_progress(
            g, workers, progress, lambda ms: [s.add(m) for s, m in zip(streams, ms)]
        )
        counts = [s.close() for s in streams]
    finally:
        for s in streams:
            s.abort()
    summaries = []
    for cfg, d, count in zip(configs, dirs, counts):
        summaries.append(
            {
                "directory": str(out / d.relative_to(tmp)),
                "scenario": cfg.scenario,
                "band": get_band(cfg.band).name,
                "toa_method": cfg.toa_method,
                "epochs": len(g.times_s),
                **count,
                "static_trace_s": t_static,
                "group_seconds": time.perf_counter() - g.t_start,
                "stage_seconds": stats,
            }
        )
    return summaries


def make_datasets(
    out_dir: str | os.PathLike[str],
    datasets: Iterable[tuple[str, str]],
    *,
    scene: str | os.PathLike[str] | Scene = "hall",
    duration_s: float = 60.0,
    rate_hz: float = 10.0,
    seed: int = 1,
    toa_method: str | Sequence[str] = DEFAULT_TOA_METHOD,
    noise: bool = True,
    workers: int = 1,
    force: bool = False,
    progress: bool = False,
    budget: LinkBudget | None = None,
    first_lobe: FirstLobeSettings | None = None,
    prs: PrsSettings | None = None,
    first_path_threshold: bool = True,
    trace_settings: TraceConfig | None = None,
    subdirectories: bool = True,
    staging: bool = True,
) -> list[dict[str, Any]]:
    """Write several ToA datasets, sharing the traces between them.

    All datasets of one scenario are computed in one pass over the epochs (one geometric trace
    per snapshot for all bands). Everything is written to a temporary directory beside
    ``out_dir`` and renamed to ``out_dir`` only when complete.

    Parameters
    ----------
    out_dir : path, the output directory (must not exist or be empty, unless ``force``)
    datasets : (scenario, band) pairs
    scene : scene file, bundled name or Scene; must carry base stations and points (and routes
        for semi-dynamic) in its ``metadata["hallray"]``
    duration_s, rate_hz, seed, noise : see :class:`DatasetConfig`
    toa_method : str or sequence of str, the receiver (:class:`DatasetConfig`); with several, each
        (scenario, band) is written for each receiver from the same traces, the first receiver's
        in ``<scenario>-<band>``, the others' in ``<scenario>-<band>-<receiver>``
    workers : int, processes for the snapshots (the files do not depend on it)
    force : bool, replace a non-empty ``out_dir``
    progress : bool, tqdm progress bars on stderr
    budget : LinkBudget, optional
    first_lobe : FirstLobeSettings, optional, settings of the first-lobe receiver
    prs : PrsSettings, optional, the PRS CFR of the receivers on it (comb, timing offsets)
    first_path_threshold : bool, ``first-path``: False takes the first traced path above the
        tracer's power floor, not the first detectable one
    trace_settings : TraceConfig, optional, the tracer limits
    subdirectories : bool, each dataset in ``out_dir/<scenario>-<band>`` (True) or, for a
        single dataset, directly in ``out_dir``
    staging : bool, build in a temporary directory and rename it (True), or write straight into
        ``out_dir``, an empty directory the caller stages itself (False: the command-line tools,
        through :mod:`hallray.safe_output`)

    Returns
    -------
    list of dict, one summary per dataset (directory, rows, fractions, timings)
    """
    methods = [toa_method] if isinstance(toa_method, str) else list(dict.fromkeys(toa_method))
    if not methods:
        raise HallrayError("no ToA receiver requested")
    configs = _dataset_configs(
        datasets, methods, duration_s=duration_s, rate_hz=rate_hz, seed=seed, noise=noise,
        budget=budget or LinkBudget(), first_lobe=first_lobe or FirstLobeSettings(),
        prs=prs or PrsSettings(), first_path_threshold=first_path_threshold,
        trace=trace_settings or TraceConfig(),
    )  # fmt: skip
    if not subdirectories and len(configs) != 1:
        raise HallrayError("several datasets need subdirectories")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise HallrayError(f"workers must be an integer >= 1, got {workers!r}")
    t_start = time.perf_counter()
    sc = _open_scene(scene)
    inputs = SceneMetadata.from_scene(sc, require=True)
    facts = SceneFacts.of(sc, inputs.block)  # read once for every dataset's meta.json
    if any(c.scenario == "semi-dynamic" for c in configs) and not inputs.routes:
        raise SceneError("the semi-dynamic scenario needs forklift routes in the scene metadata")
    rows = float(len(configs[0].times_s)) * len(inputs.point_names) * len(inputs.bs_names)
    check_size("dataset rows", rows, f"{len(configs[0].times_s)} epochs x "
               f"{len(inputs.point_names)} points x {len(inputs.bs_names)} base stations")  # fmt: skip
    out = Path(out_dir)
    if not staging and (not out.is_dir() or any(out.iterdir())):
        raise HallrayError(f"unstaged output {out} must be an empty directory")
    summaries: list[dict[str, Any]] = []
    # the static scene's paths per carrier, traced once for both scenarios
    static_cache: dict[float, Paths] = {}
    source = None if isinstance(scene, Scene) else scene
    # staged: the one output layer (whole or nothing, inputs untouched, only an earlier dataset
    # replaced, with force); unstaged: the caller's empty staging directory
    with output_dir(out, command=DATASET_COMMAND, force=force, inputs=[source]) if staging \
            else nullcontext(out) as tmp:  # fmt: skip
        for scenario in SCENARIOS:
            group = [c for c in configs if c.scenario == scenario]
            if group:
                g = scenario_group(scenario, group, sc, inputs, static_cache)
                summaries += _write_group(g, group, (sc, inputs, facts), tmp, out,
                                          subdirectories, methods[0], workers, progress)  # fmt: skip
    for s in summaries:
        s["total_seconds"] = time.perf_counter() - t_start
    return summaries


def make_dataset(
    out_dir: str | os.PathLike[str],
    scenario: str,
    band: str,
    **kwargs: Any,
) -> dict[str, Any]:
    """Write one ToA dataset (``toa.csv``, ``meta.json``) to ``out_dir``.

    Keyword arguments are those of :func:`make_datasets` (scene, duration_s, rate_hz, seed,
    toa_method, noise, workers, force, progress, budget, trace_settings).

    Returns
    -------
    dict, the dataset's summary: directory, epochs, rows, detected / LoS fractions, timings
    """
    return make_datasets(out_dir, [(scenario, band)], subdirectories=False, **kwargs)[0]
