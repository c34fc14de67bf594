"""The ``paper`` receiver (raytrace.emulation.receivers.paper) against an independent brute-force
evaluation of the paper's definition, closed forms and eq. 3."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from raytrace.core.constants import C0
from raytrace.emulation.bands import get_band
from raytrace.emulation.channel import LinkBudget, PulseShape, raised_cosine, toa_std_eq3_s
from raytrace.emulation.channel.pulse import raised_cosine1
from raytrace.emulation.receivers import Receiver, estimate_toa
from raytrace.emulation.receivers import paper as paper_module
from raytrace.emulation.receivers.paper import (
    CLIMB_STEP_T,
    POWER_FLOOR_DB,
    first_traced_path,
    lobe_tops,
)
from raytrace.solver.config import MIN_POWER_DB

C_BAND = get_band("c-band")
MMWAVE = get_band("mmwave")
PULSE = PulseShape()
BETA = PULSE.roll_off

#: Lobe top of the receiver against the brute-force definition, in T: both maximise the exact
#: continuous response (Brent to 1e-9 T here, a bounded root-find to 1e-10 of the bracket there).
TOP_TOL_T = 1e-6
#: Relative agreement of a Monte Carlo standard deviation (20k draws: sampling std 0.5 %) with
#: eq. 3.
STD_REL_TOL = 0.02


def period(band=C_BAND) -> float:
    return PULSE.period_s(band)


def rc(t, T, beta=BETA):
    """Raised cosine of eq. 2 written out directly (the textbook form), h(0) = 1/T."""
    t = np.asarray(t, dtype=float)
    x = t / T
    den = 1 - (2 * beta * x) ** 2
    lim = np.isclose(den, 0.0, atol=1e-12)
    fac = np.where(lim, np.pi / 4, np.cos(np.pi * beta * x) / np.where(lim, 1.0, den))
    return np.sinc(x) / T * fac


def brute_force_lobe_top(delays, gains, band=C_BAND):
    """The paper's ToA by its definition, independently: ``|sum_j A_j h(t - tau_j)|`` (no
    truncation) on a T/256 grid over the whole response, the lobe of the first-arriving path
    delimited by the grid minima on either side of its delay, its largest sample refined by a
    bounded root-find of the continuous response."""
    delays = np.asarray(delays, dtype=float)
    gains = np.asarray(gains, dtype=complex)
    T = period(band)

    def mag(t):
        t = np.atleast_1d(t)
        return np.abs((gains[None, :] * rc(t[:, None] - delays[None, :], T)).sum(axis=1))

    t1 = delays.min()
    dt = T / 256
    t = t1 + dt * np.arange(-20 * 256, int((delays.max() - t1) / dt) + 20 * 256)
    m = mag(t)
    k1 = int(np.argmin(np.abs(t - t1)))
    minima = np.flatnonzero((m[1:-1] <= m[:-2]) & (m[1:-1] <= m[2:])) + 1
    left = minima[minima <= k1].max(initial=0)
    right = minima[minima > k1].min(initial=t.size - 1)
    k = left + int(np.argmax(m[left : right + 1]))
    lo, hi = t[k - 1], t[k + 1]
    res = minimize_scalar(lambda u: -mag(lo + u * (hi - lo))[0], bounds=(0.0, 1.0),
                          method="bounded", options={"xatol": 1e-10})  # fmt: skip
    return lo + res.x * (hi - lo)


def paper_toa(delays, gains, band=C_BAND, **kw):
    d = np.asarray(delays, dtype=float)
    g = np.asarray(gains, dtype=complex)
    return estimate_toa(np.zeros(d.size, np.int64), d, g, 1, band, method="paper", **kw)


def amp_db(power_db: float) -> float:
    """|gain| of a path with power gain ``power_db``."""
    return 10 ** (power_db / 20)


# --------------------------------------------------------------------------------------------
# The pulse as a kernel helper
# --------------------------------------------------------------------------------------------


def test_scalar_pulse_is_the_array_pulse():
    x = np.concatenate([np.linspace(-40, 40, 4001), [0.0, 2.0, -2.0, 1e-9, 2.0 + 1e-12]])
    T = 1.0
    for beta in (0.0, 0.25, 0.5, 1.0):
        want = raised_cosine(x * T, T, beta) * T
        got = np.array([raised_cosine1(v, beta) for v in x])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    np.testing.assert_allclose(raised_cosine(x, 1.0, BETA), rc(x, 1.0), atol=1e-12)


# --------------------------------------------------------------------------------------------
# The first-arriving MPC and its lobe
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
def test_a_lone_path_gives_its_own_delay(band):
    rng = np.random.default_rng(3)
    n = 50
    delay = 40.0 / C0 + rng.uniform(0, 3 * period(band), n)
    gain = amp_db(-70.0) * np.exp(1j * rng.uniform(0, 2 * np.pi, n))
    est = estimate_toa(np.arange(n), delay, gain, n, band, method="paper", noise=False)
    assert est.detected.all()
    assert np.max(np.abs(est.toa_s - delay)) < TOP_TOL_T * period(band)
    assert est.first_path.tolist() == list(range(n)) == est.lobe_path.tolist()
    lb = LinkBudget()
    np.testing.assert_allclose(est.snr_db, lb.path_snr_db(gain, band), atol=1e-9)
    assert np.isnan(est.peak_ratio_db).all() and np.isnan(est.lobe_width).all()


@pytest.mark.parametrize(
    "sep_t, a2, phase",
    [(0.25, 0.8, 0.0), (0.4, 0.5, 2.0), (0.3, 0.7, 2.6), (0.6, 1.5, 1.0), (0.8, 1.0, np.pi)],
)
def test_two_paths_within_a_pulse_width_give_the_brute_force_lobe_top(sep_t, a2, phase):
    """The bias the paper adds: a second path within a pulse width moves the top of the lobe that
    holds the first path, late in phase, early or late out of phase."""
    T = period()
    a = amp_db(-60.0)
    t1 = 60e-9
    delays = [t1, t1 + sep_t * T]
    gains = [a, a * a2 * np.exp(1j * phase)]
    est = paper_toa(delays, gains, noise=False)
    want = brute_force_lobe_top(delays, gains)
    assert est.toa_s[0] == pytest.approx(want, abs=TOP_TOL_T * T)
    assert abs(est.toa_s[0] - t1) > 1e-3 * T  # a real bias, not the first path's delay


def test_the_first_path_is_the_earliest_traced_above_the_floor_however_weak():
    """No detection threshold: a path 100 dB under the next is the first arrival; its lobe is
    the strong path's main lobe when it lies within a pulse width, its own when it is far
    enough; a path under the tracer's floor is no MPC."""
    T = period()
    strong = amp_db(-60.0)
    weak = amp_db(-160.0)
    below = amp_db(POWER_FLOOR_DB - 1.0)
    t1 = 70e-9
    # link 0: weak 0.5 T before strong; link 1: weak 40 T before strong; link 2: a path under
    # the floor first
    link = np.array([0, 0, 1, 1, 2, 2])
    delay = np.array([t1, t1 + 0.5 * T, t1, t1 + 40 * T, t1, t1 + 0.5 * T])
    gain = np.array([weak, strong, weak, strong, below, strong], dtype=complex)
    est = estimate_toa(link, delay, gain, 3, C_BAND, method="paper", noise=False)
    assert est.first_path.tolist() == [0, 2, 5]
    assert est.toa_s[0] == pytest.approx(
        brute_force_lobe_top(delay[:2], gain[:2]), abs=TOP_TOL_T * T
    )
    # the strong path's lobe, its top moved by the weak one by about their amplitude ratio, 1e-5
    assert est.toa_s[0] == pytest.approx(t1 + 0.5 * T, abs=1e-4 * T)
    assert est.lobe_path.tolist()[0] == 1
    want1 = brute_force_lobe_top(delay[2:4], gain[2:4])
    assert est.toa_s[1] == pytest.approx(want1, abs=TOP_TOL_T * T)
    assert abs(est.toa_s[1] - t1) < 0.5 * T  # near the weak path's own delay
    assert est.toa_s[2] == pytest.approx(t1 + 0.5 * T, abs=TOP_TOL_T * T)
    lb = LinkBudget()
    assert est.snr_db[0] == pytest.approx(lb.path_snr_db(np.array([weak]), C_BAND)[0])
    assert POWER_FLOOR_DB == MIN_POWER_DB
    np.testing.assert_array_equal(
        first_traced_path(link, delay, gain, 3, floor_db=-130.0), [1, 3, 5]
    )


