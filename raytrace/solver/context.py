"""Per-call state of a trace: :class:`TraceContext`, shared by every stage.

The scene, the links, the frequency and the :class:`~raytrace.solver.config.TraceConfig`, the
material constants at that frequency, which objects block (opaque), which elements may take part
(``involving``), and the counters the stages report. Stages (:mod:`raytrace.solver.specular`,
:mod:`raytrace.solver.diffraction`) generate candidates from it; :mod:`raytrace.solver.evaluate`
turns candidates into paths with it.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from hallray.errors import brief

from ..core.constants import C0
from ..core.errors import TraceInputError
from ..physics.materials import slab
from ..scene.model import Scene
from .config import MIN_POWER_DB, TraceConfig

#: An object is opaque when its slab loss at normal incidence, through its sheet thickness (open
#: sheets) or through this chord (closed solids, m), is more than ``OPAQUE_MARGIN_DB`` below
#: ``min_power_db``: metals at these frequencies (skin depth ~1 um). A path that crosses an
#: opaque object is dropped by one Embree query before the crossing analysis.
OPAQUE_CHORD_M = 1e-3
#: dB of headroom for the other factors of a path (oblique incidence, diffraction coefficients).
OPAQUE_MARGIN_DB = 100.0


def material_constants(
    scene: Scene, frequency_hz: float, extrapolate: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Relative permittivity ``eta`` and its slope ``f d eta / d f`` of each used material at
    ``frequency_hz``: two ``(n_materials,) complex`` arrays, in ``scene.material_names`` order."""
    mats = [scene.materials[m] for m in scene.material_names]
    eta = np.array([m.permittivity(frequency_hz, extrapolate=extrapolate) for m in mats])
    slope = np.array([m.permittivity_slope(frequency_hz, extrapolate=extrapolate) for m in mats])
    return eta.astype(complex).reshape(-1), slope.astype(complex).reshape(-1)


class TraceContext:
    """Per-call state shared by the path stages: scene, links, material constants, counters.

    Parameters
    ----------
    scene : Scene
    tx : (T, 3) float, metres, validated transmitter positions
    rx : (R, 3) float, metres, validated receiver positions
    f : float, Hz
    cfg : TraceConfig
    involving : object indices, optional: only facets and wedges of these objects take part
    opaque : (O,) bool, optional: objects that block (default :func:`opaque_objects`); with
        ``cfg.max_penetrations == 0`` every object blocks (no path may cross one)

    Attributes
    ----------
    k0, wavelength : free-space wavenumber (rad/m) and wavelength (m)
    eta, eta_slope : (n_materials,) complex, see :func:`material_constants`
    thickness : (n_materials,) float, slab thickness of open sheets, m
    obj_material, obj_closed : (O,) per-object material index and closed-solid flag
    facet_mask, wedge_mask : (K,), (W,) bool or None, elements that may take part
    stats : dict, counters and stage times (``time_us[<stage>]``)
    shadows : dict, ``"tx"`` / ``"rx"`` -> the facets and edges each end sees only through an
        opaque solid, computed once per trace (:func:`raytrace.solver.shadow.shadows_of`)
    shadows_lock : threading.Lock, held while one stage thread computes them
    """

    def __init__(
        self,
        scene: Scene,
        tx: np.ndarray,
        rx: np.ndarray,
        f: float,
        cfg: TraceConfig,
        involving: np.ndarray | list[int] | None = None,
        opaque: np.ndarray | None = None,
    ):
        self.scene, self.tx, self.rx, self.f, self.cfg = scene, tx, rx, f, cfg
        # which facets / wedges may take part (all, unless restricted to some objects)
        if involving is None:
            self.facet_mask = None
            self.wedge_mask = None
        else:
            objs = np.zeros(len(scene.objects), dtype=bool)
            objs[check_involving(scene, involving)] = True
            self.facet_mask = objs[scene.facets.object]
            self.wedge_mask = objs[scene.wedges.object] if len(scene.wedges) else np.zeros(0, bool)
        self.k0 = 2 * np.pi * f / C0
        self.wavelength = C0 / f
        with warnings.catch_warnings():
            if cfg.extrapolate:  # once per material, whatever the filters around
                warnings.simplefilter("default")
            self.eta, self.eta_slope = material_constants(scene, f, cfg.extrapolate)
        self.thickness = scene.material_thickness()
        self.obj_material = scene.object_material
        self.obj_closed = scene.object_closed
        if opaque is None:
            self.opaque = opaque_objects(scene, f, cfg.min_power_db, eta=self.eta)
        else:
            self.opaque = np.asarray(opaque, dtype=bool).reshape(-1)
            if self.opaque.shape != (len(scene.objects),):
                raise TraceInputError(
                    f"opaque must have one flag per object ({len(scene.objects)}), "
                    f"got {self.opaque.shape[0]}"
                )
        if cfg.max_penetrations == 0:
            # a path that crosses anything is dropped: every object blocks, so that the shadows
            # prune candidates and one Embree query drops a blocked one before the crossing walk
            # (a city model's buildings: 99 % of its mixed candidates)
            self.opaque = np.ones(len(scene.objects), dtype=bool)
        self.stats: dict[str, int] = {}
        self._lock = threading.Lock()
        self.shadows: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.shadows_lock = threading.Lock()

    @property
    def n_links(self) -> int:
        return len(self.tx) * len(self.rx)

    def timed(self, name: str, stage: Callable[[], Any]) -> Any:
        """Run a stage and record its wall time (microseconds) as ``time_us[<name>]``."""
        t0 = time.perf_counter()
        out = stage()
        self.count(f"time_us[{name}]", int((time.perf_counter() - t0) * 1e6))
        return out

    def count(self, key: str, n: int) -> None:
        with self._lock:
            self.stats[key] = self.stats.get(key, 0) + int(n)

    def wedge_object(self, idx: np.ndarray) -> np.ndarray:
        """Object of each wedge index (-1 if the scene has no wedges)."""
        w = self.scene.wedges
        if len(w) == 0:
            return np.full(idx.shape, -1)
        return w.object[np.clip(idx, 0, len(w) - 1)]


