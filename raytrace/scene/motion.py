"""Motion of objects in a hall: forklift routes driven at constant speed, snapshot times.

One :class:`Route` serves the hall builder (which writes routes into the scene metadata) and the
incremental tracer (which drives forklifts along them); see ``docs/dynamics.md`` for the model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hallray.limits import check_size

from ..core.errors import SceneError

#: Height of the forklift box's underside above the floor plane z = 0, m. Keeps the box from
#: sharing a plane with the floor (coplanar faces are ambiguous for a ray caster) and clears the
#: hall builder's drive-over height (objects lower than 5 cm, such as floor markings).
FORKLIFT_CLEARANCE_M = 0.05
#: Route modes.
ROUTE_MODES = ("loop", "back_and_forth")


def route_pose(
    polyline: np.ndarray, speed: float, mode: str, t_s: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Position and heading of a vehicle driving a polyline at constant speed.

    Parameters
    ----------
    polyline : (K, 2) float, waypoints, metres
    speed : float, m/s
    mode : ``"loop"`` (back to the first waypoint, then again) or ``"back_and_forth"``
    t_s : (T,) float, seconds (t = 0 at the first waypoint)

    Returns
    -------
    xy : (T, 2) float, metres
    heading_rad : (T,) float, driving direction counter-clockwise from +x, in (-pi, pi]
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    poly = np.asarray(polyline, dtype=float)
    seg = np.diff(poly, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    total = cum[-1]
    s = speed * t
    back = np.zeros(t.shape, dtype=bool)
    if mode == "loop":
        s = np.mod(s, total)
    else:
        s = np.mod(s, 2.0 * total)
        back = s > total
        s = np.where(back, 2.0 * total - s, s)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[i]) / seg_len[i]
    xy = poly[i] + frac[:, None] * seg[i]
    heading = np.arctan2(seg[i, 1], seg[i, 0]) + np.where(back, np.pi, 0.0)
    heading = np.where(heading > np.pi, heading - 2 * np.pi, heading)
    return xy, heading


@dataclass(frozen=True)
class Route:
    """A forklift route.

    Attributes
    ----------
    name : str
    size : (3,) float, metres: length (along the driving direction), width, height
    material : str
    waypoints : (n, 2) float, metres, the polyline in the floor plane
    speed : float, m/s
    mode : "loop" (back to the first waypoint) or "back_and_forth"
    """

    name: str
    size: tuple[float, float, float]
    material: str
    waypoints: tuple[tuple[float, float], ...]
    speed: float
    mode: str = "loop"

    @classmethod
    def from_dict(cls, entry: Mapping[str, Any], where: str = "route") -> Route:
        """A route from its metadata entry (``name, size, material, waypoints, speed, mode``);
        one-line :class:`SceneError` naming the bad field."""
        if not isinstance(entry, Mapping):
            raise SceneError(f"{where}: expected a mapping, got {type(entry).__name__}")
        for key in ("name", "size", "material", "waypoints", "speed"):
            if key not in entry:
                raise SceneError(f"{where}: missing key '{key}'")
        name = str(entry["name"])
        where = f"route '{name}'"
        try:
            size = np.asarray(entry["size"], dtype=float)
            wp = np.asarray(entry["waypoints"], dtype=float)
            speed = float(entry["speed"])
        except (TypeError, ValueError):
            raise SceneError(f"{where}: size, waypoints and speed must be numbers") from None
        if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size <= 0):
            raise SceneError(f"{where}: size must be 3 positive numbers (length, width, height)")
        if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) < 2 or not np.all(np.isfinite(wp)):
            raise SceneError(f"{where}: waypoints must be at least 2 finite [x, y] pairs")
        if not math.isfinite(speed) or speed <= 0:
            raise SceneError(f"{where}: speed must be a positive number of m/s, got {speed!r}")
        mode = str(entry.get("mode", "loop"))
        if mode not in ROUTE_MODES:
            raise SceneError(f"{where}: unknown mode {mode!r} (use {' or '.join(ROUTE_MODES)})")
        route = cls(
            name,
            (float(size[0]), float(size[1]), float(size[2])),
            str(entry["material"]),
            tuple((float(x), float(y)) for x, y in wp),
            speed,
            mode,
        )
        seg = np.linalg.norm(np.diff(route.polyline, axis=0), axis=1)
        if np.any(seg <= 1e-9):
            raise SceneError(f"{where}: two consecutive waypoints coincide")
        if route.size[2] <= FORKLIFT_CLEARANCE_M:
            raise SceneError(
                f"{where}: height {route.size[2]} m is not above the clearance "
                f"{FORKLIFT_CLEARANCE_M} m"
            )
        return route

    @property
    def polyline(self) -> np.ndarray:
        """(m, 2) float, the waypoints driven through in one pass (a loop ends where it starts)."""
        pts = np.asarray(self.waypoints, dtype=float)
        return np.vstack([pts, pts[:1]]) if self.mode == "loop" else pts

    @property
    def length_m(self) -> float:
        """Length of one pass (one lap, or one way for back-and-forth), m."""
        return float(np.linalg.norm(np.diff(self.polyline, axis=0), axis=1).sum())

    @property
    def period_s(self) -> float:
        """Time after which the motion repeats, s."""
        return (1.0 if self.mode == "loop" else 2.0) * self.length_m / self.speed

    def pose(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Centre and heading at times ``t_s``.

        Parameters
        ----------
        t_s : (T,) float, seconds (t = 0 at the first waypoint)

        Returns
        -------
        xy : (T, 2) float, metres, the box centre in the floor plane
        heading_rad : (T,) float, driving direction counter-clockwise from +x, in (-pi, pi]
        """
        return route_pose(self.polyline, self.speed, self.mode, t_s)


def snapshot_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """Snapshot times ``k / rate`` for ``k = 0 .. floor(duration * rate) - 1``, seconds.

    60 s at 10 Hz gives 600 snapshots at 0, 0.1, ..., 59.9 s.
    """
    d, r = float(duration_s), float(rate_hz)
    if not math.isfinite(d) or d <= 0:
        raise SceneError(f"duration must be a positive number of seconds, got {duration_s!r}")
    if not math.isfinite(r) or r <= 0:
        raise SceneError(f"rate must be a positive number of Hz, got {rate_hz!r}")
    # the size limit before the count is made an int and the times allocated
    check_size("epochs", math.floor(d * r + 1e-9), f"duration {d:g} s x rate {r:g} Hz")
    n = int(math.floor(d * r + 1e-9))
    if n < 1:
        raise SceneError(f"duration {d:g} s at {r:g} Hz gives no snapshot")
    return np.arange(n) / r
