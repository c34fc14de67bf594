"""Synthetic ToA datasets in the contract's format (toa.csv + meta.json) for the positioning tests.

Not a test module itself (no ``test_`` prefix): a helper of the tests in tests/ and
tests/positioning/, which import it by name (pytest puts tests/ on the import path when it loads
tests/conftest.py, as for ``from conftest import ...``).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from positioning.model.noise import FLOOR_FIRST_LOBE
from positioning.model.problem import LinkInfo

C0 = 299_792_458.0
#: Base stations at the corners of a 29 m x 25 m area at 4 m, as in the paper.
PAPER_BS = np.array([[0.0, 0.0, 4.0], [29.0, 0.0, 4.0], [29.0, 25.0, 4.0], [0.0, 25.0, 4.0]])
#: Transmission schedule: base station k transmits at k * 10 ms (paper, section II).
SCHEDULE_STEP_S = 0.01

HEADER = (
    "epoch,time_s,point,bs,toa_s,x_true,y_true,z_true,distance_m,los,first_kind,snr_db,"
    "tx_offset_s,clock_offset_s"
).split(",")


def write_dataset(
    directory: str | Path,
    *,
    points: np.ndarray,
    bs: np.ndarray = PAPER_BS,
    n_epochs: int = 3,
    sigma_m: float = 0.05,
    nlos: Mapping[tuple[int, int], float] | None = None,
    missing: Sequence[tuple[int, int, int]] = (),
    scenario: str = "static",
    band: str = "c-band",
    seed: int = 0,
    extra_meta: Mapping | None = None,
) -> Path:
    """Write a dataset; returns the directory.

    ``points`` (P, 3) true positions; ``nlos[(point, bs)] = bias_m`` adds a positive excess range;
    ``missing`` lists (epoch, point, bs) links written with an empty ``toa_s``.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    nlos = dict(nlos or {})
    miss = set(missing)
    names = [f"BS{i + 1}" for i in range(len(bs))]
    pnames = [f"P{i + 1:02d}" for i in range(len(points))]
    meta = {
        "schema_version": 1,
        "scenario": scenario,
        "band": band,
        "base_stations": [{"name": n, "xyz": b.tolist()} for n, b in zip(names, bs, strict=True)],
        "points": [{"name": n, "xyz": p.tolist()} for n, p in zip(pnames, points, strict=True)],
        "schedule_s": {n: i * SCHEDULE_STEP_S for i, n in enumerate(names)},
        "seed": seed,
        "scene_sha256": "0" * 64,
        "version": "test",
        "hall_xy": [[-2.0, -2.0], [31.0, 27.0]],
        "obstacles_2d": [
            {
                "name": "shelf",
                "material": "metal",
                "polygon": [[10, 10], [14, 10], [14, 12], [10, 12]],
            }
        ],
    }
    meta.update(extra_meta or {})
    (d / "meta.json").write_text(json.dumps(meta, indent=1))
    with (d / "toa.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for e in range(n_epochs):
            for i, p in enumerate(points):
                clk = rng.uniform(-1e-3, 1e-3)
                for j, b in enumerate(bs):
                    dist = float(np.linalg.norm(p - b))
                    bias = nlos.get((i, j), 0.0)
                    off = j * SCHEDULE_STEP_S
                    rng_err = rng.normal(0.0, sigma_m) + bias
                    toa = clk + off + (dist + rng_err) / C0
                    toa_s = "" if (e, i, j) in miss else repr(toa)
                    w.writerow(
                        [
                            e,
                            0.1 * e,
                            pnames[i],
                            names[j],
                            toa_s,
                            *p.tolist(),
                            dist,
                            int(bias == 0),
                            "LoS" if bias == 0 else "R",
                            30.0,
                            off,
                            clk,
                        ]
                    )
    return d


def nlos_bias(xy: np.ndarray, n_bs: int = 4, nlos_bs: int = 2) -> np.ndarray:
    """(A, n_bs) excess range (m) of the synthetic twin hall at ``xy`` (A, 2): base station
    ``nlos_bs`` is NLoS everywhere, with an excess of 1.5 m growing by 0.05 m per metre of x (a
    shelf row along its line of sight); the others are LoS."""
    b = np.zeros((len(xy), n_bs))
    b[:, nlos_bs] = 1.5 + 0.05 * xy[:, 0]
    return b


def synth_map(
    bs: np.ndarray = PAPER_BS,
    step: float = 0.5,
    height: float = 1.0,
    bias: Callable[[np.ndarray], np.ndarray] = nlos_bias,
    area: tuple[float, float] = (29.0, 25.0),
):
    """A fingerprint map of the synthetic hall: cells on a ``step`` lattice offset by half a step
    over ``area`` (x, y from 0), first arrival = straight distance + ``bias(xy)``, service area the
    rectangle."""
    from positioning.twin.fingerprint import FingerprintMap

    xs = np.arange(step / 2, area[0], step)
    ys = np.arange(step / 2, area[1], step)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    cells = np.column_stack([xy, np.full(len(xy), height)])
    dist = np.linalg.norm(cells[:, None, :] - bs[None, :, :], axis=2)
    ex = bias(xy)
    n, b = ex.shape
    return FingerprintMap(
        cell_xyz=cells,
        bs_xyz=bs,
        bs_names=np.array([f"BS{i + 1}" for i in range(b)]),
        los=ex < 0.01,
        first_kind=np.where(ex < 0.01, "LoS", "D"),
        excess_m=ex,
        toa_s=(dist + ex) / C0,
        toa_std_s=np.zeros((n, b)),
        detected_fraction=np.ones((n, b)),
        gdop=np.ones(n),
        methods=np.array(["irls"]),
        err_p90_m=np.zeros((1, n)),
        err_mean_m=np.zeros((1, n)),
        availability=np.ones((1, n)),
        meta={"service_area": [[0, 0], [area[0], 0], [area[0], area[1]], [0, area[1]]]},
    )


def synth_toa(
    n: int,
    *,
    bs: np.ndarray = PAPER_BS,
    sigma_m: float = 0.05,
    bias: Callable[[np.ndarray], np.ndarray] = nlos_bias,
    extra_m: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """(toa_s (n, B), true_xyz (n, 3)) of devices uniform in [2, 27] x [2, 23] at 1 m in the
    synthetic twin hall (``bias`` + Gaussian range noise + ``extra_m`` (n, B) + clock offset)."""
    rng = np.random.default_rng(seed)
    p = np.column_stack([rng.uniform(2, 27, n), rng.uniform(2, 23, n), np.ones(n)])
    d = np.linalg.norm(p[:, None, :] - bs[None, :, :], axis=2) + bias(p[:, :2])
    d = d + rng.normal(0.0, sigma_m, d.shape) + (0.0 if extra_m is None else extra_m)
    return d / C0 + rng.uniform(0.0, 1e-3, (n, 1)), p


#: Receiver model of the synthetic v2 maps: the C-band first-lobe receiver's settings (as
#: raytrace.studies.accuracy_map.receiver_model_meta gives them).
CBAND_MODEL = {"frequency_hz": 3.775e9, "period_s": 1.25e-8, "roll_off": 0.25, "oversampling": 8,
               "span": 16, "noise_std": 7.81, "alpha": 15.42, "rho": 10 ** (-12 / 20)}  # fmt: skip


def two_ray_paths(xyz: np.ndarray, bs: np.ndarray = PAPER_BS, k: int = 4, refl: float = -0.7):
    """Per point (n, 3) and base station: the line-of-sight path and the floor reflection (image
    source below the floor, coefficient ``refl``), padded to ``k`` slots: delay (n, B, k) s,
    gain, direction (n, B, k, 3), radius (n, B, k) m."""
    f = CBAND_MODEL["frequency_hz"]
    n, b = len(xyz), len(bs)
    delay = np.full((n, b, k), np.nan)
    gain = np.zeros((n, b, k), complex)
    u = np.full((n, b, k, 3), np.nan)
    radius = np.full((n, b, k), np.nan)
    for j, (src, r) in enumerate(((bs, 1.0), (bs * np.array([1.0, 1.0, -1.0]), refl))):
        v = xyz[:, None, :] - src[None]
        d = np.linalg.norm(v, axis=2)
        delay[..., j] = d / C0
        gain[..., j] = r * C0 / f / (4 * np.pi * d) * np.exp(-2j * np.pi * f * d / C0)
        u[..., j, :] = v / d[..., None]
        radius[..., j] = d
    return delay, gain, u, radius


def two_ray_map(step: float = 0.5, area: tuple[float, float] = (29.0, 25.0)):
    """A schema-v2 map of the synthetic hall with :func:`two_ray_paths` per cell and ``toa_s``
    from the first-lobe receiver on them (the overlap of the two rays biases it by up to
    decimetres, changing within a cell)."""
    from positioning.twin.fingerprint import FingerprintMap
    from positioning.twin.lobe import LobeReceiver

    base = synth_map(step=step, area=area, bias=lambda xy: np.zeros((len(xy), len(PAPER_BS))))
    delay, gain, u, radius = two_ray_paths(base.cell_xyz)
    n, b, k = delay.shape
    model = LobeReceiver.from_meta(CBAND_MODEL)
    toa = model.toa(delay.reshape(n * b, k), gain.reshape(n * b, k)).reshape(n, b)
    return FingerprintMap(**{**base.arrays(), "toa_s": toa},
                          meta={**base.meta, "receiver_model": CBAND_MODEL},
                          path_delay_s=delay, path_gain=gain, path_dir=u, path_radius_m=radius)  # fmt: skip


#: mmWave-like band: 400 MHz, 28 GHz; link budget offset so that the free-space SNR at 20 m is
#: about 12 dB (as in the bundled hall).
BAND = {"bandwidth_hz": 400e6, "center_frequency_hz": 28e9, "subcarrier_spacing_hz": 120e3}
SNR_OFFSET_DB = 99.4
#: The noise core of nlos-map's error model in BAND (FLOOR_FIRST_LOBE c / B = 0.045 m).
SIGMA_M = FLOOR_FIRST_LOBE * C0 / BAND["bandwidth_hz"]


def nlos_scene(seed: int, n: int, bs: np.ndarray, n_nlos: int, excess=(5.0, 30.0)):
    """ToAs and receiver reports of n devices: range noise SIGMA_M, ``n_nlos`` base stations per
    epoch with a uniform excess and an SNR 15 dB under free space (a blocked link); LoS links
    at their free-space SNR."""
    rng = np.random.default_rng(seed)
    dev = np.column_stack([rng.uniform(2, 27, n), rng.uniform(2, 23, n), np.full(n, 1.0)])
    d = np.linalg.norm(dev[:, None] - bs[None], axis=2)
    lam = C0 / BAND["center_frequency_hz"]
    snr = SNR_OFFSET_DB + 20 * np.log10(lam / (4 * np.pi * d))
    bias = np.zeros_like(d)
    for i in range(n):
        j = rng.choice(len(bs), n_nlos, replace=False)
        bias[i, j] = rng.uniform(*excess, n_nlos)
        snr[i, j] -= 15.0
    toa = (d + bias + rng.normal(0, SIGMA_M, d.shape)) / C0 + rng.uniform(0, 1e-3, (n, 1))
    links = LinkInfo(
        snr_db=snr,
        peak_ratio_db=np.zeros_like(d),
        lobe_width=np.ones_like(d),
        receiver="first-lobe",
        snr_offset_db=SNR_OFFSET_DB,
        **BAND,
    )
    return dev, toa, links
