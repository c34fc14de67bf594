"""The twin's receiver model (positioning.twin.lobe) against the tracer's first-lobe receiver.

positioning must not import raytrace, so the window and threshold rules of the noiseless
first-lobe receiver are written twice (the pulse, its table and the peak fit are one module,
positioning.model.pulse, that both use). This test, outside both packages, runs both on the
same random path sets and requires the same detections and ToAs within ``TOL_T`` pulse periods.
"""

from __future__ import annotations

import numpy as np
import pytest

from positioning.twin.lobe import LobeReceiver
from raytrace.emulation.receivers import Receiver
from raytrace.studies.accuracy_map import receiver_model_meta

#: Largest ToA difference, in pulse periods T: both interpolate the same table
#: (positioning.model.pulse); the two implementations differ in the order of their sums.
TOL_T = 1e-4


def random_links(rng: np.random.Generator, n_links: int, k_max: int, freq: float):
    """Path sets like a hall's: a first path at 10-60 m, up to k_max - 1 later ones within
    300 ns (a third of them within one pulse of another), gains 0 to -40 dB below free space."""
    link, delay, gain = [], [], []
    lam = 299_792_458.0 / freq
    for lk in range(n_links):
        k = int(rng.integers(1, k_max + 1))
        d0 = rng.uniform(10.0, 60.0) / 299_792_458.0
        d = d0 + np.sort(rng.exponential(60e-9, k)) * (rng.random(k) > 0.1)
        d[rng.random(k) < 0.3] += rng.uniform(-3e-9, 3e-9)
        d = np.maximum(d, d0)
        fs = lam / (4 * np.pi * 299_792_458.0 * d)
        g = fs * 10 ** (-rng.uniform(0, 40, k) / 20) * np.exp(2j * np.pi * rng.random(k))
        link += [lk] * k
        delay += d.tolist()
        gain += g.tolist()
    return np.array(link), np.array(delay), np.array(gain)


@pytest.mark.parametrize("band", ["c-band", "mmwave"])
def test_lobe_receiver_matches_raytrace(band):
    rng = np.random.default_rng(15)
    rx = Receiver("first-lobe", band)
    model = LobeReceiver.from_meta(receiver_model_meta(rx))
    link, delay, gain = random_links(rng, 400, 24, rx.band.center_frequency_hz)
    want = rx.measure(rx.prepare(link, delay, gain, 400), None, noise=False)
    want_toa = np.where(want.detected, want.toa_s, np.nan)
    k = np.bincount(link).max()
    D = np.full((400, k), np.nan)
    G = np.zeros((400, k), complex)
    pos = np.arange(link.size) - np.searchsorted(link, link)
    D[link, pos], G[link, pos] = delay, gain
    got = model.toa(D, G)
    assert np.array_equal(np.isfinite(got), np.isfinite(want_toa))
    assert np.isfinite(got).sum() > 300  # most links detected: the comparison means something
    T = model.period_s
    assert np.nanmax(np.abs(got - want_toa)) <= TOL_T * T
