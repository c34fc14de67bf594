"""The files of one dataset: ``toa.csv`` (streamed in blocks), ``meta.json`` and, for the
semi-dynamic scenario, ``forklifts.csv``; :func:`write_dataset` writes them from measurements
already made (schema in docs/dataset.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hallray.safe_output import output_dir

from ...core.errors import HallrayError
from ...scene.facts import SceneFacts
from ...scene.metadata import SceneMetadata
from ...scene.model import Scene
from ...solver.incremental import Fleet
from ..bands import Band
from ..measurement import Measurements
from ..receivers.paper import CLIMB_STEP_T, MAX_CLIMB_T, POWER_FLOOR_DB, TOP_TOL_T
from ..receivers.receiver import CFR_METHODS
from .config import COLUMNS, SCHEMA_VERSION, DatasetConfig

#: The name a dataset directory's marker records (:func:`hallray.safe_output.write_marker`).
DATASET_COMMAND = "make-dataset"


def _num(values: np.ndarray, fmt: str) -> list[str]:
    """CSV texts of floats in ``fmt``: empty for NaN."""
    return [format(v, fmt) if math.isfinite(v) else "" for v in values.ravel().tolist()]


def _toa_csv(inputs: SceneMetadata, times_s: np.ndarray, m: Measurements) -> str:
    """``toa.csv``: header and one row per (epoch, point, base station), in that order.

    Floats are written with ``repr`` (shortest round trip), SNR and lobe figures with fixed
    decimals; an undetected link has an empty ``toa_s``.
    """
    return "".join(_toa_csv_blocks(inputs, times_s, m))


#: Epochs formatted per block of ``toa.csv`` text (memory: one block, not the whole file).
CSV_BLOCK_EPOCHS = 100


def _toa_csv_blocks(inputs: SceneMetadata, times_s: np.ndarray, m: Measurements) -> Iterator[str]:
    """The text of ``toa.csv`` (:func:`_toa_csv`) in blocks of :data:`CSV_BLOCK_EPOCHS` epochs,
    so that a writer streams it."""
    yield ",".join(COLUMNS) + "\n"
    yield from _toa_rows(inputs, times_s, m)


def _toa_rows(inputs: SceneMetadata, times_s: np.ndarray, m: Measurements) -> Iterator[str]:
    """The rows of ``toa.csv`` for the epochs of ``m`` (any consecutive epochs: a dataset
    streamed chunk by chunk gives the bytes of the whole), in blocks of
    :data:`CSV_BLOCK_EPOCHS` epochs."""
    n_e, n_p, n_b = m.toa_s.shape
    # the texts of what repeats (per point, base station, link), then one join a row
    point_xyz = [",".join(map(repr, p)) for p in inputs.point_xyz.tolist()]
    dist = np.linalg.norm(inputs.bs_xyz[None, :, :] - inputs.point_xyz[:, None, :], axis=2)
    dist_txt = [[repr(d) for d in row] for row in dist.tolist()]
    tx_txt = [repr(t) for t in m.tx_offset_s.tolist()]
    for e0 in range(0, n_e, CSV_BLOCK_EPOCHS):
        sl = slice(e0, min(n_e, e0 + CSV_BLOCK_EPOCHS))
        ep = m.epochs[sl]
        epoch = [f"{e},{t!r}" for e, t in zip(ep.tolist(), times_s[ep].tolist())]
        clock_txt = [[repr(c) for c in row] for row in m.clock_offset_s[sl].tolist()]
        det = m.detected[sl].ravel().tolist()
        toa = [repr(t) if d else "" for t, d in zip(m.toa_s[sl].ravel().tolist(), det)]
        los = m.los[sl].ravel().astype(np.int64).tolist()
        snr, ratio = _num(m.snr_db[sl], ".3f"), _num(m.peak_ratio_db[sl], ".3f")
        width = _num(m.lobe_width[sl], ".4f")
        first, lobe = m.first_kind[sl].ravel().tolist(), m.lobe_kind[sl].ravel().tolist()
        lines = []
        i = 0
        for e in range(len(epoch)):  # formatting only; the numbers are in the arrays
            for p in range(n_p):
                for b in range(n_b):
                    lines.append(
                        f"{epoch[e]},{inputs.point_names[p]},{inputs.bs_names[b]},{toa[i]},"
                        f"{point_xyz[p]},{dist_txt[p][b]},{los[i]},{first[i]},{snr[i]},"
                        f"{ratio[i]},{width[i]},{lobe[i]},{tx_txt[b]},{clock_txt[e][p]}\n"
                    )
                    i += 1
        yield "".join(lines)


def dataset_summary(m: Measurements | np.ndarray) -> dict[str, Any]:
    """``meta.json`` ``summary``: rows and the detected / LoS / first-path LoS fractions, of
    measurements or of their summed :meth:`Measurements.counts`."""
    counts = m if isinstance(m, np.ndarray) else m.counts()
    rows, det, los, first_los = (int(v) for v in counts)
    return {
        "rows": rows,
        "detected_fraction": det / rows if rows else 0.0,
        "los_fraction": los / rows if rows else 0.0,
        "first_path_los_fraction": first_los / rows if rows else 0.0,
    }


def _obstacles_2d(meta: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The scene's obstacle footprints, each with a ``polygon`` [[x, y], ...] (the positioning
    package's plots read that key) besides the scene metadata's own ``xy``."""
    out = []
    for o in meta.get("obstacles_2d") or []:
        if isinstance(o, Mapping) and "xy" in o:
            out.append({**o, "polygon": o["xy"]})
    return out


