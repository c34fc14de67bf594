"""Parameter sweeps of the whole pipeline over synthetic InF halls, locally or on a Dask cluster.

A sweep is a grid of *cells*; every cell runs::

    InF hall (raytrace.halls.inf)  ->  trace  ->  ToA per epoch (the measurement model of
    raytrace.emulation.measurement: schedule + device clock offset + the receiver's estimate)
    ->  positioning of every fix with every method (positioning.locate)  ->  errors and counts

and returns one small result (a JSON-able dict). Results are written one file per cell,
``OUT/cells/<key>.json``, atomically, where ``key`` is a hash of every parameter of the cell
(and :data:`PIPELINE_VERSION`): a rerun skips the cells whose file exists, so an interrupted sweep
resumes where it stopped. At the end (and on a partial run, over the finished cells)
``OUT/results.csv`` and ``OUT/results.md`` collect one row per cell: the parameters that vary, the
LoS and detected fractions, the mean and 90th-percentile 2D error of each method, timings.

Execution: in this process (``workers=1``), on a local process pool, or on a Dask distributed
cluster (``scheduler=ADDRESS``; needs ``dask[distributed]``, the optional extra ``cluster``). The
cells are independent and return their results to the driver, which writes the files: the
workers need hallray installed, not a shared file system.

The config format is in ``docs/sweep.md`` (example ``docs/sweep_example.yaml``).

Modules: :mod:`.config` (parameters, cells, the config file), :mod:`.cell` (one cell's pipeline),
:mod:`.files` (cell files and results tables), :mod:`.run` (:func:`run_sweep`); the Dask
connection is :mod:`raytrace.studies.cluster`.
"""

from ..cluster import (
    CONNECT_TIMEOUT_S,
    MMAP_THRESHOLD_BYTES,
    TRIM_THRESHOLD_BYTES,
    tune_malloc,
)
from .cell import (
    NLOS_STREAM,
    CellData,
    CellHall,
    cell_dataset_config,
    cell_hall,
    inject_nlos,
    run_cell,
    simulate_cell,
)
from .config import (
    CELL_KEYS,
    DATASET_FILES,
    DEFAULT_METHODS,
    HALL_KEYS,
    KEY_LENGTH,
    PIPELINE_VERSION,
    TOA_KEYS,
    TRACE_KEYS,
    Cell,
    SweepConfig,
    cell_key,
    load_sweep_config,
    n_epochs,
    parse_sweep_config,
    validate_cell,
)
from .files import (
    cell_path,
    dataset_dir,
    read_cell_result,
    results_table_csv,
    results_table_markdown,
    table_rows,
    write_cell_result,
    write_tables,
)
from .run import SweepReport, default_output, run_sweep

__all__ = [
    "CELL_KEYS",
    "CONNECT_TIMEOUT_S",
    "DATASET_FILES",
    "DEFAULT_METHODS",
    "HALL_KEYS",
    "KEY_LENGTH",
    "MMAP_THRESHOLD_BYTES",
    "NLOS_STREAM",
    "PIPELINE_VERSION",
    "TOA_KEYS",
    "TRACE_KEYS",
    "TRIM_THRESHOLD_BYTES",
    "Cell",
    "CellData",
    "CellHall",
    "SweepConfig",
    "SweepReport",
    "cell_dataset_config",
    "cell_hall",
    "cell_key",
    "cell_path",
    "dataset_dir",
    "default_output",
    "inject_nlos",
    "load_sweep_config",
    "n_epochs",
    "parse_sweep_config",
    "read_cell_result",
    "results_table_csv",
    "results_table_markdown",
    "run_cell",
    "run_sweep",
    "simulate_cell",
    "table_rows",
    "tune_malloc",
    "validate_cell",
    "write_cell_result",
    "write_tables",
]
