"""Oracle: how well can a fingerprint map that stores paths (not ToAs) predict the receiver?

Feasibility check for issue 15's 0.2 m target (docs/positioning.md, "Re-synthesised paths (map
schema v2): measured", which has the numbers). The first-lobe receiver's noiseless ToA at a test point is
predicted from the map cell nearest to it:

``cell``
    the current twin model: the cell's bias held, ``c toa(cell) - |cell - b| + |p - b|``;
``resynth``
    the cell's K strongest paths moved to ``p`` and the receiver
    (:class:`raytrace.emulation.receivers.Receiver`, noise off) run on them. ``--order 1``: plane
    wave, ``tau_k(p) = tau_k(cell) + u_k . (p - cell) / c`` with ``u_k`` the unit vector of the
    path's last segment towards the receiver; ``--order 2``: spherical wave about the path's
    virtual source (image source at the unfolded length; the edge for a diffracted path) with
    its ``1 / r`` amplitude; ``--fd-gradient``: in addition the part of the delay gradient that
    the geometry misses (the penetrated slabs' group delays change with the crossing) measured
    by finite differences, tracing the cells again 5 cm off in x and in y and matching paths by
    identity (transmitter, interaction codes, objects, elements). The gain's phase turns by
    ``exp(-j 2 pi f dtau)``;
``truth``
    the receiver on the paths traced at ``p`` itself (what the device measures, noise off).

(a) per band: the range error ``c (toa_pred - toa_truth)`` over points and base stations, raw
and about each point's mean, and its decomposition at the test points: ``common`` = the
prediction from only the paths that exist at both the cell and the point against the truth of
the same paths (extrapolation and receiver decisions, no visibility change), ``visibility`` =
the truth of the common paths against the whole truth (paths that appear or vanish between
cell and point). (b) positioning: a grid search (``--grid`` 2.5 cm) over a +-``--half`` m
square around each test point of the TDoA misfit (offset free) of the noiseless true ToAs
against the prediction from each candidate's nearest cell, for both predictors; p50 / p90 /
max of the 2D error over the 23 test points (the window bounds the error at 0.71 m).

The grid of cells is the evaluation map's (``tools/build_twin_map.py``: 0.5 m, offset for the
largest point clearance, cells < 0.25 m from a test point and inside solids dropped). The cells
within 1.1 m of a test point are traced (every candidate's nearest cell is among them); the
traces are cached in ``--cache``.

Usage::

    python tools/oracle_twin_resynth.py --bands c-band,mmwave --k 0,16 --order 1   # or --order 2
    python tools/oracle_twin_resynth.py --bands c-band --k 0 --order 2 --fd-gradient --no-search
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from raytrace.cli.harness import OneLineParser, run_tool  # noqa: E402
from raytrace.core.errors import HallrayError  # noqa: E402
from raytrace.emulation.bands import get_band  # noqa: E402
from raytrace.emulation.dataset import DatasetConfig, service_area  # noqa: E402
from raytrace.emulation.receivers import Receiver  # noqa: E402
from raytrace.scene.io import load_scene  # noqa: E402
from raytrace.scene.metadata import SceneMetadata  # noqa: E402
from raytrace.solver.paths import DIFFRACTION, Paths  # noqa: E402
from raytrace.solver.tracer import trace  # noqa: E402

C0 = 299_792_458.0
#: Finite-difference step of ``--fd-gradient``, m.
FD_STEP_M = 0.05


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
    idx = np.flatnonzero(n_int > 0)
    start[idx] = paths.points[idx, n_int[idx] - 1]
    d = paths.rx[paths.rx_index] - start
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def wave_radius(paths: Paths) -> np.ndarray:
    """(P,) m, radius of the path's wavefront at the receiver: the unfolded length (image
    source) for line of sight, reflections and penetrations; the distance to the last
    diffraction point for a diffracted path (edge source)."""
    out = C0 * paths.delay_s
    for i in np.flatnonzero(np.any(paths.interaction == DIFFRACTION, axis=1)):
        j = int(np.flatnonzero(paths.interaction[i] == DIFFRACTION)[-1])
        out[i] = np.linalg.norm(paths.rx[paths.rx_index[i]] - paths.points[i, j])
    return out


def move(
    u: np.ndarray, radius: np.ndarray, disp: np.ndarray, extra: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Delay change (s) and amplitude factor of paths (direction ``u`` (P, 3), wavefront radius
    ``radius`` (P,), inf: plane wave) when the receiver moves by ``disp`` (P, 3); ``extra``
    (P, 3): a delay gradient (m/m) added to the geometric one."""
    plane = ~np.isfinite(radius)
    r = np.where(plane, 1.0, radius)
    dnew = np.linalg.norm(disp + r[:, None] * u, axis=1)
    dl = np.where(plane, np.einsum("pk,pk->p", u, disp), dnew - r)
    if extra is not None:
        dl = dl + np.einsum("pk,pk->p", extra, disp)
    return dl / C0, np.where(plane, 1.0, r / dnew)


