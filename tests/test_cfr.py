"""The PRS channel frequency response (raytrace.emulation.channel.cfr) against closed forms: the
delay profile of its inverse DFT is the pulse-shaped response of eq. 2, folded into the comb's
unambiguous delay; its noise follows the link budget; the receivers' windowed evaluation of it
(prepare_cfr) is the same signal."""

from __future__ import annotations

import math

import numpy as np
import pytest

from raytrace.core.errors import HallrayError
from raytrace.emulation.bands import Band, get_band
from raytrace.emulation.channel import (
    LinkBudget,
    PrsSettings,
    PulseShape,
    cfr_delay_profile,
    prs_cfr,
)
from raytrace.emulation.channel.cfr import (
    delay_profile_noise_std,
    fold_cir,
    subcarrier_noise_std,
    window_weights,
)
from raytrace.emulation.channel.cir import discrete_cir
from raytrace.emulation.channel.response import correlator_noise
from raytrace.emulation.receivers import FirstLobeSettings
from raytrace.emulation.receivers.search_back import prepare_cfr

C_BAND = get_band("c-band")
MMWAVE = get_band("mmwave")
PULSE = PulseShape()
BETA = PULSE.roll_off
#: The inverse DFT of the windowed CFR vs the raised cosine written out (Poisson's sum is exact:
#: the window's support is the band), relative to the peak: float64 rounding over 3333 terms and
#: the written-out formula's cancellation near |2 beta x| = 1 (measured 4e-9).
PROFILE_TOL = 1e-7
#: The windowed evaluation truncates the pulse at +-16 T (-70 dB) and interpolates a table at
#: T/2048 (1.1e-7): relative to the strongest path's peak.
WINDOW_TOL = 5e-4
#: Monte Carlo variance (8000 x 256 draws, correlated samples) against its closed form.
VAR_REL_TOL = 0.03


def rc(t, T, beta=BETA):
    """Raised cosine of eq. 2 written out (h(0) = 1/T)."""
    x = np.asarray(t, dtype=float) / T
    den = 1 - (2 * beta * x) ** 2
    lim = np.isclose(den, 0.0, atol=1e-12)
    fac = np.where(lim, np.pi / 4, np.cos(np.pi * beta * x) / np.where(lim, 1.0, den))
    return np.sinc(x) / T * fac


def direct_profile(f, cfr, w, step, t):
    """r(t) = dF sum_k W_k Y_k exp(j 2 pi f_k t), summed term by term at the times ``t``."""
    return step * (np.exp(2j * np.pi * np.outer(t, f)) @ (w * cfr))


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
def test_subcarriers_and_lone_path_profile_is_the_pulse(band):
    prs = PrsSettings()
    f = prs.subcarrier_hz(band)
    assert f.size == band.n_subcarriers == 3333
    assert f[-1] <= band.bandwidth_hz / 2 and np.allclose(np.diff(f), band.subcarrier_spacing_hz)
    T = PULSE.period_s(band)
    tau, a = 137.3 * T / 7, 1e-4 * np.exp(0.7j)
    _, cfr = prs_cfr(np.zeros(1, np.int64), np.array([tau]), np.array([a]), 1, band)
    # H(f) = a exp(-j 2 pi f tau), exactly
    np.testing.assert_allclose(cfr[0], a * np.exp(-2j * np.pi * f * tau), rtol=1e-10)
    t, r = cfr_delay_profile(cfr, band)
    assert t[1] - t[0] <= T / PULSE.oversampling
    period = prs.period_s(band)  # the profile is periodic: the path's images m / dF
    want = a * sum(rc(t - tau - m * period, T) for m in (-1, 0, 1))
    assert np.max(np.abs(r[0] - want)) < PROFILE_TOL * abs(a) / T


