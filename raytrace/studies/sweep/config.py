"""A sweep's configuration: the cell parameters and their defaults, :class:`Cell` and
:class:`SweepConfig`, the config file's validation (every cell checked before any work), cell
keys.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hallray.errors import brief
from hallray.limits import check_size

from ...core.errors import HallrayError
from ...core.fileio import read_yaml
from ...emulation.receivers.receiver import DEFAULT_TOA_METHOD
from ...solver.config import TRACE_KEYS as TRACE_FIELDS
from ...solver.config import TraceConfig

#: Bumped when the pipeline's results change for the same parameters (old cell files are then
#: not reused: their keys differ).
PIPELINE_VERSION = 3
#: Characters of the parameter hash used as a cell key.
KEY_LENGTH = 16
#: Parameters of a cell and their defaults. ``None`` = the generator's own default.
HALL_KEYS: dict[str, Any] = {
    "profile": None,  # required
    "seed": 0,
    "size": None,
    "density": None,
    "clutter_size": None,
    "clutter_height": None,
    "height_spread": 0.0,
    "bs_height": None,
    "bs_spacing": 20.0,
    "bs_grid": None,
    "n_points": 50,
    "ut_height": 1.5,
}
#: The tracer's limits and switches, with their defaults: the fields of TraceConfig.
TRACE_KEYS: dict[str, Any] = {k: getattr(TraceConfig(), k) for k in TRACE_FIELDS}
TOA_KEYS: dict[str, Any] = {
    "band": "c-band",
    "toa_method": DEFAULT_TOA_METHOD,
    "noise": True,
    "duration_s": 1.0,
    "rate_hz": 10.0,
    # NLoS injection for stress tests: each received ToA gets, with this probability, an extra
    # path length uniform in [0.5, 1.5] * inject_nlos_bias_m
    "inject_nlos_fraction": 0.0,
    "inject_nlos_bias_m": 0.0,
    # positioning in 2D with the device height known ("known") or in 3D ("free")
    "height": "known",
}
CELL_KEYS: dict[str, Any] = {**HALL_KEYS, **TRACE_KEYS, **TOA_KEYS}
#: Files of a cell's ToA dataset (``datasets: true``), written to ``OUT/datasets/<key>/``.
DATASET_FILES = ("toa.csv", "meta.json")
#: Positioning methods of a sweep unless the config says otherwise (the paper's two).
DEFAULT_METHODS = ("ls", "irls")
_TOP_KEYS = (
    "name",
    "description",
    "grid",
    "fixed",
    "methods",
    "method_params",
    "output",
    "datasets",
)


def canonical(value: Any) -> Any:
    """JSON-stable form of a parameter value (what cell keys hash and sweep.json records):
    tuples -> lists, numpy scalars -> Python, mappings with string keys (sorted on dump)."""
    if isinstance(value, Mapping):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [canonical(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def cell_key(params: Mapping[str, Any], methods: Mapping[str, Mapping[str, Any]]) -> str:
    """Hash of everything that determines a cell's result (hex, :data:`KEY_LENGTH` chars)."""
    blob = json.dumps(
        {"v": PIPELINE_VERSION, "params": canonical(params), "methods": canonical(methods)},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(blob.encode("utf-8")).hexdigest()[:KEY_LENGTH]


@dataclass(frozen=True)
class Cell:
    """One point of the sweep grid.

    Attributes
    ----------
    index : int, position in grid order
    params : dict, every cell parameter (:data:`CELL_KEYS`), defaults filled in
    methods : dict, positioning method -> its parameters (validated, defaults filled in)
    key : str, :func:`cell_key` of params and methods
    """

    index: int
    params: dict[str, Any]
    methods: dict[str, dict[str, Any]]
    key: str
    datasets: bool = False

    def value(self, key: str) -> Any:
        """The cell's value of a grid key: a parameter, or ``<method>.<parameter>``."""
        if "." in key:
            m, p = key.split(".", 1)
            return self.methods[m][p]
        return self.params[key]

    def describe(self, keys: Sequence[str]) -> str:
        """``key=value, ...`` of the given grid keys (the cell's key if there are none)."""
        return ", ".join(f"{k}={self.value(k)}" for k in keys) or self.key

    def task(self) -> dict[str, Any]:
        """What a worker needs (plain data, picklable)."""
        return {
            "key": self.key,
            "params": self.params,
            "methods": self.methods,
            "datasets": self.datasets,
        }


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the grid, the fixed parameters and the positioning methods."""

    name: str
    grid: dict[str, list[Any]]
    fixed: dict[str, Any]
    methods: dict[str, dict[str, Any]]
    description: str = ""
    output: str | None = None
    source: str = ""
    datasets: bool = False

    def cells(self) -> list[Cell]:
        """Every combination of the grid values (the first grid key varies slowest)."""
        keys = list(self.grid)
        out = []
        for i, combo in enumerate(itertools.product(*(self.grid[k] for k in keys))):
            params = dict(CELL_KEYS)
            params.update(self.fixed)
            methods = {m: dict(p) for m, p in self.methods.items()}
            for k, v in zip(keys, combo):
                if "." in k:
                    m, p = k.split(".", 1)
                    methods[m][p] = v
                else:
                    params[k] = v
            methods = _resolve_methods(methods, self.source)
            params = canonical(params)
            out.append(Cell(i, params, methods, cell_key(params, methods), self.datasets))
        return out

    @property
    def varying(self) -> list[str]:
        """Grid keys with more than one value (the table's parameter columns)."""
        return [k for k, v in self.grid.items() if len(v) > 1]


def _fail(source: str, msg: str) -> None:
    raise HallrayError(f"{source}: {msg}" if source else msg)


def _resolve_methods(
    methods: Mapping[str, Mapping[str, Any]], source: str
) -> dict[str, dict[str, Any]]:
    from positioning import PositioningError
    from positioning import resolve_params as resolve_method

    out = {}
    for m, p in methods.items():
        try:
            out[m] = canonical(resolve_method(m, dict(p)))
        except PositioningError as exc:
            _fail(source, str(exc))
    return out


def _parse_methods(data: Mapping[str, Any], source: str) -> dict[str, dict[str, Any]]:
    """``methods`` and ``method_params``: method -> its fixed parameters (not yet resolved)."""
    from positioning import METHODS

    raw_methods = data.get("methods", list(DEFAULT_METHODS))
    if isinstance(raw_methods, str):
        raw_methods = [raw_methods]
    if not isinstance(raw_methods, list) or not raw_methods:
        _fail(source, f"methods: expected a non-empty list, got {brief(raw_methods)}")
    for m in raw_methods:
        if m not in METHODS:
            _fail(source, f"methods: unknown method {brief(m)} (known: {', '.join(METHODS)})")
    if len(set(raw_methods)) != len(raw_methods):
        _fail(source, "methods: listed twice")
    mparams = data.get("method_params") or {}
    if not isinstance(mparams, Mapping):
        _fail(source, "method_params: expected a mapping method -> {parameter: value}")
    for m, p in mparams.items():
        if m not in raw_methods:
            _fail(source, f"method_params: {brief(m)} is not in methods")
        if not isinstance(p, Mapping):
            _fail(source, f"method_params.{m}: expected a mapping")
    return {m: dict(mparams.get(m, {})) for m in raw_methods}


def _parse_grid_and_fixed(
    data: Mapping[str, Any], methods: Mapping[str, Any], source: str
) -> tuple[Mapping[str, Any], Mapping[str, Any]]:
    """``grid`` (parameter -> non-empty list of distinct values) and ``fixed`` (parameter ->
    value): known parameters (``<method>.<parameter>`` in grid), none in both, a profile."""
    grid = data.get("grid") or {}
    fixed = data.get("fixed") or {}
    if not isinstance(grid, Mapping) or not isinstance(fixed, Mapping):
        _fail(source, "grid and fixed must be mappings of parameter -> value(s)")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            _fail(source, f"grid.{k}: expected a non-empty list of values, got {brief(v)}")
        if len({json.dumps(canonical(x), sort_keys=True) for x in v}) != len(v):
            _fail(source, f"grid.{k}: a value is listed twice")
    for where, block in (("grid", grid), ("fixed", fixed)):
        for k in block:
            if "." in k and where == "grid":
                m, p = k.split(".", 1)
                if m not in methods:
                    _fail(source, f"grid.{k}: method {brief(m)} is not in methods")
                continue
            if k not in CELL_KEYS:
                _fail(
                    source,
                    f"{where}.{k}: unknown parameter (known: {', '.join(CELL_KEYS)}, or "
                    "<method>.<parameter> in grid)",
                )
    both = sorted(set(grid) & set(fixed))
    if both:
        _fail(source, f"{brief(both[0])} is in both grid and fixed")
    if "profile" not in grid and "profile" not in fixed:
        _fail(source, "give the profile (InF-SL, InF-DL, InF-SH, InF-DH) in grid or fixed")
    return grid, fixed


def _check_cells(cfg: SweepConfig) -> None:
    """Validate every cell (dry layout of its hall included); refuse identical cells."""
    seen: dict[str, int] = {}
    for cell in cfg.cells():
        try:
            validate_cell(cell.params)
        except HallrayError as exc:
            _fail(cfg.source, f"cell {cell.index} ({cell.describe(cfg.varying)}): {exc}")
        if cell.key in seen:
            _fail(cfg.source, f"cells {seen[cell.key]} and {cell.index} are identical")
        seen[cell.key] = cell.index


def parse_sweep_config(data: Any, *, source: str = "") -> SweepConfig:
    """Validate a sweep config given as a parsed YAML mapping (see ``docs/sweep.md``).

    Every cell is checked here (generator parameters, tracer limits, band, ToA method, positioning
    methods), so a bad cell fails before any work starts. Raises :class:`HallrayError` with a
    one-line message.
    """
    if not isinstance(data, Mapping):
        _fail(source, "a sweep config is a mapping with 'grid', 'fixed', 'methods', ...")
    for k in data:
        if k not in _TOP_KEYS:
            _fail(source, f"unknown key {brief(k)} (allowed: {', '.join(_TOP_KEYS)})")
    methods = _parse_methods(data, source)
    grid, fixed = _parse_grid_and_fixed(data, methods, source)
    name = data.get("name", Path(source).stem if source else "sweep")
    if not isinstance(name, str) or not name:
        _fail(source, f"name: expected a string, got {brief(name)}")
    output = data.get("output")
    if output is not None and not isinstance(output, str):
        _fail(source, f"output: expected a directory name, got {brief(output)}")
    datasets = data.get("datasets", False)
    if not isinstance(datasets, bool):
        _fail(source, f"datasets: expected true or false, got {brief(datasets)}")
    cfg = SweepConfig(
        name=name,
        grid={k: list(v) for k, v in grid.items()},
        fixed=dict(fixed),
        methods=methods,
        description=str(data.get("description", "")),
        output=output,
        source=source,
        datasets=datasets,
    )
    n_cells = float(np.prod([float(len(v)) for v in cfg.grid.values()]))
    check_size("sweep cells", n_cells, f"{source or 'sweep'}: the grid")  # before listing them
    _check_cells(cfg)
    return cfg


def load_sweep_config(source: str | os.PathLike[str] | Mapping[str, Any]) -> SweepConfig:
    """Read and validate a sweep config file (YAML) or mapping; see :func:`parse_sweep_config`."""

    if isinstance(source, Mapping):
        return parse_sweep_config(source)
    path = Path(source)
    return parse_sweep_config(read_yaml(path, "sweep config"), source=str(path))


def hall_kwargs(params: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`raytrace.halls.inf.generate_hall` in a cell's parameters
    (every hall key but the profile, size and seed, which it takes by position)."""
    return {k: params[k] for k in HALL_KEYS if k not in ("profile", "size", "seed")}


def n_epochs(params: Mapping[str, Any]) -> int:
    """Epochs of a cell: ``floor(duration_s * rate_hz)``, as the dataset writer counts them."""
    from ...scene.motion import snapshot_times

    return len(snapshot_times(params["duration_s"], params["rate_hz"]))


def validate_cell(params: Mapping[str, Any]) -> None:
    """Check one cell's parameters without running it (one-line :class:`HallrayError`)."""
    from ...emulation.bands import get_band
    from ...emulation.receivers.receiver import TOA_METHODS
    from ...halls.inf.generator import check_hall

    if params.get("profile") is None:
        raise HallrayError("no profile given")
    check_hall(params["profile"], params["size"], params["seed"], **hall_kwargs(params))
    TraceConfig.from_mapping(params)  # one-line TraceInputError for a bad limit
    get_band(params["band"])
    if params["toa_method"] not in TOA_METHODS:
        raise HallrayError(
            f"unknown toa_method {brief(params['toa_method'])} (known: {', '.join(TOA_METHODS)})"
        )
    if not isinstance(params["noise"], bool):
        raise HallrayError(f"noise must be true or false, got {brief(params['noise'])}")
    for k in ("duration_s", "rate_hz", "inject_nlos_fraction", "inject_nlos_bias_m"):
        v = params[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise HallrayError(f"{k} must be a finite number >= 0, got {brief(v)}")
    if params["duration_s"] <= 0 or params["rate_hz"] <= 0:
        raise HallrayError("duration_s and rate_hz must be > 0")
    n_epochs(params)  # at least one epoch
    if params["inject_nlos_fraction"] > 1:
        raise HallrayError(
            f"inject_nlos_fraction must be in [0, 1], got {brief(params['inject_nlos_fraction'])}"
        )
    if params["height"] not in ("known", "free"):
        raise HallrayError(f"height must be 'known' or 'free', got {brief(params['height'])}")
