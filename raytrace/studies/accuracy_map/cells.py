"""Per-cell quantities of a chunk of cells: the noiseless receiver's detections and first
arrivals, the ToA spread over noise draws, the GDOP, the fixes' errors per method, and the
strongest paths stored for the twin's re-synthesis (:func:`measure_cells`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...core.constants import C0
from ...emulation.measurement import ToaModel, emulate_toa, prepare_links
from ...emulation.receivers.receiver import Receiver
from ...solver.paths import Paths
from .settings import MapSettings


def gdop_2d(cell_xyz: np.ndarray, bs_xyz: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Horizontal GDOP of the TDoA fix with the device height known, per cell.

    The ToAs ``t_b = |p - b| / c + offset`` have the unknowns (x, y, offset); with the Jacobian
    rows ``h_b = [(p - b)_x / |p - b|, (p - b)_y / |p - b|, 1]`` of the used base stations,
    ``GDOP = sqrt(trace of the (x, y) block of (H^T H)^-1)``: the RMS 2D error per metre of
    i.i.d. range noise (c times the ToA standard deviation). Eliminating the offset is the same
    as TDoA with a full difference covariance.

    Parameters
    ----------
    cell_xyz : (N, 3) float, m
    bs_xyz : (B, 3) float, m
    use : (N, B) bool, optional, base stations received at each cell (default all)

    Returns
    -------
    (N,) float, dimensionless; NaN with fewer than 3 base stations or a singular geometry
    """
    d = np.asarray(cell_xyz, float)[:, None, :] - np.asarray(bs_xyz, float)[None, :, :]
    r = np.linalg.norm(d, axis=2)
    rows = np.concatenate([d[:, :, :2] / r[:, :, None], np.ones(r.shape + (1,))], axis=2)
    w = np.ones(r.shape) if use is None else np.asarray(use, dtype=float)
    g = np.einsum("nb,nbi,nbj->nij", w, rows, rows)
    out = np.full(len(g), np.nan)
    ok = w.sum(axis=1) >= 3
    if ok.any():
        cond = np.linalg.cond(g[ok])
        sub = np.flatnonzero(ok)[cond < 1e12]
        if len(sub):
            inv = np.linalg.inv(g[sub])
            out[sub] = np.sqrt(inv[:, 0, 0] + inv[:, 1, 1])
    return out