def test_random_multipath_links_give_the_brute_force_lobe_top():
    """Random links (2-30 paths over 120 ns, power gains -60 to -130 dB, random phases, some
    first paths far weaker than the rest): the kernel's lobe tops are the brute-force ones."""
    rng = np.random.default_rng(11)
    for band in (C_BAND, MMWAVE):
        T = period(band)
        links, delays, gains, want = [], [], [], []
        for lk in range(25):
            n = int(rng.integers(2, 31))
            d = 30e-9 + np.sort(rng.uniform(0, 120e-9, n))
            g = amp_db(1.0) * 10 ** (rng.uniform(-130, -60, n) / 20)
            g = g * np.exp(1j * rng.uniform(0, 2 * np.pi, n))
            links.append(np.full(n, lk))
            delays.append(d)
            gains.append(g)
            want.append(brute_force_lobe_top(d, g, band))
        est = estimate_toa(np.concatenate(links), np.concatenate(delays), np.concatenate(gains),
                           25, band, method="paper", noise=False)  # fmt: skip
        np.testing.assert_allclose(est.toa_s, want, rtol=0, atol=TOP_TOL_T * T)


def test_the_climb_and_its_limit(monkeypatch):
    """From the flank of a lone pulse the climb reaches its top; a top further away than the
    longest climb gives no ToA; a link without paths or start gives none either."""
    T = period()
    one = (np.zeros(1, np.int64), np.array([1e-7]), np.array([1e-3 + 0j]), 1)
    for start in (1e-7 - 0.9 * T, 1e-7 + 0.6 * T, 1e-7):
        top, path = lobe_tops(*one, np.array([start]), C_BAND, PULSE)
        assert top[0] == pytest.approx(1e-7, abs=TOP_TOL_T * T) and path[0] == 0
    assert CLIMB_STEP_T * T < 0.5e-9  # the climb resolves lobes of a fraction of a nanosecond
    monkeypatch.setattr(paper_module, "MAX_CLIMB_T", 0.5)
    top, path = lobe_tops(*one, np.array([1e-7 - 0.9 * T]), C_BAND, PULSE)
    assert np.isnan(top[0]) and path[0] == -1
    top, path = lobe_tops(*one, np.array([1e-7 - 0.4 * T]), C_BAND, PULSE)
    assert top[0] == pytest.approx(1e-7, abs=TOP_TOL_T * T)
    top, path = lobe_tops(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, complex), 2,
                          np.array([np.nan, 1e-7]), C_BAND, PULSE)  # fmt: skip
    assert np.isnan(top).all() and path.tolist() == [-1, -1]


