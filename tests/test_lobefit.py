"""The two-pulse refinement of a first lobe (positioning.model.lobefit) against closed forms: the
noise correlation against a direct integral of eq. 2 and against the noise the receivers draw;
the fit of one or two pulses recovers their delays and amplitudes exactly without noise; the
delays' standard errors against a Monte Carlo of the fit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from positioning.model.lobefit import (
    FIT_PER_T,
    LEAD_MIN_T,
    _cross,
    _pulse_and_slope,
    _ridge,
    _weighted_pulses,
    delay_error,
    fit_pulses,
    fit_pulses_numpy,
    noise_correlation,
    noise_gain,
    refine_lobe,
)
from positioning.model.pulse import pulse_table, raised_cosine
from raytrace.emulation.channel.response import correlator_noise

BETA, SPAN = 0.25, 16
TABLE = pulse_table(BETA, SPAN)
#: The correlation table (fftconvolve of eq. 2 on a grid of T/64 over +-16 T) against quad of the
#: product of two pulses over +-16 T: the grid's quadrature error (measured 2e-5).
CORR_TOL = 1e-4
#: Noiseless fit (the receiver's 8 rounds; 30 give the same): delays in T and amplitudes relative
#: to the first's. The fit uses the tabulated pulse (linear interpolation, 1.1e-7 of the peak), the
#: samples are eq. 2 itself; a pair 0.1 T apart in anti-phase, nearly the pulse's derivative,
#: amplifies that by its conditioning: measured 1.1e-4 T and 2.2e-3 at 0.1 T, 3e-6 T from 0.2 T,
#: 2e-7 T from 0.3 T.
EXACT_TOL = {0.1: (2e-4, 5e-3), 0.2: (1e-5, 1e-4)}
EXACT_FAR = (1e-6, 1e-5)
#: Monte Carlo of the delay's standard error: 2000 draws give the std to 1/sqrt(2 x 2000) = 1.6 %;
#: the residual-based estimate itself scatters by its effective degrees of freedom (~10 %).
SE_REL_TOL = 0.25
#: Compiled fit vs its numpy reference: the same arithmetic but the order of the sums. The
#: slope is piecewise constant on the pulse table's cells (1/2048 T), so a rounding-level
#: difference in a delay can cross a cell and change a Gauss-Newton step: measured up to 4e-11
#: T on the test's rows, up to 6e-7 T on noisier close pairs.
KERNEL_TOL = 1e-5


def _autocorr(x: float) -> float:
    f = lambda u: raised_cosine(u, BETA) * raised_cosine(u + x, BETA)  # noqa: E731
    return quad(f, -SPAN, SPAN - x, limit=800, points=np.arange(-SPAN, SPAN + 1))[0]


def test_noise_correlation_is_the_pulse_autocorrelation():
    lags, rho = noise_correlation(BETA, SPAN)
    zero = _autocorr(0.0)
    for x in (0.125, 0.25, 0.5, 0.8, 1.0, 1.5, 2.5):
        assert np.interp(x, lags, rho) == pytest.approx(_autocorr(x) / zero, abs=CORR_TOL)


def test_noise_correlation_is_that_of_the_noise_the_receivers_draw():
    """correlator_noise(power=2) (spectrum W^2, the CFR receivers' noise): its sample
    correlation at T/4 spacing, and kappa_n, the power a unit pulse collects from it, both as
    noise_correlation and noise_gain say (2000 rows x 64 samples, 4 standard errors)."""
    T, os_ = 1.0, 8
    n = correlator_noise(np.random.default_rng(3), 4000, 64 * os_, T / os_, T, BETA, 1.0,
                         guard=16 * os_, power=2)[:, :: os_ // FIT_PER_T]  # fmt: skip
    lags, rho = noise_correlation(BETA, SPAN)
    for k in (1, 2, 3, 4):
        got = np.mean(np.real(n[:, k:] * np.conj(n[:, :-k]))) / np.mean(np.abs(n) ** 2)
        assert got == pytest.approx(np.interp(k / FIT_PER_T, lags, rho), abs=0.01)
    p = raised_cosine(np.arange(-16, 17) / FIT_PER_T, BETA)
    proj = n[:, 10 : 10 + p.size] @ p / math.sqrt(p @ p)
    got = np.mean(np.abs(proj) ** 2) / np.mean(np.abs(n) ** 2)
    assert got == pytest.approx(noise_gain(BETA, SPAN), rel=4 * math.sqrt(2 / 4000))


def _samples(tau_t, amp, lead=1.25, tail=1.75, top=0.0):
    t = (top + np.arange(-lead, tail + 1e-9, 1 / FIT_PER_T))[None, :]
    s = sum(a * raised_cosine(t - d, BETA) for d, a in zip(tau_t, amp))
    return s.astype(complex), t, np.ones_like(t, dtype=bool)


@pytest.mark.parametrize("sep", [0.1, 0.2, 0.3, 0.5, 0.7, 1.0])
@pytest.mark.parametrize("ratio_db, phase_deg", [(0.0, 180.0), (-3.0, 160.0), (-6.0, 0.0), (0.0, 90.0)])
def test_two_pulses_are_recovered_exactly_without_noise(sep, ratio_db, phase_deg):
    """Two pulses ``sep`` periods apart, the second ``ratio_db`` weaker at ``phase_deg``:
    started 0.25 T off each delay, the fit returns both delays and amplitudes."""
    amp = np.array([1.0, 10 ** (ratio_db / 20) * np.exp(1j * math.radians(phase_deg))])
    s, t, v = _samples([0.0, sep], amp)
    tau, a, e = fit_pulses(s, t, v, np.array([[-0.25, sep + 0.25]]), 1.0, TABLE)
    tol_t, tol_a = EXACT_TOL.get(sep, EXACT_FAR)
    assert tau[0] == pytest.approx([0.0, sep], abs=tol_t)
    assert a[0] == pytest.approx(amp, abs=tol_a)
    assert e[0] < 1e-6


def test_compiled_pulses_are_numpys_bit_for_bit():
    """The fit's compiled inner loop is the numpy formula it replaced, bit for bit (outputs of the
    receiver must not move): pulse and slope at random lags (zero, beyond the table, exact
    table nodes included) times the weights; the symmetric cross products and the ridge are the
    plain ones."""
    rng = np.random.default_rng(11)
    r, n, k, period = 37, 21, 2, 3.7e-9
    t = np.sort(rng.uniform(-20, 20, (r, n)), axis=1) * period
    tau = rng.uniform(-2, 2, (r, k)) * period
    t[0, :k] = tau[0]  # lag exactly 0
    t[1, 0] = tau[1, 0] + 40 * period  # beyond the table
    t[2, 0] = tau[2, 0] + 3 * period / 2048  # on a table node
    w = (rng.uniform(size=(r, n)) < 0.8).astype(float)
    h, slope = _weighted_pulses(t, tau, w, 2048 / period, *TABLE)
    h0, s0 = _pulse_and_slope(t[None, :, :] - tau.T[:, :, None], period, TABLE)
    h0 *= w[None]
    s0 *= w[None]
    assert h.tobytes() == h0.tobytes() and slope.tobytes() == s0.tobytes()
    g = np.einsum("krn,jrn->rkj", h, h)
    assert np.array_equal(_cross(h, h, symmetric=True), g)
    a = g.copy()
    a[3, 0, 1] = a[3, 1, 0] = -0.0
    eye = np.eye(k)[None]
    plain = a + (1e-10 * np.maximum(np.abs(np.einsum("rkk->rk", a)).max(axis=1), 1e-300))[:, None, None] * eye
    assert _ridge(a).tobytes() == plain.tobytes()


@pytest.mark.parametrize("k", [1, 2, 3])
def test_compiled_fit_is_the_numpy_fit(k):
    """The compiled fit (fit_pulses) against its numpy reference (fit_pulses_numpy), 300 rows of
    ``k`` pulses 0.4-0.6 T apart in noise (std 0.1 % of the peak), masked tails, starts 0.1 T
    off: the same delays, amplitudes and residual energies (KERNEL_TOL)."""
    rng = np.random.default_rng(k)
    n = 300
    t = np.tile(np.arange(-1.25, 3.5, 0.25), (n, 1))
    tau = np.cumsum(rng.uniform(0.4, 0.6, (n, k)), axis=1) - 0.4
    amp = np.exp(2j * np.pi * rng.random((n, k))) * rng.uniform(0.5, 1.0, (n, k))
    s = sum(amp[:, j, None] * raised_cosine(t - tau[:, j, None], BETA) for j in range(k))
    s = s + 1e-3 * (rng.standard_normal(t.shape) + 1j * rng.standard_normal(t.shape))
    v = np.ones(t.shape, dtype=bool)
    v[: n // 2, -3:] = False
    start = tau + rng.choice([-0.1, 0.1], tau.shape)
    got, ref = fit_pulses(s, t, v, start, 1.0, TABLE), fit_pulses_numpy(s, t, v, start, 1.0, TABLE)
    # rows the reference fits (a few pairs fall into an anti-phase pair on one delay, where the
    # delays are not determined and any rounding moves them)
    ok = np.all(np.abs(ref[0] - tau) < 0.1, axis=1)
    assert np.mean(ok) > 0.9
    assert got[0][ok] == pytest.approx(ref[0][ok], abs=KERNEL_TOL)
    assert got[1][ok] == pytest.approx(ref[1][ok], abs=KERNEL_TOL)
    assert got[2][ok] == pytest.approx(ref[2][ok], rel=KERNEL_TOL)


def test_one_pulse_fit_and_masked_samples():
    """K = 1: delay and complex amplitude of a lone pulse; samples outside ``valid`` do not count
    (a large value there changes nothing)."""
    s, t, v = _samples([0.3], [0.5 - 0.2j])
    v[0, -3:] = False
    s[0, -3:] = 1e6
    tau, a, e = fit_pulses(s, t, v, np.array([[0.1]]), 1.0, TABLE)
    assert tau[0, 0] == pytest.approx(0.3, abs=EXACT_FAR[0])
    assert a[0, 0] == pytest.approx(0.5 - 0.2j, abs=EXACT_FAR[1])


def test_delay_error_matches_the_scatter_of_the_fit():
    """Two pulses 0.6 T apart in white noise (sample std 0.01 of the peak, kappa_n = 1): the
    median of the residual-based standard error is the std of the fitted delays over 2000 draws."""
    n, sigma = 2000, 0.01
    amp = np.array([1.0, -0.7])
    s, t, v = _samples([0.0, 0.6], amp)
    rng = np.random.default_rng(5)
    noise = sigma * (rng.standard_normal((n, t.size)) + 1j * rng.standard_normal((n, t.size))) / math.sqrt(2)
    s = s + noise
    t, v = np.repeat(t, n, axis=0), np.repeat(v, n, axis=0)
    tau, a, e = fit_pulses(s, t, v, np.tile([0.0, 0.6], (n, 1)), 1.0, TABLE)
    se = delay_error(t, v, tau, a, e, 1.0, TABLE, 1.0)
    for k in (0, 1):
        assert np.median(se[:, k]) == pytest.approx(np.std(tau[:, k]), rel=SE_REL_TOL)


def test_refine_lobe_keeps_a_lone_pulse_and_takes_the_first_of_two():
    """Noiseless rows (noise power 1e-12 of the peak's): a lone pulse's lobe is one pulse (its
    top stands); two anti-phase pulses 0.2 T apart (the second -1 dB), whose merged lobe tops
    0.4 T before the first, give the first delay; a weak earlier pulse (-10 dB) is not taken
    (the earlier component must be at least half the later)."""
    T, os_ = 1.0, 8
    t = np.arange(-6.0, 6.0, T / os_)
    rows = [[(0.0, 1.0)], [(0.0, 1.0), (0.2, -(10**-0.05))], [(0.0, 10**-0.5), (0.5, 1.0)]]
    sig = np.array([sum(a * raised_cosine(t - d, BETA) for d, a in r) for r in rows], complex)
    tops = np.array([t[np.argmax(np.abs(x))] for x in sig])
    assert tops[1] < -0.25  # the merged lobe leads the first path
    m = len(rows)
    out, peak, fit = refine_lobe(
        sig, np.full(m, t.size), np.full(m, t[0]), T / os_, T, os_, TABLE, tops, tops,
        np.full((m, 1), np.nan), np.zeros((m, 1), complex), np.full(m, 1e-5), np.full(m, 1e-12),
        20.0, 0.25, noise_gain(BETA, SPAN),
    )  # fmt: skip
    assert fit.one_pulse[0] and out[0] == tops[0]
    assert fit.applied[1] and out[1] == pytest.approx(0.0, abs=1e-4)
    assert not fit.applied[2] and out[2] == tops[2]


def _first_lobe_top(t, mag, rho=0.25):
    """Time of the top (largest sample) of the first lobe above ``rho`` of the largest: the
    first-lobe rule on samples."""
    i = int(np.argmax(mag >= rho * mag.max()))
    while i + 1 < mag.size and mag[i + 1] > mag[i]:
        i += 1
    return t[i]


def _refine(rows, sigma2=1e-12, seed=None, noise=0.0):
    """refine_lobe on noiseless (or noisy) rows of pulses ``[(delay_t, amp), ...]``, T = 1,
    8 samples per T: the first lobe's top (sample) and the strongest peak as the receiver
    passes them."""
    T, os_ = 1.0, 8
    t = np.arange(-6.0, 6.0, T / os_)
    sig = np.array([sum(a * raised_cosine(t - d, BETA) for d, a in r) for r in rows], complex)
    if noise:
        rng = np.random.default_rng(seed)
        sig += noise * (rng.standard_normal(sig.shape) + 1j * rng.standard_normal(sig.shape)) / math.sqrt(2)
    tops = np.array([_first_lobe_top(t, np.abs(x)) for x in sig])
    peaks = np.array([t[np.argmax(np.abs(x))] for x in sig])
    m = len(rows)
    out, peak, fit = refine_lobe(
        sig, np.full(m, t.size), np.full(m, t[0]), T / os_, T, os_, TABLE, tops, peaks,
        np.full((m, 1), np.nan), np.zeros((m, 1), complex), np.full(m, 1e-5),
        np.full(m, sigma2), 20.0, 0.25, noise_gain(BETA, SPAN),
    )  # fmt: skip
    return tops, out, peak, fit


def test_lobe_top_gives_way_only_to_a_later_fitted_component():
    """Random lobes of two or three paths within half a period (amplitudes 0 to -10 dB, random
    phases) in noise (post-correlation SNR ~40 dB): where no earlier component is accepted, the
    lobe top stands or moves later, by more than the early margin (LEAD_MIN_T) and more than
    CONSISTENT_SE of the fitted component's standard errors; never earlier."""
    rng = np.random.default_rng(21)
    n, sigma = 300, 0.01
    rows = []
    for _ in range(n):
        k = rng.integers(2, 4)
        d = np.sort(rng.uniform(0.0, 0.5, k))
        d -= d[0]
        a = 10 ** (-rng.uniform(0, 10, k) / 20) * np.exp(2j * np.pi * rng.random(k))
        rows.append(list(zip(d, a)))
    tops, out, peak, fit = _refine(rows, sigma2=sigma**2, seed=4, noise=sigma)
    two = fit.applied & ~fit.moved
    assert np.array_equal(out[two], fit.tau[two, 0])
    assert np.array_equal(out[~fit.applied], tops[~fit.applied])
    assert np.all(out[fit.moved] - tops[fit.moved] > LEAD_MIN_T)
    assert np.all(fit.order[fit.moved] >= 2) and np.all(np.isfinite(peak[fit.applied]))
    assert fit.moved.sum() >= 3  # the rule is exercised: anti-phase lobes that top early


#: Lobes of three paths (delay after the first in T, dB under it, phase in degrees) whose merged
#: first lobe tops early and whose two-pulse fit is not determined: the best fit of two and of
#: three pulses places the first path (found among 400 random lobes, tests below).
CLUSTERS = [[(0.0, 0.0, -157.0), (0.11, -1.6, -11.0), (0.13, -3.8, 71.0)],
            [(0.0, 0.0, -47.0), (0.21, -0.1, 94.0), (0.32, -5.2, -154.0)]]  # fmt: skip


def test_anti_phase_clusters_are_not_reported_early():
    """Noiseless (60 dB) lobes of :data:`CLUSTERS`: the merged first lobe tops 0.75 and 1.6 T
    before the first path (more than the early margin), no earlier component is accepted, and
    the lobe top gives way to the best fit's first component (two and three pulses): within
    0.01 T of the first path."""
    rows = [[(d, 10 ** (db / 20) * np.exp(1j * np.radians(ph))) for d, db, ph in c] for c in CLUSTERS]
    tops, out, peak, fit = _refine(rows, sigma2=1e-6)
    assert np.all(tops < -0.5)
    assert np.all(fit.moved) and list(fit.order) == [2, 3]
    assert out == pytest.approx([0.0, 0.0], abs=0.01)
