"""The accuracy map of a hall: per grid cell, what the base stations' signals and a positioning
method give a device there, predicted by the twin.

A grid of cells covers the floor (the scene's floor outline inside its walls, else the hall size
of its metadata, else its bounding box), at device height, without the cells inside solids. The
grid's origin is shifted within one step so that every cell centre lies at least ``clearance_m``
(horizontally) from every test point of the scene's metadata: a map used as a fingerprint then
never contains the evaluation points themselves (:func:`grid_offset`).

Per cell and base station the map holds the line-of-sight flag, the first arrival's kind and
excess delay, the receiver's noiseless ToA and, over ``draws`` noise epochs of the one
measurement model (:class:`raytrace.emulation.measurement.ToaModel`), the ToA spread and the
detected fraction; per cell the GDOP of the TDoA fix and, per positioning method
(:func:`positioning.locate`, 2D with the device height known), the p90 and mean 2D error and
the share of draws with a fix. The result is a :class:`positioning.twin.fingerprint.FingerprintMap`
(schema ``hallray-accuracy-map`` v1), written only through :func:`positioning.twin.fingerprint.write_map`.

Work is split into chunks of cells (:func:`raytrace.solver.parallel.receiver_chunks`); each chunk
is traced, measured and positioned on its own, in this process or on worker processes
(:class:`raytrace.solver.parallel.ScenePool`), so memory is bounded by one chunk. A chunk's noise
streams come from ``SeedSequence([seed, first cell of the chunk])``: the map depends on the seed
and the chunk size, not on the number of workers. See docs/accuracy_map.md.

Modules: :mod:`.settings` (:class:`MapSettings`), :mod:`.grid` (the cells), :mod:`.cells`
(per-cell quantities of a chunk), :mod:`.compute` (:func:`compute_map`), :mod:`.files` (the map's
files and pictures).
"""

from .cells import (
    chunk_seed,
    gdop_2d,
    last_segment_dirs,
    measure_cells,
    path_table,
    receiver_model_meta,
    stored_paths,
    wave_radius,
)
from .compute import AccuracyMap, compute_map
from .files import (
    CSV_SCHEMA,
    CSV_VERSION,
    ERR_FLOOR_M,
    PICTURES,
    check_output,
    csv_columns,
    map_csv,
    map_csv_meta,
    map_pictures,
    write_outputs,
)
from .grid import MapGrid, area_polygon, device_height, grid_offset, lattice_distance, make_grid
from .settings import (
    DEFAULT_CLEARANCE_M,
    DEFAULT_DRAWS,
    DEFAULT_METHODS,
    DEFAULT_PATHS,
    DEFAULT_SEED,
    DEFAULT_STEP_M,
    FALLBACK_HEIGHT_M,
    MAX_CELLS,
    MAX_CHUNK_LINKS,
    OFFSET_CANDIDATES,
    MapSettings,
)

__all__ = [
    "CSV_SCHEMA",
    "CSV_VERSION",
    "DEFAULT_CLEARANCE_M",
    "DEFAULT_DRAWS",
    "DEFAULT_METHODS",
    "DEFAULT_PATHS",
    "DEFAULT_SEED",
    "DEFAULT_STEP_M",
    "ERR_FLOOR_M",
    "FALLBACK_HEIGHT_M",
    "MAX_CELLS",
    "MAX_CHUNK_LINKS",
    "OFFSET_CANDIDATES",
    "PICTURES",
    "AccuracyMap",
    "MapGrid",
    "MapSettings",
    "area_polygon",
    "check_output",
    "chunk_seed",
    "compute_map",
    "csv_columns",
    "device_height",
    "gdop_2d",
    "grid_offset",
    "last_segment_dirs",
    "lattice_distance",
    "make_grid",
    "map_csv",
    "map_csv_meta",
    "map_pictures",
    "measure_cells",
    "path_table",
    "receiver_model_meta",
    "stored_paths",
    "wave_radius",
    "write_outputs",
]
