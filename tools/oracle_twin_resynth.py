"""Oracle: how well can a fingerprint map that stores paths (not ToAs) predict the receiver?

Feasibility check for issue 15's 0.2 m target (docs/positioning.md, "twin: re-synthesised
paths"). The first-lobe receiver's ToA at a test point is predicted from the map cell nearest to
it in three ways:

``cell``
    the current twin model: the cell's bias held, ``c toa(cell) - |cell - b| + |p - b|``;
``resynth``
    the cell's K strongest paths moved to ``p`` to first order, ``tau_k(p) = tau_k(cell) +
    u_k . (p - cell) / c`` (``u_k`` the unit vector of the path's last segment, towards the
    receiver), the gain's phase turned by ``exp(-j 2 pi f (tau_k(p) - tau_k(cell)))``, and the
    receiver (:class:`raytrace.emulation.receivers.Receiver`, noise off) run on them;
``truth``
    the receiver on the paths traced at ``p`` itself (what the device measures, noise off).

(a) per band: the range error ``c (toa_pred - toa_truth)`` over points and base stations, raw and
about each point's mean (TDoA-relevant part); (b) positioning: a grid search (2.5 cm) over a
+-0.5 m square around each test point with the TDoA misfit (offset free) of the noiseless true
ToAs against the prediction from each candidate's nearest cell, for both predictors; p50 / p90
/ max of the 2D error over the 23 test points.

The grid of cells is the evaluation map's (``tools/build_twin_map.py``: 0.5 m, offset for the
largest point clearance, cells < 0.25 m from a test point and inside solids dropped). The cells
within 1.1 m of a test point are traced (every candidate's nearest cell is among them); the
traces are cached in ``--cache``.

Usage::

    python tools/oracle_twin_resynth.py --bands c-band,mmwave --k 0,16,8 --cache /tmp/oracle
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from raytrace.emulation.bands import get_band  # noqa: E402
from raytrace.emulation.dataset import DatasetConfig, service_area  # noqa: E402
from raytrace.scene.io import load_scene  # noqa: E402
from raytrace.scene.metadata import SceneMetadata  # noqa: E402
from raytrace.solver.paths import Paths  # noqa: E402
from raytrace.solver.tracer import trace  # noqa: E402

C0 = 299_792_458.0


def _build_twin_map():
    spec = importlib.util.spec_from_file_location(
        "build_twin_map", Path(__file__).with_name("build_twin_map.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def last_segment_dirs(paths: Paths) -> np.ndarray:
    """(P, 3) unit vector of each path's last segment, from its last interaction (or the
    transmitter) towards the receiver."""
    n_int = (paths.interaction != 0).sum(axis=1)
    start = paths.tx[paths.tx_index].copy()
    has = n_int > 0
    idx = np.flatnonzero(has)
    start[idx] = paths.points[idx, n_int[idx] - 1]
    d = paths.rx[paths.rx_index] - start
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def wave_radius(paths: Paths) -> np.ndarray:
    """(P,) m, radius of curvature of each path's wavefront at the receiver: the unfolded
    length for line of sight, reflections and penetrations (image source), the last segment's
    length for a path whose last non-penetration interaction is a diffraction (edge source)."""
    n_int = (paths.interaction != 0).sum(axis=1)
    total = C0 * paths.delay_s
    out = total.copy()
    for i in np.flatnonzero(np.any(paths.interaction == 3, axis=1)):
        j = int(np.flatnonzero(paths.interaction[i] == 3)[-1])
        out[i] = np.linalg.norm(paths.rx[paths.rx_index[i]] - paths.points[i, j])
    del n_int
    return out


def move(u: np.ndarray, radius: np.ndarray, disp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delay change (s) and amplitude factor of paths (direction ``u`` (P, 3), wavefront radius
    ``radius`` (P,), inf: plane wave) when the receiver moves by ``disp`` (P, 3)."""
    plane = ~np.isfinite(radius)
    r = np.where(plane, 1.0, radius)
    src = -r[:, None] * u  # virtual source relative to the cell
    dnew = np.linalg.norm(disp - src, axis=1)
    dl = np.where(plane, np.einsum("pk,pk->p", u, disp), dnew - r)
    scale = np.where(plane, 1.0, r / dnew)
    return dl / C0, scale