def check_involving(scene: Scene, involving: Any) -> np.ndarray:
    """``involving`` as object indices (int64 array), each in ``0 .. objects - 1``; a one-line
    :class:`TraceInputError` otherwise (not an ``IndexError``, nor a negative index that wraps)."""
    try:
        idx = np.asarray(involving)
    except (TypeError, ValueError):
        idx = np.asarray([None])
    n = len(scene.objects)
    if idx.dtype.kind not in "iu" and not (idx.dtype.kind == "f" and idx.size == 0):
        raise TraceInputError(f"involving must be object indices (integers), got {brief(involving)}")
    idx = idx.astype(np.int64).reshape(-1)
    bad = idx[(idx < 0) | (idx >= n)]
    if bad.size:
        raise TraceInputError(
            f"involving: object index {int(bad[0])} is not one of the scene's {n} objects "
            f"(0 .. {n - 1})"
        )
    return idx


def opaque_objects(
    scene: Scene,
    frequency_hz: float,
    min_power_db: float = MIN_POWER_DB,
    *,
    eta: np.ndarray | None = None,
    extrapolate: bool = False,
) -> np.ndarray:
    """(O,) bool: objects through which no path can carry power above ``min_power_db``.

    An object is opaque when its slab loss (ITU-R P.2040 eqs. 37-39 via :func:`slab`) at normal
    incidence, through its sheet thickness (open sheets) or :data:`OPAQUE_CHORD_M` (closed
    solids), is below ``min_power_db - OPAQUE_MARGIN_DB``: metals, whose skin depth is about a
    micrometre. A chord through a metal solid shorter than that (a ray grazing a corner by
    less than a millimetre) is blocked too, which is what the edge's diffraction accounts for.

    Parameters
    ----------
    scene : Scene
    frequency_hz : float
    min_power_db : float
    eta : (n_materials,) complex, optional, relative permittivity of each used material at the
        frequency (computed when not given)
    extrapolate : bool, allow materials outside their valid frequency range

    Returns
    -------
    (O,) bool
    """
    if eta is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            eta, _ = material_constants(scene, frequency_hz, extrapolate)
    mat = scene.object_material
    if len(mat) == 0:
        return np.zeros(0, dtype=bool)
    th = np.where(scene.object_closed, OPAQUE_CHORD_M, scene.material_thickness()[mat])
    _, _, t_te, t_tm = slab(eta[mat], np.ones(len(mat)), th, frequency_hz)
    amp = np.maximum(np.abs(t_te), np.abs(t_tm))
    loss_db = 20 * np.log10(np.maximum(amp, 1e-300))
    return loss_db < min_power_db - OPAQUE_MARGIN_DB
