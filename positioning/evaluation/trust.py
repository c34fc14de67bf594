"""Can the fixes be trusted: the geometry of their base stations, and the counts a command
refuses a run without.

The geometry check flags fixes whose base stations cannot determine the position: collinear
stations in 2D (a mirror image), stations all at one height in 3D (z is ambiguous).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import PositioningError
from ..estimators.fixes import Status

#: Smallest ratio of the station spread's last to first singular value for a usable geometry.
MIN_SPREAD_RATIO = 0.05


def ill_conditioned(received: np.ndarray, bs_xyz: np.ndarray, three_d: bool) -> np.ndarray:
    """Fixes whose received base stations cannot determine the position.

    2D (known height): the stations' horizontal positions are collinear. 3D: the stations lie in
    one plane (e.g. all at one height), so the position and its mirror image fit alike. Measured
    by the ratio of the last to the first singular value of the centred station positions
    (< :data:`MIN_SPREAD_RATIO`).

    Parameters
    ----------
    received : (F, N) bool, base stations with a ToA in each fix
    bs_xyz : (N, 3) float, metres
    three_d : bool, solving for x, y, z

    Returns
    -------
    (F,) bool
    """
    dims = 3 if three_d else 2
    out = np.zeros(len(received), dtype=bool)
    patterns, inverse = np.unique(received, axis=0, return_inverse=True)
    for k, mask in enumerate(patterns):
        pts = bs_xyz[mask, :dims]
        if len(pts) < dims:
            continue  # too few stations: unsolved, counted as such
        s = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        if s[0] <= 0 or s[dims - 1] / s[0] < MIN_SPREAD_RATIO:
            out[np.ravel(inverse) == k] = True
    return out


def trust_counts(ds: Any, fixes: Any, height: str | float) -> dict[str, int]:
    """Counts of a method's fixes: ``unsolved``, ``not_converged``, ``ill_conditioned`` (station
    geometry, :func:`ill_conditioned`) and ``trustworthy`` (solved, converged, well
    conditioned)."""
    ill = ill_conditioned(np.isfinite(ds.toa_s), ds.bs_xyz, height == "3d")
    solved = np.asarray(fixes.solved)
    not_conv = (np.asarray(fixes.status) & int(Status.NOT_CONVERGED)) != 0
    return {
        "unsolved": int(np.count_nonzero(~solved)),
        "not_converged": int(np.count_nonzero(not_conv & solved)),
        "ill_conditioned": int(np.count_nonzero(ill & solved)),
        "trustworthy": int(np.count_nonzero(solved & ~not_conv & ~ill)),
    }


def check_trustworthy(counts: dict[str, int], where: str, height: str | float) -> None:
    """Refuse a result without a single trustworthy fix (exit non-zero, nothing written)."""
    if counts["trustworthy"] > 0:
        return
    why = (
        "collinear base stations"
        if height != "3d"
        else "base stations in one plane (all at one height?): give --height"
    )
    raise PositioningError(
        f"{where}: no trustworthy fix ({counts['ill_conditioned']} ill-conditioned by the "
        f"geometry: {why}; {counts['not_converged']} not converged; {counts['unsolved']} "
        "unsolved)"
    )