def _meta(
    cfg: DatasetConfig,
    band: Band,
    facts: SceneFacts,
    inputs: SceneMetadata,
    m: Measurements | MeasuredSoFar,
    scene_name: str,
) -> dict[str, Any]:
    """``meta.json``: every parameter that produced the dataset (schema in docs/dataset.md)."""
    from ...core.version import __version__

    routes = (
        [dataclasses.asdict(r) for r in inputs.routes] if cfg.scenario == "semi-dynamic" else []
    )
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario": cfg.scenario,
        "band": band.name,
        "band_parameters": {
            "center_frequency_hz": band.center_frequency_hz,
            "bandwidth_hz": band.bandwidth_hz,
            "subcarrier_spacing_hz": band.subcarrier_spacing_hz,
        },
        "seed": int(cfg.seed),
        "version": __version__,
        "scene": scene_name,
        "scene_sha256": facts.sha256,
        "duration_s": float(cfg.duration_s),
        "rate_hz": float(cfg.rate_hz),
        "n_epochs": int(m.n_epochs) if isinstance(m, MeasuredSoFar) else len(m.epochs),
        "epoch_time_s": "epoch / rate_hz",
        "toa_method": cfg.toa_method,
        "noise": bool(cfg.noise),
        "delta_s": float(cfg.delta_s),
        "schedule_s": {n: float(o) for n, o in zip(inputs.bs_names, m.tx_offset_s)},
        "clock_offset": {
            "distribution": "uniform",
            "low_s": 0.0,
            "high_s": float(cfg.clock_offset_max_s),
            "per": "epoch and point",
        },
        "random_streams": "numpy SeedSequence([seed, epoch]).spawn(2): clock offsets, noise",
        "toa_model": "toa_s = tx_offset_s + clock_offset_s + estimated propagation delay",
        "link_budget": dataclasses.asdict(cfg.budget),
        "pulse": dataclasses.asdict(cfg.pulse),
        "first_lobe": dataclasses.asdict(cfg.first_lobe),
        **_receiver_settings(cfg),
        "trace": dataclasses.asdict(cfg.trace),
        **_receiver_meta(cfg),
        "forklifts": {"clearance_m": float(cfg.clearance_m), "routes": routes},
        "base_stations": [
            {"name": n, "xyz": [float(v) for v in p]}
            for n, p in zip(inputs.bs_names, inputs.bs_xyz)
        ],
        "points": [
            {"name": n, "xyz": [float(v) for v in p]}
            for n, p in zip(inputs.point_names, inputs.point_xyz)
        ],
        "hall_xy": facts.hall_xy,
        "service_area": facts.service_area,
        "area_of_interest": inputs.block.get("area_of_interest"),
        "obstacles_2d": _obstacles_2d(inputs.block),
        "columns": list(COLUMNS),
        "summary": dataset_summary(m.counts()),
    }


def _receiver_settings(cfg: DatasetConfig) -> dict[str, Any]:
    """``meta.json`` ``receiver_settings`` of a receiver on the PRS CFR (comb, timing offsets,
    its own settings); the other receivers' settings are the ``first_lobe`` and ``link_budget``
    entries, as before."""
    if cfg.toa_method not in CFR_METHODS:
        return {}
    return {"receiver_settings": cfg.receiver().settings_meta()}
