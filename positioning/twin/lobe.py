"""The first-lobe receiver without noise, vectorised over links: what the twin re-runs on paths.

A fingerprint map of schema v2 (:mod:`positioning.twin.fingerprint`) stores per cell and base
station the K strongest paths (delay, complex gain, direction of arrival, wavefront radius) and, in
its meta, the receiver's settings. The ``twin`` estimator moves those paths to a candidate position
(:func:`move_paths`) and runs this receiver on them (:meth:`LobeReceiver.toa`): the ToA it predicts
then includes the receiver's own bias from paths that overlap within one pulse, which changes within
a grid cell and which no interpolation of the map's ToAs reproduces.

This is the vectorised twin of the noiseless path of :mod:`raytrace.emulation.receivers`
(``prepare_first_lobe`` + ``measure_first_lobe`` with ``rng=None``): ``positioning`` never imports
``raytrace`` (docs/architecture.md), so the window and threshold rules are written here again,
while the pulse, its tabulation and the peak fit are the same code in both
(:mod:`positioning.model.pulse`). Same rules, in the same order:

1. paths whose own peak ``|A| / T`` is :attr:`LobeReceiver.negligible_db` below the noise std are
   dropped;
2. the strongest peak ``p_max`` of ``|s(t)|``, ``s(t) = sum_j A_j h(t - tau_j)`` with the raised
   cosine ``h`` of eq. 2, is searched on the ``T / oversampling`` grid within ``+-T/2`` of the
   strongest path and at the next :attr:`top_paths` - 1 strongest paths and one sample either
   side;
3. a window of samples ``t0 + k dt`` from the precursor extent before the earliest path that
   could cross the threshold alone to :attr:`post_t` periods after the first path that surely
   crosses it (or the strongest peak);
4. per sample the threshold ``max(gamma, rho p_max, env(lead) p_max + gamma [lead > 0])`` with
   ``gamma = sigma_n sqrt(alpha)`` (the noise threshold with the exact noise estimate) and
   ``env`` the pulse's precursor envelope before the strongest peak;
5. the first sample above it, the first falling sample after it (the lobe's top), refined by the
   quartic through the five samples around the top; a lobe that does not fit the window is
   measured again on the link's whole response.

The raised cosine is tabulated at ``T / 2048`` and interpolated linearly
(:func:`positioning.model.pulse.pulse_at`, error below 1.1e-7 of its peak);
``tests/test_lobe_agreement.py`` checks that both receivers give the same ToA on random path sets.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from ..errors import PositioningError
from ..model.pulse import envelope_table, precursor_extent_t, pulse_at, pulse_table, quartic_top
from ..model.tdoa import C0


@dataclass(frozen=True)
class LobeReceiver:
    """The noiseless first-lobe receiver (module docstring) and its settings.

    Attributes
    ----------
    frequency_hz : float, Hz, carrier (phase of moved paths)
    period_s : float, s, pulse period T = (1 + roll_off) / bandwidth
    roll_off : float, raised-cosine beta
    oversampling : int, samples per T
    span : int, the pulse is zero beyond +-span T
    noise_std : float, 1/s, correlator noise std sigma_n (a path of gain A peaks at |A| / T)
    alpha : float, CFAR power threshold factor
    rho : float, relative threshold (amplitude ratio to the strongest peak)
    negligible_db, min_crossing, sure_crossing, post_t, top_paths : the window rules
    """

    frequency_hz: float
    period_s: float
    roll_off: float
    oversampling: int
    span: int
    noise_std: float
    alpha: float
    rho: float
    negligible_db: float = -40.0
    min_crossing: float = 0.1
    sure_crossing: float = 2.0
    post_t: int = 2
    top_paths: int = 4

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise PositioningError(f"receiver model: {f.name} must be a finite number")
        if not (self.period_s > 0 and self.noise_std > 0 and self.alpha > 0 and 0 < self.rho < 1
                and 0 <= self.roll_off <= 1 and self.oversampling >= 2 and self.span >= 2
                and self.top_paths >= 1):  # fmt: skip
            raise PositioningError("receiver model: settings out of range")

    @classmethod
    def from_meta(cls, d: Any) -> LobeReceiver:
        """From a map's ``meta["receiver_model"]`` (one-line :class:`PositioningError`)."""
        if not isinstance(d, dict):
            raise PositioningError("receiver model: meta['receiver_model'] is not an object")
        names = {f.name for f in fields(cls)}
        missing = [n for n in ("frequency_hz", "period_s", "roll_off", "oversampling", "span",
                               "noise_std", "alpha", "rho") if n not in d]  # fmt: skip
        if missing:
            raise PositioningError(f"receiver model: missing {missing[0]!r}")
        kw = {k: v for k, v in d.items() if k in names}
        for k in ("oversampling", "span", "post_t", "top_paths"):
            if k in kw and isinstance(kw[k], float) and kw[k].is_integer():
                kw[k] = int(kw[k])
        return cls(**kw)

    def to_meta(self) -> dict[str, Any]:
        """The settings as a JSON object (``meta["receiver_model"]``)."""
        return asdict(self)

    @property
    def dt_s(self) -> float:
        """Sample spacing T / oversampling, s."""
        return self.period_s / self.oversampling

    @property
    def precursor_t(self) -> int:
        """Whole periods before a path beyond which the pulse stays below ``rho / 4``."""
        return precursor_extent_t(self.roll_off, self.rho, self.span)

    # ------------------------------------------------------------------------------------------
    def _response(self, t: np.ndarray, delay: np.ndarray, gain: np.ndarray) -> np.ndarray:
        """``s(t)`` (A, W) complex, 1/s, of links with paths ``delay, gain`` (A, K) at ``t``
        (A, W); padded paths have gain 0."""
        table = pulse_table(float(self.roll_off), int(self.span))
        h = pulse_at(t[:, :, None] - delay[:, None, :], self.period_s, table)
        g = gain / self.period_s
        return np.einsum("awk,ak->aw", h, g.real) + 1j * np.einsum("awk,ak->aw", h, g.imag)

    def toa(self, delay: np.ndarray, gain: np.ndarray, chunk_elems: int = 2_000_000) -> np.ndarray:
        """(A,) ToA of the first detected lobe, s; NaN where nothing is detected.

        Parameters
        ----------
        delay : (A, K) float, s, path delays (NaN: no path)
        gain : (A, K) complex, path gains (field amplitude relative to transmitted)
        """
        delay = np.asarray(delay, dtype=float)
        gain = np.asarray(gain, dtype=complex)
        if delay.ndim != 2 or delay.shape != gain.shape:
            raise PositioningError("LobeReceiver.toa: delay and gain must be (A, K) arrays")
        A, K = delay.shape
        out = np.full(A, np.nan)
        if A == 0 or K == 0:
            return out
        amp = np.abs(gain) / self.period_s
        keep = np.isfinite(delay) & (amp >= self.noise_std * 10.0 ** (self.negligible_db / 20.0))
        # paths in order of delay, dropped ones last with gain 0
        d = np.where(keep, delay, np.inf)
        order = np.argsort(d, axis=1, kind="stable")
        d = np.take_along_axis(d, order, axis=1)
        g = np.where(np.take_along_axis(keep, order, axis=1),
                     np.take_along_axis(gain, order, axis=1), 0.0)  # fmt: skip
        a = np.abs(g) / self.period_s
        valid = np.isfinite(d)
        k_used = max(1, int(valid.sum(axis=1).max()))  # padded slots are last: drop them
        d, g, a, valid = d[:, :k_used], g[:, :k_used], a[:, :k_used], valid[:, :k_used]
        K = k_used
        d0 = np.where(valid, d, 0.0)
        per_row = max(1, chunk_elems // max(1, K * 64))
        for s in range(0, A, per_row):
            r = slice(s, min(s + per_row, A))
            out[r] = self._toa_rows(d0[r], g[r], a[r], valid[r])
        return out

    def _toa_rows(self, d: np.ndarray, g: np.ndarray, a: np.ndarray, valid: np.ndarray):
        A, K = d.shape
        T, dt = self.period_s, self.dt_s
        res = np.full(A, np.nan)
        live_rows = valid.any(axis=1)
        if not live_rows.any():
            return res
        # 2. strongest peak
        ntop = min(self.top_paths, K)
        top = np.argsort(-np.where(valid, a, -1.0), axis=1, kind="stable")[:, :ntop]
        half = self.oversampling // 2
        t_top = np.take_along_axis(d, top, axis=1)
        ok_top = np.take_along_axis(valid, top, axis=1)
        cand = [t_top[:, :1] + np.arange(-half, half + 1)[None, :] * dt]
        cand_ok = [np.repeat(ok_top[:, :1], 2 * half + 1, axis=1)]
        if ntop > 1:
            cand.append((t_top[:, 1:, None] + np.arange(-1, 2)[None, None, :] * dt).reshape(A, -1))
            cand_ok.append(np.repeat(ok_top[:, 1:], 3, axis=1))
        tc = np.concatenate(cand, axis=1)
        okc = np.concatenate(cand_ok, axis=1)
        sc = np.abs(self._response(tc, d, g))
        sc = np.where(okc, sc, -1.0)
        k = np.argmax(sc, axis=1)
        rows = np.arange(A)
        pmax = np.maximum(sc[rows, k], 0.0)
        t_peak = tc[rows, k]
        # 3. window
        gamma = self.noise_std * math.sqrt(self.alpha)
        gamma0 = np.maximum(gamma, self.rho * pmax)
        can = valid & (a >= self.min_crossing * gamma0[:, None])
        start = np.where(can.any(axis=1), d[rows, np.argmax(can, axis=1)], t_peak)
        sure = valid & (a >= self.sure_crossing * gamma0[:, None])
        t_sure = np.where(sure.any(axis=1), d[rows, np.argmax(sure, axis=1)], np.inf)
        t_end = np.minimum(t_sure, t_peak) + self.post_t * T
        t0 = start - self.precursor_t * T
        t_end = np.maximum(t_end, t0 + (self.post_t + 2) * T)
        n = np.maximum(np.floor((t_end - t0) / dt).astype(np.int64) + 1, 5)
        live = live_rows & (pmax >= gamma)  # 5. the strongest peak is above the noise threshold
        t, ok = self._scan(t0, n, d, g, pmax, t_peak, gamma, live)
        # a lobe that does not fit: the whole response
        redo = live & ~ok
        if redo.any():
            last = np.max(np.where(valid, d, -np.inf), axis=1)
            first = d[rows, np.argmax(valid, axis=1)]
            t0w = first - self.precursor_t * T
            t_endw = np.maximum(last + self.span * T, t0w + (self.post_t + 2) * T)
            nw = np.maximum(np.floor((t_endw - t0w) / dt).astype(np.int64) + 1, 5)
            i = np.flatnonzero(redo)
            t2, ok2 = self._scan(t0w[i], nw[i], d[i], g[i], pmax[i], t_peak[i], gamma,
                                 np.ones(i.size, bool))  # fmt: skip
            t[i], ok[i] = t2, ok2
        res[live & ok] = t[live & ok]
        return res

    def _scan(self, t0, n, d, g, pmax, t_peak, gamma, live, block: int = 128):
        """ToA (A,) and ok (A,) of the first lobe in the windows ``t0 + k dt``, ``k < n``; rows
        in blocks of similar window length (padding every row to the longest is slow)."""
        t = np.full(t0.size, np.nan)
        ok = np.zeros(t0.size, dtype=bool)
        order = np.argsort(n, kind="stable")
        for s in range(0, order.size, block):
            r = order[s : s + block]
            t[r], ok[r] = self._scan_block(t0[r], n[r], d[r], g[r], pmax[r], t_peak[r], gamma,
                                           live[r])  # fmt: skip
        return t, ok

    def _scan_block(self, t0, n, d, g, pmax, t_peak, gamma, live):
        """:meth:`_scan` of one block of rows."""
        A = t0.size
        W = int(n.max()) if A else 0
        T, dt = self.period_s, self.dt_s
        idx = np.arange(W)[None, :]
        inside = idx < n[:, None]
        tk = t0[:, None] + idx * dt
        amp = np.where(inside, np.abs(self._response(tk, d, g)), 0.0)
        x, env = envelope_table(float(self.roll_off), int(self.span))
        lead = (t_peak[:, None] - tk) / T
        side = np.where(lead > 0, np.interp(lead, x, env, right=0.0), 0.0)
        thr = np.maximum(np.maximum(gamma, self.rho * pmax)[:, None],
                         side * pmax[:, None] + gamma * (lead > 0))  # fmt: skip
        above = (amp >= thr) & inside
        has = above.any(axis=1)
        cross = np.argmax(above, axis=1)
        falling = np.zeros_like(above)
        falling[:, :-1] = amp[:, 1:] < amp[:, :-1]
        top = np.argmax(falling & (idx >= cross[:, None]) & inside, axis=1)
        ok = live & has & (cross > 0) & (top >= 2) & (top <= n - 3)
        k5 = np.clip(top[:, None] + np.arange(-2, 3)[None, :], 0, max(W - 1, 0))
        y = np.take_along_axis(amp, k5, axis=1)
        u, _ = quartic_top(y)
        return t0 + (top + u) * dt, ok


def move_paths(
    delay: np.ndarray,
    gain: np.ndarray,
    direction: np.ndarray,
    radius: np.ndarray,
    disp: np.ndarray,
    frequency_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Paths stored at a cell, moved with the receiver by ``disp``.

    Each path's wave is spherical about its virtual source at ``radius`` behind the receiver
    along ``-direction`` (the image source of a reflection or line of sight, the edge of a
    diffraction; ``inf``: plane wave): ``tau(p) = tau + (|disp + r u| - r) / c``, amplitude
    ``r / |disp + r u|``, phase turned by ``exp(-j 2 pi f dtau)``.

    Parameters
    ----------
    delay : (..., K) float, s; gain : (..., K) complex
    direction : (..., K, 3) float, unit vector of the last segment, towards the receiver
    radius : (..., K) float, m, wavefront radius at the cell (inf: plane wave)
    disp : (..., 3) float, m, receiver displacement from the cell
    frequency_hz : float, carrier

    Returns
    -------
    delay, gain of the moved paths (same shapes)
    """
    plane = ~np.isfinite(radius)
    r = np.where(plane, 1.0, radius)
    dnew = np.linalg.norm(disp[..., None, :] + r[..., None] * direction, axis=-1)
    dl = np.where(plane, np.einsum("...kc,...c->...k", direction, disp), dnew - r)
    dt = dl / C0
    scale = np.where(plane, 1.0, r / np.maximum(dnew, 1e-9))
    return delay + dt, gain * scale * np.exp(-2j * np.pi * frequency_hz * dt)
