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

import json
import time
from pathlib import Path

import numpy as np

from hallray.harness import OneLineParser, run_command
from positioning import C0, METHODS, error_2d, locate, summarize
from positioning.errors import PositioningError
from positioning.twin.fingerprint import FingerprintMap, write_map

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


#: Size (x, y from 0, m) of the benchmark's fingerprint map: the bundled hall's.
HALL_AREA_M = (42.0, 46.0)
#: The C-band first-lobe receiver's settings (as raytrace.studies.accuracy_map.receiver_model_meta
#: gives them): the receiver model of the schema-v2 map.
CBAND_MODEL = {"frequency_hz": 3.775e9, "period_s": 1.25e-8, "roll_off": 0.25, "oversampling": 8,
               "span": 16, "noise_std": 7.81, "alpha": 15.42, "rho": 10 ** (-12 / 20)}  # fmt: skip


def los_map(step: float = 0.5, height: float = 1.0) -> FingerprintMap:
    """A schema-v1 map of a :data:`HALL_AREA_M` hall around :data:`BS` where every base station
    is in line of sight everywhere: cells on a ``step`` lattice offset by half a step, first
    arrival = straight distance, the service area the rectangle."""
    xs = np.arange(step / 2, HALL_AREA_M[0], step)
    ys = np.arange(step / 2, HALL_AREA_M[1], step)
    X, Y = np.meshgrid(xs, ys)
    cells = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, height)])
    dist = np.linalg.norm(cells[:, None, :] - BS[None, :, :], axis=2)
    n, b = dist.shape
    ax, ay = HALL_AREA_M
    return FingerprintMap(
        cell_xyz=cells,
        bs_xyz=BS,
        bs_names=np.array([f"BS{i + 1}" for i in range(b)]),
        los=np.ones((n, b), dtype=bool),
        first_kind=np.full((n, b), "LoS"),
        excess_m=np.zeros((n, b)),
        toa_s=dist / C0,
        toa_std_s=np.zeros((n, b)),
        detected_fraction=np.ones((n, b)),
        gdop=np.ones(n),
        methods=np.array(["irls"]),
        err_p90_m=np.zeros((1, n)),
        err_mean_m=np.zeros((1, n)),
        availability=np.ones((1, n)),
        meta={"service_area": [[0, 0], [ax, 0], [ax, ay], [0, ay]]},
    )


def two_ray_paths(xyz: np.ndarray, k: int = 16, refl: float = -0.7):
    """Per point (n, 3) and base station of :data:`BS`: the line-of-sight path and the floor
    reflection (image source below the floor, coefficient ``refl``), padded to ``k`` slots:
    delay (n, B, k) s, gain (n, B, k) complex, direction (n, B, k, 3), radius (n, B, k) m."""
    f = CBAND_MODEL["frequency_hz"]
    n, b = len(xyz), len(BS)
    delay = np.full((n, b, k), np.nan)
    gain = np.zeros((n, b, k), complex)
    u = np.full((n, b, k, 3), np.nan)
    radius = np.full((n, b, k), np.nan)
    for j, (src, r) in enumerate(((BS, 1.0), (BS * np.array([1.0, 1.0, -1.0]), refl))):
        v = xyz[:, None, :] - src[None]
        d = np.linalg.norm(v, axis=2)
        delay[..., j] = d / C0
        gain[..., j] = r * C0 / f / (4 * np.pi * d) * np.exp(-2j * np.pi * f * d / C0)
        u[..., j, :] = v / d[..., None]
        radius[..., j] = d
    return delay, gain, u, radius


def hall_map_file(folder: str) -> str:
    """:func:`los_map` written to ``folder``; returns its path."""
    return str(write_map(Path(folder) / "hall-map.npz", los_map()))


def hall_map_v2_file(folder: str, k: int = 16) -> str:
    """:func:`los_map` in schema version 2: per cell and base station the line-of-sight path and
    a floor reflection (coefficient -0.7), padded to ``k`` slots (:func:`two_ray_paths`), the
    C-band first-lobe receiver model, ``toa_s`` from that receiver; returns its path."""
    from positioning.twin.lobe import LobeReceiver

    model = LobeReceiver.from_meta(CBAND_MODEL)  # C-band, as accuracy-map writes it
    base = los_map()
    n, b = len(base.cell_xyz), len(BS)
    delay, gain, u, radius = two_ray_paths(base.cell_xyz, k=k)
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
    p.add_argument("--speed-only", action="store_true", help="skip the accuracy comparison")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: {speed: {name: rate}, accuracy: [...]}")  # fmt: skip
    return p


def accuracy_tables() -> list[dict]:
    """:func:`compare` for 4 and 6 base stations and range noise 0.1 and 0.75 m."""
    return [
        {"n_bs": n_bs, "sigma_m": sigma, "methods": compare(n_bs=n_bs, sigma_m=sigma)}
        for n_bs in (4, 6)
        for sigma in (0.1, 0.75)
    ]


def _main(args) -> int:
    if args.n_epochs < 1:
        raise PositioningError(f"n_epochs must be >= 1, got {args.n_epochs}")
    n, cpu = args.n_epochs, args.cpu_time
    speed = run(n, clock=time.process_time if cpu else time.perf_counter)
    accuracy = [] if args.speed_only else accuracy_tables()
    if args.json:
        print(json.dumps({"epochs": n, "clock": "cpu" if cpu else "wall", "speed": speed,
                          "accuracy": accuracy}, indent=1))  # fmt: skip
        return 0
    unit = "fixes per CPU second" if cpu else "fixes/s"
    print(f"speed, {n} epochs, 4 base stations, 2D:")
    for name, rate in speed.items():
        if name.startswith("twin-v2 prepare"):
            print(f"  {name:<26} {rate:10.1f}")
        else:
            print(f"  {name:<12} {rate:10.0f} {unit}")
    for table in accuracy:
        print(f"accuracy, {table['n_bs']} base stations, sigma {table['sigma_m']} m, "
              "one +5 m NLoS per epoch:")  # fmt: skip
        for name, (mean, p90) in table["methods"].items():
            print(f"  {name:<12} mean {mean:6.2f} m   p90 {p90:6.2f} m")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
