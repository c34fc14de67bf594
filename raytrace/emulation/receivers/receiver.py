"""All ToA estimators behind one interface: :class:`Receiver` (``first-lobe``, the
realistic receiver of :mod:`.first_lobe`; ``first-path``, the ideal one: the first detectable
path's exact delay plus eq. 3 noise; ``peak`` and ``leading-edge`` on the whole response;
``paper``, the paper's model as written, :mod:`.paper`; ``first-lobe-cfr``, ``search-back`` and
``super-res`` on the PRS CFR) and :func:`estimate_toa`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ...core.constants import linear_power_to_db
from ...core.errors import HallrayError
from ..bands import Band, get_band
from ..channel.budget import LinkBudget, toa_std_eq3_s
from ..channel.cfr import PrsSettings
from ..channel.cir import DiscreteCIR, SharedPaths, first_detectable_path
from ..channel.pulse import PulseShape
from ..channel.response import pulse_toa
from .first_lobe import FirstLobeSettings, LobePlan, measure_first_lobe, prepare_first_lobe
from .paper import PaperPlan, first_traced_path, measure_paper, prepare_paper
from .search_back import SearchBackSettings, measure_search_back, prepare_cfr
from .super_res import SuperResSettings, measure_super_res

#: Names accepted as ``method``.
TOA_METHODS = (
    "first-lobe", "first-path", "peak", "leading-edge", "paper", "first-lobe-cfr", "search-back",
    "super-res",
)  # fmt: skip
#: The receivers that work on the PRS channel frequency response (:mod:`..channel.cfr`).
CFR_METHODS = ("first-lobe-cfr", "search-back", "super-res")
#: The default ToA estimator of datasets, sweeps and maps: ``search-back``, chosen by the receiver
#: study (docs/channel.md, "Receiver study: the default").
DEFAULT_TOA_METHOD = "search-back"


@dataclass(frozen=True)
class ToAEstimate:
    """Per-link ToA estimates.

    Attributes
    ----------
    toa_s : (L,) float, seconds
        Estimated time of arrival (propagation delay, transmit time 0); NaN where not detected.
    detected : (L,) bool
        True where ``toa_s`` is a number. ``first-path``: the link has a detectable path.
        ``peak`` / ``leading-edge``: additionally the response crossed the noise threshold.
        ``first-lobe``: the receiver's own thresholds were crossed.
    first_path : (L,) int64
        Index (into the caller's path arrays) of the first detectable path by the link budget's
        rule (:meth:`LinkBudget.detectable`), -1 if none: the channel's first arrival. ``paper``
        and ``first-path`` without its threshold: the first traced path above the tracer's
        power floor (:data:`raytrace.emulation.receivers.paper.POWER_FLOOR_DB`).
    snr_db : (L,) float, dB
        SNR before processing gain (the SNR of eq. 3), NaN if none. ``first-lobe``: measured by the
        receiver on its first lobe; the others: the true SNR of the first detectable path.
    sigma_s : (L,) float, seconds
        Eq. 3 standard deviation at ``snr_db``: the noise ``first-path`` adds (0 with noise off),
        a reference for the others; NaN if none.
    method : str
        Estimator name.
    peak_ratio_db : (L,) float, dB
        ``first-lobe``: the first lobe's peak over the strongest peak (<= 0); NaN otherwise.
    lobe_width : (L,) float
        ``first-lobe``: half-amplitude width of the first lobe over an isolated pulse's; NaN
        otherwise or where the lobe leaves the window.
    lobe_path : (L,) int64
        ``first-lobe`` and ``paper``: index of the path contributing most at the measured ToA
        (``paper``: at the noiseless lobe top), -1 if none; ``first-path``: ``first_path``; -1
        for the others.
    """

    toa_s: np.ndarray
    detected: np.ndarray
    first_path: np.ndarray
    snr_db: np.ndarray
    sigma_s: np.ndarray
    method: str
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    lobe_path: np.ndarray


@dataclass(frozen=True)
class PreparedLinks:
    """What a receiver computes from the paths alone (reused by every epoch of a snapshot).

    Attributes
    ----------
    n_links : int
    link, delay_s, gain : checked path arrays
    first_path : (L,) int64, first detectable path per link (-1 if none)
    snr : (L,) float, linear SNR of that path before processing gain (NaN if none)
    cir : DiscreteCIR, paths per link in order of arrival
    plan : LobePlan or None, the first-lobe receiver's windows
    paper : PaperPlan or None, the ``paper`` receiver's noiseless lobe tops
    """

    n_links: int
    link: np.ndarray
    delay_s: np.ndarray
    gain: np.ndarray
    first_path: np.ndarray
    snr: np.ndarray
    cir: DiscreteCIR
    plan: LobePlan | None
    paper: PaperPlan | None = None


class Receiver:
    """A ToA estimator bound to a band, link budget, pulse and settings.

    :meth:`prepare` does the work that depends on the paths alone; :meth:`measure` adds one
    epoch's noise. For a scene that does not change, prepare once and measure every epoch.

    Methods (``method``)
    --------------------
    ``first-lobe`` (default)
        The realistic receiver (:mod:`raytrace.emulation.receivers.first_lobe`): correlator output of all paths plus noise, CA-CFAR
        and relative thresholds, ToA at the top of the first detected lobe.
    ``first-path`` (ideal)
        Exact delay of the first *detectable* path (:meth:`LinkBudget.detectable`: a detection
        threshold on its post-correlation SNR, which the paper does not have) plus zero-mean
        Gaussian error of eq. 3, ``sigma^2 = 1 / ((2 pi B)^2 t_s B SNR)`` s^2, with ``t_s`` =
        :meth:`LinkBudget.integration_time_s` and SNR that path's ``P_rx / N``. No pulse, so no
        overlap bias. ``first_path_threshold=False``: the first traced path above the tracer's
        power floor instead.
    ``paper`` (the paper's model as written, :mod:`.paper`)
        The first traced path above the tracer's power floor (no detection threshold), its ToA
        the top of the lobe of ``|sum_j A_j h(t - tau_j)|`` that holds it (eq. 2: the bias of the
        paths), plus eq. 3 noise at that path's SNR.
    ``peak``
        Time of the maximum of ``|r(t)|`` over the link's whole response (:func:`pulse_toa`).
    ``leading-edge``
        First sample of the whole response at or above ``max(peak * 10**(leading_edge_db/20),
        noise threshold)`` (noise power known), then the top of that lobe (:func:`pulse_toa`).
    ``first-lobe-cfr``, ``search-back``, ``super-res``
        On the delay profile of the PRS channel frequency response
        (:mod:`raytrace.emulation.channel.cfr`): the first-lobe rule; the first lobe and a
        sidelobe-aware search for an earlier arrival (:mod:`.search_back`); a sparse fit of the
        first lobe's region (:mod:`.super_res`).

    Parameters
    ----------
    method : str, one of :data:`TOA_METHODS`
    band : Band or band name
    budget : LinkBudget, optional
    pulse : PulseShape, optional
    first_lobe : FirstLobeSettings, optional (also the first lobe of the CFR receivers)
    leading_edge_db : float, dB, threshold of ``leading-edge`` relative to the strongest sample
        (default -12 dB, 2.3 dB above the pulse's first sidelobe)
    prs : PrsSettings, optional, the CFR the CFR receivers see (comb, timing offsets)
    search_back : SearchBackSettings, optional, settings of ``search-back``
    super_res : SuperResSettings, optional, settings of ``super-res``
    first_path_threshold : bool, ``first-path`` only: True (default) takes the first path the
        link budget detects, False the first traced path above the tracer's power floor
    """

    def __init__(
        self,
        method: str = DEFAULT_TOA_METHOD,
        band: Band | str = "c-band",
        *,
        budget: LinkBudget | None = None,
        pulse: PulseShape | None = None,
        first_lobe: FirstLobeSettings | None = None,
        leading_edge_db: float = -12.0,
        prs: PrsSettings | None = None,
        search_back: SearchBackSettings | None = None,
        super_res: SuperResSettings | None = None,
        first_path_threshold: bool = True,
    ) -> None:
        if method not in TOA_METHODS:
            raise HallrayError(f"unknown ToA method {method!r}; known: {', '.join(TOA_METHODS)}")
        if not (isinstance(leading_edge_db, (int, float)) and leading_edge_db < 0):
            raise HallrayError(
                f"leading_edge_db must be a negative number, got {leading_edge_db!r}"
            )
        self.method = method
        self.band = get_band(band)
        self.budget = budget or LinkBudget()
        self.pulse = pulse or PulseShape()
        self.first_lobe = first_lobe or FirstLobeSettings()
        self.leading_edge_db = float(leading_edge_db)
        self.prs = prs or PrsSettings()
        self.search_back = search_back or SearchBackSettings()
        self.super_res = super_res or SuperResSettings()
        if not isinstance(first_path_threshold, (bool, np.bool_)):
            raise HallrayError(
                f"first_path_threshold must be True or False, got {first_path_threshold!r}"
            )
        self.first_path_threshold = bool(first_path_threshold)

    def settings_meta(self) -> dict[str, object]:
        """The settings of this receiver that are not the link budget's or the pulse's, as a
        JSON object (a dataset's ``meta.json`` ``receiver_settings``)."""
        out: dict[str, object] = {"method": self.method}
        if self.method in ("first-lobe", *CFR_METHODS):
            out["first_lobe"] = asdict(self.first_lobe)
        if self.method in CFR_METHODS:
            out["prs"] = {"comb": self.prs.comb, "timing_offsets_s": list(self.prs.timing_offsets_s)}
        if self.method == "search-back":
            out["search_back"] = asdict(self.search_back)
        if self.method == "super-res":
            out["super_res"] = asdict(self.super_res)
        if self.method == "leading-edge":
            out["leading_edge_db"] = self.leading_edge_db
        return out

    def prepare(
        self,
        link: np.ndarray,
        delay_s: np.ndarray,
        gain: np.ndarray,
        n_links: int,
        shared: SharedPaths | None = None,
    ) -> PreparedLinks:
        """Deterministic part of the estimate for the paths ``link, delay_s, gain`` (see
        :func:`estimate_toa`).

        ``shared``: a :class:`~raytrace.emulation.channel.cir.SharedPaths` of these very arrays
        (another one is not used), whose CIR and first paths other receivers of the band
        computed already; the result is the same.
        """
        if shared is None or not shared.holds(link, delay_s, gain, n_links):
            shared = SharedPaths(link, delay_s, gain, n_links)
        link, delay_s, gain, n_links = shared.link, shared.delay_s, shared.gain, shared.n_links
        band, budget = self.band, self.budget
        if self.method == "paper" or (
            self.method == "first-path" and not self.first_path_threshold
        ):
            first = shared.first_path(
                "traced", lambda: first_traced_path(link, delay_s, gain, n_links)
            )
        else:

            def detectable_first() -> np.ndarray:
                ok = budget.detectable(gain, band, link, n_links)
                return first_detectable_path(link, delay_s, ok, n_links)

            first = shared.first_path(("detectable", budget, band), detectable_first)
        has = first >= 0
        snr = np.full(n_links, np.nan)
        snr[has] = budget.path_snr(gain[first[has]], band)
        cir = shared.cir
        plan = None
        if self.method == "first-lobe":
            plan = prepare_first_lobe(cir, band, budget, self.pulse, self.first_lobe)
        elif self.method in CFR_METHODS:
            depth = {"search-back": self.search_back.depth, "super-res": self.super_res.depth}
            plan = prepare_cfr(cir, band, budget, self.pulse, self.first_lobe, self.prs,
                               depth.get(self.method))  # fmt: skip
        paper = None
        if self.method == "paper":
            paper = prepare_paper(link, delay_s, gain, n_links, band, budget, self.pulse,
                                  first=first.copy(), cir=cir)  # fmt: skip
        return PreparedLinks(n_links, link, delay_s, gain, first, snr, cir, plan, paper)

    def measure(
        self, prep: PreparedLinks, rng: np.random.Generator | None, *, noise: bool = True
    ) -> ToAEstimate:
        """One epoch's estimates for prepared paths.

        Parameters
        ----------
        prep : PreparedLinks, from :meth:`prepare` of this receiver
        rng : numpy.random.Generator, required when ``noise`` is True
        noise : bool, False: no estimation noise (``first-path`` returns the exact first
            detectable delay); detectability and thresholds still follow the link budget
        """
        if noise and not isinstance(rng, np.random.Generator):
            raise HallrayError("estimate_toa: noise=True needs rng=numpy.random.default_rng(seed)")
        band, budget, n = self.band, self.budget, prep.n_links
        first, has = prep.first_path, prep.first_path >= 0
        t_s = budget.integration_time_s(band)
        nan = np.full(n, np.nan)
        toa = nan.copy()
        ratio, width, lobe = nan.copy(), nan.copy(), np.full(n, -1, dtype=np.int64)
        snr = prep.snr
        if self.method == "first-path":
            sigma = toa_std_eq3_s(snr, band.bandwidth_hz, t_s)
            toa[has] = prep.delay_s[first[has]]
            if noise:
                toa[has] += sigma[has] * rng.standard_normal(int(has.sum()))
            detected = has.copy()
            lobe = first.copy()
        elif self.method in ("first-lobe", *CFR_METHODS):
            assert prep.plan is not None, "PreparedLinks from another receiver"
            rng_ = rng if noise else None
            if self.method == "search-back":
                m = measure_search_back(prep.plan, rng_, self.search_back)
            elif self.method == "super-res":
                m = measure_super_res(prep.plan, rng_, self.super_res)
            else:
                m = measure_first_lobe(prep.plan, rng_)
            toa, detected = m.toa_s, m.detected
            snr = np.asarray(10.0 ** (m.snr_db / 10.0), dtype=float)
            ratio, width, lobe = m.peak_ratio_db, m.lobe_width, m.lobe_path
        elif self.method == "paper":
            assert prep.paper is not None, "PreparedLinks from another receiver"
            toa, detected = measure_paper(prep.paper, rng if noise else None)
            lobe = prep.paper.lobe_path.copy()
        else:
            links = np.flatnonzero(has)
            toa[links], found = pulse_toa(
                prep.cir, links, band, self.pulse, budget, rng if noise else None, self.method,
                self.leading_edge_db,
            )  # fmt: skip
            detected = np.zeros(n, dtype=bool)
            detected[links] = found
        sigma = toa_std_eq3_s(snr, band.bandwidth_hz, t_s)
        with np.errstate(divide="ignore", invalid="ignore"):
            snr_db = np.asarray(linear_power_to_db(snr), dtype=float)
        return ToAEstimate(
            toa, detected, first, snr_db, np.asarray(sigma, dtype=float), self.method, ratio,
            width, lobe,
        )  # fmt: skip


def estimate_toa(
    link: np.ndarray,
    delay_s: np.ndarray,
    gain: np.ndarray,
    n_links: int,
    band: Band | str,
    *,
    method: str = DEFAULT_TOA_METHOD,
    budget: LinkBudget | None = None,
    pulse: PulseShape | None = None,
    rng: np.random.Generator | None = None,
    noise: bool = True,
    leading_edge_db: float = -12.0,
    first_lobe: FirstLobeSettings | None = None,
) -> ToAEstimate:
    """Time of arrival of every link from its paths (one epoch; see :class:`Receiver`).

    Parameters
    ----------
    link : (P,) int
        Link of each path, in ``[0, n_links)``.
    delay_s : (P,) float, seconds
    gain : (P,) complex
        Field amplitude relative to transmitted, between isotropic antennas.
    n_links : int
    band : Band or str
        Band or band name (:func:`raytrace.emulation.bands.get_band`).
    method : {"first-lobe", "first-path", "peak", "leading-edge", "paper"}
    budget : LinkBudget, optional
        Default :class:`LinkBudget()`.
    pulse : PulseShape, optional
        Default :class:`PulseShape()` (beta = 0.25, T = 1.25 / B).
    rng : numpy.random.Generator
        Noise source; required when ``noise`` is True. Links are processed in index order, so the
        same seed and inputs give the same estimates.
    noise : bool
        False: no estimation noise; detectability and thresholds still follow the link budget.
    leading_edge_db : float, dB
        Threshold of ``leading-edge`` relative to the strongest sample (default -12 dB).
    first_lobe : FirstLobeSettings, optional
        Settings of ``first-lobe``.

    Returns
    -------
    ToAEstimate
    """
    rx = Receiver(
        method, band, budget=budget, pulse=pulse, first_lobe=first_lobe,
        leading_edge_db=leading_edge_db,
    )  # fmt: skip
    if noise and not isinstance(rng, np.random.Generator):
        raise HallrayError("estimate_toa: noise=True needs rng=numpy.random.default_rng(seed)")
    return rx.measure(rx.prepare(link, delay_s, gain, n_links), rng, noise=noise)
