"""The compiled grid NLL (positioning.estimators.mixture_kernel) against the numpy mixture NLL
it replaces (positioning.model.noise.mixture_nll), and nlos-map's grid starts against their
numpy form."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from pos_synth import PAPER_BS, nlos_scene
from scipy.special import log_ndtr

from positioning.estimators.mixture_kernel import (
    deepest_by_numpy,
    deepest_cells,
    pairwise_mixture_nll,
)
from positioning.estimators.nlos import SEPARATION_PITCHES, grid_starts
from positioning.model.area import ServiceArea
from positioning.model.noise import (
    LATE_MEAN_M,
    WIDE_PULSES,
    link_sigma,
    mixture_nll,
    pulse_width_m,
    shares,
)
from positioning.model.problem import make_problem

#: Where numpy's exp and log are not the C library's (numpy vectorises them on CPUs with
#: AVX-512), the kernel's values may differ from numpy's in the last bits: relative tolerance.
RTOL_OTHER_LIBM = 1e-13


def _numpy_is_libm() -> bool:
    """numpy's exp and log give the C library's bits (math.exp, math.log) on this machine."""
    x = np.random.default_rng(7).normal(0.0, 20.0, 4096)
    return all(np.exp(v) == math.exp(v) and np.log(abs(v)) == math.log(abs(v)) for v in x)


def _assert_same(got: np.ndarray, want: np.ndarray) -> None:
    if _numpy_is_libm():
        np.testing.assert_array_equal(got, want)
    else:
        np.testing.assert_allclose(got, want, rtol=RTOL_OTHER_LIBM, atol=0.0)


def _numpy_pairwise(s, valid, sigma, pw, pl, s_w):
    """The numpy form of the grid's NLL (grid_starts before the kernel)."""
    r = s[:, :, None, :] - s[:, :, :, None]
    nll, _ = mixture_nll(r, sigma[:, None, None, :], pw[:, :, None, :], pl[:, :, None, :], s_w)
    both = valid[:, None, None, :] & valid[:, None, :, None]
    return np.where(both, nll, 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pairwise_nll_is_numpys_mixture_nll(seed):
    rng = np.random.default_rng(seed)
    A, G, N = 5, 40, 6
    # residuals from millimetres to tens of metres either way: the core, wide and late
    # components each dominate somewhere, and the late one's log_ndtr runs on both branches
    s = rng.normal(0.0, 1.0, (A, G, N)) * 10.0 ** rng.uniform(-3.0, 1.5, (A, G, N))
    valid = rng.random((A, N)) > 0.2
    sigma = 10.0 ** rng.uniform(-2.5, -0.5, (A, N))
    pw = rng.uniform(0.01, 0.5, (A, G, N))
    pl = rng.uniform(0.01, 0.45, (A, G, N))
    s_w = 1.3
    got = pairwise_mixture_nll(s, valid, sigma, pw, pl, s_w, LATE_MEAN_M)
    want = _numpy_pairwise(s, valid, sigma, pw, pl, s_w)
    assert np.isfinite(want).all() and (want != 0.0).any()
    _assert_same(got, want)


def test_pairwise_nll_of_an_invalid_measurement_or_reference_is_zero():
    s = np.array([[[0.3, -1.2, 4.0]]])
    valid = np.array([[True, False, True]])
    got = pairwise_mixture_nll(s, valid, np.full((1, 3), 0.05), np.full((1, 1, 3), 0.05),
                               np.full((1, 1, 3), 0.1), 1.0, LATE_MEAN_M)  # fmt: skip
    assert (got[0, 0, 1, :] == 0.0).all() and (got[0, 0, :, 1] == 0.0).all()
    assert (got[0, 0, [0, 2]][:, [0, 2]] != 0.0).all()


def _numpy_grid_starts(prob, rows, step_m, n_starts):
    """grid_starts as it was before the kernel (numpy only), for the comparison."""
    E, N = prob.rho.shape
    out = np.full((n_starts, E, prob.dims + 1), np.nan)
    g = prob.area.grid(step_m)
    sigma = np.sqrt(link_sigma(prob.links, (E, N)) ** 2 + (0.5 * step_m) ** 2)
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    idx = np.flatnonzero(rows)
    A = idx.size
    xyz = np.empty((A, g.shape[0], 3))
    xyz[..., :2] = g[None]
    xyz[..., 2] = prob.height[idx, None]
    R = np.linalg.norm(xyz[:, :, None, :] - prob.bs[None, None], axis=3)
    valid = prob.valid[idx][:, None, :]
    s = np.where(valid, prob.rho[idx][:, None, :] - R, 0.0)
    r = s[:, :, None, :] - s[:, :, :, None]
    links = prob.links.take(idx)
    links = replace(links, snr_db=links.snr_db[:, None, None, :],
                    peak_ratio_db=links.peak_ratio_db[:, None, None, :],
                    lobe_width=links.lobe_width[:, None, None, :])  # fmt: skip
    pw, pl = shares(links, R[:, :, None, :], valid[:, :, None, :])
    nll, _ = mixture_nll(r, sigma[idx][:, None, None, :], pw, pl, s_w)
    tot = np.sum(np.where(valid[:, :, None, :], nll, 0.0), axis=3)
    tot = np.where(prob.valid[idx][:, None, :], tot, np.inf)
    jb = np.argmin(tot, axis=2)
    score = np.take_along_axis(tot, jb[..., None], axis=2)[..., 0].copy()
    ar = np.arange(A)
    for m in range(n_starts):
        gi = np.argmin(score, axis=1)
        ok = np.isfinite(score[ar, gi])
        th = np.column_stack([g[gi], s[ar, gi, jb[ar, gi]]])
        out[m, idx[ok]] = th[ok]
        near = np.linalg.norm(g[None, :, :] - g[gi][:, None, :], axis=2)
        score = np.where(near < SEPARATION_PITCHES * step_m, np.inf, score)
    return out


@pytest.mark.parametrize("heights", [(1.0,), (1.0, 1.5, 0.7)])
def test_grid_starts_are_those_of_the_numpy_form(heights):
    """On NLoS-biased epochs with receiver reports: the same starts, bit for bit (the kernel
    only decides which cells are deepest; the starts are the grid's own numbers), also where
    the device height varies (the cells' ranges are computed once per height)."""
    _, toa, links = nlos_scene(3, 120, PAPER_BS, 1)
    area = ServiceArea.box((-2.0, -2.0), (31.0, 27.0))
    height = np.resize(np.array(heights), len(toa))
    prob = make_problem(toa, PAPER_BS, None, height, area=area, links=links)
    rows = prob.solvable
    got = grid_starts(prob, rows, 2.0, 3)
    want = _numpy_grid_starts(prob, rows, 2.0, 3)
    assert np.isfinite(want).any()
    np.testing.assert_array_equal(got, want)


def _random_grid(seed, A, G, N):
    rng = np.random.default_rng(seed)
    cells = np.column_stack([rng.uniform(0, 30, G), rng.uniform(0, 25, G)])
    s = rng.normal(0.0, 3.0, (A, G, N)) + rng.normal(0.0, 10.0, (A, 1, N))
    valid = rng.random((A, N)) > 0.15
    valid[:, :2] = True
    sigma = 10.0 ** rng.uniform(-1.5, 0.2, (A, N))
    pw = rng.uniform(0.02, 0.3, (A, G, N))
    pl = rng.uniform(0.05, 0.6, (A, G, N))
    return s, valid, sigma, pw, pl, cells


@pytest.mark.parametrize("N", [3, 4, 7, 8, 11, 20])
def test_deepest_cells_are_numpys_argmins_of_the_whole_nll(N):
    """Branch and bound picks the cells and references numpy picks from every total (the
    totals summed in numpy's order: one by one under 8 stations, pairwise from 8), and
    computes far fewer of them."""
    A, G = 6, 150
    s, valid, sigma, pw, pl, cells = _random_grid(N, A, G, N)
    # a tie: two cells with the same numbers (numpy takes the lower index)
    s[:, 7], pw[:, 7], pl[:, 7] = s[:, 90], pw[:, 90], pl[:, 90]
    cells[7] = cells[90] + 0.01
    nll = pairwise_mixture_nll(s, valid, sigma, pw, pl, 1.3, LATE_MEAN_M)
    tot = np.where(valid[:, None, :], np.sum(nll, axis=3), np.inf)
    want = deepest_by_numpy(tot, cells, 4.0, 3)
    pick, ref, ok, n_exact = deepest_cells(s, valid, sigma, pw, pl, 1.3, LATE_MEAN_M, cells,
                                           4.0, 3)  # fmt: skip
    assert ok.all()
    np.testing.assert_array_equal(pick, want[0])
    np.testing.assert_array_equal(ref, want[1])
    np.testing.assert_array_equal(ok, want[2])
    assert n_exact < A * G * N


def test_deepest_cells_of_a_non_finite_epoch_take_numpys_way():
    s, valid, sigma, pw, pl, cells = _random_grid(5, 3, 40, 4)
    s[1, 3, 2] = np.nan
    nll = pairwise_mixture_nll(s, valid, sigma, pw, pl, 1.3, LATE_MEAN_M)
    tot = np.where(valid[:, None, :], np.sum(nll, axis=3), np.inf)
    want = deepest_by_numpy(tot, cells, 4.0, 2)
    got = deepest_cells(s, valid, sigma, pw, pl, 1.3, LATE_MEAN_M, cells, 4.0, 2)
    for g, w in zip(got[:3], want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_deepest_cells_with_every_cell_taken_is_not_ok():
    """More picks than separated cells: the rest are not ok, as numpy's inf scores say."""
    s, valid, sigma, pw, pl, cells = _random_grid(9, 2, 5, 4)
    cells[:] = [[0, 0], [1, 0], [2, 0], [10, 0], [11, 0]]
    pick, ref, ok, _ = deepest_cells(s, valid, sigma, pw, pl, 1.3, LATE_MEAN_M, cells, 5.0, 4)
    assert ok[:, :2].all() and not ok[:, 2:].any()


def test_late_term_bound_holds_for_scipys_log_ndtr():
    """The bound's premise: scipy's log_ndtr(x) <= -x^2/2 on -1e4 < x < -1 (by about
    0.92 + ln(-x), far more than its rounding)."""
    x = -np.concatenate([np.linspace(1.0, 50.0, 20001)[1:], np.geomspace(50.0, 1e4, 20001)[:-1]])
    assert (log_ndtr(x) <= -0.5 * (x * x)).all()


def _estep_problem(seed, links_kind):
    """A problem with receiver reports of every kind the E-step meets: lobes wide, narrow and
    weak, unknown reports (NaN), a station not received, or no reports at all."""
    rng = np.random.default_rng(seed)
    _, toa, links = nlos_scene(seed, 150, PAPER_BS, 1)
    toa[rng.random(toa.shape) < 0.1] = np.nan
    links = replace(links, lobe_width=rng.choice([0.9, 1.0, 1.2, np.nan], toa.shape),
                    peak_ratio_db=rng.choice([0.0, -6.0, np.nan], toa.shape))  # fmt: skip
    if links_kind == "no offset":
        links = replace(links, snr_offset_db=None)
    elif links_kind == "none":
        links = None
    prob = make_problem(toa, PAPER_BS, None, np.full(len(toa), 1.0), links=links)
    theta = np.column_stack([rng.uniform(-5, 35, len(toa)), rng.uniform(-5, 30, len(toa)),
                             rng.normal(0.0, 20.0, len(toa))])  # fmt: skip
    return prob, theta


@pytest.mark.parametrize("links_kind", ["reports", "no offset", "none"])
def test_compiled_estep_is_numpys(links_kind):
    """MixtureEStep's NLL, responsibilities, residuals, weights and shifted pseudo-ranges are
    nlos-map's numpy E-step and M-step weights (em_fit before the kernel), bit for bit."""
    from positioning.estimators.mixture_kernel import MixtureEStep
    from positioning.estimators.nlos import _nll
    from positioning.model.noise import late_mean_excess
    from positioning.model.tdoa import ranges

    prob, theta = _estep_problem(3, links_kind)
    E, N = prob.rho.shape
    sigma = link_sigma(prob.links, (E, N))
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    idx = np.flatnonzero(prob.solvable)[::2]
    sub, sig, th = prob.take(idx), sigma[idx], theta[idx]
    want = _nll(sub, th, sig, s_w)
    step = MixtureEStep(prob.rho, prob.valid, prob.links, sigma, s_w, LATE_MEAN_M)
    got = step.at(idx, ranges(prob.position(th, idx), prob.bs), th[:, 2])
    for g, w in zip(got, want, strict=True):
        _assert_same(g, w)
    nll, resp, r = want
    excess = late_mean_excess(r, sig)
    w = resp[0] / sig**2 + resp[1] / (sig**2 + s_w**2) + resp[2] / sig**2
    shift = resp[2] / sig**2 * excess / w
    W, rho_shifted = step.weights(idx, r, resp)
    _assert_same(W, np.where(sub.valid, w, 0.0))
    _assert_same(rho_shifted, sub.rho - np.where(sub.valid, shift, 0.0))
    assert (resp[2] > 0.5).any() and (resp[0] > 0.5).any()  # late and core both dominate


@pytest.mark.parametrize("links_kind", ["reports", "no offset", "none"])
def test_compiled_grid_log_shares_are_numpys(links_kind):
    """grid_log_shares: the logs of shares() at every cell, as grid_starts took them in numpy
    (the cells' free-space SNR per height, two heights), bit for bit."""
    from positioning.estimators.mixture_kernel import grid_log_shares
    from positioning.model.noise import free_space_snr_db
    from positioning.model.tdoa import ranges

    prob, _ = _estep_problem(5, links_kind)
    idx = np.arange(0, 60)
    at = idx % 2
    cells = np.column_stack([np.linspace(-3.0, 33.0, 50), np.linspace(28.0, -2.0, 50)])
    R_h = np.stack([ranges(np.column_stack([cells, np.full(50, h)]), prob.bs) for h in (1.0, 1.6)])
    links = None if prob.links is None else prob.links.take(idx)
    fs = None if links is None or links.snr_offset_db is None else free_space_snr_db(links, R_h)
    got = grid_log_shares(fs, at, links, len(cells), prob.n_bs)
    R = R_h[at]
    if links is not None:
        links = replace(links, snr_db=links.snr_db[:, None, :],
                        peak_ratio_db=links.peak_ratio_db[:, None, :],
                        lobe_width=links.lobe_width[:, None, :])  # fmt: skip
    pw, pl = shares(links, R, np.ones((len(idx), 1, prob.n_bs), dtype=bool))
    pw, pl = np.broadcast_to(pw, R.shape), np.broadcast_to(pl, R.shape)
    _assert_same(got, np.stack([np.log1p(-(pw + pl)), np.log(pw), np.log(pl)]))
