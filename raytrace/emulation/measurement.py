"""The ToA measurement model: what a device measures per epoch, point and base station.

Paper, section II: the base stations are synchronised and transmit in turn, ``delta`` = 10 ms
apart; the device measures every time of arrival with its own clock, whose offset is unknown and
cancels in the TDoAs of eq. 5. So the ToA the device measures in epoch ``e`` at point ``p`` from
base station ``b`` is::

    toa_s[e, p, b] = tx_offset_s[b] + clock_offset_s[e, p] + delay_hat_s[e, p, b]

* ``tx_offset_s[b] = b * delta_s``: base station ``b`` in the scene's order (the schedule);
* ``clock_offset_s[e, p]``: one draw per epoch and point (one device, one clock: the same for all
  base stations of that fix), uniform in ``[0, clock_offset_max_s)``;
* ``delay_hat_s``: the receiver's estimated propagation delay of the link
  (:class:`raytrace.emulation.receivers.Receiver` on the paths: detection by the link budget,
  eq. 3 noise or the band-limited estimators); NaN where the receiver detects nothing, and then
  ``toa_s`` is NaN too.

Random streams: epoch ``e`` draws from ``numpy.random.SeedSequence([seed, e]).spawn(n)`` (see
:func:`epoch_rngs`): stream 0 the clock offsets, stream 1 the estimator noise, further streams
for studies (the sweep's NLoS injection uses stream 2). Results therefore depend only on the
seed and the epoch index, not on how epochs are grouped into chunks or worker processes, and
every consumer that measures the same paths with the same seed gets the same numbers (common
random numbers across scenarios and bands).

This is the one implementation of the model: the dataset writer (:mod:`raytrace.emulation.dataset`)
and the sweeps (:mod:`raytrace.studies.sweep`) both call :meth:`ToaModel.measure`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..solver.paths import Paths
from .bands import Band
from .channel.budget import LinkBudget
from .channel.cir import SharedPaths
from .channel.pulse import PulseShape
from .receivers.first_lobe import FirstLobeSettings
from .receivers.receiver import DEFAULT_TOA_METHOD, PreparedLinks, Receiver

#: Period between two base stations' transmissions, s (paper, section II).
DELTA_S = 0.01
#: The device clock offset of a fix is drawn uniformly from [0, CLOCK_OFFSET_MAX_S), s.
CLOCK_OFFSET_MAX_S = 1e-3
#: Index of the clock-offset and estimator-noise streams among an epoch's streams.
CLOCK_STREAM, NOISE_STREAM = 0, 1


def epoch_rngs(seed: int, epoch: int, n_streams: int = 2) -> tuple[np.random.Generator, ...]:
    """The random streams of an epoch: ``SeedSequence([seed, epoch]).spawn(n_streams)``.

    Stream :data:`CLOCK_STREAM` (0) draws the clock offsets, :data:`NOISE_STREAM` (1) the
    estimator noise; a study may ask for more (stream ``k`` is the same whatever ``n_streams``).
    """
    seqs = np.random.SeedSequence([int(seed), int(epoch)]).spawn(n_streams)
    return tuple(np.random.default_rng(s) for s in seqs)


def tx_offsets_s(n_bs: int, delta_s: float = DELTA_S) -> np.ndarray:
    """(B,) float, seconds: the schedule, base station ``b`` transmits at ``b * delta_s``."""
    return np.arange(n_bs) * delta_s


# --------------------------------------------------------------------------------------------
# paths -> per-link ToA (the receiver call)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinkToA:
    """Per-link ToA of one epoch (L = transmitters x receivers, link = tx * R + rx).

    Attributes
    ----------
    toa_s : (L,) float, seconds, estimated propagation delay (no schedule, no clock offset);
        NaN where not detected
    detected : (L,) bool
    snr_db : (L,) float, dB, SNR before processing gain (measured on the first lobe by
        ``first-lobe``, the first detectable path's otherwise; NaN if none)
    sigma_s : (L,) float, seconds, eq. 3 standard deviation at that SNR (NaN if none)
    first_path : (L,) int, index of the first detectable path into the paths, -1 if none
    first_kind : (L,) str, its interaction sequence ("LoS", "R", "TD", ...; "" if none)
    los : (L,) bool, the link has an unobstructed line-of-sight path (detectable or not)
    peak_ratio_db : (L,) float, dB, ``first-lobe``: first lobe's peak over the strongest (NaN else)
    lobe_width : (L,) float, ``first-lobe``: first lobe's half-amplitude width over an isolated
        pulse's (NaN else)
    lobe_kind : (L,) str, kind of the path that dominates the measured lobe (``first-path``: the
        first path's kind; "" if none or not known)
    """

    toa_s: np.ndarray
    detected: np.ndarray
    snr_db: np.ndarray
    sigma_s: np.ndarray
    first_path: np.ndarray
    first_kind: np.ndarray
    los: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    lobe_kind: np.ndarray


def _kinds(paths: Paths, index: np.ndarray) -> np.ndarray:
    """Kind labels of the paths ``index`` (-1: "")."""
    kind = np.full(index.size, "", dtype=object)
    has = index >= 0
    if has.any():
        kind[has] = paths.select(index[has]).kind_label
    return kind.astype(str)


def prepare_links(
    paths: Paths, receiver: Receiver, shared: SharedPaths | None = None
) -> PreparedLinks:
    """The receiver's path-only work for ``paths`` (reusable by every epoch of a snapshot);
    ``shared``: :func:`shared_paths` of these paths, kept between the receivers of a band."""
    return receiver.prepare(paths.link, paths.delay_s, paths.gain, paths.n_links, shared)


def shared_paths(paths: Paths) -> SharedPaths:
    """The paths' :class:`~raytrace.emulation.channel.cir.SharedPaths`: the CIR and first paths
    that several receivers of the same paths compute once (:func:`prepare_links`)."""
    return SharedPaths(paths.link, paths.delay_s, paths.gain, paths.n_links)


def link_los(paths: Paths) -> np.ndarray:
    """(L,) bool: the links of ``paths`` with an unobstructed line-of-sight path (detectable or
    not)."""
    return np.bincount(paths.link[paths.los], minlength=paths.n_links) > 0


def emulate_toa(
    paths: Paths,
    band: Band | str,
    *,
    method: str = DEFAULT_TOA_METHOD,
    budget: LinkBudget | None = None,
    pulse: PulseShape | None = None,
    first_lobe: FirstLobeSettings | None = None,
    rng: np.random.Generator | None = None,
    noise: bool = True,
    receiver: Receiver | None = None,
    prepared: PreparedLinks | None = None,
    los: np.ndarray | None = None,
) -> LinkToA:
    """Times of arrival of every link of ``paths`` (:class:`raytrace.emulation.receivers.Receiver`)
    with the first path's kind and the link's line-of-sight flag.

    Parameters
    ----------
    paths : Paths
    band : Band or band name
    method, budget, pulse, first_lobe, rng, noise : as in
        :func:`raytrace.emulation.receivers.estimate_toa`
    receiver : Receiver, optional, used instead of ``band, method, budget, pulse, first_lobe``
    prepared : PreparedLinks, optional, ``prepare_links(paths, receiver)`` done before (a scene
        that does not change between epochs)
    los : (L,) bool, optional, :func:`link_los` of ``paths`` computed before

    Returns
    -------
    LinkToA
    """
    rx = receiver or Receiver(method, band, budget=budget, pulse=pulse, first_lobe=first_lobe)
    prep = prepared if prepared is not None else prepare_links(paths, rx)
    est = rx.measure(prep, rng, noise=noise)
    first = np.asarray(est.first_path, dtype=np.int64)
    los = link_los(paths) if los is None else los
    return LinkToA(
        toa_s=np.asarray(est.toa_s, dtype=float),
        detected=np.asarray(est.detected, dtype=bool),
        snr_db=np.asarray(est.snr_db, dtype=float),
        sigma_s=np.asarray(est.sigma_s, dtype=float),
        first_path=first,
        first_kind=_kinds(paths, first),
        los=los,
        peak_ratio_db=np.asarray(est.peak_ratio_db, dtype=float),
        lobe_width=np.asarray(est.lobe_width, dtype=float),
        lobe_kind=_kinds(paths, np.asarray(est.lobe_path, dtype=np.int64)),
    )


# --------------------------------------------------------------------------------------------
# the model: epochs x points x base stations
# --------------------------------------------------------------------------------------------

#: Per-link fields of :class:`LinkToA` that :class:`Measurements` keeps, as (E, N, B) arrays.
_LINK_FIELDS = (
    "detected",
    "los",
    "first_kind",
    "snr_db",
    "sigma_s",
    "peak_ratio_db",
    "lobe_width",
    "lobe_kind",
)


@dataclass(frozen=True)
class Measurements:
    """What the devices measure in a set of epochs (E epochs, N points, B base stations).

    Attributes
    ----------
    epochs : (E,) int, the epoch indices (their random streams, :func:`epoch_rngs`)
    toa_s : (E, N, B) float, seconds, measured ToA in the device clock (module docstring);
        NaN where not detected
    delay_s : (E, N, B) float, seconds, estimated propagation delay (no schedule, no clock
        offset); NaN where not detected
    tx_offset_s : (B,) float, seconds, the schedule
    clock_offset_s : (E, N) float, seconds, the device clock offset of each fix
    detected : (E, N, B) bool
    los : (E, N, B) bool, the link has an unobstructed line-of-sight path (detectable or not)
    first_kind : (E, N, B) str, interaction sequence of the first detectable path ("" if none)
    snr_db : (E, N, B) float, dB, SNR before processing gain (NaN if none)
    sigma_s : (E, N, B) float, seconds, eq. 3 standard deviation at that SNR (NaN if none)
    peak_ratio_db : (E, N, B) float, dB, ``first-lobe`` only (NaN else)
    lobe_width : (E, N, B) float, ``first-lobe`` only (NaN else)
    lobe_kind : (E, N, B) str, kind of the path that dominates the measured lobe ("" if none)
    """

    epochs: np.ndarray
    toa_s: np.ndarray
    delay_s: np.ndarray
    tx_offset_s: np.ndarray
    clock_offset_s: np.ndarray
    detected: np.ndarray
    los: np.ndarray
    first_kind: np.ndarray
    snr_db: np.ndarray
    sigma_s: np.ndarray
    peak_ratio_db: np.ndarray
    lobe_width: np.ndarray
    lobe_kind: np.ndarray

    @classmethod
    def concatenate(cls, parts: Sequence[Measurements]) -> Measurements:
        """The epochs of ``parts`` one after the other (same points, base stations, schedule)."""
        if not parts:
            raise ValueError("Measurements.concatenate needs at least one part")
        joined = {
            name: np.concatenate([getattr(p, name) for p in parts])
            for name in ("epochs", "toa_s", "delay_s", "clock_offset_s", *_LINK_FIELDS)
        }
        return cls(tx_offset_s=parts[0].tx_offset_s, **joined)

    def counts(self) -> np.ndarray:
        """(4,) int: ToAs (rows), detected, with a LoS path, detected with a LoS first path."""
        det = self.detected
        return np.array(
            [
                det.size,
                int(det.sum()),
                int(self.los.sum()),
                int((det & (self.first_kind == "LoS")).sum()),
            ]
        )


@dataclass(frozen=True)
class ToaModel:
    """The ToA measurement model (module docstring) bound to a receiver and a seed.

    Attributes
    ----------
    receiver : Receiver, the ToA estimator (band, link budget, method, settings)
    seed : int, root of the epochs' random streams
    noise : bool, estimation noise on (False: ``first-path`` gives exact first detectable delays)
    delta_s : float, seconds between two base stations' transmissions
    clock_offset_max_s : float, seconds, clock offsets are uniform in [0, this)
    """

    receiver: Receiver
    seed: int
    noise: bool = True
    delta_s: float = DELTA_S
    clock_offset_max_s: float = CLOCK_OFFSET_MAX_S

    def prepare(self, paths: Paths, shared: SharedPaths | None = None) -> PreparedLinks:
        """The receiver's path-only work (do it once for a scene that does not change);
        ``shared``: :func:`shared_paths` of ``paths``, kept between the models of a band."""
        return prepare_links(paths, self.receiver, shared)

    def measure(
        self,
        paths: Paths,
        epochs: Sequence[int],
        prepared: PreparedLinks | None = None,
        los: np.ndarray | None = None,
    ) -> Measurements:
        """Measure the given epochs on the same paths (base stations = the paths' transmitters,
        points = their receivers).

        Parameters
        ----------
        paths : Paths, of B transmitters (base stations) and N receivers (points)
        epochs : sequence of int, epoch indices (each draws from its own streams)
        prepared : PreparedLinks, optional, :meth:`prepare` of ``paths`` done before
        los : (L,) bool, optional, :func:`link_los` of ``paths`` (the models of a band share it)

        Returns
        -------
        Measurements, with E = len(epochs)
        """
        n_b, n_p = len(paths.tx), len(paths.rx)
        n_e = len(epochs)
        prep = prepared if prepared is not None else self.prepare(paths)
        los = link_los(paths) if los is None else los  # the same for every epoch of the paths
        tx_offset = tx_offsets_s(n_b, self.delta_s)
        clock = np.empty((n_e, n_p))
        per_link: dict[str, list[np.ndarray]] = {k: [] for k in ("toa_s", *_LINK_FIELDS)}
        # one receiver call per epoch: each epoch draws from its own streams (module docstring)
        for i, e in enumerate(epochs):
            streams = epoch_rngs(self.seed, e)
            clock[i] = streams[CLOCK_STREAM].uniform(0.0, self.clock_offset_max_s, n_p)
            est = emulate_toa(
                paths, self.receiver.band, receiver=self.receiver, prepared=prep,
                rng=streams[NOISE_STREAM], noise=self.noise, los=los,
            )  # fmt: skip
            for name, values in per_link.items():
                # link = bs * N + point -> (N, B)
                values.append(getattr(est, name).reshape(n_b, n_p).T)
        arrays = {k: np.array(v).reshape(n_e, n_p, n_b) for k, v in per_link.items()}
        delay = np.where(arrays["detected"], arrays.pop("toa_s"), np.nan)
        return Measurements(
            epochs=np.asarray(epochs, dtype=np.int64).reshape(n_e),
            toa_s=tx_offset[None, None, :] + clock[:, :, None] + delay,
            delay_s=delay,
            tx_offset_s=tx_offset,
            clock_offset_s=clock,
            **arrays,
        )