def _excess_m(paths: Paths, first: np.ndarray) -> np.ndarray:
    """(L,) float, m: first path's delay x c minus the straight distance (NaN without one)."""
    n_rx = len(paths.rx)
    link = np.arange(paths.n_links)
    dist = np.linalg.norm(paths.tx[link // n_rx] - paths.rx[link % n_rx], axis=1)
    out = np.full(paths.n_links, np.nan)
    has = first >= 0
    out[has] = C0 * paths.delay_s[first[has]] - dist[has]
    return out


def last_segment_dirs(paths: Paths) -> np.ndarray:
    """(P, 3) float: unit vector of each path's last segment, from its last interaction (or the
    transmitter) towards the receiver (the gradient of its length in the receiver position)."""
    n_int = (paths.interaction != 0).sum(axis=1)
    start = paths.tx[paths.tx_index].copy()
    idx = np.flatnonzero(n_int > 0)
    start[idx] = paths.points[idx, n_int[idx] - 1]
    d = paths.rx[paths.rx_index] - start
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def wave_radius(paths: Paths) -> np.ndarray:
    """(P,) float, m: radius of each path's wavefront at the receiver: the unfolded length (its
    image source) for line of sight, reflections and penetrations; the distance from the last
    diffraction point for a diffracted path (its edge source)."""
    from ...solver.paths import DIFFRACTION

    out = C0 * paths.delay_s
    dif = paths.interaction == DIFFRACTION
    rows = np.flatnonzero(dif.any(axis=1))
    if rows.size:
        last = dif.shape[1] - 1 - np.argmax(dif[rows, ::-1], axis=1)
        out[rows] = np.linalg.norm(paths.rx[paths.rx_index[rows]] - paths.points[rows, last], axis=1)
    return out


def path_table(paths: Paths, k: int) -> dict[str, np.ndarray]:
    """The ``k`` strongest paths of every link as the schema-v2 arrays (n cells, B, k).

    Links are ``tx * n + rx`` (base stations are the transmitters, cells the receivers); slots
    without a path have delay NaN, gain 0, direction NaN and radius NaN.
    """
    n_b, n_c = len(paths.tx), len(paths.rx)
    out = {
        "path_delay_s": np.full((n_b, n_c, k), np.nan),
        "path_gain": np.zeros((n_b, n_c, k), dtype=complex),
        "path_dir": np.full((n_b, n_c, k, 3), np.nan),
        "path_radius_m": np.full((n_b, n_c, k), np.nan),
    }
    if paths.n_paths and k > 0:
        order = np.lexsort((-np.abs(paths.gain), paths.link))
        link = paths.link[order]
        rank = np.arange(order.size) - np.searchsorted(link, link, side="left")
        sel = order[rank < k]
        rank = rank[rank < k]
        b, c = paths.tx_index[sel], paths.rx_index[sel]
        out["path_delay_s"][b, c, rank] = paths.delay_s[sel]
        out["path_gain"][b, c, rank] = paths.gain[sel]
        out["path_dir"][b, c, rank] = last_segment_dirs(paths.select(sel))
        out["path_radius_m"][b, c, rank] = wave_radius(paths.select(sel))
    return {key: np.swapaxes(v, 0, 1) for key, v in out.items()}


def receiver_model_meta(receiver: Receiver) -> dict[str, Any]:
    """The settings the twin's copy of the noiseless first-lobe receiver
    (:class:`positioning.twin.lobe.LobeReceiver`) needs, as the map's ``meta["receiver_model"]``."""
    from ...emulation.receivers import first_lobe as rx_mod
    from ...emulation.receivers.first_lobe import cfar_factor

    band, budget, pulse, fl = receiver.band, receiver.budget, receiver.pulse, receiver.first_lobe
    return {
        "frequency_hz": float(band.center_frequency_hz),
        "period_s": float(pulse.period_s(band)),
        "roll_off": float(pulse.roll_off),
        "oversampling": int(pulse.oversampling),
        "span": int(pulse.span),
        "noise_std": float(budget.correlator_noise_std(band, pulse)),
        "alpha": float(cfar_factor(budget.false_alarm_probability, fl.cfar_cells)),
        "rho": float(fl.rho),
        "negligible_db": float(rx_mod.NEGLIGIBLE_DB),
        "min_crossing": float(rx_mod.MIN_CROSSING),
        "sure_crossing": float(rx_mod.SURE_CROSSING),
        "post_t": int(rx_mod.POST_T),
        "top_paths": int(rx_mod.TOP_PATHS),
    }


def stored_paths(settings: MapSettings) -> int:
    """Paths stored per link: ``settings.paths`` for the first-lobe receiver (the one the twin's
    re-synthesis models), 0 for the others."""
    return int(settings.paths) if settings.receiver == "first-lobe" else 0


def chunk_seed(seed: int, first_cell: int) -> int:
    """Seed of the noise streams of the chunk starting at ``first_cell`` (module docstring)."""
    return int(np.random.SeedSequence([int(seed), int(first_cell)]).generate_state(1)[0])


def measure_cells(
    paths: Paths, receiver: Receiver, seed: int, draws: int, methods: Sequence[str],
    n_paths: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Per-cell quantities of a chunk: the paths of B base stations (tx) to n cells (rx).

    Returns
    -------
    dict with ``los, first_kind, excess_m, toa_s, toa_std_s, detected_fraction`` (n, B),
    ``gdop`` (n,), ``err_p90_m, err_mean_m, availability`` (M, n), with ``n_paths > 0`` the
    :func:`path_table` arrays, and ``time_s`` (dict)
    """
    from positioning import locate

    t0 = time.perf_counter()
    n_b, n_c = len(paths.tx), len(paths.rx)
    prep = prepare_links(paths, receiver)
    clean = emulate_toa(paths, receiver.band, receiver=receiver, prepared=prep, noise=False)

    def cells(a: np.ndarray) -> np.ndarray:  # link = bs * n + cell -> (n, B)
        return a.reshape(n_b, n_c).T

    out: dict[str, Any] = {
        "los": cells(clean.los),
        "first_kind": cells(clean.first_kind),
        "excess_m": cells(_excess_m(paths, clean.first_path)),
        "toa_s": cells(np.where(clean.detected, clean.toa_s, np.nan)),
    }
    out["gdop"] = gdop_2d(paths.rx, paths.tx, np.isfinite(out["toa_s"]))
    if n_paths > 0:
        out.update(path_table(paths, n_paths))
    meas = ToaModel(receiver, seed).measure(paths, range(draws), prepared=prep)
    t1 = time.perf_counter()
    out["detected_fraction"] = meas.detected.mean(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN cells give NaN, as documented
        out["toa_std_s"] = np.nanstd(meas.delay_s, axis=0)
        flat = meas.toa_s.reshape(draws * n_c, n_b)
        height = np.tile(paths.rx[:, 2], draws)
        true_xy = np.tile(paths.rx[:, :2], (draws, 1))
        stats = []
        for m in methods:
            fix = np.asarray(
                # every cell's fixes, whatever its geometry: the map shows where it fails
                locate(flat, paths.tx, m, tx_offsets_s=meas.tx_offset_s, height_m=height,
                       checks=False)  # fmt: skip
            )
            err = np.hypot(*(fix[:, :2] - true_xy).T).reshape(draws, n_c)
            stats.append((np.nanpercentile(err, 90, axis=0), np.nanmean(err, axis=0),
                          np.isfinite(err).mean(axis=0)))  # fmt: skip
    for k, key in enumerate(("err_p90_m", "err_mean_m", "availability")):
        out[key] = np.array([s[k] for s in stats]).reshape(len(methods), n_c)
    out["time_s"] = {"measure": t1 - t0, "locate": time.perf_counter() - t1}
    return out