def strongest(paths: Paths, k: int) -> np.ndarray:
    """Indices of the ``k`` strongest paths of every link (all paths for ``k <= 0``)."""
    if k <= 0:
        return np.arange(paths.n_paths)
    order = np.lexsort((-np.abs(paths.gain), paths.link))
    link = paths.link[order]
    first = np.searchsorted(link, link, side="left")
    rank = np.arange(order.size) - first
    return np.sort(order[rank < k])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bands", default="c-band,mmwave")
    ap.add_argument("--k", default="0,16,8", help="paths kept per link (0: all)")
    ap.add_argument("--cache", default="/tmp/oracle_twin")
    ap.add_argument("--half", type=float, default=0.5, help="search half-width, m")
    ap.add_argument("--grid", type=float, default=0.025, help="search step, m")
    ap.add_argument("--order", type=int, default=1, choices=(1, 2),
                    help="1: plane wave; 2: spherical wave about each path's virtual source")
    ap.add_argument("--no-search", action="store_true", help="only (a)")
    a = ap.parse_args(argv)
    btm = _build_twin_map()
    scene = load_scene("hall")
    md = SceneMetadata.from_scene(scene, require=True)
    poly = np.asarray(service_area(scene, md.block)["polygon"], dtype=float)
    cells, _ = btm.grid_cells(poly, md.point_xyz[:, :2], 0.5, 0.25, 1.0)
    cells = cells[scene.inside_solid(cells) < 0]
    pts = md.point_xyz
    d = np.linalg.norm(cells[:, None, :2] - pts[None, :, :2], axis=2)
    near = cells[d.min(axis=1) <= 1.1]
    nearest = np.argmin(np.linalg.norm(pts[:, None, :2] - near[None, :, :2], axis=2), axis=1)
    print(f"{len(pts)} test points, {len(near)} cells traced; nearest-cell distance "
          f"{np.linalg.norm(pts[:, :2] - near[nearest, :2], axis=1).min():.3f} - "
          f"{np.linalg.norm(pts[:, :2] - near[nearest, :2], axis=1).max():.3f} m")  # fmt: skip
    bs = md.bs_xyz
    B = len(bs)
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    ks = [int(v) for v in a.k.split(",")]
    off = np.arange(-a.half, a.half + 1e-9, a.grid)
    gx, gy = np.meshgrid(off, off, indexing="ij")
    cand_off = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    for band_name in a.bands.split(","):
        band = get_band(band_name)
        cfg = DatasetConfig("static", band_name, duration_s=1.0)
        rx = cfg.receiver()
        f = band.center_frequency_hz
        cp = cache / f"paths-{band_name}.npz"
        rxs = np.vstack([pts, near])
        if cp.exists():
            paths = Paths.load(cp)
        else:
            t0 = time.perf_counter()
            paths = trace(scene, bs, rxs, f, cfg.trace)
            paths.save(cp)
            print(f"{band_name}: traced {len(rxs)} receivers in {time.perf_counter() - t0:.0f} s")
        R = len(rxs)

        def toa_of(link, delay, gain, n_links):
            est = rx.measure(rx.prepare(link, delay, gain, n_links), None, noise=False)
            return np.where(est.detected, est.toa_s, np.nan)

        full = toa_of(paths.link, paths.delay_s, paths.gain, paths.n_links).reshape(B, R).T
        truth = full[: len(pts)]  # (P, B)
        cell_toa = full[len(pts) :]  # (C, B)
        dirs = last_segment_dirs(paths)
        rad = wave_radius(paths) if a.order == 2 else np.full(paths.n_paths, np.inf)
        dist_c = np.linalg.norm(near[:, None, :] - bs[None], axis=2)  # (C, B)
        cbias = C0 * cell_toa - dist_c
        for k in ks:
            sel = strongest(paths, k)
            # per cell: path arrays of its links
            p_link, p_d, p_g, p_u = paths.link[sel], paths.delay_s[sel], paths.gain[sel], dirs[sel]
            p_r = rad[sel]
            p_bs, p_rx = p_link // R, p_link % R

            def resynth(cell_idx: np.ndarray, disp: np.ndarray) -> np.ndarray:
                """(A, B) predicted ToA for A (cell, displacement) pairs."""
                rows = []
                # gather every path of the cells' links
                order = np.argsort(p_rx, kind="stable")
                rx_sorted = p_rx[order]
                lo = np.searchsorted(rx_sorted, cell_idx + len(pts), "left")
                hi = np.searchsorted(rx_sorted, cell_idx + len(pts), "right")
                cnt = hi - lo
                idx = order[np.concatenate([np.arange(s, e) for s, e in zip(lo, hi)])]
                pair = np.repeat(np.arange(cell_idx.size), cnt)
                dt, scale = move(p_u[idx], p_r[idx], disp[pair])
                delay = p_d[idx] + dt
                gain = p_g[idx] * scale * np.exp(-2j * np.pi * f * dt)
                link = pair * B + p_bs[idx]
                rows = toa_of(link, delay, gain, cell_idx.size * B)
                return rows.reshape(cell_idx.size, B)

            disp = pts - near[nearest]
            pred = resynth(nearest, disp)
            dist_p = np.linalg.norm(pts[:, None, :] - bs[None], axis=2)
            pred_cell = (cbias[nearest] + dist_p) / C0
            for name, pr in (("cell", pred_cell), (f"resynth K={k or 'all'}", pred)):
                e = C0 * (pr - truth)
                ok = np.isfinite(e)
                ec = e - np.nanmean(e, axis=1, keepdims=True)
                ae = np.abs(e[ok])
                print(f"  (a) {band_name} {name:>16}: |range err| p50 {np.median(ae):.3f} "
                      f"p90 {np.percentile(ae, 90):.3f} max {ae.max():.3f} m; about the point "
                      f"mean p90 {np.nanpercentile(np.abs(ec), 90):.3f} m; "
                      f"missing {int((~ok & np.isfinite(truth)).sum())}")  # fmt: skip
            if a.no_search:
                continue
            # (b) grid search over candidates: nearest cell of each candidate
            t0 = time.perf_counter()
            err = {"cell": [], "resynth": []}
            for i, p in enumerate(pts):
                cp_ = p[None] + cand_off
                nc = np.argmin(
                    np.linalg.norm(cp_[:, None, :2] - near[None, :, :2], axis=2), axis=1
                )
                pr_r = resynth(nc, cp_ - near[nc])
                dist = np.linalg.norm(cp_[:, None, :] - bs[None], axis=2)
                pr_c = (cbias[nc] + dist) / C0
                meas = truth[i]
                use = np.isfinite(meas)
                for name, pr in (("cell", pr_c), ("resynth", pr_r)):
                    r = C0 * (meas[None, use] - pr[:, use])
                    cost = np.sum((r - r.mean(axis=1, keepdims=True)) ** 2, axis=1)
                    cost = np.where(np.isfinite(cost), cost, np.inf)
                    j = int(np.argmin(cost))
                    err[name].append(np.hypot(*cand_off[j, :2]))
            for name, e in err.items():
                e = np.array(e)
                worst = np.argsort(-e)[:5]
                print(f"  (b) {band_name} K={k or 'all'} {name:>8}: 2D err p50 {np.median(e):.3f} "
                      f"p90 {np.percentile(e, 90):.3f} max {e.max():.3f} m; worst "
                      + " ".join(f"{md.point_names[w]}:{e[w]:.2f}" for w in worst)
                      + f"  ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
