"""What defines a dataset besides its scene: the scenarios, bands and columns of the
paper's datasets, and :class:`DatasetConfig`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...core.errors import HallrayError
from ...scene.motion import FORKLIFT_CLEARANCE_M, snapshot_times
from ...solver.config import TraceConfig
from ..bands import Band, get_band
from ..channel.budget import LinkBudget
from ..channel.cfr import PrsSettings
from ..channel.pulse import PulseShape
from ..measurement import CLOCK_OFFSET_MAX_S, DELTA_S, ToaModel
from ..receivers.first_lobe import FirstLobeSettings
from ..receivers.receiver import DEFAULT_TOA_METHOD, TOA_METHODS, Receiver
from ..receivers.search_back import SearchBackSettings
from ..receivers.super_res import SuperResSettings

#: Version of the dataset schema (``meta.json`` ``schema_version``).
SCHEMA_VERSION = 2
#: Scenarios of the paper.
SCENARIOS = ("static", "semi-dynamic")
#: Bands of the paper (any band of :func:`raytrace.emulation.bands.get_band` works in the library).
PAPER_BANDS = ("c-band", "mmwave")
#: Header of ``toa.csv`` (the shared data contract).
COLUMNS = (
    "epoch",
    "time_s",
    "point",
    "bs",
    "toa_s",
    "x_true",
    "y_true",
    "z_true",
    "distance_m",
    "los",
    "first_kind",
    "snr_db",
    "peak_ratio_db",
    "lobe_width",
    "lobe_kind",
    "tx_offset_s",
    "clock_offset_s",
)
#: Sub-directories written by ``--all``.
ALL_DATASETS = tuple((s, b) for s in SCENARIOS for b in PAPER_BANDS)


# --------------------------------------------------------------------------------------------
# configuration
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DatasetConfig:
    """Everything that defines a dataset besides the scene.

    Attributes
    ----------
    scenario : "static" or "semi-dynamic"
    band : str, band name (``c-band``, ``mmwave`` or a user band)
    duration_s : float, seconds of emulation (the paper: 60 s)
    rate_hz : float, snapshots (epochs) per second
    seed : int
    toa_method : ToA estimator, one of :data:`raytrace.emulation.receivers.TOA_METHODS`
        (default :data:`raytrace.emulation.receivers.DEFAULT_TOA_METHOD`): "first-lobe",
        "first-lobe-cfr", "search-back" and "super-res" (realistic receivers), "first-path"
        (ideal: exact delay of the first detectable path plus eq. 3 noise), "peak",
        "leading-edge" or "paper" (the paper's model as written: lobe top of the first traced
        path plus eq. 3 noise)
    noise : bool, estimation noise on (False: no noise; ``first-path`` gives exact delays)
    delta_s : float, seconds between two base stations' transmissions
    clock_offset_max_s : float, device clock offsets are uniform in [0, this)
    budget : LinkBudget
    pulse : PulseShape
    first_lobe : FirstLobeSettings, settings of the first-lobe receiver (and of the first lobe
        of the receivers on the PRS CFR)
    prs : PrsSettings, the PRS CFR the receivers on it see (comb, timing offsets)
    search_back : SearchBackSettings, settings of ``search-back``
    super_res : SuperResSettings, settings of ``super-res``
    first_path_threshold : bool, ``first-path`` only: False takes the first traced path above
        the tracer's power floor instead of the first detectable one
    trace : TraceConfig, the tracer limits
    clearance_m : float, forklift underside above the floor
    """

    scenario: str
    band: str
    duration_s: float = 60.0
    rate_hz: float = 10.0
    seed: int = 1
    toa_method: str = DEFAULT_TOA_METHOD
    noise: bool = True
    delta_s: float = DELTA_S
    clock_offset_max_s: float = CLOCK_OFFSET_MAX_S
    budget: LinkBudget = field(default_factory=LinkBudget)
    pulse: PulseShape = field(default_factory=PulseShape)
    first_lobe: FirstLobeSettings = field(default_factory=FirstLobeSettings)
    prs: PrsSettings = field(default_factory=PrsSettings)
    search_back: SearchBackSettings = field(default_factory=SearchBackSettings)
    super_res: SuperResSettings = field(default_factory=SuperResSettings)
    first_path_threshold: bool = True
    trace: TraceConfig = field(default_factory=TraceConfig)
    clearance_m: float = FORKLIFT_CLEARANCE_M

    def validate(self) -> Band:
        """Check the settings (one-line :class:`HallrayError`); return the band."""
        if self.scenario not in SCENARIOS:
            raise HallrayError(f"unknown scenario {self.scenario!r}; use {' or '.join(SCENARIOS)}")
        band = get_band(self.band)
        if self.toa_method not in TOA_METHODS:
            raise HallrayError(
                f"unknown ToA method {self.toa_method!r}; use one of {', '.join(TOA_METHODS)}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise HallrayError(f"seed must be an integer, got {self.seed!r}")
        if self.seed < 0:
            raise HallrayError(f"seed must be >= 0, got {self.seed}")
        snapshot_times(self.duration_s, self.rate_hz)  # raises on a bad duration or rate
        for name in ("delta_s", "clock_offset_max_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise HallrayError(f"{name} must be a finite number >= 0, got {v!r}")
        return band

    @property
    def times_s(self) -> np.ndarray:
        """Epoch times, seconds."""
        return snapshot_times(self.duration_s, self.rate_hz)

    def receiver(self) -> Receiver:
        """The dataset's ToA receiver (checks the settings first)."""
        band = self.validate()
        return Receiver(self.toa_method, band, budget=self.budget, pulse=self.pulse,
                        first_lobe=self.first_lobe, prs=self.prs, search_back=self.search_back,
                        super_res=self.super_res,
                        first_path_threshold=self.first_path_threshold)  # fmt: skip

    def model(self) -> ToaModel:
        """The measurement model of this dataset (receiver, seed, schedule, clock offsets)."""
        return ToaModel(
            self.receiver(), int(self.seed), bool(self.noise), self.delta_s,
            self.clock_offset_max_s,
        )  # fmt: skip
