"""ToA datasets: the paper's static and semi-dynamic scenarios in both bands.

A dataset directory holds ``toa.csv`` (one row per epoch, point and base station) and
``meta.json`` (every parameter that produced it); the schema is in ``docs/dataset.md`` and is
read by :mod:`positioning.io.dataset`. For the semi-dynamic scenario it also holds
``forklifts.csv`` (the forklift poses of every epoch).

Measurements: :mod:`raytrace.emulation.measurement` (base station k transmits at ``k * delta``,
one device clock offset per epoch and point, the receiver's estimated delay)::

    toa_s = tx_offset_s + clock_offset_s + estimated propagation delay

Epochs: one per snapshot of the forklifts (``k / rate`` s, k = 0 .. duration * rate - 1) for
``semi-dynamic``; for ``static`` the scene never changes, so it is traced once and every epoch
draws its own clock offsets and estimation noise (the same number of epochs, so that the
statistics are comparable).

Reproducibility: the random numbers of epoch ``e`` come from
``numpy.random.SeedSequence([seed, e]).spawn(2)`` (clock offsets, then estimator noise;
:func:`raytrace.emulation.measurement.epoch_rngs`), so the files depend only on the inputs and the
seed, not on the number of worker processes.

Two ways in: :func:`make_datasets` traces a scene and writes its datasets;
:func:`write_dataset` (and :func:`dataset_files`) writes a dataset from measurements already made
with :meth:`DatasetConfig.model` (a sweep cell does this with the ToAs it positions). Both format
the files with the same code, so the two give the same bytes for the same inputs.

Modules: :mod:`.config` (the scenarios, bands, columns and :class:`DatasetConfig`), :mod:`.files`
(the files of one dataset, built whole through :mod:`hallray.safe_output`), :mod:`.epochs`
(the epochs of one scenario, in this process or in workers), :mod:`.make` (:func:`make_datasets`).
"""

from ...scene.facts import service_area
from .config import ALL_DATASETS, COLUMNS, PAPER_BANDS, SCENARIOS, SCHEMA_VERSION, DatasetConfig
from .files import CSV_BLOCK_EPOCHS, dataset_files, write_dataset
from .make import make_dataset, make_datasets

__all__ = [
    "ALL_DATASETS",
    "COLUMNS",
    "CSV_BLOCK_EPOCHS",
    "PAPER_BANDS",
    "SCENARIOS",
    "SCHEMA_VERSION",
    "DatasetConfig",
    "dataset_files",
    "make_dataset",
    "make_datasets",
    "service_area",
    "write_dataset",
]
