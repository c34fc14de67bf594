"""Build a fingerprint map (schema hallray-accuracy-map v2, v1 with --paths 0) of the bundled hall for the twin
estimator's evaluation, before the ``accuracy-map`` tool exists on main.

This is an evaluation helper, not the product: it fills the map's ToA fields (``toa_s``,
``excess_m``, ``los``, ``first_kind``, ``toa_std_s``, ``detected_fraction``) from the same
measurement model the datasets use (``raytrace.emulation.measurement.ToaModel`` on the tracer's
paths, noise off for ``toa_s``, a few noise draws for the spread) and leaves the accuracy
fields (``methods``, ``err_*``, ``availability``) empty (M = 0), which the twin does not read.
With ``--paths K`` (default 16) it also stores the K strongest paths per cell and base station
and the receiver model (schema v2, ``raytrace.studies.accuracy_map.path_table``), which the
twin re-runs the receiver on.

The grid: a square lattice of ``--step`` m over the service area whose offset is chosen so that
every cell centre is at least ``--min-dist`` m from every test point of the scene; cells that
still come closer are dropped (holes are handled by the twin's interpolation).

Robustness variants (the map is wrong on purpose): ``--shift DX,DY`` moves every obstacle
(scene objects other than the walls, floor and ceiling) by (DX, DY) metres before tracing;
``--material OBJECT=MATERIAL`` rebinds one object's material.

Usage::

    python tools/build_twin_map.py --band c-band -o /tmp/maps/hall-c-band.npz
    python tools/build_twin_map.py --band mmwave --shift 0.5,0 -o /tmp/maps/shift-mmwave.npz
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hallray.safe_output import check_output  # noqa: E402
from positioning.twin.fingerprint import FingerprintMap, write_map  # noqa: E402
from raytrace.cli.harness import OneLineParser, run_tool  # noqa: E402
from raytrace.core.errors import HallrayError  # noqa: E402
from raytrace.emulation.bands import get_band  # noqa: E402
from raytrace.emulation.dataset import DatasetConfig, service_area  # noqa: E402
from raytrace.scene.io import load_scene  # noqa: E402
from raytrace.scene.metadata import SceneMetadata  # noqa: E402
from raytrace.solver.tracer import trace  # noqa: E402
from raytrace.studies.accuracy_map import path_table, receiver_model_meta  # noqa: E402

C0 = 299_792_458.0


def grid_cells(
    polygon: np.ndarray, points_xy: np.ndarray, step: float, min_dist: float, height: float
) -> tuple[np.ndarray, float]:
    """(N, 3) cell centres of a ``step`` lattice inside the polygon's box, offset chosen to keep
    the test points at least ``min_dist`` away (offending cells dropped); and the worst
    distance before dropping."""
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    best, best_off = -1.0, (step / 2, step / 2)
    for ox in np.arange(0.0, step, 0.01):
        for oy in np.arange(0.0, step, 0.01):
            d = np.hypot(
                (points_xy[:, 0] - ox + step / 2) % step - step / 2,
                (points_xy[:, 1] - oy + step / 2) % step - step / 2,
            ).min()
            if d > best:
                best, best_off = d, (ox, oy)
    ox, oy = best_off
    xs = np.arange(lo[0] + ((ox - lo[0]) % step), hi[0], step)
    ys = np.arange(lo[1] + ((oy - lo[1]) % step), hi[1], step)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    d = np.hypot(*(xy[:, None, :] - points_xy[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    xy = xy[d >= min_dist]
    return np.column_stack([xy, np.full(len(xy), height)]), float(best)


def perturb(scene, shift: tuple[float, float] | None, material: str | None):
    """The scene with its obstacles (every object but the ``shell_`` walls, floor and ceiling)
    shifted by ``shift`` (dx, dy) metres, or one object rebound to another material
    (``OBJECT=MATERIAL``): a wrong twin. Rebuilt with ``Scene.from_meshes``."""
    if shift is None and material is None:
        return scene
    import trimesh

    from raytrace.scene.model import Scene

    rebind = dict([material.split("=", 1)]) if material else {}
    unknown = set(rebind) - set(scene.object_names)
    if unknown:
        raise HallrayError(f"--material: no object {sorted(unknown)[0]!r} in the scene")
    meshes = []
    for o in scene.objects:
        f = scene.faces[o.face_start : o.face_start + o.face_count]
        used, inv = np.unique(f, return_inverse=True)
        v = scene.vertices[used].copy()
        if shift is not None and not o.name.startswith("shell_"):
            v[:, :2] += shift
        mesh = trimesh.Trimesh(vertices=v, faces=inv.reshape(f.shape), process=False)
        meshes.append((o.name, mesh, rebind.get(o.name, o.material)))
    return Scene.from_meshes(meshes, scene.materials, scene.metadata, scene.source + " (perturbed)")


def _shift(text: str) -> tuple[float, float]:
    """``--shift DX,DY`` in metres -> two finite floats (argparse type)."""
    try:
        dx, dy = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DX,DY in metres, got {text!r}") from None
    if not (np.isfinite(dx) and np.isfinite(dy)):
        raise argparse.ArgumentTypeError(f"expected finite DX,DY in metres, got {text!r}")
    return dx, dy


def _rebinding(text: str) -> str:
    """``--material OBJECT=MATERIAL`` (argparse type: checks the form, returns it as is)."""
    obj, sep, material = text.partition("=")
    if not (sep and obj and material):
        raise argparse.ArgumentTypeError(f"expected OBJECT=MATERIAL, got {text!r}")
    return text


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="hall")
    ap.add_argument("--band", default="c-band")
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--min-dist", type=float, default=0.25)
    ap.add_argument("--height", type=float, default=1.0)
    ap.add_argument("--draws", type=int, default=8, help="noise draws for toa_std_s")
    ap.add_argument("--limit", type=int, default=0, help="only the first N cells (timing)")
    ap.add_argument(
        "--near-points",
        type=float,
        default=0.0,
        metavar="R",
        help="only cells within R m of a test point (a cheaper map for robustness runs)",
    )
    ap.add_argument("--shift", type=_shift, default=None,
                    help="DX,DY: shift every obstacle (wrong map)")  # fmt: skip
    ap.add_argument("--material", type=_rebinding, default=None,
                    help="OBJECT=MATERIAL (wrong map)")  # fmt: skip
    ap.add_argument("--paths", type=int, default=16, metavar="K",
                    help="strongest paths stored per cell and BS (schema v2; 0: v1 map)")
    ap.add_argument("-o", "--output", required=True)
    return ap


def check_args(a: argparse.Namespace) -> None:
    """Refuse meaningless settings and an unwritable output before any work."""
    if not (np.isfinite(a.step) and a.step > 0):
        raise HallrayError(f"--step must be a positive number of metres, got {a.step:g}")
    if not (np.isfinite(a.min_dist) and a.min_dist >= 0):
        raise HallrayError(f"--min-dist must be >= 0 m, got {a.min_dist:g}")
    if not np.isfinite(a.height):
        raise HallrayError(f"--height must be a finite number of metres, got {a.height:g}")
    if not (np.isfinite(a.near_points) and a.near_points >= 0):
        raise HallrayError(f"--near-points must be >= 0 m (0: every cell), got {a.near_points:g}")
    for name, v, lo in (("--draws", a.draws, 1), ("--limit", a.limit, 0), ("--paths", a.paths, 0)):
        if v < lo:
            raise HallrayError(f"{name} must be >= {lo}, got {v}")
    get_band(a.band)  # one line naming the known bands
    check_output(a.output, what="-o")


def _main(a: argparse.Namespace) -> int:
    check_args(a)
    scene = load_scene(a.scene)
    md = SceneMetadata.from_scene(scene, require=True)
    area = service_area(scene, md.block)
    poly = np.asarray(area["polygon"], dtype=float)
    cells, worst = grid_cells(poly, md.point_xyz[:, :2], a.step, a.min_dist, a.height)
    shift = a.shift
    traced_scene = perturb(scene, shift, a.material)
    # a device cannot be inside a cabinet: no cell there (in the map's own scene)
    cells = cells[traced_scene.inside_solid(cells) < 0]
    if a.near_points > 0:
        d = np.linalg.norm(cells[:, None, :2] - md.point_xyz[None, :, :2], axis=2).min(axis=1)
        cells = cells[d <= a.near_points]
    if a.limit:
        cells = cells[: a.limit]
    cfg = DatasetConfig("static", a.band, duration_s=1.0, rate_hz=float(a.draws))
    band = get_band(a.band)
    t0 = time.perf_counter()
    paths = trace(traced_scene, md.bs_xyz, cells, band.center_frequency_hz, cfg.trace)
    t_trace = time.perf_counter() - t0
    model = cfg.model()
    prep = model.prepare(paths)
    exact = DatasetConfig("static", a.band, duration_s=1.0, noise=False).model()
    m0 = exact.measure(paths, [0], prep)
    mn = model.measure(paths, range(a.draws), prep)
    toa = m0.delay_s[0]  # (N, B) propagation delay, no clock, no schedule
    dist = np.linalg.norm(cells[:, None, :] - md.bs_xyz[None, :, :], axis=2)
    n, b = toa.shape
    extra = {}
    if a.paths > 0:
        extra = path_table(paths, a.paths)
    fmap = FingerprintMap(
        **extra,
        cell_xyz=cells,
        bs_xyz=md.bs_xyz,
        bs_names=np.array(md.bs_names),
        los=m0.los[0],
        first_kind=m0.first_kind[0].astype(str),
        excess_m=toa * C0 - dist,
        toa_s=toa,
        toa_std_s=np.nanstd(mn.delay_s, axis=0),
        detected_fraction=mn.detected.mean(axis=0),
        gdop=np.full(n, np.nan),
        methods=np.array([], dtype=str),
        err_p90_m=np.zeros((0, n)),
        err_mean_m=np.zeros((0, n)),
        availability=np.zeros((0, n)),
        meta={
            "band": a.band,
            "frequency_hz": band.center_frequency_hz,
            "bandwidth_hz": band.bandwidth_hz,
            "receiver": cfg.toa_method,
            "step_m": a.step,
            "height_m": a.height,
            "scene": a.scene,
            "draws": a.draws,
            "service_area": poly.tolist(),
            "min_point_distance_m": a.min_dist,
            "builder": "tools/build_twin_map.py",
            "perturbation": {"shift_m": shift, "material": a.material},
            **({"receiver_model": receiver_model_meta(model.receiver)} if a.paths > 0 else {}),
        },
    )
    write_map(a.output, fmap)
    print(
        f"{a.output}: {n} cells x {b} BS, worst point-lattice distance {worst:.3f} m, "
        f"trace {t_trace:.1f} s, total {time.perf_counter() - t0:.1f} s"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
