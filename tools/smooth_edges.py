"""The field error of treating a tessellated curve's edges as smooth (no diffraction): the
measurement behind the default smooth angle of :func:`raytrace.load_scene` (issue 36).

Curved metal objects (cylinders of 16 to 128 sections, icospheres, and the same with 1 cm of
vertex noise, as a scan gives) stand in a ring of receivers; every object is traced with the
smooth angle at 1 degree (every bent edge a wedge: the reference) and at larger angles. Per
angle: wedges left, the narrowband received power's error against the reference (median, p90,
max, dB), the receivers in the object's shadow that lose every path, and the largest shift of
the first arrival (m). Example::

    python tools/smooth_edges.py --angles 2,5,10,20 --band c-band
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.scene.construction import check_smooth_angle


def _objects(rng: np.random.Generator) -> list[tuple[str, object]]:
    import trimesh

    out = []
    for sections in (16, 32, 64, 128):
        out.append((f"cylinder {sections}", trimesh.creation.cylinder(0.6, 3.0, sections=sections)))
    for sub in (3, 4):
        out.append((f"icosphere {sub}", trimesh.creation.icosphere(sub, 0.8)))
    noisy = trimesh.creation.icosphere(4, 0.8)
    noisy.vertices += rng.normal(0.0, 0.01, noisy.vertices.shape)
    out.append(("icosphere 4 + 1 cm noise", noisy))
    for _, m in out:
        m.apply_translation([0.0, 0.0, 1.5])
    return out


def _field(mesh, angle_deg: float, f_hz: float, tx: np.ndarray, rx: np.ndarray):
    import raytrace
    from raytrace import TraceConfig
    from raytrace.physics.materials import MaterialLibrary
    from raytrace.scene.model import Scene

    scene = Scene.from_meshes([("obj_metal", mesh, "metal")], MaterialLibrary.itu(),
                              smooth_angle_deg=angle_deg)  # fmt: skip
    p = raytrace.trace(scene, tx, rx, f_hz, TraceConfig(max_reflections=2, max_diffractions=1))
    field = np.zeros(len(rx), complex)
    first = np.full(len(rx), np.nan)
    for r in range(len(rx)):
        m = p.rx_index == r
        if m.any():
            field[r] = (p.gain[m] * np.exp(-2j * np.pi * f_hz * p.delay_s[m])).sum()
            first[r] = p.delay_s[m].min()
    return len(scene.wedges), field, first


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles", default="2,3,5,10,20", help="smooth angles to compare, degrees")
    ap.add_argument("--band", default="c-band", choices=["c-band", "mmwave"], help="[c-band]")
    ap.add_argument("--seed", type=int, default=1, help="seed of the vertex noise [1]")
    return ap


def _angles(text: str) -> list[float]:
    try:
        angles = [float(a) for a in text.split(",")]
    except ValueError:
        raise HallrayError(f"--angles expects numbers separated by commas, got {text!r}") from None
    for a in angles:
        check_smooth_angle(a)
    return angles


def _main(args: argparse.Namespace) -> int:
    angles = _angles(args.angles)
    warnings.simplefilter("ignore", UserWarning)  # the ends lie far outside a one-object scene
    f_hz = {"c-band": 3.775e9, "mmwave": 26.85e9}[args.band]
    tx = np.array([[-6.0, 0.0, 1.5]])
    ang = np.deg2rad(np.arange(2.5, 360, 5))
    rx = np.column_stack([6 * np.cos(ang), 6 * np.sin(ang), np.full(len(ang), 1.5)])
    print(f"{'object':26s} {'angle':>5s} {'wedges':>13s} {'err med':>7s} {'p90':>6s} {'max':>6s} "
          f"{'lost rx':>7s} {'first shift m':>13s}")  # fmt: skip
    for label, mesh in _objects(np.random.default_rng(args.seed)):
        n0, f0, t0 = _field(mesh, 1.0, f_hz, tx, rx)
        p0 = 20 * np.log10(np.abs(f0) + 1e-30)
        for a in angles:
            n1, f1, t1 = _field(mesh, a, f_hz, tx, rx)
            err = np.abs(20 * np.log10(np.abs(f1) + 1e-30) - p0)[np.isfinite(t1)]
            lost = int((np.isnan(t1) & np.isfinite(t0)).sum())
            both = np.isfinite(t0) & np.isfinite(t1)
            shift = float(np.max(np.abs(t1[both] - t0[both]))) * 299_792_458.0 if both.any() else 0.0
            print(f"{label:26s} {a:5.1f} {n0:6d}->{n1:6d} {np.median(err):7.2f} "
                  f"{np.percentile(err, 90):6.2f} {err.max():6.2f} {lost:7d} {shift:13.3f}")  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
