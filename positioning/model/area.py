"""The service area: the floor polygon a device can be on (convex or not), and its geometry.

A :class:`ServiceArea` is a simple polygon in the horizontal plane (metres). The positioning methods
use it to keep a fix from running away (see :mod:`positioning.estimators.bounded`): a solve whose
result leaves the polygon is solved again inside it. The dataset's ``meta.json`` carries it as
``service_area: {polygon: [[x, y], ...], source}``; :func:`area_from_meta` falls back to the
rectangle ``hall_xy`` and then to no area at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hallray.units import MAX_SCENE_M

from ..errors import PositioningError
from .scale import ScaleError, length_hint

#: A point this close to the outline (m) counts as inside: projections land on the outline up to
#: rounding, and must count as inside.
BOUNDARY_TOL_M = 1e-7
#: Most points of :meth:`ServiceArea.grid` and :meth:`ServiceArea.outline`: a larger area gets a
#: coarser pitch (a legal 4.2 km hall at 1 m would be 17.6 million points and 5 GB).
MAX_GRID_POINTS = 100_000
#: Point x edge pairs evaluated at once by :meth:`ServiceArea.contains` (memory bound).
_PAIRS_PER_BLOCK = 1_000_000


@dataclass(frozen=True)
class ServiceArea:
    """A simple polygon (M >= 3 vertices, either orientation, not closed: the last vertex is not
    a repeat of the first).

    Attributes
    ----------
    polygon : (M, 2) float, metres
    source : str -- where it came from (``meta.json`` ``service_area``, ``hall_xy``, ...)
    """

    polygon: np.ndarray
    source: str = ""

    def __post_init__(self) -> None:
        poly = np.asarray(self.polygon, dtype=float)
        if poly.ndim == 2 and poly.shape[0] >= 2 and np.allclose(poly[0], poly[-1]):
            poly = poly[:-1]
        if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
            raise PositioningError(
                f"service area polygon must have at least 3 [x, y] vertices, got {poly.shape}"
            )
        if not np.isfinite(poly).all():
            raise PositioningError("service area polygon has non-finite vertices")
        x, y = poly[:, 0], poly[:, 1]
        if abs(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) <= 0.0:
            raise PositioningError("service area polygon has zero area")
        span = float(np.max(np.ptp(poly, axis=0)))
        if span > MAX_SCENE_M:  # the scale rule (hallray.units): a polygon in millimetres
            raise ScaleError(
                f"service area polygon spans {span:,.0f} m, beyond the {MAX_SCENE_M / 1000:g} km "
                f"a hall can span: coordinates {length_hint(span)}"
            )
        object.__setattr__(self, "polygon", poly)

    @classmethod
    def box(cls, lo: Any, hi: Any, source: str = "box") -> ServiceArea:
        """The rectangle with corners ``lo`` = (xmin, ymin) and ``hi`` = (xmax, ymax)."""
        (x0, y0), (x1, y1) = np.asarray(lo, float), np.asarray(hi, float)
        return cls(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]), source)

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """(M, 2) start and (M, 2) end points of the outline's segments."""
        return self.polygon, np.roll(self.polygon, -1, axis=0)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(2,) lower-left and (2,) upper-right corners of the bounding box."""
        return self.polygon.min(axis=0), self.polygon.max(axis=0)

    def nearest_on_outline(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest point of the outline to each point.

        Parameters
        ----------
        xy : (A, 2) float, metres

        Returns
        -------
        (A, 2) nearest outline points and (A,) their distances, metres (NaN rows stay NaN).
        """
        a, b = self.edges
        ab = b - a
        ap = xy[:, None, :] - a[None, :, :]
        t = np.clip(np.einsum("aej,ej->ae", ap, ab) / np.sum(ab * ab, axis=1), 0.0, 1.0)
        foot = a[None] + t[..., None] * ab[None]
        d = np.linalg.norm(xy[:, None, :] - foot, axis=2)
        k = np.argmin(np.where(np.isfinite(d), d, np.inf), axis=1)
        ar = np.arange(xy.shape[0])
        return foot[ar, k], d[ar, k]

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(A,) bool: inside the polygon or on its outline (within :data:`BOUNDARY_TOL_M`).

        Even-odd rule (a horizontal ray crossing count), vectorised over points and edges, in
        blocks of points (memory: :data:`_PAIRS_PER_BLOCK` point-edge pairs); NaN points are
        outside.
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        block = max(1, _PAIRS_PER_BLOCK // len(self.polygon))
        if len(xy) > block:
            return np.concatenate([self.contains(xy[i : i + block])
                                   for i in range(0, len(xy), block)])  # fmt: skip
        _, d = self.nearest_on_outline(xy)
        return np.isfinite(xy).all(axis=1) & (self._odd(xy) | (d <= BOUNDARY_TOL_M))

    def _odd(self, xy: np.ndarray) -> np.ndarray:
        """(A,) bool: an odd number of the outline's edges cross the horizontal ray from each
        point to +x (False for a point that is not finite), in blocks of points."""
        block = max(1, _PAIRS_PER_BLOCK // len(self.polygon))
        if len(xy) > block:
            return np.concatenate([self._odd(xy[i : i + block])
                                   for i in range(0, len(xy), block)])  # fmt: skip
        a, b = self.edges
        x, y = xy[:, :1], xy[:, 1:]
        with np.errstate(divide="ignore", invalid="ignore"):
            straddle = (a[None, :, 1] > y) != (b[None, :, 1] > y)
            xc = a[None, :, 0] + (y - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
                b[None, :, 1] - a[None, :, 1]
            )
            return np.count_nonzero(straddle & (x < xc), axis=1) % 2 == 1

    def project(self, xy: np.ndarray) -> np.ndarray:
        """(A, 2): each point itself if inside, else its nearest outline point."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        # a point the crossing count puts inside is inside whatever its outline distance: the
        # distances (most of the work) only for the others; every number is a point's own
        out = xy.copy()
        rest = np.flatnonzero(~self._odd(xy))
        if rest.size:
            p = xy[rest]
            foot, d = self.nearest_on_outline(np.where(np.isfinite(p), p, 0.0))
            on = np.isfinite(p).all(axis=1) & (d <= BOUNDARY_TOL_M)
            out[rest] = np.where(on[:, None], p, foot)
        return out

    def outline(self, step_m: float) -> np.ndarray:
        """(K, 2) points along the outline, at most ``step_m`` apart (farther when that would be
        more than :data:`MAX_GRID_POINTS`), vertices included."""
        a, b = self.edges
        perimeter = float(np.sum(np.linalg.norm(b - a, axis=1)))
        step_m = max(step_m, perimeter / MAX_GRID_POINTS)
        pts = []
        for p, q in zip(a, b, strict=True):
            n = max(int(np.ceil(np.linalg.norm(q - p) / step_m)), 1)
            t = np.arange(n)[:, None] / n
            pts.append(p + t * (q - p))
        return np.concatenate(pts)

    def grid(self, step_m: float) -> np.ndarray:
        """(G, 2) points of a square grid of pitch ``step_m`` that lie inside (cell centres); a
        coarser pitch where ``step_m`` would give more than :data:`MAX_GRID_POINTS` points."""
        lo, hi = self.bounds
        w, h = np.maximum(hi - lo, 1e-9)
        step_m = max(step_m, float(np.sqrt(w * h / MAX_GRID_POINTS)))
        xs = np.arange(lo[0] + 0.5 * step_m, hi[0], step_m)
        ys = np.arange(lo[1] + 0.5 * step_m, hi[1], step_m)
        g = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
        return g[self.contains(g)]

    def to_meta(self) -> dict[str, Any]:
        """The ``meta.json`` form ``{polygon: [[x, y], ...], source}``."""
        return {"polygon": self.polygon.tolist(), "source": self.source}


def area_from_meta(meta: Mapping[str, Any]) -> ServiceArea | None:
    """The service area of a dataset: ``service_area.polygon``, else the ``hall_xy`` rectangle,
    else None (no area: fixes are not bounded).

    Raises
    ------
    PositioningError
        A ``service_area`` or ``hall_xy`` that is present but malformed.
    """
    sa = meta.get("service_area")
    if sa is not None:
        poly = sa.get("polygon") if isinstance(sa, Mapping) else None
        try:
            arr = np.asarray(poly, dtype=float)
        except (TypeError, ValueError):
            raise PositioningError(
                "meta.json: service_area.polygon must be [[x, y], ...]"
            ) from None
        src = str(sa.get("source", "meta.json service_area")) if isinstance(sa, Mapping) else ""
        try:
            return ServiceArea(arr, src or "meta.json service_area")
        except PositioningError as exc:
            raise PositioningError(f"meta.json: {exc}") from None
    hall = meta.get("hall_xy")
    if hall is not None:
        try:
            h = np.asarray(hall, dtype=float)
        except (TypeError, ValueError):
            h = np.empty(0)
        if h.shape != (2, 2) or not np.isfinite(h).all() or np.any(h[1] <= h[0]):
            raise PositioningError("meta.json: hall_xy must be [[xmin, ymin], [xmax, ymax]]")
        return ServiceArea.box(h[0], h[1], "meta.json hall_xy")
    return None
