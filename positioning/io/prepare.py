"""A dataset as the estimators' input: a :class:`~positioning.model.problem.Problem` with the
schedule removed per measurement, the dataset's service area, its receiver reports and the device
heights of the solve ("2D" with a known height, or 3D)."""

from __future__ import annotations

import numpy as np

from ..model.problem import Problem, make_problem
from .dataset import ToaDataset, dataset_area, link_reports


def heights_for(ds: ToaDataset, mode: str | float) -> np.ndarray | None:
    """Device heights of a dataset's fixes: ``"true"`` -> the points' true z, ``"3d"`` -> None,
    a number -> that constant."""
    if mode == "3d":
        return None
    if mode == "true":
        return ds.true_xyz[:, 2]
    return np.full(ds.n_fixes, float(mode))


def dataset_problem(ds: ToaDataset, height: str | float = "true") -> Problem:
    """The dataset as a :class:`Problem`: schedule removed per measurement, its service area and
    its receiver reports (``snr_db``, first-lobe shape, band) attached."""
    return make_problem(
        ds.toa_unscheduled_s,
        ds.bs_xyz,
        None,
        heights_for(ds, height),
        area=dataset_area(ds),
        links=link_reports(ds),
    )
