"""Benchmark of the positioning methods: speed and accuracy on synthetic NLoS data.

Run from a checkout: ``python tools/bench_positioning.py [n_epochs] [--cpu-time]``.

``run`` measures fixes per second, batched, with 4 base stations and the 2D solve. The data: the
paper's geometry (4 base stations at the corners of 29 m x 25 m, 4 m high; devices uniformly in
the area at 1 m), Gaussian range noise of 0.1 m, a +5 m NLoS excess on one random base station in
a quarter of the epochs, the 10 ms transmission schedule and a random device clock offset.

``run`` includes ``twin`` with a fingerprint map of a 42 m x 46 m hall (the bundled hall's size)
on a 0.5 m grid (7728 cells), written to a temporary file and loaded once before timing (the
loaded map and its lattice are cached); the map predicts LoS everywhere, so the quarter of the
epochs with the +5 m excess do not match it and fall back to ``irls`` (the realistic cost of a
stale map). ``twin-v2`` is the same with the map in schema version 2 (:func:`hall_map_v2_file`:
per cell and base station the line-of-sight path and a floor reflection, padded to 16 paths, and
the C-band first-lobe receiver model), so its refinement re-runs the receiver on moved paths:
``twin-v2 cold`` is the first pass with an empty ToA raster (tiles re-synthesised as the fixes
reach them), ``twin-v2`` the best of two later passes (look-ups), and ``twin-v2 prepare`` the
time and receiver rate of :func:`positioning.twin.prepare` filling the whole raster at once.

``compare`` gives mean / 90th percentile of the 2D error of every method on the same data with
one NLoS base station (random per epoch) in *every* epoch, for 4 or more base stations.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hallray.harness import OneLineParser, run_command  # noqa: E402
from positioning import C0, METHODS, error_2d, locate, summarize  # noqa: E402
from positioning.errors import PositioningError  # noqa: E402

BS = np.array([[0.0, 0.0, 4.0], [29.0, 0.0, 4.0], [29.0, 25.0, 4.0], [0.0, 25.0, 4.0]])


def make_data(n_epochs: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(toa_s (E, 4), tx_offsets_s (4,), true_xyz (E, 3)) of the benchmark scenario."""
    rng = np.random.default_rng(seed)
    p = np.column_stack(
        [rng.uniform(1, 28, n_epochs), rng.uniform(1, 24, n_epochs), np.ones(n_epochs)]
    )
    d = np.linalg.norm(p[:, None, :] - BS[None, :, :], axis=2)
    err = rng.normal(0.0, 0.1, d.shape)
    nlos = rng.random(n_epochs) < 0.25
    err[np.flatnonzero(nlos), rng.integers(0, 4, nlos.sum())] += 5.0
    off = np.arange(4) * 0.01
    clk = rng.uniform(-1e-3, 1e-3, n_epochs)
    return (d + err) / C0 + off + clk[:, None], off, p


def ring(n_bs: int) -> np.ndarray:
    """The paper's 4 corners, plus base stations at the middle of the long sides for n_bs > 4."""
    extra = np.array([[14.5, -3.0, 4.0], [14.5, 28.0, 4.0], [-3.0, 12.5, 4.0], [32.0, 12.5, 4.0]])
    return np.vstack([BS, extra[: n_bs - 4]])


def compare(
    n_epochs: int = 5000,
    sigma_m: float = 0.1,
    bias_m: float = 5.0,
    n_bs: int = 4,
    seed: int = 0,
    **params: float,
) -> dict[str, tuple[float, float]]:
    """Mean and 90th percentile (m) of the 2D error of every method, one NLoS base station per
    epoch (``bias_m`` on a random base station), Gaussian range noise ``sigma_m``. ``params``
    (e.g. ``sigma_m`` for subset / nlos-aware) go to every method that has them."""
    rng = np.random.default_rng(seed)
    bs = ring(n_bs)
    p = np.column_stack(
        [rng.uniform(1, 28, n_epochs), rng.uniform(1, 24, n_epochs), np.ones(n_epochs)]
    )
    d = np.linalg.norm(p[:, None, :] - bs[None, :, :], axis=2)
    err = rng.normal(0.0, sigma_m, d.shape)
    err[np.arange(n_epochs), rng.integers(0, n_bs, n_epochs)] += bias_m
    toa = (d + err) / C0 + rng.uniform(-1e-3, 1e-3, (n_epochs, 1))
    out = {}
    for m, spec in METHODS.items():
        if spec.needs_map:
            continue
        kw = {k: v for k, v in params.items() if k in spec.params}
        e = error_2d(locate(toa, bs, m, height_m=p[:, 2], **kw), p)
        s = summarize(e)
        out[m] = (s["mean_m"], s["p90_m"])
    return out


