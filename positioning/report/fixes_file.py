"""A method's fixes as ``fixes.csv`` (what ``estimate-positions`` writes): one row per fix with
the position, the truth and the 2D error, the status flags and the integrity figures."""

from __future__ import annotations

import csv
import io

import numpy as np

from ..estimators.fixes import Fixes, status_label
from ..evaluation.metrics import error_2d
from ..io.dataset import ToaDataset

FIXES_COLUMNS = (
    "epoch",
    "time_s",
    "point",
    "method",
    "x",
    "y",
    "z",
    "x_true",
    "y_true",
    "z_true",
    "error_m",
    "status",
    "iterations",
    "n_bs",
    "hpl_m",
    "chi2n",
    "flagged",
)
#: Extra trailing columns of a ``twin`` method's fixes.csv.
TWIN_COLUMNS = ("nlos_bs", "match_m")


def fixes_csv(ds: ToaDataset, fixes: Fixes) -> str:
    """CSV text of one method's fixes (columns :data:`FIXES_COLUMNS`; a ``twin`` fix adds
    ``nlos_bs``, the base stations it judged NLoS joined by ``|``, and ``match_m``)."""
    err = error_2d(fixes.xyz, ds.true_xyz)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    twin_cols = "nlos" in fixes.extra and "match_m" in fixes.extra
    w.writerow(FIXES_COLUMNS + (TWIN_COLUMNS if twin_cols else ()))

    def num(v: float, fmt: str = ".6f") -> str:
        return "" if not np.isfinite(v) else format(v, fmt)

    for i in range(ds.n_fixes):
        x, y, z = fixes.xyz[i]
        tx, ty, tz = ds.true_xyz[i]
        extra = []
        if twin_cols:
            nlos = fixes.extra["nlos"][i]
            extra = ["|".join(n for n, f in zip(ds.bs_names, nlos, strict=True) if f)]
            extra.append(num(fixes.extra["match_m"][i], ".4f"))
        w.writerow(
            [
                int(ds.epoch[i]),
                num(ds.time_s[i], ".6g"),
                ds.point[i],
                fixes.method,
                num(x),
                num(y),
                num(z),
                num(tx),
                num(ty),
                num(tz),
                num(err[i]),
                status_label(fixes.status[i]),
                int(fixes.iterations[i]),
                int(fixes.n_used[i]),
                num(fixes.hpl_m[i], ".4f"),
                num(fixes.chi2n[i], ".4g"),
                int(fixes.flagged[i]),
                *extra,
            ]
        )
    return buf.getvalue()
