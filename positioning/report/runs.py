"""Every method run on a dataset: :func:`evaluate` and :func:`solve_dataset` (the service area,
the integrity figures, ``METHOD+track``), their results per dataset (:class:`DatasetResult`) in
the paper's order, and the display names of methods and bands."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..estimators.eq7 import reference_by_name
from ..estimators.fixes import Fixes
from ..estimators.track import check_params, split_method, track_fixes
from ..evaluation.integrity import ALERT_LIMIT_M
from ..evaluation.metrics import error_2d, summarize
from ..io.dataset import ToaDataset
from ..io.prepare import dataset_problem
from ..methods.run import run_method
from ..model.problem import Problem

_SCENARIO_ORDER = {"static": 0, "semi-dynamic": 1}
_BAND_ORDER = {"c-band": 0, "mmwave": 1}
_BAND_LABEL = {"c-band": "C-band", "mmwave": "mmWave"}
_METHOD_LABEL = {"ls": "LS", "irls": "IRLS"}


def method_label(name: str) -> str:
    """Display name of a method (``LS``, ``IRLS``, others as registered)."""
    return _METHOD_LABEL.get(name, name)


def band_label(band: str) -> str:
    """Display name of a band (``C-band``, ``mmWave``, others as given)."""
    return _BAND_LABEL.get(band, band)


@dataclass(frozen=True)
class DatasetResult:
    """All methods run on one dataset."""

    dataset: ToaDataset
    fixes: dict[str, Fixes]
    errors: dict[str, np.ndarray]  # method -> (F,) 2D error, metres (NaN unsolved)
    summaries: dict[str, dict[str, float | int]]

    @property
    def label(self) -> str:
        ds = self.dataset
        return f"{ds.scenario} / {band_label(ds.band)} ({ds.name})"


def solve_dataset(
    ds: ToaDataset,
    method: str,
    params: Mapping[str, Any],
    height: str | float = "true",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = ALERT_LIMIT_M,
    problem: Problem | None = None,
    track: Mapping[str, Any] | None = None,
) -> Fixes:
    """Run one method on every fix of a dataset (schedule removed per measurement), bounded to
    the dataset's service area, with integrity figures at ``alert_limit_m``.

    ``METHOD+track``: the method's fixes tracked per point over time
    (:func:`positioning.estimators.track.track_fixes` with the ``track`` parameters).
    """
    base, tracked = split_method(method)
    if tracked:
        single = solve_dataset(
            ds, base, params, height, outside=outside, alert_limit_m=alert_limit_m, problem=problem
        )
        return track_fixes(single, ds.point, ds.time_s, check_params(track or {}))
    prob = problem if problem is not None else dataset_problem(ds, height)
    p = dict(params)
    if "reference" in p:
        p["reference"] = reference_by_name(p["reference"], list(ds.bs_names))
    return run_method(prob, method, outside=outside, alert_limit_m=alert_limit_m, **p)


def evaluate(
    ds: ToaDataset,
    methods: Sequence[str],
    params: Mapping[str, Mapping[str, Any]] | None = None,
    height: str | float = "true",
    *,
    outside: str = "constrain",
    alert_limit_m: float | None = ALERT_LIMIT_M,
) -> DatasetResult:
    """Run ``methods`` on ``ds``; 2D errors and their summaries per method."""
    params = params or {}
    fixes, errors, summaries = {}, {}, {}
    # the methods keep what they compute alike in its memo: the robust ones' hypothesis fits,
    # the integrity figures' fault hypotheses (a seventh of a report's time, once per method)
    prob = dataset_problem(ds, height).with_memo()
    single: dict[str, Fixes] = {}  # a tracked method reuses its base method's fixes
    for m in methods:
        base, tracked = split_method(m)
        if base not in single:
            single[base] = solve_dataset(
                ds,
                base,
                params.get(base, {}),
                height,
                outside=outside,
                alert_limit_m=alert_limit_m,
                problem=prob,
            )
        f = single[base]
        if tracked:
            f = track_fixes(f, ds.point, ds.time_s, check_params(params.get("track", {})))
        e = error_2d(f.xyz, ds.true_xyz)
        fixes[m], errors[m], summaries[m] = f, e, summarize(e)
        summaries[m]["availability_pct"] = 100.0 * f.availability
    return DatasetResult(dataset=ds, fixes=fixes, errors=errors, summaries=summaries)


def _sort_key(r: DatasetResult) -> tuple:
    ds = r.dataset
    return (
        _SCENARIO_ORDER.get(ds.scenario, 9),
        ds.scenario,
        _BAND_ORDER.get(ds.band, 9),
        ds.band,
        ds.name,
    )


def sort_results(results: Sequence[DatasetResult]) -> list[DatasetResult]:
    """Results in the paper's order: static before semi-dynamic, C-band before mmWave."""
    return sorted(results, key=_sort_key)
