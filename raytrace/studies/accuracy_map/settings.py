"""What an accuracy map is computed with: :class:`MapSettings`, its defaults and limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hallray.limits import check_size

from ...core.errors import HallrayError
from ...emulation.bands import get_band
from ...emulation.receivers.receiver import DEFAULT_TOA_METHOD, TOA_METHODS
from ...solver.config import TraceConfig
from ...solver.parallel import (
    CHUNK_LINKS,
)

#: Most links per chunk of cells (a chunk is traced whole: its candidate arrays in memory at once).
MAX_CHUNK_LINKS = 999


#: Most cells a map may have unless the caller raises it (a 1 m grid of the hall has ~1700).
MAX_CELLS = 20000
DEFAULT_STEP_M = 2.0
DEFAULT_DRAWS = 100
DEFAULT_CLEARANCE_M = 0.25
DEFAULT_SEED = 1
#: The paper's two positioning methods.
DEFAULT_METHODS = ("ls", "irls")
#: Device height when neither the caller nor the scene's test points give one, m.
FALLBACK_HEIGHT_M = 1.5
#: Candidate grid offsets per axis and step searched for the clearance rule.
OFFSET_CANDIDATES = 64
#: Paths stored per cell and base station (schema v2; 0: a v1 map without paths).
DEFAULT_PATHS = 16


@dataclass(frozen=True)
class MapSettings:
    """What an accuracy map is computed with (validated by :meth:`check`).

    Attributes
    ----------
    step_m : float, m, grid step in x and y
    height_m : float or None, m, device height (None: the median height of the scene's test
        points, else :data:`FALLBACK_HEIGHT_M`)
    band : str, band name (:func:`raytrace.emulation.bands.get_band`)
    receiver : str, ToA receiver (:data:`raytrace.emulation.receivers.TOA_METHODS`)
    methods : tuple of str, positioning methods (:func:`positioning.method_names`)
    draws : int, noise epochs per cell (K)
    seed : int, root of the noise streams
    clearance_m : float, m, least horizontal distance of a cell centre from a test point
    max_cells : int, refuse grids with more cells
    trace : TraceConfig, the tracer's limits
    chunk_links : int, links per chunk of cells
    paths : int, strongest paths stored per cell and base station (schema v2, for the twin's
        re-synthesis); 0: a version-1 map without paths
    """

    step_m: float = DEFAULT_STEP_M
    height_m: float | None = None
    band: str = "c-band"
    receiver: str = DEFAULT_TOA_METHOD
    methods: tuple[str, ...] = DEFAULT_METHODS
    draws: int = DEFAULT_DRAWS
    seed: int = DEFAULT_SEED
    clearance_m: float = DEFAULT_CLEARANCE_M
    max_cells: int = MAX_CELLS
    trace: TraceConfig = field(default_factory=TraceConfig)
    chunk_links: int = CHUNK_LINKS
    paths: int = DEFAULT_PATHS

    def check(self) -> None:
        """Raise a one-line :class:`HallrayError` for a bad setting (before any tracing)."""
        from positioning import method_names

        if not (np.isfinite(self.step_m) and self.step_m > 0):
            raise HallrayError(f"--step must be a positive number of metres, got {self.step_m}")
        if not (np.isfinite(self.clearance_m) and self.clearance_m >= 0):
            raise HallrayError(f"--clearance must be >= 0 m, got {self.clearance_m}")
        if self.height_m is not None and not np.isfinite(self.height_m):
            raise HallrayError(f"--height must be a finite number of metres, got {self.height_m}")
        get_band(self.band)  # HallrayError naming the known bands
        if self.receiver not in TOA_METHODS:
            raise HallrayError(
                f"unknown receiver {self.receiver!r}; known: {', '.join(TOA_METHODS)}"
            )
        known = method_names()
        bad = [m for m in self.methods if m not in known]
        if bad or not self.methods:
            raise HallrayError(
                f"unknown positioning method {bad[0] if bad else '(none)'!r}; known: {', '.join(known)}"
            )
        for name, v, lo, hi in (("--draws", self.draws, 1, None),
                                ("--paths", self.paths, 0, None),
                                ("--max-cells", self.max_cells, 1, None),
                                ("chunk_links", self.chunk_links, 1, MAX_CHUNK_LINKS)):  # fmt: skip
            if (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo
                    or (hi is not None and v > hi)):  # fmt: skip
                raise HallrayError(f"{name} must be an integer in [{lo}, {hi or 'inf'}], got {v!r}")
        check_size("draws", self.draws, f"--draws {self.draws}")
        check_size("paths per link", self.paths, f"--paths {self.paths}")

    def check_grid(self, n_cells: int, n_bs: int) -> None:
        """The size limits on a grid of ``n_cells`` cells and ``n_bs`` base stations (before any
        tracing): the fixes computed and the paths stored in all."""
        check_size("map fixes", float(n_cells) * self.draws * len(self.methods),
                   f"{n_cells} cells x --draws {self.draws} x {len(self.methods)} methods")  # fmt: skip
        check_size("map paths", float(n_cells) * n_bs * self.paths,
                   f"{n_cells} cells x {n_bs} base stations x --paths {self.paths}")  # fmt: skip
