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

#: Smallest ratio of the station spread's last to first singular value for a geometry that
#: surely determines the position; below it, the fix's mirror image is tested (:func:`mirror_fits`).
MIN_SPREAD_RATIO = 0.05
#: The mirror image of a fix "fits as well" when its RMS pseudo-range residual is at most this
#: many times the fix's own, or at most :data:`MIRROR_FLOOR_M`.
MIRROR_RATIO = 2.0
#: RMS residual, m, under which the mirror image always fits (range noise of a good receiver).
MIRROR_FLOOR_M = 0.05


def ill_conditioned(
    received: np.ndarray, bs_xyz: np.ndarray, three_d: bool, *,
    xyz: np.ndarray | None = None, rho: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """Fixes whose received base stations cannot determine the position.

    2D (known height): the stations' horizontal positions are (nearly) collinear. 3D: the
    stations lie (nearly) in one plane (e.g. all at one height), so the position and its mirror
    image fit alike. Nearly: the ratio of the last to the first singular value of the centred
    station positions is below :data:`MIN_SPREAD_RATIO`. With the fixes and their pseudo-ranges
    given, such a fix is ill-conditioned only when its mirror image across the stations' line
    (plane) fits the measurements about as well as the fix (:func:`mirror_fits`): near-collinear
    stations with precise ToAs do determine the position.

    Parameters
    ----------
    received : (F, N) bool, base stations with a ToA in each fix
    bs_xyz : (N, 3) float, metres
    three_d : bool, solving for x, y, z
    xyz : (F, 3) float, metres, optional, the fixes (NaN: unsolved)
    rho : (F, N) float, metres, optional, the pseudo-ranges (c x ToA, schedule removed)

    Returns
    -------
    (F,) bool
    """
    dims = 3 if three_d else 2
    out = np.zeros(len(received), dtype=bool)
    patterns, inverse = np.unique(received, axis=0, return_inverse=True)
    inverse = np.ravel(inverse)
    for k, mask in enumerate(patterns):
        pts = bs_xyz[mask, :dims]
        if len(pts) < dims:
            continue  # too few stations: unsolved, counted as such
        centre = pts.mean(axis=0)
        _, s, vt = np.linalg.svd(pts - centre)
        if s[0] > 0 and s[dims - 1] / s[0] >= MIN_SPREAD_RATIO:
            continue
        rows = np.flatnonzero(inverse == k)
        if xyz is None or rho is None or s[0] <= 0:
            out[rows] = True
            continue
        normal = vt[dims - 1]  # across the stations' line (2D) or plane (3D)
        out[rows] = mirror_fits(xyz[rows], rho[rows][:, mask], bs_xyz[mask], centre, normal)
    return out


def mirror_fits(
    xyz: np.ndarray, rho: np.ndarray, bs: np.ndarray, centre: np.ndarray, normal: np.ndarray
) -> np.ndarray:
    """Whether each fix's mirror image across the stations' line or plane fits the measurements
    about as well as the fix (the geometry cannot tell them apart).

    Parameters
    ----------
    xyz : (A, 3) float, metres, fixes (NaN rows: unsolved, counted as fitting)
    rho : (A, K) float, metres, the pseudo-ranges of the K received stations
    bs : (K, 3) float, metres
    centre : (d,) and normal : (d,) float, the line's or plane's point and unit normal (d = 2:
        horizontal, d = 3)

    Returns
    -------
    (A,) bool
    """
    d = len(normal)
    mirror = np.array(xyz, dtype=float)
    off = (mirror[:, :d] - centre) @ normal
    mirror[:, :d] -= 2.0 * off[:, None] * normal[None, :]

    def rms(p: np.ndarray) -> np.ndarray:
        s = rho - np.linalg.norm(p[:, None, :] - bs[None, :, :], axis=2)
        s = s - s.mean(axis=1, keepdims=True)  # the device clock, at its best
        return np.sqrt(np.mean(s * s, axis=1))

    with np.errstate(invalid="ignore"):
        r_fix, r_mirror = rms(np.asarray(xyz, dtype=float)), rms(mirror)
        fits = r_mirror <= np.maximum(MIRROR_RATIO * r_fix, MIRROR_FLOOR_M)
    return fits | ~np.isfinite(r_fix)


def trust_counts(ds: Any, fixes: Any, height: str | float) -> dict[str, int]:
    """Counts of a method's fixes: ``unsolved``, ``not_converged``, ``ill_conditioned`` (station
    geometry, :func:`ill_conditioned` with the fixes' mirror test) and ``trustworthy`` (solved,
    converged, well conditioned)."""
    from ..model.tdoa import C0

    ill = ill_conditioned(np.isfinite(ds.toa_s), ds.bs_xyz, height == "3d",
                          xyz=np.asarray(fixes.xyz), rho=C0 * ds.toa_unscheduled_s)  # fmt: skip
    return counts_of(fixes, ill)


def counts_of(fixes: Any, ill: np.ndarray) -> dict[str, int]:
    """The counts of :func:`trust_counts` from the fixes and their ill-conditioned flags."""
    solved = np.asarray(fixes.solved)
    not_conv = (np.asarray(fixes.status) & int(Status.NOT_CONVERGED)) != 0
    return {
        "unsolved": int(np.count_nonzero(~solved)),
        "not_converged": int(np.count_nonzero(not_conv & solved)),
        "ill_conditioned": int(np.count_nonzero(ill & solved)),
        "trustworthy": int(np.count_nonzero(solved & ~not_conv & ~ill)),
    }


def check_trustworthy(
    counts: dict[str, int], where: str, height: str | float, height_option: str = "--height"
) -> None:
    """Refuse a result without a single trustworthy fix (exit non-zero, nothing written);
    ``height_option``: how the message names the known height (``--height``, ``height_m``)."""
    if counts["trustworthy"] > 0:
        return
    why = (
        "collinear base stations"
        if height != "3d"
        else f"base stations in one plane (all at one height?): give {height_option}"
    )
    raise PositioningError(
        f"{where}: no trustworthy fix ({counts['ill_conditioned']} ill-conditioned by the "
        f"geometry: {why}; {counts['not_converged']} not converged; {counts['unsolved']} "
        "unsolved)"
    )