def hall_map_file(folder: str) -> str:
    """A LoS-only fingerprint map of a 42 m x 46 m hall around :data:`BS`, 0.5 m grid, written
    to ``folder``; returns its path."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "positioning"))
    from pos_synth import synth_map

    from positioning.twin.fingerprint import write_map

    fmap = synth_map(BS, area=(42.0, 46.0), bias=lambda xy: np.zeros((len(xy), len(BS))))
    return str(write_map(Path(folder) / "hall-map.npz", fmap))


def hall_map_v2_file(folder: str, k: int = 16) -> str:
    """:func:`hall_map_file`'s map in schema version 2: per cell and base station the
    line-of-sight path and a floor reflection (coefficient -0.7), padded to ``k`` slots, the
    C-band first-lobe receiver model, ``toa_s`` from that receiver; returns its path."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "positioning"))
    from pos_synth import CBAND_MODEL, synth_map, two_ray_paths

    from positioning.twin.fingerprint import FingerprintMap, write_map
    from positioning.twin.lobe import LobeReceiver

    model = LobeReceiver.from_meta(CBAND_MODEL)  # C-band, as accuracy-map writes it
    base = synth_map(BS, area=(42.0, 46.0), bias=lambda xy: np.zeros((len(xy), len(BS))))
    cells = base.cell_xyz
    n, b = len(cells), len(BS)
    delay, gain, u, radius = two_ray_paths(cells, BS, k=k, refl=-0.7)
    toa = model.toa(delay.reshape(n * b, k), gain.reshape(n * b, k)).reshape(n, b)
    arrays = {**base.arrays(), "toa_s": toa}
    fmap = FingerprintMap(**arrays, meta={**base.meta, "receiver_model": model.to_meta()},
                          path_delay_s=delay, path_gain=gain, path_dir=u, path_radius_m=radius)  # fmt: skip
    return str(write_map(Path(folder) / "hall-map-v2.npz", fmap))


def run(n_epochs: int = 20000, seed: int = 0, clock=time.perf_counter) -> dict[str, float]:
    """Fixes per second of every registered method (best of 2 runs, batched over all epochs);
    ``twin`` with the map of :func:`hall_map_file` loaded. ``clock=time.process_time`` counts
    CPU seconds (fixes per CPU second: insensitive to other jobs on a loaded machine; run with
    ``OPENBLAS_NUM_THREADS=1`` so that it is single-threaded)."""
    import tempfile

    toa, off, p = make_data(n_epochs, seed)
    locate(toa[:100], BS, "ls", tx_offsets_s=off, height_m=1.0)  # warm-up (imports, caches)
    tmp = tempfile.TemporaryDirectory()
    extra = {"twin": {"map": hall_map_file(tmp.name)}}
    v2 = {"map": hall_map_v2_file(tmp.name)}
    locate(toa[:100], BS, "twin", tx_offsets_s=off, height_m=1.0, **extra["twin"])  # load map
    out = {}
    for name in [*METHODS, "twin-v2 cold", "twin-v2"]:
        m, kw = ("twin", v2) if name.startswith("twin-v2") else (name, extra.get(name, {}))
        n = n_epochs
        locate(toa[:10], BS, m, tx_offsets_s=off, height_m=1.0, **kw)  # load the map
        if name == "twin-v2 cold":
            # the raster holds nothing yet: every fix near a new place re-synthesises its tiles
            from positioning.twin.lattice import load

            load(kw["map"])[1].rasters.clear()
            t0 = clock()
            locate(toa[:n], BS, m, tx_offsets_s=off, height_m=p[:n, 2], **kw)
            out[name] = n / (clock() - t0)
            continue
        best = np.inf
        for _ in range(2):
            t0 = clock()
            locate(toa[:n], BS, m, tx_offsets_s=off, height_m=p[:n, 2], **kw)
            best = min(best, clock() - t0)
        out[name] = n / best
    from positioning.twin.lattice import load, prepare

    load(v2["map"])[1].rasters.clear()
    t0 = clock()
    links = prepare(v2["map"], 1.0)
    out["twin-v2 prepare (s)"] = clock() - t0
    out["twin-v2 prepare (links/s)"] = links / out["twin-v2 prepare (s)"]
    tmp.cleanup()
    return out


def parser() -> OneLineParser:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("n_epochs", nargs="?", type=int, default=20000,
                   help="epochs of the speed runs [20000]")  # fmt: skip
    p.add_argument("--cpu-time", action="store_true",
                   help="fixes per CPU second instead of per wall-clock second")  # fmt: skip
    return p


def _main(args) -> int:
    if args.n_epochs < 1:
        raise PositioningError(f"n_epochs must be >= 1, got {args.n_epochs}")
    n, cpu = args.n_epochs, args.cpu_time
    unit = "fixes per CPU second" if cpu else "fixes/s"
    print(f"speed, {n} epochs, 4 base stations, 2D:")
    for name, rate in run(n, clock=time.process_time if cpu else time.perf_counter).items():
        if name.startswith("twin-v2 prepare"):
            print(f"  {name:<26} {rate:10.1f}")
        else:
            print(f"  {name:<12} {rate:10.0f} {unit}")
    for n_bs in (4, 6):
        for sigma in (0.1, 0.75):
            print(f"accuracy, {n_bs} base stations, sigma {sigma} m, one +5 m NLoS per epoch:")
            for name, (mean, p90) in compare(n_bs=n_bs, sigma_m=sigma).items():
                print(f"  {name:<12} mean {mean:6.2f} m   p90 {p90:6.2f} m")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