def _receiver_meta(cfg: DatasetConfig) -> dict[str, Any]:
    """``meta.json`` keys of the receivers with their own settings: ``paper`` (its power floor
    and climb, eq. 3's SNR and t_s) and ``first-path`` with its detection threshold off."""
    if cfg.toa_method == "paper":
        return {
            "paper": {
                "first_arrival": "earliest traced path with power gain >= power_floor_db",
                "power_floor_db": POWER_FLOOR_DB,
                "toa": "top of the lobe of |sum_j gain_j h(t - delay_j)| holding the first "
                "arrival (h: the pulse, untruncated) + eq. 3 noise",
                "eq3_snr": "first arrival's P_rx / N (link_budget), before processing gain",
                "eq3_t_s": "link_budget.n_symbols / subcarrier_spacing_hz",
                "climb_step_t": CLIMB_STEP_T,
                "max_climb_t": MAX_CLIMB_T,
                "top_tolerance_t": TOP_TOL_T,
            }
        }
    if cfg.toa_method == "first-path" and not cfg.first_path_threshold:
        return {"first_path": {"detection_threshold": False}}
    return {}
@dataclass
class MeasuredSoFar:
    """What ``meta.json`` needs of a dataset's measurements streamed to disk: the epochs written,
    the schedule and the summed :meth:`Measurements.counts`."""

    n_epochs: int = 0
    tx_offset_s: np.ndarray | None = None
    counted: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(4, dtype=np.int64))

    def counts(self) -> np.ndarray:
        return self.counted


class DatasetStream:
    """One dataset written while its epochs are measured: ``toa.csv`` grows chunk by chunk
    (:meth:`add`, epochs in order), ``meta.json`` and ``forklifts.csv`` are written at the end
    (:meth:`close`). Memory stays that of one chunk however long the dataset; the bytes are those
    of :func:`dataset_files` for the same measurements.

    Parameters
    ----------
    directory : Path, the dataset's directory (created), inside a staged output
    scene, cfg, inputs, facts, fleet : as in :func:`dataset_parts`
    """

    def __init__(self, directory: Path, scene: Scene, cfg: DatasetConfig, *,
                 inputs: SceneMetadata, facts: SceneFacts, fleet: Fleet | None) -> None:  # fmt: skip
        self.band = cfg.validate()
        if (cfg.scenario == "semi-dynamic") != (fleet is not None):
            raise HallrayError("a semi-dynamic dataset needs its forklift fleet, a static one none")
        self.directory, self.scene, self.cfg = directory, scene, cfg
        self.inputs, self.facts, self.fleet = inputs, facts, fleet
        self.times = cfg.times_s
        self.so_far = MeasuredSoFar()
        directory.mkdir(exist_ok=True)
        self._fh = (directory / "toa.csv").open("w", encoding="utf-8", newline="")
        self._fh.write(",".join(COLUMNS) + "\n")

    def add(self, m: Measurements) -> None:
        """Write the rows of the next consecutive epochs."""
        shape = (len(self.inputs.point_names), len(self.inputs.bs_names))
        first = self.so_far.n_epochs
        if m.toa_s.shape[1:] != shape or not np.array_equal(
            m.epochs, np.arange(first, first + len(m.epochs))
        ):
            raise HallrayError("a dataset's measurements are streamed in epoch order, whole")
        for block in _toa_rows(self.inputs, self.times, m):
            self._fh.write(block)
        self.so_far.n_epochs += len(m.epochs)
        self.so_far.tx_offset_s = m.tx_offset_s
        self.so_far.counted += m.counts()

    def close(self) -> dict[str, Any]:
        """Finish ``toa.csv``, write ``meta.json`` (and ``forklifts.csv``); the summary."""
        self._fh.close()
        if self.so_far.n_epochs != len(self.times):
            raise HallrayError(
                f"a dataset streamed {self.so_far.n_epochs} of its {len(self.times)} epochs"
            )
        meta = _meta(self.cfg, self.band, self.facts, self.inputs, self.so_far,
                     _scene_name(self.scene))  # fmt: skip
        files = {"meta.json": json.dumps(meta, indent=1, sort_keys=False) + "\n"}
        if self.fleet is not None:
            files["forklifts.csv"] = _forklift_csv(self.fleet, self.times)
        write_files(self.directory, files)
        return dataset_summary(self.so_far.counts())

    def abort(self) -> None:
        """Close the file after an error (the staged output is removed by its owner)."""
        self._fh.close()


