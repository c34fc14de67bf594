"""A generated hall's line of sight against the 3GPP model: the LoS fraction the halls really
give per distance bin (Embree segment tests), Wilson intervals and the fitted decay distance
(:func:`los_check`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core.errors import HallrayError
from ...scene.model import Scene
from ..spec.los import tracer_scene
from ..spec.model import HallSpec
from ..spec.parse import parse_hall_spec
from .generator import generate_hall, split_spec
from .params import canonical_profile, los_probability_3gpp


def scene_from_spec(spec: HallSpec | Mapping[str, Any]) -> Scene:
    """The tracer's :class:`Scene` of a hall spec or of a :func:`generate_hall` mapping, built
    in memory (:func:`raytrace.halls.spec.tracer_scene`)."""
    hall = spec if isinstance(spec, HallSpec) else parse_hall_spec(split_spec(spec)[0])
    return tracer_scene(hall)


@dataclass
class LosSample:
    """Line-of-sight samples of one or more halls of one configuration.

    Attributes
    ----------
    d2d_m : (L,) float, horizontal BS-UT distance of each link, m
    los : (L,) bool, segment BS -> UT clear (Embree, :meth:`Scene.occluded`)
    k_3gpp_m : float, the 3GPP decay distance of the configuration, m
    label : str
    n_halls : int
    """

    d2d_m: np.ndarray
    los: np.ndarray
    k_3gpp_m: float
    label: str = ""
    n_halls: int = 1

    @property
    def n_links(self) -> int:
        return int(self.d2d_m.size)

    @property
    def los_fraction(self) -> float:
        return float(np.mean(self.los)) if self.los.size else math.nan

    @property
    def los_fraction_3gpp(self) -> float:
        """Expected fraction under TR 38.901 for the same distances."""
        return float(np.mean(los_probability_3gpp(self.d2d_m, self.k_3gpp_m)))

    def fit_k_m(self) -> float:
        """Maximum-likelihood k of ``P = exp(-d / k)`` for these samples, m (inf if all LoS,
        0 if none)."""
        return fit_decay_distance_m(self.d2d_m, self.los)

    def bins(self, width_m: float = 5.0) -> list[dict[str, float]]:
        """Per distance bin ``[lo, hi)``: links, LoS fraction (with its Wilson 95 % interval)
        and the 3GPP expectation (mean P_LOS over the bin's links)."""
        if self.d2d_m.size == 0:
            return []
        top = float(np.max(self.d2d_m))
        edges = np.arange(0.0, top + width_m, width_m)
        which = np.clip(np.digitize(self.d2d_m, edges) - 1, 0, len(edges) - 2)
        p3 = los_probability_3gpp(self.d2d_m, self.k_3gpp_m)
        rows = []
        for b in range(len(edges) - 1):
            sel = which == b
            n = int(sel.sum())
            if n == 0:
                continue
            k = int(self.los[sel].sum())
            lo, hi = wilson_interval(k, n)
            rows.append(
                {
                    "d_lo_m": float(edges[b]),
                    "d_hi_m": float(edges[b + 1]),
                    "n": n,
                    "n_los": k,
                    "los_fraction": k / n,
                    "ci_lo": lo,
                    "ci_hi": hi,
                    "p_los_3gpp": float(np.mean(p3[sel])),
                }
            )
        return rows

    def summary(self, width_m: float = 5.0) -> dict[str, Any]:
        k_fit = self.fit_k_m()
        return {
            "label": self.label,
            "n_halls": self.n_halls,
            "n_links": self.n_links,
            "los_fraction": self.los_fraction,
            "los_fraction_3gpp": self.los_fraction_3gpp,
            "k_3gpp_m": self.k_3gpp_m,
            "k_fit_m": k_fit,
            "bins": self.bins(width_m),
        }


def wilson_interval(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (95 % for the default z)."""
    if n == 0:
        return (math.nan, math.nan)
    phat = k / n
    den = 1.0 + z * z / n
    centre = (phat + z * z / (2 * n)) / den
    half = z * math.sqrt(phat * (1 - phat) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def fit_decay_distance_m(d2d_m: np.ndarray, los: np.ndarray) -> float:
    """Maximum-likelihood ``k`` of ``P(LoS | d) = exp(-d / k)`` from samples, m.

    The log-likelihood ``-sum_LoS d / k + sum_NLoS ln(1 - exp(-d / k))`` is concave in
    ``1 / k``; it is maximised on a bracket in ``log k``. Returns ``inf`` when every sample is
    LoS and ``0`` when none is.
    """
    from scipy.optimize import minimize_scalar

    d = np.asarray(d2d_m, dtype=float)
    y = np.asarray(los, dtype=bool)
    if d.size == 0:
        return math.nan
    if y.all():
        return math.inf
    if not y.any():
        return 0.0
    d = np.maximum(d, 1e-6)

    def nll(log_k: float) -> float:
        k = math.exp(log_k)
        return float(np.sum(d[y]) / k - np.sum(np.log(-np.expm1(-d[~y] / k))))

    res = minimize_scalar(
        nll, bounds=(math.log(1e-3), math.log(1e6)), method="bounded", options={"xatol": 1e-6}
    )
    return float(math.exp(res.x))


def los_sample(scene: Scene, hall: HallSpec, k_3gpp_m: float, label: str = "") -> LosSample:
    """LoS of every base station -> point link of a hall (Embree segment tests)."""
    bs = hall.base_station_xyz
    pts = hall.point_xyz
    o = np.repeat(bs, len(pts), axis=0)
    e = np.tile(pts, (len(bs), 1))
    los = ~scene.occluded(o, e)
    d2d = np.hypot(e[:, 0] - o[:, 0], e[:, 1] - o[:, 1])
    return LosSample(d2d, los, k_3gpp_m, label=label)


def merge_samples(samples: Sequence[LosSample], label: str = "") -> LosSample:
    """One sample from several halls of the same configuration (same k)."""
    if not samples:
        raise HallrayError("no LoS samples to merge")
    return LosSample(
        np.concatenate([s.d2d_m for s in samples]),
        np.concatenate([s.los for s in samples]),
        samples[0].k_3gpp_m,
        label=label or samples[0].label,
        n_halls=sum(s.n_halls for s in samples),
    )


def los_check(
    profile: str,
    seeds: Sequence[int] | int = 5,
    size: str | Sequence[float] | None = None,
    *,
    n_points: int = 200,
    **kwargs: Any,
) -> LosSample:
    """Generate one hall per seed and pool the LoS of all their BS -> point links.

    ``seeds`` is a list of seeds or a count (seeds 0 .. n-1). Other keyword arguments go to
    :func:`generate_hall`.
    """
    seed_list = list(range(seeds)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not seed_list:
        raise HallrayError("give at least one seed")
    samples = []
    for s in seed_list:
        spec = generate_hall(profile, size, s, n_points=n_points, los_notes=False, **kwargs)
        hall = parse_hall_spec(split_spec(spec)[0])
        samples.append(los_sample(scene_from_spec(hall), hall, spec["_inf"]["k_subsce_m"]))
    return merge_samples(samples, label=canonical_profile(profile))
