"""The first-lobe receiver against closed forms and an independent brute-force implementation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import minimize_scalar

from positioning.model.pulse import TABLE_PER_T, pulse_at, pulse_table
from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.emulation.bands import get_band
from raytrace.emulation.channel import LinkBudget, PulseShape, discrete_cir
from raytrace.emulation.receivers import (
    DEFAULT_TOA_METHOD,
    FirstLobeSettings,
    Receiver,
    cfar_factor,
    estimate_toa,
    isolated_half_width_t,
    precursor_extent_t,
)
from raytrace.emulation.receivers import first_lobe as receivers

C_BAND = get_band("c-band")
MMWAVE = get_band("mmwave")
PULSE = PulseShape()
BETA = PULSE.roll_off

#: Quartic sub-sample refinement at 8 samples per T: bias below this (in T) on a lone pulse.
REFINE_TOL_T = 1e-5
#: Lobe top of a merged response vs a root-find of the continuous |s(t)|, in T: the quartic
#: through five samples of a non-symmetric lobe (0.6 mm at 100 MHz).
MERGED_TOL_T = 5e-4
#: Relative agreement of a Monte Carlo variance (20k draws: sampling std 1 %) with its closed form.
VAR_REL_TOL = 0.05


def period(band=C_BAND) -> float:
    return PULSE.period_s(band)


def rc(t, T, beta=BETA):
    """Raised cosine of eq. 2 written out directly (scalar or array), h(0) = 1/T."""
    t = np.asarray(t, dtype=float)
    x = t / T
    out = np.sinc(x) / T
    den = 1 - (2 * beta * x) ** 2
    lim = np.isclose(den, 0.0, atol=1e-12)
    safe = np.where(lim, 1.0, den)
    fac = np.where(lim, np.pi / 4, np.cos(np.pi * beta * x) / safe)
    return out * fac


def amp_for_post_snr(post_db: float, band=C_BAND, budget=None) -> float:
    """|gain| of a path whose post-correlation SNR is ``post_db``."""
    lb = budget or LinkBudget()
    unit = lb.path_snr(np.array([1.0]), band)[0] * lb.processing_gain(band)
    return math.sqrt(10 ** (post_db / 10) / unit)


def one_link(delays, gains, band=C_BAND, **kw):
    d = np.asarray(delays, dtype=float)
    g = np.asarray(gains, dtype=complex)
    return estimate_toa(np.zeros(d.size, np.int64), d, g, 1, band, method="first-lobe", **kw)


# --------------------------------------------------------------------------------------------
# Thresholds
# --------------------------------------------------------------------------------------------


def test_cfar_factor_gives_the_false_alarm_rate_by_monte_carlo():
    """CA-CFAR with M cells: P(|n|^2 > alpha * mean of M cells) = P_fa (exponential powers)."""
    rng = np.random.default_rng(1)
    for m, pfa in ((8, 0.01), (64, 0.01), (16, 0.05)):
        alpha = cfar_factor(pfa, m)
        ref = rng.exponential(size=(400_000, m)).mean(axis=1)
        cell = rng.exponential(size=400_000)
        rate = np.mean(cell > alpha * ref)
        assert rate == pytest.approx(pfa, rel=0.05)
    assert cfar_factor(1e-6, None) == pytest.approx(-math.log(1e-6))
    assert cfar_factor(1e-6, 10**7) == pytest.approx(-math.log(1e-6), rel=1e-5)  # M -> inf


def test_precursor_extent_and_half_width():
    T = 1.0
    # beyond the extent the pulse stays under rho / 4 of its peak, checked on a fine grid
    for rho_db in (-12.0, -20.0, -30.0):
        rho = 10 ** (rho_db / 20)
        n = precursor_extent_t(BETA, rho, 16)
        x = np.linspace(n, 16, 20001)
        assert np.max(np.abs(rc(x, T))) * T < rho / 4
    w = isolated_half_width_t(BETA)
    assert rc(w / 2, T) * T == pytest.approx(0.5, abs=1e-12)
    assert 1.1 < w < 1.3


def test_detection_probability_follows_the_square_law_detector():
    """With the noise power known, a lone path at the link budget's required post-correlation
    SNR (13.18 dB for P_fa 1e-6, P_d 0.9) is detected 90 % of the time."""
    lb = LinkBudget()
    n = 20_000
    a = amp_for_post_snr(lb.required_snr_db)
    rng = np.random.default_rng(7)
    delay = 1e-7 + rng.uniform(0, period(), n)
    est = estimate_toa(np.arange(n), delay, np.full(n, a, complex), n, C_BAND, method="first-lobe",
                       rng=rng, first_lobe=FirstLobeSettings(cfar_cells=None))  # fmt: skip
    assert est.detected.mean() == pytest.approx(0.9, abs=0.01)
    # a CA-CFAR estimate of the noise costs a little detection probability at the same P_fa
    rng = np.random.default_rng(7)
    cfar = estimate_toa(np.arange(n), delay, np.full(n, a, complex), n, C_BAND,
                        method="first-lobe", rng=rng)  # fmt: skip
    assert 0.8 < cfar.detected.mean() < est.detected.mean()


# --------------------------------------------------------------------------------------------
# Noiseless: the lobe top, against closed forms
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
def test_lone_path_toa_is_its_delay(band):
    T = period(band)
    rng = np.random.default_rng(3)
    n = 200
    delay = 40.0 / C0 + rng.uniform(0, 3 * T, n)  # every sub-sample offset
    gain = amp_for_post_snr(30.0, band) * np.exp(1j * rng.uniform(0, 2 * np.pi, n))
    est = estimate_toa(np.arange(n), delay, gain, n, band, method="first-lobe", noise=False)
    assert est.detected.all()
    assert np.max(np.abs(est.toa_s - delay)) < REFINE_TOL_T * T
    np.testing.assert_allclose(est.peak_ratio_db, 0.0, atol=1e-9)
    np.testing.assert_allclose(est.lobe_width, 1.0, atol=0.01)  # linear interpolation of |r|
    np.testing.assert_array_equal(est.lobe_path, np.arange(n))
    # the measured SNR is the path's own (noise estimate exact without noise)
    lb = LinkBudget()
    np.testing.assert_allclose(est.snr_db, 10 * np.log10(lb.path_snr(gain, band)), atol=1e-6)


def _local_max(f, lo, hi):
    """Maximum of a smooth scalar function in [lo, hi] (bounded Brent on -f, in units of the
    interval so that the tolerance is relative)."""
    width = hi - lo
    res = minimize_scalar(lambda u: -f(lo + u * width), bounds=(0.0, 1.0), method="bounded",
                          options={"xatol": 1e-10})  # fmt: skip
    return lo + res.x * width


@pytest.mark.parametrize("sep_t, a2, phase", [(0.25, 0.8, 0.0), (0.4, 0.5, 2.0), (0.3, 0.7, 2.6)])
def test_overlapping_paths_bias_as_the_merged_lobe_says(sep_t, a2, phase):
    """Two paths within a pulse width merge into one lobe; its top (the ToA) is where
    |h(t) + a2 e^{j phase} h(t - sep)| peaks, found here by a bounded root-find on the
    continuous closed form. In phase the top moves late, out of phase it can move early."""
    T = period()
    a = amp_for_post_snr(40.0)
    t1 = 60e-9
    est = one_link([t1, t1 + sep_t * T], [a, a * a2 * np.exp(1j * phase)], noise=False)

    def mag(t):
        return abs(rc(t, T) + a2 * np.exp(1j * phase) * rc(t - sep_t * T, T))

    expected = _local_max(mag, -0.5 * T, (sep_t + 0.5) * T)
    assert est.toa_s[0] - t1 == pytest.approx(expected, abs=MERGED_TOL_T * T)
    assert est.lobe_width[0] > 1.0  # broadened by the overlap


def _first_lobe_top(mag, lo, hi, T):
    """Top of the first local maximum of ``mag`` above a quarter of its largest value in
    [lo, hi]: a T/200 scan, then a bounded root-find around it."""
    t = np.arange(lo, hi, T / 200)
    m = np.array([mag(x) for x in t])
    top = (m[1:-1] >= m[:-2]) & (m[1:-1] >= m[2:]) & (m[1:-1] > 0.25 * m.max())
    k = int(np.argmax(top)) + 1
    return _local_max(mag, t[k - 1], t[k + 1])


def test_overlap_bias_shrinks_with_bandwidth():
    """A reflection half as strong, in phase, 0.2-5 m behind the first path: it pulls the first
    lobe's top late by up to ~0.8 m at 100 MHz and ~0.2 m at 400 MHz (the bias scales with the
    pulse width 1.25/B), exactly where the closed-form lobe top is."""
    worst = {}
    for band in (C_BAND, MMWAVE):
        T = period(band)
        a = amp_for_post_snr(40.0, band)
        t1 = 50e-9
        seps = np.arange(0.2, 5.01, 0.4) / C0
        link = np.repeat(np.arange(seps.size), 2)
        delay = np.column_stack([np.full(seps.size, t1), t1 + seps]).reshape(-1)
        gain = np.tile([a, 0.5 * a], seps.size).astype(complex)
        est = estimate_toa(link, delay, gain, seps.size, band, method="first-lobe", noise=False)
        for i, sep in enumerate(seps):

            def mag(t, T=T, sep=sep):
                return abs(rc(t, T) + 0.5 * rc(t - sep, T))

            expected = _first_lobe_top(mag, -2 * T, sep + 2 * T, T)
            assert est.toa_s[i] - t1 == pytest.approx(expected, abs=MERGED_TOL_T * T)
        worst[band.name] = np.max(est.toa_s - t1) * C0
    assert 0.6 < worst["c-band"] < 1.0
    assert worst["mmwave"] < 0.3 * worst["c-band"]


def test_a_first_path_below_the_relative_threshold_is_missed():
    """20 dB below the strongest path (threshold -12 dB): the ToA is the strong path's, and the
    receiver reports the first lobe as the strongest (0 dB). At -25 dB threshold it is found."""
    T = period()
    a = amp_for_post_snr(50.0)
    delays = [60e-9, 60e-9 + 4 * T]
    est = one_link(delays, [0.1 * a, a], noise=False)
    assert abs(est.toa_s[0] - delays[1]) < 0.01 * T
    assert est.peak_ratio_db[0] == pytest.approx(0.0, abs=0.05)
    low = one_link(delays, [0.1 * a, a], noise=False,
                   first_lobe=FirstLobeSettings(relative_threshold_db=-25.0))  # fmt: skip

    def mag(t):  # the strong path's precursor tail pulls the weak lobe
        return abs(0.1 * rc(t, T) + rc(t - 4 * T, T))

    expected = _first_lobe_top(mag, -2 * T, 2 * T, T)
    assert low.toa_s[0] - delays[0] == pytest.approx(expected, abs=MERGED_TOL_T * T)
    assert abs(expected) < 0.25 * T
    strong = _first_lobe_top(mag, 3 * T, 5 * T, T)
    ratio = 20 * np.log10(mag(expected) / mag(strong))  # -19.4 dB: the tail adds to the lobe
    assert low.peak_ratio_db[0] == pytest.approx(ratio, abs=0.01)
    assert low.lobe_path[0] == 0


# --------------------------------------------------------------------------------------------
# Brute force: the same receiver written out on a fine grid of the whole response
# --------------------------------------------------------------------------------------------


def brute_force_first_lobe(delays, gains, band, settings, budget=None):
    """Noiseless first-lobe ToA by the definition: the whole response on a T/64 grid with the
    closed-form pulse, the CFAR (exact noise), relative and sidelobe thresholds, the first
    crossing, the first local maximum after it, refined by a bounded root-find."""
    lb = budget or LinkBudget()
    T = period(band)
    sigma = lb.correlator_noise_std(band, PULSE)
    gamma = sigma * math.sqrt(cfar_factor(lb.false_alarm_probability, settings.cfar_cells))
    rho = 10 ** (settings.relative_threshold_db / 20)

    def s(t):
        t = np.atleast_1d(t)
        return (gains[None, :] * rc(t[:, None] - delays[None, :], T)).sum(axis=1)

    t = np.arange(delays.min() - 16 * T, delays.max() + 16 * T, T / 64)
    mag = np.abs(s(t))
    k_peak = int(np.argmax(mag))
    t_peak = _local_max(lambda x: abs(s(x)[0]), t[k_peak] - T / 64, t[k_peak] + T / 64)
    p = abs(s(t_peak)[0])
    if p < gamma:
        return math.nan
    lead = (t_peak - t) / T
    env_x = np.linspace(0, 16, 16 * 512 + 1)
    env = np.maximum.accumulate(np.abs(rc(env_x[::-1], 1.0)))[::-1]
    side = np.where(lead > 0, np.interp(lead, env_x, env, right=0.0), 0.0)
    thr = np.maximum(max(gamma, rho * p), side * p + gamma * (lead > 0))
    k = int(np.argmax(mag >= thr))
    while mag[k + 1] >= mag[k]:
        k += 1
    return _local_max(lambda x: abs(s(x)[0]), t[k] - T / 64, t[k] + T / 64)


def test_windowed_receiver_equals_the_brute_force_definition():
    """Random multipath links (3-40 paths over 150 ns, random phases, 0-45 dB): the windowed
    evaluation gives the ToA of the brute-force definition."""
    rng = np.random.default_rng(11)
    T = period()
    settings = FirstLobeSettings()
    links, delays, gains, expected = [], [], [], []
    for lk in range(40):
        n = int(rng.integers(3, 41))
        d = 30e-9 + np.sort(rng.uniform(0, 150e-9, n))
        g = (np.array([amp_for_post_snr(x) for x in rng.uniform(0, 45, n)])
             * np.exp(1j * rng.uniform(0, 2 * np.pi, n)))  # fmt: skip
        links.append(np.full(n, lk))
        delays.append(d)
        gains.append(g)
        expected.append(brute_force_first_lobe(d, g, C_BAND, settings))
    est = estimate_toa(np.concatenate(links), np.concatenate(delays), np.concatenate(gains), 40,
                       C_BAND, method="first-lobe", noise=False)  # fmt: skip
    expected = np.array(expected)
    np.testing.assert_array_equal(np.isnan(est.toa_s), np.isnan(expected))
    ok = np.isfinite(expected)
    assert ok.sum() >= 35
    assert np.max(np.abs(est.toa_s[ok] - expected[ok])) < MERGED_TOL_T * T


@pytest.mark.parametrize("band", [C_BAND, MMWAVE])
def test_pulse_matrix_kernel_gives_the_bits_of_pulse_at(band):
    """The windows' pulse matrix in one compiled pass is positioning's pulse_at of the lag
    matrix bit for bit (the datasets must not change): lags inside the table, on its grid,
    beyond its span and at zero."""
    T = period(band)
    rng = np.random.default_rng(3)
    table = pulse_table(float(BETA), int(PULSE.span))
    delay = np.sort(rng.uniform(0.0, 60 * T, 300))
    t = np.concatenate([delay[:5], rng.uniform(-30 * T, 90 * T, 40) + np.arange(40) * T / 8,
                        delay[-3:] + 20 * T])  # fmt: skip
    want = pulse_at(t[None, :] - delay[:, None], T, table)
    got = np.full_like(want, np.nan)
    receivers.pulse_matrix_kernel(t, delay, TABLE_PER_T / T, table[0], table[1], got)
    assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert (want == 0).any() and (want == 1).any()  # beyond the span, on a path


def test_short_windows_fall_back_to_the_whole_response(monkeypatch):
    """Windows too short for the lobe are measured again on the whole response: same result."""
    rng = np.random.default_rng(5)
    n_links = 12
    link = np.repeat(np.arange(n_links), 8)
    delay = 30e-9 + rng.uniform(0, 100e-9, link.size)
    gain = np.array([amp_for_post_snr(x) for x in rng.uniform(0, 40, link.size)])
    gain = gain * np.exp(1j * rng.uniform(0, 2 * np.pi, link.size))
    ref = estimate_toa(link, delay, gain, n_links, C_BAND, method="first-lobe", noise=False)
    monkeypatch.setattr(receivers, "POST_T", -6)  # windows end before their lobes
    rx = Receiver("first-lobe", C_BAND)
    prep = rx.prepare(link, delay, gain, n_links)
    m = receivers.measure_first_lobe(prep.plan, None)
    assert m.refits > 0
    np.testing.assert_allclose(m.toa_s, ref.toa_s, rtol=0, atol=MERGED_TOL_T * period())


# --------------------------------------------------------------------------------------------
# Noise
# --------------------------------------------------------------------------------------------


def test_lone_path_error_attains_the_pulse_crlb_without_early_outliers():
    """At post-correlation SNR 30 dB the ToA error of a lone path is unbiased with the variance
    1 / (8 pi^2 f_rms^2 SNR_post) of the pulse (f_rms by quadrature of the raised-cosine
    spectrum), and no precursor sidelobe is ever taken for the path."""
    T = period()
    f1, f2 = (1 - BETA) / (2 * T), (1 + BETA) / (2 * T)

    def spec(f):
        f = abs(f)
        return 1.0 if f <= f1 else 0.5 * (1 + math.cos(math.pi * T / BETA * (f - f1)))

    f_rms2 = quad(lambda f: f * f * spec(f), 0, f2, points=[f1])[0] / quad(spec, 0, f2,
                                                                         points=[f1])[0]  # fmt: skip
    n = 20_000
    rng = np.random.default_rng(2)
    delay = 1e-7 + rng.uniform(0, T, n)
    a = amp_for_post_snr(30.0)
    est = estimate_toa(np.arange(n), delay, np.full(n, a, complex), n, C_BAND,
                       method="first-lobe", rng=rng)  # fmt: skip
    err = est.toa_s - delay
    crlb = 1 / (8 * math.pi**2 * f_rms2 * 10**3.0)
    assert est.detected.all()
    assert np.var(err) == pytest.approx(crlb, rel=VAR_REL_TOL)
    assert abs(np.mean(err)) < 5 * math.sqrt(crlb / n)
    assert np.max(np.abs(err)) < 0.2 * T  # no sidelobe (1.4 T early) detections


def test_seeded_and_deterministic():
    rng = np.random.default_rng(9)
    link = np.repeat(np.arange(6), 5)
    delay = 30e-9 + rng.uniform(0, 80e-9, link.size)
    gain = np.array([amp_for_post_snr(x) for x in rng.uniform(5, 40, link.size)]).astype(complex)
    a = estimate_toa(link, delay, gain, 6, C_BAND, rng=np.random.default_rng(4))
    b = estimate_toa(link, delay, gain, 6, C_BAND, rng=np.random.default_rng(4))
    c = estimate_toa(link, delay, gain, 6, C_BAND, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(a.toa_s, b.toa_s)
    assert not np.array_equal(a.toa_s, c.toa_s)
    assert a.method == DEFAULT_TOA_METHOD == "search-back"  # the default (receiver study)


def test_prepare_once_measure_many_is_the_same_as_one_call():
    rng = np.random.default_rng(8)
    link = np.repeat(np.arange(4), 6)
    delay = 30e-9 + rng.uniform(0, 80e-9, link.size)
    gain = np.array([amp_for_post_snr(x) for x in rng.uniform(5, 40, link.size)]).astype(complex)
    rx = Receiver("first-lobe", MMWAVE)
    prep = rx.prepare(link, delay, gain, 4)
    for seed in (1, 2):
        one = estimate_toa(link, delay, gain, 4, MMWAVE, method="first-lobe",
                           rng=np.random.default_rng(seed))  # fmt: skip
        two = rx.measure(prep, np.random.default_rng(seed))
        np.testing.assert_array_equal(one.toa_s, two.toa_s)
        np.testing.assert_array_equal(one.snr_db, two.snr_db)


def test_links_without_paths_or_power_are_not_detected():
    a = amp_for_post_snr(30.0)
    est = estimate_toa(np.array([0, 2]), np.array([50e-9, 60e-9]), np.array([a, 1e-12]), 3,
                       C_BAND, noise=False)  # fmt: skip
    assert est.detected.tolist() == [True, False, False]
    assert np.isnan(est.toa_s[1:]).all() and np.isnan(est.snr_db[1:]).all()
    assert est.lobe_path.tolist() == [0, -1, -1]


def test_bad_settings_and_unknown_receiver():
    with pytest.raises(HallrayError, match="unknown ToA method 'ideal'; known: first-lobe, "
                                           "first-path, peak, leading-edge"):  # fmt: skip
        Receiver("ideal", C_BAND)
    with pytest.raises(HallrayError, match="relative_threshold_db"):
        FirstLobeSettings(relative_threshold_db=3.0)
    with pytest.raises(HallrayError, match="cfar_cells"):
        FirstLobeSettings(cfar_cells=0)
    cir = discrete_cir(np.array([0]), np.array([1e-7]), np.array([1e-4 + 0j]), 1)
    assert cir.n_links == 1


def test_preparing_some_links_again_gives_their_rows_of_the_full_plan():
    """The first-lobe refit prepares only the refitted links (``only``), padded to the width of
    the plan of all links (``min_width``): the same rows, so the same noise draws."""
    rng = np.random.default_rng(5)
    n_links, per = 12, 9
    link = np.repeat(np.arange(n_links), per)
    delay = 3e-8 + rng.uniform(0, 4e-7, link.size)
    gain = 1e-5 * rng.lognormal(0, 1, link.size) * np.exp(2j * np.pi * rng.random(link.size))
    cir = discrete_cir(link, delay, gain, n_links)
    args = (cir, C_BAND, LinkBudget(), PULSE, FirstLobeSettings())
    whole = np.zeros(n_links, dtype=bool)
    whole[[2, 7, 8]] = True
    every = receivers.prepare_first_lobe(*args, full=whole)
    others = every.n_samples[~whole[every.links]].max()
    some = receivers.prepare_first_lobe(*args, full=whole, only=whole, min_width=others)
    np.testing.assert_array_equal(some.links, np.flatnonzero(whole))
    assert some.signal.shape[1] == every.signal.shape[1]
    rows = np.searchsorted(every.links, some.links)
    for name in ("t0_s", "n_samples", "signal", "peak_signal", "peak_time_s"):
        np.testing.assert_array_equal(getattr(some, name), getattr(every, name)[rows], err_msg=name)


def _random_paths(seed: int, n_links: int = 12, per_link: int = 30):
    rng = np.random.default_rng(seed)
    link = np.repeat(np.arange(n_links), per_link)
    delay = 20e-9 + rng.uniform(0.0, 300e-9, link.size)
    amp = 10.0 ** (rng.uniform(-120.0, -60.0, link.size) / 20.0)
    gain = amp * np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, link.size))
    return link, delay, gain, n_links


@pytest.mark.parametrize("band", ["c-band", "mmwave"])
def test_receivers_sharing_one_set_of_paths_prepare_what_each_prepares_alone(band):
    """A band's receivers given one SharedPaths (the CIR and first paths computed once) prepare
    exactly what each prepares alone, array for array and bit for bit, and measure the same."""
    from dataclasses import fields

    from raytrace.emulation.channel.cir import SharedPaths

    link, delay, gain, n = _random_paths(3)
    shared = SharedPaths(link, delay, gain, n)
    rxs = [Receiver(m, band) for m in ("search-back", "paper", "first-path", "first-lobe")]
    rxs.append(Receiver("first-path", band, first_path_threshold=False))
    for rx in rxs:
        alone = rx.prepare(link, delay, gain, n)
        together = rx.prepare(link, delay, gain, n, shared)
        _assert_same(alone, together)
        a = rx.measure(alone, np.random.default_rng(5))
        b = rx.measure(together, np.random.default_rng(5))
        for f in fields(a):
            np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name))
    assert together.cir is shared.cir  # computed once for all of them
    # paths other than the shared ones' arrays: the SharedPaths is not used
    other = Receiver("paper", band).prepare(link, delay * 1.5, gain, n, shared)
    _assert_same(other, Receiver("paper", band).prepare(link, delay * 1.5, gain, n))


def _assert_same(a, b):
    from dataclasses import fields, is_dataclass

    assert type(a) is type(b)
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if is_dataclass(x):
            _assert_same(x, y)
        elif isinstance(x, np.ndarray):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)
        elif isinstance(x, tuple):
            assert len(x) == len(y)
            for u, v in zip(x, y):
                np.testing.assert_array_equal(u, v)
        else:
            assert x == y, f.name