def _forklift_csv(fleet: Fleet, times: np.ndarray) -> str:
    lines = ["epoch,time_s,forklift,x,y,z,heading_rad\n"]
    for e, t in enumerate(times):
        centre, yaw = fleet.poses(float(t))
        for name, c, h in zip(fleet.names, centre, yaw):
            lines.append(
                f"{e},{float(t)!r},{name},{float(c[0])!r},{float(c[1])!r},{float(c[2])!r},"
                f"{float(h)!r}\n"
            )
    return "".join(lines)


def _scene_name(scene: Scene) -> str:
    """``meta.json`` ``scene``: the scene file's name."""
    return Path(scene.source).name or "scene"


def dataset_files(
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    inputs: SceneMetadata | None = None,
    fleet: Fleet | None = None,
) -> dict[str, str]:
    """The files of one dataset: file name -> text.

    Parameters
    ----------
    scene : Scene, with base stations and points in its metadata (their order is the rows')
    cfg : DatasetConfig
    measured : Measurements of every epoch of ``cfg`` (0 .. n - 1, in order), made by
        ``cfg.model()`` on the scene's paths: (n_epochs, points, base stations)
    inputs : SceneMetadata of the scene, optional (read from the scene otherwise)
    fleet : Fleet, the forklifts (semi-dynamic only: ``forklifts.csv``)

    Returns
    -------
    dict: ``toa.csv``, ``meta.json`` and, for semi-dynamic, ``forklifts.csv``
    """
    parts = dataset_parts(scene, cfg, measured, inputs=inputs, fleet=fleet)
    return {k: v if isinstance(v, str) else "".join(v) for k, v in parts.items()}


def dataset_parts(
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    inputs: SceneMetadata | None = None,
    fleet: Fleet | None = None,
    facts: SceneFacts | None = None,
) -> dict[str, str | Iterable[str]]:
    """:func:`dataset_files` with ``toa.csv`` as an iterable of text blocks (streamed);
    ``facts``: the scene's, when the caller has read them."""
    band = cfg.validate()
    inputs = inputs if inputs is not None else SceneMetadata.from_scene(scene, require=True)
    facts = facts if facts is not None else SceneFacts.of(scene, inputs.block)
    times = cfg.times_s
    shape = (len(times), len(inputs.point_names), len(inputs.bs_names))
    if measured.toa_s.shape != shape:
        raise HallrayError(
            f"measurements of shape {measured.toa_s.shape} do not fit the dataset's "
            f"(epochs, points, base stations) = {shape}"
        )
    if not np.array_equal(measured.epochs, np.arange(len(times))):
        raise HallrayError("a dataset's measurements are of its epochs 0 .. n - 1, in order")
    if (cfg.scenario == "semi-dynamic") != (fleet is not None):
        raise HallrayError("a semi-dynamic dataset needs its forklift fleet, a static one none")
    meta = _meta(cfg, band, facts, inputs, measured, _scene_name(scene))
    files = {
        "toa.csv": _toa_csv_blocks(inputs, times, measured),
        "meta.json": json.dumps(meta, indent=1, sort_keys=False) + "\n",
    }
    if fleet is not None:
        files["forklifts.csv"] = _forklift_csv(fleet, times)
    return files


def write_files(directory: Path, files: Mapping[str, str | Iterable[str]]) -> None:
    """Write each file's text (or text blocks, streamed) into ``directory``, inside a staged
    directory (whole or not at all)."""
    directory.mkdir(exist_ok=True)
    for name, text in files.items():
        with (directory / name).open("w", encoding="utf-8", newline="") as fh:
            for block in [text] if isinstance(text, str) else text:
                fh.write(block)


def write_dataset(
    out_dir: str | os.PathLike[str],
    scene: Scene,
    cfg: DatasetConfig,
    measured: Measurements,
    *,
    fleet: Fleet | None = None,
    force: bool = False,
) -> Path:
    """Write one dataset from measurements already made (:func:`dataset_files`) to ``out_dir``.

    The files are those :func:`make_dataset` writes for the same scene and configuration (the
    same formatting code). Written to a temporary directory beside ``out_dir`` and renamed when
    complete; ``force`` replaces a non-empty ``out_dir``.

    Returns
    -------
    Path, the dataset directory
    """
    files = dataset_files(scene, cfg, measured, fleet=fleet)
    out = Path(out_dir)
    with output_dir(out, command=DATASET_COMMAND, force=force) as tmp:
        write_files(tmp, files)
    return out