def test_comb_folds_late_paths_into_its_unambiguous_delay():
    band = MMWAVE
    prs = PrsSettings(comb=12)
    period = prs.period_s(band)
    assert period == pytest.approx(1 / (12 * 120e3))  # 694 ns, 208 m
    T = PULSE.period_s(band)
    delays = np.array([20e-9, 20e-9 + period + 9 * T])  # the late path folds to 9 T after
    gains = np.array([1e-4, 5e-5j])
    _, cfr = prs_cfr(np.zeros(2, np.int64), delays, gains, 1, band, prs=prs)
    t, r = cfr_delay_profile(cfr, band, prs=prs)
    assert t[-1] < period
    # the periodic pulse train of both paths (Poisson's sum over the images m / dF)
    m = np.arange(-3, 4)[:, None]
    want = sum(g * rc(t[None, :] - d - m * period, T).sum(axis=0) for d, g in zip(delays, gains))
    assert np.max(np.abs(r[0] - want)) < PROFILE_TOL * 1e-4 / T
    folded = fold_cir(discrete_cir(np.zeros(2, np.int64), delays, gains, 1), period, np.zeros(1))
    np.testing.assert_allclose(folded.delay_s, [20e-9, 20e-9 + 9 * T], rtol=0, atol=1e-18)
    # with a lead, a path within it of the period's end shows its image before the first path
    late = np.array([20e-9, 20e-9 + period - 3 * T])
    cir = discrete_cir(np.zeros(2, np.int64), late, gains, 1)
    np.testing.assert_allclose(fold_cir(cir, period, np.zeros(1)).delay_s, late, rtol=0, atol=0)
    folded = fold_cir(cir, period, np.zeros(1), 16 * T)
    np.testing.assert_allclose(folded.delay_s, [20e-9 - 3 * T, 20e-9], rtol=0, atol=1e-18)
    assert list(folded.path_index) == [1, 0]


def test_timing_offsets_shift_each_base_stations_links():
    band = C_BAND
    prs = PrsSettings(timing_offsets_s=(3e-9, -2e-9))
    np.testing.assert_array_equal(prs.link_offsets_s(4), [3e-9, 3e-9, -2e-9, -2e-9])
    with pytest.raises(HallrayError, match="cannot be split"):
        prs.link_offsets_s(3)
    delays = np.full(4, 50e-9)
    f, cfr = prs_cfr(np.arange(4), delays, np.full(4, 1e-4 + 0j), 4, band, prs=prs)
    for i, d in enumerate(prs.link_offsets_s(4)):
        np.testing.assert_allclose(cfr[i], 1e-4 * np.exp(-2j * np.pi * f * (50e-9 + d)), rtol=1e-10)


@pytest.mark.parametrize("comb", [1, 4])
def test_subcarrier_noise_follows_the_link_budget(comb):
    """A coherent sum over the observed subcarriers gives a path the post-correlation SNR of the
    link budget, |A|^2 snr_1 t_s B; the delay profile's noise std is dF sigma_sc ||W||."""
    band, lb = C_BAND, LinkBudget()
    prs = PrsSettings(comb=comb)
    k = prs.subcarrier_hz(band).size
    sigma = subcarrier_noise_std(band, lb, prs)
    snr_1 = float(lb.path_snr(np.ones(1), band)[0])
    assert k / sigma**2 == pytest.approx(snr_1 * lb.processing_gain(band), rel=1e-12)
    # Monte Carlo: noise-only CFRs (a path far below the noise) through the inverse DFT
    n = 400
    _, y = prs_cfr(np.arange(n), np.full(n, 1e-7), np.full(n, 1e-12 + 0j), n, band, prs=prs,
                   rng=np.random.default_rng(5))  # fmt: skip
    assert np.var(y) == pytest.approx(sigma**2, rel=VAR_REL_TOL)
    _, r = cfr_delay_profile(y, band, prs=prs)
    want = delay_profile_noise_std(band, lb, PULSE, prs)
    w = window_weights(band, PULSE, prs)
    assert want == pytest.approx(prs.spacing_hz(band) * sigma * np.linalg.norm(w), rel=1e-12)
    assert np.mean(np.abs(r) ** 2) == pytest.approx(want**2, rel=VAR_REL_TOL)
    # 0.69 dB above the correlator model's noise (the window is not the matched filter)
    ratio_db = 20 * math.log10(want / lb.correlator_noise_std(band, PULSE))
    assert ratio_db == pytest.approx(0.69 + 10 * math.log10(1.0), abs=0.02)