def strongest(paths: Paths, k: int) -> np.ndarray:
    """Sorted indices of the ``k`` strongest paths of every link (all for ``k <= 0``)."""
    if k <= 0:
        return np.arange(paths.n_paths)
    order = np.lexsort((-np.abs(paths.gain), paths.link))
    link = paths.link[order]
    rank = np.arange(order.size) - np.searchsorted(link, link, side="left")
    return np.sort(order[rank < k])


def identities(paths: Paths) -> list[bytes]:
    """A hashable identity per path: transmitter, interaction codes, objects, elements."""
    rec = np.concatenate(
        [paths.tx_index[:, None].astype(np.int64), paths.interaction.astype(np.int64),
         paths.objects.astype(np.int64), paths.elements.astype(np.int64)], axis=1,
    )  # fmt: skip
    return [r.tobytes() for r in rec]


def fd_extra_gradient(base: Paths, dx: Paths, dy: Paths, u: np.ndarray) -> np.ndarray:
    """(P, 3) delay gradient of each path of ``base`` beyond its last segment's direction ``u``,
    from the same paths traced at the receivers moved by :data:`FD_STEP_M` in x (``dx``) and y
    (``dy``); 0 for paths not found in both."""
    out = np.zeros((base.n_paths, 3))
    ib = identities(base)
    for axis, other in ((0, dx), (1, dy)):
        look = {(int(other.rx_index[i]), k): i for i, k in enumerate(identities(other))}
        j = np.array([look.get((int(base.rx_index[i]), k), -1) for i, k in enumerate(ib)])
        ok = j >= 0
        g = C0 * (other.delay_s[j[ok]] - base.delay_s[ok]) / FD_STEP_M
        out[ok, axis] = g - u[ok, axis]
    # a jump (the path changed its crossing) is not a gradient
    out[np.abs(out) > 2.0] = 0.0
    return out


class Resynth:
    """The cells' paths (a subset of ``paths``) moved to other positions, and the receiver."""

    def __init__(self, paths: Paths, sel: np.ndarray, n_points: int, receiver: Receiver,
                 frequency_hz: float, radius: np.ndarray, u: np.ndarray,
                 extra: np.ndarray | None) -> None:  # fmt: skip
        order = sel[np.argsort(paths.rx_index[sel], kind="stable")]
        self.rx_sorted = paths.rx_index[order]
        self.order = order
        self.paths, self.n_points, self.receiver, self.f = paths, n_points, receiver, frequency_hz
        self.radius, self.u, self.extra = radius, u, extra
        self.n_bs = len(paths.tx)

    def toa(self, cell: np.ndarray, disp: np.ndarray) -> np.ndarray:
        """(A, B) predicted ToA, s, for A pairs of a cell index and a displacement (A, 3)."""
        lo = np.searchsorted(self.rx_sorted, cell + self.n_points, "left")
        hi = np.searchsorted(self.rx_sorted, cell + self.n_points, "right")
        idx = self.order[np.concatenate([np.arange(s, e) for s, e in zip(lo, hi, strict=True)])]
        pair = np.repeat(np.arange(cell.size), hi - lo)
        ex = None if self.extra is None else self.extra[idx]
        dt, scale = move(self.u[idx], self.radius[idx], disp[pair], ex)
        p = self.paths
        gain = p.gain[idx] * scale * np.exp(-2j * np.pi * self.f * dt)
        link = pair * self.n_bs + p.tx_index[idx]
        return receiver_toa(self.receiver, link, p.delay_s[idx] + dt, gain,
                            cell.size * self.n_bs).reshape(cell.size, self.n_bs)  # fmt: skip


def receiver_toa(rx: Receiver, link, delay, gain, n_links: int) -> np.ndarray:
    """(n_links,) noiseless ToA of the receiver, s (NaN: not detected)."""
    est = rx.measure(rx.prepare(link, delay, gain, n_links), None, noise=False)
    return np.where(est.detected, est.toa_s, np.nan)


