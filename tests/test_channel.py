"""Link budget, raised-cosine pulse (eq. 2), CIR and the ToA estimators (eq. 3), against closed forms
and independent computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.emulation.bands import get_band
from raytrace.emulation.channel import (
    LinkBudget,
    PulseShape,
    band_limited_response,
    detection_snr_db,
    discrete_cir,
    first_detectable_path,
    raised_cosine,
    raised_cosine_spectrum,
    response,
    thermal_noise_power_w,
    toa_std_eq3_s,
)
from raytrace.emulation.receivers import TOA_METHODS, estimate_toa

#: dB agreement of link-budget arithmetic with hand values (hand values quoted to 0.01 dB).
HAND_DB_TOL = 0.005
#: dB agreement of two evaluations of the same closed form.
DB_TOL = 1e-9
#: Relative tolerance of closed-form pulse values (float64 arithmetic).
PULSE_REL_TOL = 1e-12
#: |h(kT)| at zero crossings, relative to h(0) = 1/T (sin(k pi) in float64 is ~1e-16 k).
ZERO_TOL = 1e-13
#: Spectrum of the sampled, truncated pulse vs. the closed-form spectrum (truncation at +-400 T).
SPECTRUM_TOL = 1e-4
#: Sub-sample peak refinement vs. an independent root-find, in units of the pulse period T.
PEAK_TOL_T = 1e-5
#: Relative agreement of empirical variances with their closed forms (200k or 20k draws: the
#: sampling std of a variance estimate is sqrt(2/n) = 0.3 % or 1 %).
VAR_REL_TOL = 0.05
#: Exact ToA (noise off) of the first-path estimator: the delay itself.
DELAY_TOL_S = 0.0

C_BAND = get_band("c-band")
MMWAVE = get_band("mmwave")
PULSE = PulseShape()
T_C = PULSE.period_s(C_BAND)


def los_gain(distance_m: float, band=C_BAND) -> complex:
    """Free-space field gain between isotropic antennas, lambda/(4 pi d) exp(-j k d)."""
    lam = C0 / band.center_frequency_hz
    return lam / (4 * math.pi * distance_m) * np.exp(-2j * math.pi * distance_m / lam)


def naive_rc(t, T, beta):
    """Eq. 2 written literally; at t = +-T/(2 beta) exactly, its limit (pi / 4T) sinc(1/(2 beta))."""
    x = np.asarray(t, dtype=float) / T
    den = 1 - (2 * beta * x) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        h = (1 / T) * np.sinc(x) * np.cos(np.pi * beta * x) / den
    return np.where(den == 0, np.pi / (4 * T) * np.sinc(1 / (2 * beta)), h)


def local_max(fun, lo, hi, step):
    """Root of the central-difference derivative of fun in [lo, hi] (independent peak finder)."""
    return brentq(lambda t: fun(t + step) - fun(t - step), lo, hi, xtol=1e-22, rtol=1e-15)


# --------------------------------------------------------------------------------------------
# Link budget
# --------------------------------------------------------------------------------------------


def test_ktb_over_100_mhz():
    # k T B = 1.380649e-23 * 290 * 1e8 = 4.0039e-13 W = -93.98 dBm (hand value).
    dbm = 10 * math.log10(thermal_noise_power_w(100e6, 290.0) / 1e-3)
    assert dbm == pytest.approx(-93.98, abs=HAND_DB_TOL)
    # With the default 9 dB noise figure: -84.975 dBm over the C band, -78.955 dBm over mmWave.
    assert LinkBudget().noise_power_dbm(C_BAND) == pytest.approx(-84.98, abs=HAND_DB_TOL)
    assert LinkBudget().noise_power_dbm(MMWAVE) == pytest.approx(-78.955, abs=HAND_DB_TOL)


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
@pytest.mark.parametrize("distance_m", [1.0, 17.3, 60.0])
def test_los_snr_is_friis_minus_noise(band, distance_m):
    lam = C0 / band.center_frequency_hz
    noise_dbm = 10 * math.log10(1.380649e-23 * 290 * band.bandwidth_hz / 1e-3) + 9.0
    expected = 20.0 + 20 * math.log10(lam / (4 * math.pi * distance_m)) - noise_dbm
    got = LinkBudget().path_snr_db(np.array([los_gain(distance_m, band)]), band)[0]
    assert got == pytest.approx(expected, abs=DB_TOL)


def test_antenna_gains_and_power_shift_snr_in_db():
    g = np.array([los_gain(10.0)])
    base = LinkBudget().path_snr_db(g, C_BAND)[0]
    other = LinkBudget(tx_power_dbm=23, tx_antenna_gain_dbi=5, rx_antenna_gain_dbi=-2)
    assert other.path_snr_db(g, C_BAND)[0] - base == pytest.approx(6.0, abs=DB_TOL)
    assert LinkBudget(noise_figure_db=7).path_snr_db(g, C_BAND)[0] - base == pytest.approx(
        2.0, abs=DB_TOL
    )


def test_processing_gain_is_subcarrier_count():
    for band in (C_BAND, MMWAVE):
        assert LinkBudget().processing_gain(band) == pytest.approx(1e5 / 30, rel=1e-12)
        assert LinkBudget(n_symbols=4).processing_gain(band) == pytest.approx(4e5 / 30, rel=1e-12)
    assert LinkBudget().integration_time_s(C_BAND) == pytest.approx(1 / 30e3, rel=1e-12)


#: Albersheim's approximation is within ~0.2 dB of the exact value for these probabilities.
ALBERSHEIM_TOL_DB = 0.2


def albersheim_db(pfa, pd):
    a = math.log(0.62 / pfa)
    b = math.log(pd / (1 - pd))
    return (6.2 + 4.54 / math.sqrt(1.44)) * math.log10(a + 0.12 * a * b + 1.7 * b)


@pytest.mark.parametrize("pfa, pd", [(1e-6, 0.9), (1e-4, 0.5), (1e-8, 0.99)])
def test_detection_snr_vs_albersheim(pfa, pd):
    assert detection_snr_db(pfa, pd) == pytest.approx(albersheim_db(pfa, pd), abs=ALBERSHEIM_TOL_DB)


#: Monte-Carlo binomial tolerance: 200k draws give a std of sqrt(p (1-p) / n) < 0.0012.
MC_PROB_TOL = 0.006


def test_detection_snr_by_monte_carlo():
    pfa, pd = 1e-2, 0.9
    snr = 10 ** (detection_snr_db(pfa, pd) / 10)
    gamma = -math.log(pfa)
    rng = np.random.default_rng(7)
    n = 200_000
    w = (rng.standard_normal(n) + 1j * rng.standard_normal(n)) / math.sqrt(2)
    assert np.mean(np.abs(w) ** 2 > gamma) == pytest.approx(pfa, abs=MC_PROB_TOL / 3)
    assert np.mean(np.abs(math.sqrt(snr) + w) ** 2 > gamma) == pytest.approx(pd, abs=MC_PROB_TOL)


def test_default_detection_threshold():
    lb = LinkBudget()
    assert lb.required_snr_db == pytest.approx(13.18, abs=HAND_DB_TOL)
    assert lb.detector_threshold_db == pytest.approx(10 * math.log10(math.log(1e6)), abs=DB_TOL)
    assert LinkBudget(detection_threshold_db=10.0).required_snr_db == 10.0


def test_detectability_at_the_threshold():
    lb = LinkBudget()
    # Per-path SNR (dB) that reaches exactly the required post-correlation SNR.
    edge_db = lb.required_snr_db - 10 * math.log10(lb.processing_gain(C_BAND))
    assert edge_db == pytest.approx(13.18 - 35.23, abs=0.01)
    unit_db = lb.path_snr_db(np.array([1.0]), C_BAND)[0]
    amp = lambda db: 10 ** ((db - unit_db) / 20)  # noqa: E731
    gains = np.array([amp(edge_db + 0.01), amp(edge_db - 0.01), 0.0])
    assert lb.detectable(gains, C_BAND).tolist() == [True, False, False]


def test_dynamic_range_rule():
    lb = LinkBudget(dynamic_range_db=25.0)
    g = np.array([1e-3, 1e-3 * 10 ** (-24 / 20), 1e-3 * 10 ** (-26 / 20), 1e-5])
    link = np.array([0, 0, 0, 1])
    assert lb.detectable(g, C_BAND, link, 2).tolist() == [True, True, False, True]
    assert LinkBudget().detectable(g, C_BAND).all()
    with pytest.raises(HallrayError, match="needs link"):
        lb.detectable(g, C_BAND)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"noise_figure_db": -1},
        {"n_symbols": 0},
        {"n_symbols": 1.5},
        {"false_alarm_probability": 0.0},
        {"detection_probability": 1.0},
        {"false_alarm_probability": 0.5, "detection_probability": 0.4},
        {"tx_power_dbm": float("nan")},
        {"dynamic_range_db": -3.0},
    ],
)
def test_bad_link_budget(kwargs):
    with pytest.raises(HallrayError):
        LinkBudget(**kwargs)


def test_correlator_noise_gives_post_correlation_snr():
    lb = LinkBudget()
    a = los_gain(25.0)
    peak_to_noise = (abs(a) / T_C / lb.correlator_noise_std(C_BAND, PULSE)) ** 2
    expected = lb.path_snr(np.array([a]), C_BAND)[0] * lb.processing_gain(C_BAND)
    assert peak_to_noise == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------------------------------------
# Eq. 3
# --------------------------------------------------------------------------------------------


def test_eq3_by_hand():
    # sigma^2 = c^2 / ((2 pi B)^2 t_s B SNR) m^2 with B = 100 MHz, t_s = 1/30 kHz, SNR = 10 dB.
    var_m2 = C0**2 / ((2 * math.pi * 1e8) ** 2 * (1 / 30e3) * 1e8 * 10.0)
    got = toa_std_eq3_s(10.0, 1e8, 1 / 30e3)
    assert float(got) == pytest.approx(math.sqrt(var_m2) / C0, rel=1e-12)
    assert float(toa_std_eq3_s(np.inf, 1e8, 1e-3)) == 0.0
    assert float(toa_std_eq3_s(0.0, 1e8, 1e-3)) == np.inf


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
def test_first_path_variance_matches_eq3(band):
    n = 200_000
    lb = LinkBudget()
    # A weak path (per-path SNR -15 dB, post-correlation +20 dB) so that sigma is visible.
    unit_db = lb.path_snr_db(np.array([1.0]), band)[0]
    gain = np.full(n, 10 ** ((-15.0 - unit_db) / 20) * np.exp(0.3j))
    delay = np.full(n, 40.0 / C0)
    est = estimate_toa(
        np.arange(n), delay, gain, n, band, method="first-path", rng=np.random.default_rng(3)
    )
    snr = lb.path_snr(gain[:1], band)[0]
    sigma = math.sqrt(1 / ((2 * math.pi * band.bandwidth_hz) ** 2 / band.subcarrier_spacing_hz
                           * band.bandwidth_hz * snr))  # fmt: skip
    err = est.toa_s - delay
    assert est.detected.all()
    assert np.var(err) == pytest.approx(sigma**2, rel=VAR_REL_TOL)
    assert abs(np.mean(err)) < 5 * sigma / math.sqrt(n)  # zero mean
    assert est.sigma_s[0] == pytest.approx(sigma, rel=1e-12)
    assert est.snr_db[0] == pytest.approx(10 * math.log10(snr), abs=DB_TOL)


# --------------------------------------------------------------------------------------------
# First detectable path
# --------------------------------------------------------------------------------------------


def _three_links():
    """Link 0: LoS; link 1: an undetectable early path, then two detectable ones (listed out of
    order); link 2: only undetectable paths; link 3: no paths at all."""
    strong = los_gain(20.0)
    weak = 1e-9  # -201 dB: far below threshold
    link = np.array([1, 0, 1, 2, 1, 2])
    delay = np.array([90e-9, 66.7e-9, 80e-9, 70e-9, 75e-9, 71e-9])
    gain = np.array([strong * 0.5, strong, strong * 0.3, weak, weak, weak])
    return link, delay, gain, 4


@pytest.mark.parametrize("method", [m for m in TOA_METHODS if m != "paper"])
def test_noiseless_first_detectable_path(method):
    # (the paper receiver has no detection threshold: tests/test_paper_receiver.py)
    link, delay, gain, n_links = _three_links()
    est = estimate_toa(link, delay, gain, n_links, C_BAND, method=method, noise=False)
    assert est.first_path.tolist() == [1, 2, -1, -1]  # the early weak path 4 is skipped
    assert est.detected.tolist() == [True, True, False, False]
    assert np.isnan(est.toa_s[2:]).all() and np.isnan(est.snr_db[2:]).all()
    assert np.isnan(est.sigma_s[2:]).all()
    if method == "first-path":
        assert est.toa_s[0] == pytest.approx(66.7e-9, abs=DELAY_TOL_S)
        assert est.toa_s[1] == pytest.approx(80e-9, abs=DELAY_TOL_S)
    else:  # isolated paths (10 ns = 0.8 T apart on link 1 though): within a fraction of T
        assert est.toa_s[0] == pytest.approx(66.7e-9, abs=PEAK_TOL_T * T_C)
    assert est.method == method


def test_band_by_name():
    link, delay, gain, n_links = _three_links()
    by_name = estimate_toa(link, delay, gain, n_links, "C-Band", noise=False)
    by_band = estimate_toa(link, delay, gain, n_links, C_BAND, noise=False)
    assert np.array_equal(by_name.toa_s, by_band.toa_s, equal_nan=True)
    with pytest.raises(HallrayError, match="known bands"):
        estimate_toa(link, delay, gain, n_links, "l-band", noise=False)


def test_first_detectable_path_ties_and_empty():
    link = np.array([0, 0, 1])
    delay = np.array([5.0, 5.0, 1.0])
    assert first_detectable_path(link, delay, [True, True, True], 3).tolist() == [0, 2, -1]
    assert first_detectable_path(link, delay, [False, True, False], 3).tolist() == [1, -1, -1]
    est = estimate_toa(np.zeros(0, int), np.zeros(0), np.zeros(0, complex), 2, C_BAND, noise=False)
    assert est.first_path.tolist() == [-1, -1] and np.isnan(est.toa_s).all()


def test_discrete_cir_groups_and_sorts():
    link, delay, gain, n_links = _three_links()
    cir = discrete_cir(link, delay, gain, n_links)
    assert cir.offsets.tolist() == [0, 1, 4, 6, 6]
    d1, g1 = cir.link(1)
    assert d1.tolist() == [75e-9, 80e-9, 90e-9]
    assert g1.tolist() == [gain[4], gain[2], gain[0]]
    assert cir.path_index[1:4].tolist() == [4, 2, 0]
    assert cir.link(3)[0].size == 0 and cir.n_links == 4


@pytest.mark.parametrize("case", ["sorted", "ties", "one-swap", "shuffled", "one", "none"])
def test_cir_and_first_path_orders_are_lexsorts_whether_sorted_or_not(case):
    # the tracer's paths come sorted (link, delay): the order is then found without a sort;
    # it must be np.lexsort's permutation in every case
    rng = np.random.default_rng(7)
    n = {"one": 1, "none": 0}.get(case, 400)
    link = np.sort(rng.integers(0, 9, n))
    delay = rng.choice(np.arange(40) * 1e-9, n)  # repeated delays: ties within a link
    for lk in np.unique(link):
        delay[link == lk] = np.sort(delay[link == lk])
    if case == "one-swap":
        delay[[10, 11]] = delay[[11, 10]] + np.array([0.0, 1e-9])
    if case == "shuffled":
        p = rng.permutation(n)
        link, delay = link[p], delay[p]
    gain = rng.normal(size=n) + 1j * rng.normal(size=n)
    cir = discrete_cir(link, delay, gain, 10)
    order = np.lexsort((np.arange(n), delay, link))
    assert cir.path_index.dtype == np.int64 and np.array_equal(cir.path_index, order)
    assert np.array_equal(cir.delay_s, delay[order]) and np.array_equal(cir.gain, gain[order])
    ok = rng.random(n) < 0.5
    idx = np.flatnonzero(ok)
    want = np.full(10, -1)
    for i in idx[np.lexsort((idx, delay[idx], link[idx]))][::-1]:
        want[link[i]] = i  # the earliest (delay, index) of each link is written last
    assert first_detectable_path(link, delay, ok, 10).tolist() == want.tolist()


# --------------------------------------------------------------------------------------------
# Raised-cosine pulse, eq. 2
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("beta", [0.25, 0.3, 0.5, 1.0])
def test_pulse_closed_form_and_h0(beta):
    t = np.array([0.3, -0.77, 1.4, 2.9, -5.55]) * T_C
    assert np.allclose(raised_cosine(t, T_C, beta), naive_rc(t, T_C, beta), rtol=PULSE_REL_TOL)
    assert raised_cosine(0.0, T_C, beta) == pytest.approx(1 / T_C, rel=PULSE_REL_TOL)


def test_sinc_pulse_for_zero_roll_off():
    t = np.linspace(-3, 3, 13) * T_C + 0.1 * T_C
    assert np.allclose(raised_cosine(t, T_C, 0.0), np.sinc(t / T_C) / T_C, rtol=PULSE_REL_TOL)


@pytest.mark.parametrize("beta", [0.25, 0.3, 0.7])
def test_pulse_zero_crossings(beta):
    k = np.array([k for k in range(-12, 13) if k != 0])
    h = raised_cosine(k * T_C, T_C, beta)
    assert np.all(np.abs(h) * T_C < ZERO_TOL)


@pytest.mark.parametrize("beta", [0.3, 0.35, 0.7])
def test_pulse_at_the_removable_singularity(beta):
    ts = T_C / (2 * beta)
    limit = math.pi / (4 * T_C) * np.sinc(1 / (2 * beta))
    assert abs(limit) * T_C > 0.01  # finite and non-zero: not a zero crossing for these beta
    for sign in (1, -1):
        assert raised_cosine(sign * ts, T_C, beta) == pytest.approx(limit, rel=PULSE_REL_TOL)
        # The literal formula approaching the point from both sides tends to the same value ...
        for eps in (1e-5, -1e-5):
            assert naive_rc(sign * ts * (1 + eps), T_C, beta) == pytest.approx(limit, rel=1e-4)
        # ... and the implementation is continuous through it (no cancellation noise).
        near = raised_cosine(sign * ts * (1 + np.array([-1e-12, 1e-12])), T_C, beta)
        assert np.allclose(near, limit, rtol=1e-9)


@pytest.mark.parametrize("beta", [0.25, 0.5])
def test_sampled_pulse_spectrum(beta):
    os_, span = 16, 400
    dt = T_C / os_
    t = np.arange(-span * os_, span * os_) * dt
    spec = np.abs(np.fft.fft(raised_cosine(t, T_C, beta))) * dt
    f = np.abs(np.fft.fftfreq(t.size, dt))
    flat = f < (1 - beta) / (2 * T_C)
    stop = f > (1 + beta) / (2 * T_C)
    assert np.max(np.abs(spec[flat] - 1.0)) < SPECTRUM_TOL
    assert np.max(spec[stop]) < SPECTRUM_TOL
    assert np.max(np.abs(spec - raised_cosine_spectrum(f, T_C, beta))) < SPECTRUM_TOL


def test_pulse_period_fills_the_band():
    for band in (C_BAND, MMWAVE):
        T = PULSE.period_s(band)
        assert (1 + PULSE.roll_off) / T == pytest.approx(band.bandwidth_hz, rel=1e-12)
    assert T_C == pytest.approx(12.5e-9, rel=1e-12)


# --------------------------------------------------------------------------------------------
# Band-limited response and pulse-based estimators
# --------------------------------------------------------------------------------------------


def test_band_limited_response_is_the_sum_of_pulses():
    link = np.array([0, 0, 1])
    delay = np.array([30e-9, 47e-9, 12e-9])
    gain = np.array([1e-3, -4e-4j, 2e-4 + 1e-4j])
    resp = band_limited_response(link, delay, gain, 2, C_BAND)
    assert resp.dt_s == pytest.approx(T_C / 8, rel=1e-12)
    for row, lk in enumerate(resp.links):
        t = resp.times(row)
        sel = link == lk
        direct = (gain[sel][None, :] * naive_rc(t[:, None] - delay[sel][None, :], T_C, 0.25)).sum(1)
        scale = np.abs(gain[sel]).max() / T_C
        # the implementation truncates each pulse at +-16 T: tail below 3e-4 of the peak
        assert np.max(np.abs(resp.samples[row, : t.size] - direct)) < 3e-4 * scale
        assert t[0] <= delay[sel].min() - 16 * T_C + 1e-15
        assert t[-1] >= delay[sel].max() + 16 * T_C - 1e-15


#: Noise statistics from 400 x ~300 correlated samples.
NOISE_VAR_TOL = 0.05
NOISE_CORR_TOL = 0.03


def test_correlator_noise_statistics():
    n = 400
    lb = LinkBudget()
    resp = band_limited_response(
        np.arange(n), np.full(n, 1e-7), np.zeros(n, complex), n, C_BAND,
        budget=lb, rng=np.random.default_rng(11),
    )  # fmt: skip
    x = resp.samples[:, : int(resp.n_samples.min())]
    sigma2 = lb.correlator_noise_std(C_BAND, PULSE) ** 2
    assert np.mean(np.abs(x) ** 2) == pytest.approx(sigma2, rel=NOISE_VAR_TOL)
    # Autocorrelation follows the pulse: zero at lag T (8 samples), h(T/2) T at lag T/2.
    for lag, expected in ((8, 0.0), (4, raised_cosine(T_C / 2, T_C, 0.25) * T_C), (16, 0.0)):
        rho = np.mean(x[:, lag:] * np.conj(x[:, :-lag])) / sigma2
        assert abs(rho - expected) < NOISE_CORR_TOL


def test_two_equal_paths_peak_halfway():
    dt = 0.2 * T_C
    a = los_gain(10.0)
    est = estimate_toa(
        np.array([0, 0]), np.array([50e-9, 50e-9 + dt]), np.array([a, a]), 1, C_BAND,
        method="peak", noise=False,
    )  # fmt: skip
    assert est.toa_s[0] - 50e-9 == pytest.approx(dt / 2, abs=PEAK_TOL_T * T_C)


@pytest.mark.parametrize("a2, dt_t", [(0.6, 0.4), (1.7, 0.5), (0.3, 0.7)])
def test_two_unequal_paths_peak_vs_root_find(a2, dt_t):
    dt = dt_t * T_C
    t1 = 50e-9
    a = los_gain(10.0)
    est = estimate_toa(
        np.array([0, 0]), np.array([t1, t1 + dt]), np.array([a, a2 * a]), 1, C_BAND,
        method="peak", noise=False,
    )  # fmt: skip

    def s(t):
        return naive_rc(t, T_C, 0.25) + a2 * naive_rc(t - dt, T_C, 0.25)

    expected = local_max(s, 0.0, dt, 1e-6 * T_C)
    assert est.toa_s[0] - t1 == pytest.approx(expected, abs=PEAK_TOL_T * T_C)
    assert 0 < expected < dt  # the merged peak is biased away from the first path


def test_leading_edge_finds_weak_first_path():
    t1, sep = 60e-9, 3 * T_C
    a1 = los_gain(15.0)
    a2 = a1 * 10 ** (10 / 20)  # 10 dB stronger, 3 T later
    link, delay, gain = np.array([0, 0]), np.array([t1, t1 + sep]), np.array([a1, a2])

    def mag(t):
        return abs(a1 * naive_rc(t, T_C, 0.25) + a2 * naive_rc(t - sep, T_C, 0.25))

    first = local_max(mag, -0.5 * T_C, 0.5 * T_C, 1e-6 * T_C)
    second = local_max(mag, sep - 0.5 * T_C, sep + 0.5 * T_C, 1e-6 * T_C)
    le = estimate_toa(link, delay, gain, 1, C_BAND, method="leading-edge", noise=False)
    pk = estimate_toa(link, delay, gain, 1, C_BAND, method="peak", noise=False)
    assert le.toa_s[0] - t1 == pytest.approx(first, abs=PEAK_TOL_T * T_C)
    assert pk.toa_s[0] - t1 == pytest.approx(second, abs=PEAK_TOL_T * T_C)
    # The strong path's precursor tail pulls the weak lobe, but by well under one period.
    assert abs(first) < 0.25 * T_C and abs(second - sep) < 0.05 * T_C
    # With noise (post-correlation SNR ~ 50 dB for the weak path) the picture is the same.
    rng = np.random.default_rng(5)
    le_n = estimate_toa(link, delay, gain, 1, C_BAND, method="leading-edge", rng=rng)
    pk_n = estimate_toa(link, delay, gain, 1, C_BAND, method="peak", rng=rng)
    assert abs(le_n.toa_s[0] - t1 - first) < 0.01 * T_C
    assert abs(pk_n.toa_s[0] - t1 - second) < 0.01 * T_C


def test_leading_edge_ignores_paths_below_its_threshold():
    # A first path 20 dB below the strongest is under the -12 dB threshold: the strong one wins.
    a1 = los_gain(15.0)
    link, delay = np.array([0, 0]), np.array([60e-9, 60e-9 + 4 * T_C])
    gain = np.array([a1 * 0.1, a1])
    le = estimate_toa(link, delay, gain, 1, C_BAND, method="leading-edge", noise=False)
    assert abs(le.toa_s[0] - delay[1]) < 0.05 * T_C
    # At -25 dB it finds the weak path, its lobe pulled by the strong path's precursor tail as the
    # closed form says.
    le = estimate_toa(
        link, delay, gain, 1, C_BAND, method="leading-edge", noise=False, leading_edge_db=-25
    )

    def mag(t):
        return abs(gain[0] * naive_rc(t, T_C, 0.25) + gain[1] * naive_rc(t - 4 * T_C, T_C, 0.25))

    expected = local_max(mag, -0.5 * T_C, 0.5 * T_C, 1e-6 * T_C)
    assert le.toa_s[0] - delay[0] == pytest.approx(expected, abs=PEAK_TOL_T * T_C)
    assert abs(expected) < 0.25 * T_C


def test_peak_estimator_variance_is_the_pulse_crlb():
    # High SNR: the peak of |matched-filter output| is the ML delay estimate of one path; its
    # variance is 1 / (8 pi^2 f_rms^2 SNR_post), f_rms the rms bandwidth of the pulse spectrum
    # (computed here by quadrature of the raised-cosine spectrum written out independently).
    beta = 0.25
    f1, f2 = (1 - beta) / (2 * T_C), (1 + beta) / (2 * T_C)

    def spec(f):
        f = abs(f)
        return 1.0 if f <= f1 else 0.5 * (1 + math.cos(math.pi * T_C / beta * (f - f1)))

    num = quad(lambda f: f * f * spec(f), 0, f2, points=[f1])[0]
    f_rms2 = num / quad(spec, 0, f2, points=[f1])[0]
    n = 20_000
    lb = LinkBudget()
    gain = np.full(n, los_gain(30.0) * 10 ** (-25 / 20), dtype=complex)
    snr_post = lb.path_snr(gain[:1], C_BAND)[0] * lb.processing_gain(C_BAND)
    assert 10 * math.log10(snr_post) == pytest.approx(42.0, abs=1.0)
    est = estimate_toa(
        np.arange(n), np.full(n, 1e-7), gain, n, C_BAND, method="peak",
        rng=np.random.default_rng(2),
    )  # fmt: skip
    crlb = 1 / (8 * math.pi**2 * f_rms2 * snr_post)
    assert np.var(est.toa_s - 1e-7) == pytest.approx(crlb, rel=VAR_REL_TOL)


def test_chunking_does_not_change_results(monkeypatch):
    rng = np.random.default_rng(4)
    n_links = 30
    link = rng.integers(0, n_links, 200)
    delay = rng.uniform(20e-9, 400e-9, 200)
    gain = los_gain(30.0) * rng.uniform(0.1, 1, 200) * np.exp(2j * np.pi * rng.uniform(size=200))
    args = (link, delay, gain, n_links, C_BAND)
    ref = {m: estimate_toa(*args, method=m, noise=False) for m in ("peak", "leading-edge")}
    monkeypatch.setattr(response, "_CHUNK_ELEMENTS", 3000)
    assert (
        len(list(response._link_chunks(discrete_cir(*args[:4]), np.arange(n_links), PULSE, T_C))) > 5
    )
    for m, r in ref.items():
        got = estimate_toa(*args, method=m, noise=False)
        assert np.array_equal(got.toa_s, r.toa_s, equal_nan=True)


@pytest.mark.parametrize("method", TOA_METHODS)
def test_seeded_and_deterministic(method):
    link, delay, gain, n_links = _three_links()
    a = estimate_toa(
        link, delay, gain, n_links, C_BAND, method=method, rng=np.random.default_rng(9)
    )
    b = estimate_toa(
        link, delay, gain, n_links, C_BAND, method=method, rng=np.random.default_rng(9)
    )
    assert np.array_equal(a.toa_s, b.toa_s, equal_nan=True)
    assert np.isfinite(a.toa_s[:2]).all()


def test_pulse_methods_report_undetected_when_below_noise_threshold():
    # A path made detectable by a low override threshold (5 dB) whose post-correlation SNR (8 dB)
    # stays below the detector's noise threshold (-ln 1e-6 = 11.4 dB): the pulse methods report no
    # ToA, while first_path still names the path.
    lb = LinkBudget(detection_threshold_db=5.0)
    unit_db = lb.path_snr_db(np.array([1.0]), C_BAND)[0]
    pg_db = 10 * math.log10(lb.processing_gain(C_BAND))
    amp = 10 ** ((8.0 - pg_db - unit_db) / 20)  # post-correlation SNR 8 dB
    est = estimate_toa(np.array([0]), np.array([1e-7]), np.array([amp]), 1, C_BAND,
                       method="peak", budget=lb, noise=False)  # fmt: skip
    assert est.first_path[0] == 0 and not est.detected[0] and np.isnan(est.toa_s[0])


def test_input_errors():
    link, delay, gain, n_links = _three_links()
    with pytest.raises(HallrayError, match="unknown ToA method.*first-path, peak, leading-edge"):
        estimate_toa(link, delay, gain, n_links, C_BAND, method="music", noise=False)
    with pytest.raises(HallrayError, match="rng"):
        estimate_toa(link, delay, gain, n_links, C_BAND)
    with pytest.raises(HallrayError, match="link indices"):
        estimate_toa(link, delay, gain, 2, C_BAND, noise=False)
    with pytest.raises(HallrayError, match="1-D of equal length"):
        estimate_toa(link, delay[:-1], gain, n_links, C_BAND, noise=False)
    with pytest.raises(HallrayError, match="NaN"):
        estimate_toa(link, np.where(link == 0, np.nan, delay), gain, n_links, C_BAND, noise=False)
    with pytest.raises(HallrayError, match="integer"):
        estimate_toa(link.astype(float), delay, gain, n_links, C_BAND, noise=False)
    with pytest.raises(HallrayError, match="roll_off"):
        PulseShape(roll_off=1.5)
