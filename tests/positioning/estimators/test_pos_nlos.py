"""nlos-map on injected NLoS (issue 13 item 5; positioning.estimators.nlos)."""

from __future__ import annotations

import numpy as np
from pos_synth import PAPER_BS, SIGMA_M, nlos_scene

from positioning import locate
from positioning.model.area import ServiceArea

HALL = ServiceArea.box((-2.0, -2.0), (31.0, 27.0))


SIX_BS = np.vstack([PAPER_BS, [[14.5, -1.0, 5.0], [14.5, 26.0, 3.0]]])


def _err(f, dev):
    return np.hypot(*(f.xyz[:, :2] - dev[:, :2]).T)


def test_nlos_map_removes_one_nlos_base_station_of_six():
    dev, toa, links = nlos_scene(1, 200, SIX_BS, 1)
    f = locate(toa, SIX_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    e = _err(f, dev)
    # with the biased one out, 5 LoS ranges of noise SIGMA_M: a few sigma at worst
    assert np.percentile(e, 90) < 3 * SIGMA_M, np.percentile(e, [50, 90, 100])
    assert np.max(e) < 10 * SIGMA_M


def test_nlos_map_with_four_base_stations_uses_snr_and_positivity():
    dev, toa, links = nlos_scene(2, 300, PAPER_BS, 1)
    f = locate(toa, PAPER_BS, "nlos-map", height_m=1.0, links=links, area=HALL, return_info=True)
    g = locate(toa, PAPER_BS, "irls", height_m=1.0, area=HALL, return_info=True)
    e, ei = _err(f, dev), _err(g, dev)
    # redundancy 1: the exact leave-one-out fits all fit; the SNR deficit and the sign of the
    # excess pick the right one in most epochs
    assert np.median(e) < 2 * SIGMA_M, np.percentile(e, [50, 90])
    assert np.mean(e) < 0.3 * np.mean(ei)


def _em_fit_reference(prob, theta0, rows, *, tol_m, max_iter, gn_max_iter):
    """em_fit as it was: the E-step's NLL computed again at every iteration's start."""
    from dataclasses import replace

    from positioning.estimators.nlos import _nll
    from positioning.estimators.solver import levenberg_marquardt
    from positioning.model.noise import WIDE_PULSES, late_mean_excess, link_sigma, pulse_width_m
    from positioning.model.residuals import pseudorange_model

    E, N = prob.rho.shape
    sigma_all = link_sigma(prob.links, (E, N))
    s_w = WIDE_PULSES * pulse_width_m(prob.links)
    theta = theta0.copy()
    act = np.flatnonzero(rows & np.isfinite(theta0).all(axis=1))
    for _ in range(max_iter):
        if act.size == 0:
            break
        sub, sig = prob.take(act), sigma_all[act]
        nll0, resp, r = _nll(sub, theta[act], sig, s_w)
        excess = late_mean_excess(r, sig)
        w = resp[0] / sig**2 + resp[1] / (sig**2 + s_w**2) + resp[2] / sig**2
        shift = resp[2] / sig**2 * excess / w
        W = np.where(sub.valid, w, 0.0)
        shifted = replace(sub, rho=sub.rho - np.where(sub.valid, shift, 0.0))
        th, _, _ = levenberg_marquardt(pseudorange_model(shifted), theta[act], W, tol=tol_m,
                                       max_iter=gn_max_iter)  # fmt: skip
        if prob.area is not None:
            th[:, :2] = prob.area.project(th[:, :2])
        step = np.linalg.norm(th - theta[act], axis=1)
        nll1, _, _ = _nll(sub, np.nan_to_num(th), sig, s_w)
        ok = np.isfinite(step) & (nll1.sum(axis=1) < nll0.sum(axis=1))
        theta[act[ok]] = th[ok]
        act = act[ok & (step > tol_m)]
    return theta


def test_em_fit_reuses_the_nll_of_the_accepted_step_exactly():
    """em_fit takes an iteration's E-step from the NLL the previous one computed at the same
    point: the fit is the one of computing it again, bit for bit."""
    from positioning.estimators.nlos import em_fit
    from positioning.estimators.robust import candidates
    from positioning.model.problem import make_problem

    dev, toa, links = nlos_scene(7, 200, PAPER_BS[:4], 1)
    prob = make_problem(toa, PAPER_BS[:4], height_m=1.0, area=HALL, links=links)
    rows = prob.solvable
    for _, sub, s in list(candidates(prob, rows, 1, 1.0))[:3]:
        kw = dict(tol_m=1e-4, max_iter=30, gn_max_iter=5)
        theta, _, _, iters = em_fit(prob, s.theta, sub, **kw)
        assert iters.max() > 2  # several iterations: the reuse is exercised
        np.testing.assert_array_equal(theta, _em_fit_reference(prob, s.theta, sub, **kw))


def test_em_fit_in_numpy_is_the_compiled_fit(monkeypatch):
    """Without the compiled E-step (numpy's exp and log not the C library's) em_fit runs in
    numpy: the same fit as the reference loop, bit for bit."""
    from positioning.estimators import nlos
    from positioning.estimators.robust import candidates
    from positioning.model.problem import make_problem

    monkeypatch.setattr(nlos, "numpy_is_libm", lambda: False)
    dev, toa, links = nlos_scene(8, 120, PAPER_BS[:4], 1)
    prob = make_problem(toa, PAPER_BS[:4], height_m=1.0, area=HALL, links=links)
    _, sub, s = next(iter(candidates(prob, prob.solvable, 1, 1.0)))
    kw = dict(tol_m=1e-4, max_iter=30, gn_max_iter=5)
    theta, _, _, _ = nlos.em_fit(prob, s.theta, sub, **kw)
    np.testing.assert_array_equal(theta, _em_fit_reference(prob, s.theta, sub, **kw))