def _stats(e: np.ndarray) -> str:
    a = np.abs(e[np.isfinite(e)])
    return f"p50 {np.median(a):.3f} p90 {np.percentile(a, 90):.3f} max {a.max():.3f}"


def decompose(paths: Paths, n_points: int, nearest: np.ndarray, disp: np.ndarray,
              rx: Receiver, f: float, radius: np.ndarray, u: np.ndarray,
              extra: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(P, B) range errors at the test points, m: ``common`` (prediction from the paths present
    at both cell and point against their truth) and ``visibility`` (truth of those paths against
    the whole truth)."""
    ident = identities(paths)
    B = len(paths.tx)
    common = np.full((n_points, B), np.nan)
    vis = np.full((n_points, B), np.nan)
    for i in range(n_points):
        c = n_points + nearest[i]
        for b in range(B):
            ip = np.flatnonzero((paths.rx_index == i) & (paths.tx_index == b))
            ic = np.flatnonzero((paths.rx_index == c) & (paths.tx_index == b))
            kc = {ident[j]: j for j in ic}
            pairs = [(j, kc[ident[j]]) for j in ip if ident[j] in kc]
            jp = np.array([q[0] for q in pairs], dtype=np.int64)
            jc = np.array([q[1] for q in pairs], dtype=np.int64)
            z = np.zeros(len(jp), np.int64)
            t_all = receiver_toa(rx, np.zeros(len(ip), np.int64), paths.delay_s[ip],
                                 paths.gain[ip], 1)[0]  # fmt: skip
            t_com = receiver_toa(rx, z, paths.delay_s[jp], paths.gain[jp], 1)[0]
            ex = None if extra is None else extra[jc]
            dt, sc = move(u[jc], radius[jc], np.repeat(disp[i][None], len(jc), 0), ex)
            g = paths.gain[jc] * sc * np.exp(-2j * np.pi * f * dt)
            t_pc = receiver_toa(rx, z, paths.delay_s[jc] + dt, g, 1)[0]
            common[i, b] = C0 * (t_pc - t_com)
            vis[i, b] = C0 * (t_com - t_all)
    return common, vis


def _counts(text: str) -> list[int]:
    """``--k``: comma-separated path counts >= 0 (argparse type)."""
    try:
        ks = [int(v) for v in text.split(",")]
    except ValueError:
        ks = []
    if not ks or min(ks) < 0:
        raise argparse.ArgumentTypeError(
            f"expected path counts >= 0, comma-separated, got {text!r}"
        )
    return ks


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bands", default="c-band,mmwave")
    ap.add_argument("--k", type=_counts, default="0,16", help="paths kept per link (0: all)")
    ap.add_argument("--cache", default="/tmp/oracle_twin")
    ap.add_argument("--half", type=float, default=0.5, help="search half-width, m")
    ap.add_argument("--grid", type=float, default=0.025, help="search step, m")
    ap.add_argument("--order", type=int, default=2, choices=(1, 2),
                    help="1: plane wave; 2: spherical wave about each path's virtual source")
    ap.add_argument("--fd-gradient", action="store_true",
                    help="add the finite-difference delay gradient beyond the geometry")
    ap.add_argument("--no-search", action="store_true", help="only (a)")
    return ap


def _main(a: argparse.Namespace) -> int:
    for band_name in a.bands.split(","):
        get_band(band_name)  # an unknown band before any work: one line naming the known ones
    for name, v in (("--half", a.half), ("--grid", a.grid)):
        if not (np.isfinite(v) and v > 0):
            raise HallrayError(f"{name} must be a positive number of metres, got {v:g}")
    scene = load_scene("hall")
    md = SceneMetadata.from_scene(scene, require=True)
    poly = np.asarray(service_area(scene, md.block)["polygon"], dtype=float)
    cells, _ = _build_twin_map().grid_cells(poly, md.point_xyz[:, :2], 0.5, 0.25, 1.0)
    cells = cells[scene.inside_solid(cells) < 0]
    pts = md.point_xyz
    P = len(pts)
    d = np.linalg.norm(cells[:, None, :2] - pts[None, :, :2], axis=2)
    near = cells[d.min(axis=1) <= 1.1]
    nearest = np.argmin(np.linalg.norm(pts[:, None, :2] - near[None, :, :2], axis=2), axis=1)
    disp = pts - near[nearest]
    dn = np.linalg.norm(disp[:, :2], axis=1)
    print(f"{P} test points, {len(near)} cells traced; nearest-cell distance "
          f"{dn.min():.3f} - {dn.max():.3f} m; order {a.order}, fd-gradient {a.fd_gradient}")  # fmt: skip
    bs = md.bs_xyz
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    off = np.arange(-a.half, a.half + 1e-9, a.grid)
    gx, gy = np.meshgrid(off, off, indexing="ij")
    cand_off = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    for band_name in a.bands.split(","):
        band = get_band(band_name)
        cfg = DatasetConfig("static", band_name, duration_s=1.0)
        rx = cfg.receiver()
        f = band.center_frequency_hz

        def traced(tag: str, where: np.ndarray, band_name=band_name, f=f, cfg=cfg) -> Paths:
            cp = cache / f"paths-{band_name}{tag}.npz"
            if cp.exists():
                return Paths.load(cp)
            t0 = time.perf_counter()
            out = trace(scene, bs, where, f, cfg.trace)
            out.save(cp)
            print(f"{band_name}: traced {len(where)} receivers{tag} in "
                  f"{time.perf_counter() - t0:.0f} s")  # fmt: skip
            return out

        rxs = np.vstack([pts, near])
        paths = traced("", rxs)
        u = last_segment_dirs(paths)
        radius = wave_radius(paths) if a.order == 2 else np.full(paths.n_paths, np.inf)
        extra = None
        if a.fd_gradient:
            shift = [np.array([FD_STEP_M, 0, 0]), np.array([0, FD_STEP_M, 0])]
            # the test points are moved too: their paths are never used from these traces
            extra = fd_extra_gradient(paths, traced("-dx", rxs + shift[0]),
                                      traced("-dy", rxs + shift[1]), u)  # fmt: skip
        full = receiver_toa(rx, paths.link, paths.delay_s, paths.gain, paths.n_links)
        full = full.reshape(len(bs), len(rxs)).T
        truth, cell_toa = full[:P], full[P:]
        cbias = C0 * cell_toa - np.linalg.norm(near[:, None, :] - bs[None], axis=2)
        dist_p = np.linalg.norm(pts[:, None, :] - bs[None], axis=2)
        pred_cell = (cbias[nearest] + dist_p) / C0
        e = C0 * (pred_cell - truth)
        print(f"  (a) {band_name} cell        : |range err| {_stats(e)} m; about the point mean "
              f"{_stats(e - np.nanmean(e, axis=1, keepdims=True))} m")  # fmt: skip
        common, vis = decompose(paths, P, nearest, disp, rx, f, radius, u, extra)
        print(f"  (a) {band_name} decomposition (K=all): common paths {_stats(common)} m; "
              f"visibility {_stats(vis)} m")  # fmt: skip
        for k in a.k:
            rs = Resynth(paths, strongest(paths, k), P, rx, f, radius, u, extra)
            e = C0 * (rs.toa(nearest, disp) - truth)
            print(f"  (a) {band_name} resynth K={k or 'all':>3}: |range err| {_stats(e)} m; about "
                  f"the point mean {_stats(e - np.nanmean(e, axis=1, keepdims=True))} m")  # fmt: skip
            if a.no_search:
                continue
            t0 = time.perf_counter()
            err: dict[str, list[float]] = {"cell": [], "resynth": []}
            for i, p in enumerate(pts):
                cp_ = p[None] + cand_off
                nc = np.argmin(np.linalg.norm(cp_[:, None, :2] - near[None, :, :2], axis=2), axis=1)
                dist = np.linalg.norm(cp_[:, None, :] - bs[None], axis=2)
                use = np.isfinite(truth[i])
                for name, pr in (("cell", (cbias[nc] + dist) / C0),
                                 ("resynth", rs.toa(nc, cp_ - near[nc]))):  # fmt: skip
                    r = C0 * (truth[i][None, use] - pr[:, use])
                    cost = np.sum((r - r.mean(axis=1, keepdims=True)) ** 2, axis=1)
                    j = int(np.argmin(np.where(np.isfinite(cost), cost, np.inf)))
                    err[name].append(float(np.hypot(*cand_off[j, :2])))
            for name, ev in err.items():
                ev = np.array(ev)
                worst = np.argsort(-ev)[:6]
                print(f"  (b) {band_name} K={k or 'all':>3} {name:>8}: 2D err p50 {np.median(ev):.3f} "
                      f"p90 {np.percentile(ev, 90):.3f} max {ev.max():.3f} m; worst "
                      + " ".join(f"{md.point_names[w]}:{ev[w]:.2f}" for w in worst)
                      + f"  ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