def test_windowed_noise_has_the_squared_spectrum():
    """correlator_noise(power=2): variance noise_std^2 and the autocorrelation of W^2 at lag T,
    sum W^2 cos(2 pi f T) / sum W^2 (W: the raised-cosine spectrum)."""
    band = C_BAND
    T = PULSE.period_s(band)
    dt = T / PULSE.oversampling
    n = correlator_noise(np.random.default_rng(2), 8000, 256, dt, T, BETA, 1.0, guard=64, power=2)
    assert np.mean(np.abs(n) ** 2) == pytest.approx(1.0, rel=VAR_REL_TOL)
    lag = PULSE.oversampling
    rho = np.mean(n[:, lag:] * np.conj(n[:, :-lag])).real
    f = np.linspace(-band.bandwidth_hz / 2, band.bandwidth_hz / 2, 20001)
    from raytrace.emulation.channel import raised_cosine_spectrum

    w2 = raised_cosine_spectrum(f, T, BETA) ** 2
    want = np.sum(w2 * np.cos(2 * np.pi * f * T)) / np.sum(w2)
    assert abs(want) > 0.05  # not the correlator's (uncorrelated at T)
    assert rho == pytest.approx(want, abs=0.01)


def test_receiver_windows_are_the_inverse_dft_of_the_cfr():
    """prepare_cfr's noiseless windows equal the delay profile of prs_cfr (comb 4, timing offsets,
    a path folded after the first, one whose image falls 5 T before it), summed term by term at
    the windows' sample times."""
    band = C_BAND
    prs = PrsSettings(comb=4, timing_offsets_s=(4e-9, -7e-9))
    T = PULSE.period_s(band)
    rng = np.random.default_rng(11)
    link = np.repeat(np.arange(2), 5)
    p = prs.period_s(band)
    delays = np.tile([60e-9, 60e-9 + 2.5 * T, 60e-9 + 6 * T, 60e-9 + p + 3.2 * T, 60e-9 + p - 5 * T], 2)
    gains = 1e-5 * np.tile([0.1, 1.0, 0.5, 0.3, 0.2], 2) * np.exp(2j * np.pi * rng.random(10))
    cir = discrete_cir(link, delays, gains, 2)
    early = fold_cir(cir, p, np.zeros(2), 16 * T).delay_s[[0, 5]]  # the image before the first
    np.testing.assert_allclose(early, 60e-9 - 5 * T, rtol=0, atol=1e-18)
    plan = prepare_cfr(cir, band, LinkBudget(), PULSE, FirstLobeSettings(), prs, depth=1e-2)
    f, cfr = prs_cfr(link, delays, gains, 2, band, prs=prs)
    w = window_weights(band, PULSE, prs)
    peak = 1e-5 / T
    for r, lk in enumerate(plan.links):
        t = plan.t0_s[r] + np.arange(plan.n_samples[r]) * plan.dt_s
        want = direct_profile(f, cfr[lk], w, prs.spacing_hz(band), t)
        assert np.max(np.abs(plan.signal[r, : plan.n_samples[r]] - want)) < WINDOW_TOL * peak


def test_bad_prs_settings_and_bands_are_one_line_errors():
    for comb in (0, 3, 5, 24, 2.0, True, "4"):
        with pytest.raises(HallrayError, match="unknown PRS comb"):
            PrsSettings(comb=comb)
    with pytest.raises(HallrayError, match="finite"):
        PrsSettings(timing_offsets_s=(float("nan"),))
    for field in ("bandwidth_hz", "subcarrier_spacing_hz"):
        kw = dict(name="x", center_frequency_hz=3.5e9, bandwidth_hz=1e8, subcarrier_spacing_hz=3e4)
        for bad in (0.0, -1.0):
            kw[field] = bad
            with pytest.raises(HallrayError) as e:
                Band(**kw)
            assert "\n" not in str(e.value)
    with pytest.raises(HallrayError, match="subcarriers"):
        cfr_delay_profile(np.zeros((1, 10), complex), C_BAND)
