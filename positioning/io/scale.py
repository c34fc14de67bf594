"""The scale rule on a ToA dataset, before any solve (:func:`check_dataset`).

The checks themselves are :mod:`positioning.model.scale`, shared with
:func:`positioning.locate`: a hall spans metres to a few hundred metres, never more than
:data:`~hallray.units.MAX_SCENE_M`. Values beyond it are refused with the unit mistake that most
likely explains them: base stations in millimetres, ToAs in milliseconds, a height or true
positions in mm. (Whether the fixes' station geometry can determine a position is judged after
the solve: :mod:`positioning.evaluation.trust`.)
"""

from __future__ import annotations

from typing import Any

from ..errors import PositioningError
from ..model.scale import (
    RANGE_SPANS,
    ScaleError,
    check_height,
    check_stations,
    check_toa_scale,
    check_truth,
)

__all__ = [
    "RANGE_SPANS",
    "ScaleError",
    "check_dataset",
    "check_distances",
    "check_height",
    "check_stations",
    "check_toa_scale",
]

#: A ``distance_m`` column may differ from the distance between the row's true position and its
#: base station by this much (rounding), m.
DISTANCE_TOL_M = 0.05


def check_distances(ds: Any) -> None:
    """Refuse a dataset whose ``distance_m`` column contradicts its base stations and true
    positions (base stations swapped or moved in meta.json, or the wrong meta.json)."""
    import numpy as np

    dist = getattr(ds, "distance_m", None)
    if dist is None:
        return
    d = np.asarray(dist, dtype=float)
    ok = np.isfinite(d)
    if not ok.any():
        return
    geo = np.linalg.norm(ds.true_xyz[:, None, :] - ds.bs_xyz[None, :, :], axis=2)
    off = np.where(ok, np.abs(geo - d), 0.0)
    f, b = np.unravel_index(int(np.argmax(off)), off.shape)
    if off[f, b] > DISTANCE_TOL_M:
        raise PositioningError(
            f"{ds.path}: base station {ds.bs_names[b]} at {ds.bs_xyz[b].round(3).tolist()} is "
            f"{geo[f, b]:.2f} m from point {ds.point[f]}'s true position, but toa.csv says "
            f"distance_m {d[f, b]:.2f}: the base-station positions in meta.json do not fit the "
            "data (swapped or moved?)"
        )


def check_dataset(ds: Any) -> None:
    """The scale rule on a loaded :class:`~positioning.io.dataset.ToaDataset`: stations, ToAs,
    true positions, and the ``distance_m`` column against the stations."""
    where = str(ds.path)
    check_stations(ds.bs_xyz, where)
    check_toa_scale(ds.toa_unscheduled_s, ds.bs_xyz, where, ds.tx_offset_s)
    check_truth(ds.true_xyz, ds.bs_xyz, where)
    check_distances(ds)