# --------------------------------------------------------------------------------------------
# Eq. 3 noise
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("band, power_db", [(C_BAND, -110.0), (MMWAVE, -95.0), (C_BAND, -150.0)])
def test_the_noise_spread_follows_eq3_at_the_first_paths_snr(band, power_db):
    T = period(band)
    delays = [50e-9, 50e-9 + 0.3 * T]
    gains = [amp_db(power_db), amp_db(power_db + 10.0) * np.exp(0.7j)]
    n = 20000  # the same link 20000 times: one draw each
    rx = Receiver("paper", band)
    link = np.repeat(np.arange(n), 2)
    prep = rx.prepare(link, np.tile(delays, n), np.tile(gains, n), n)
    top = rx.measure(prep, None, noise=False).toa_s
    np.testing.assert_allclose(top, top[0], rtol=0, atol=1e-6 * T)
    draws = rx.measure(prep, np.random.default_rng(7)).toa_s - top
    lb = LinkBudget()
    snr = lb.path_snr(np.array([gains[0]]), band)[0]
    sigma = float(toa_std_eq3_s(snr, band.bandwidth_hz, 1.0 / band.subcarrier_spacing_hz))
    # eq. 3 in metres: c^2 / ((2 pi B)^2 t_s B SNR)
    sigma_m = math.sqrt(C0**2 / ((2 * math.pi * band.bandwidth_hz) ** 2 * 3333.33 * snr))
    assert C0 * sigma == pytest.approx(sigma_m, rel=1e-4)
    assert np.std(draws) == pytest.approx(sigma, rel=STD_REL_TOL)
    assert abs(np.mean(draws)) < 4 * sigma / math.sqrt(draws.size)
    assert rx.measure(prep, None, noise=False).sigma_s[0] == pytest.approx(sigma, rel=1e-12)


def test_paper_and_first_path_without_threshold_share_the_first_path_and_the_draws():
    """Both take the first traced path; first-path without its threshold adds eq. 3 noise to its
    exact delay, paper to the lobe top, with the same standard normal per link."""
    rng = np.random.default_rng(2)
    n_links = 6
    link = np.repeat(np.arange(n_links), 5)
    delay = 30e-9 + rng.uniform(0, 80e-9, link.size)
    gain = 10 ** (rng.uniform(-150, -60, link.size) / 20) * np.exp(
        1j * rng.uniform(0, 6, link.size)
    )
    args = (link, delay, gain, n_links, C_BAND)
    paper0 = estimate_toa(*args, method="paper", noise=False)
    paper = estimate_toa(*args, method="paper", rng=np.random.default_rng(5))
    fp = Receiver("first-path", C_BAND, first_path_threshold=False)
    ideal = fp.measure(fp.prepare(link, delay, gain, n_links), np.random.default_rng(5))
    np.testing.assert_array_equal(paper.first_path, ideal.first_path)
    np.testing.assert_array_equal(paper.first_path, first_traced_path(link, delay, gain, n_links))
    z_paper = (paper.toa_s - paper0.toa_s) / paper.sigma_s
    z_ideal = (ideal.toa_s - delay[ideal.first_path]) / ideal.sigma_s
    np.testing.assert_allclose(z_paper, z_ideal, rtol=1e-6, atol=1e-6)
    # with its threshold, first-path skips the paths the link budget cannot detect
    thr = estimate_toa(*args, method="first-path", noise=False)
    assert (thr.first_path != ideal.first_path).any()
    with pytest.raises(Exception, match="first_path_threshold"):
        Receiver("first-path", C_BAND, first_path_threshold="no")
