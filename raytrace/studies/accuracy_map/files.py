"""A map's files: ``map.npz`` (:func:`positioning.twin.fingerprint.write_map`), its CSV companion
``map.csv`` with the schema and the map's meta in ``map.json`` beside it, and the PNG heatmaps,
written into a staged directory (no partial output).
"""

from __future__ import annotations

import csv
import io
import json
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from positioning.io.frames import MAP_CSV_SCHEMA, MAP_CSV_VERSION
from positioning.twin.fingerprint import write_map

from ...core.fileio import write_atomic
from ...scene.model import Scene
from .compute import AccuracyMap

#: The CSV companion of map.npz: its schema name and version (in map.json; version 1 had them
#: in a ``#`` line before the header, which spreadsheets and ``pandas.read_csv`` took for it).
CSV_SCHEMA, CSV_VERSION = MAP_CSV_SCHEMA, MAP_CSV_VERSION


def csv_columns(bs_names: Sequence[str], methods: Sequence[str]) -> list[str]:
    """Columns of map.csv (one row per cell; docs/accuracy_map.md)."""
    head = ["cell", "i", "j", "x_m", "y_m", "z_m", "n_los", "gdop"]
    for b in bs_names:
        head += [f"{b}:{k}" for k in ("los", "first_kind", "excess_m", "toa_s", "toa_std_s",
                                      "detected_fraction")]  # fmt: skip
    for m in methods:
        head += [f"{m}:{k}" for k in ("err_p90_m", "err_mean_m", "availability")]
    return head


def map_csv_meta(amap: AccuracyMap) -> bytes:
    """map.json: the schema of map.csv (name, version, columns) and the map's meta (band,
    receiver, grid, ...; docs/accuracy_map.md)."""
    f = amap.fmap
    doc = {
        "schema": CSV_SCHEMA,
        "schema_version": CSV_VERSION,
        "file": "map.csv",
        "rows": "one per cell",
        "units": "SI (m, s)",
        "columns": csv_columns(list(f.bs_names), list(f.methods)),
        "map": f.meta,
    }
    return (json.dumps(doc, indent=1) + "\n").encode("utf-8")


def map_csv(amap: AccuracyMap) -> bytes:
    """map.csv: plain CSV, the header (:func:`csv_columns`), then one row per cell."""
    f, g = amap.fmap, amap.grid
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_columns(list(f.bs_names), list(f.methods)))
    n_los = f.n_los()
    for n in range(f.n_cells):
        row: list[Any] = [n, *g.ij[n].tolist(), *(f"{v:.4f}" for v in f.cell_xyz[n]),
                          int(n_los[n]), _num(f.gdop[n])]  # fmt: skip
        for b in range(f.n_bs):
            row += [int(f.los[n, b]), f.first_kind[n, b], _num(f.excess_m[n, b]),
                    _num(f.toa_s[n, b], 12), _num(f.toa_std_s[n, b], 12),
                    _num(f.detected_fraction[n, b])]  # fmt: skip
        for m in range(len(f.methods)):
            row += [_num(f.err_p90_m[m, n]), _num(f.err_mean_m[m, n]), _num(f.availability[m, n])]
        w.writerow(row)
    return buf.getvalue().encode("utf-8")


def _num(v: float, digits: int = 6) -> str:
    """A number for the CSV, ``nan`` for NaN."""
    return "nan" if not np.isfinite(v) else f"{float(v):.{digits}g}"


#: The name an accuracy map's marker records (:func:`hallray.safe_output.write_marker`).
MAP_COMMAND = "accuracy-map"


def check_output(
    out_dir: str | Path, force: bool, inputs: Sequence[str | Path | None] = ()
) -> None:
    """Refuse, before any work, an output directory :func:`write_outputs` would refuse
    (:func:`hallray.safe_output.check_output_dir`: no input inside or around it, only an earlier
    accuracy map replaced, with ``force``)."""
    from hallray.safe_output import check_output_dir

    check_output_dir(out_dir, command=MAP_COMMAND, inputs=inputs, force=force)


def write_outputs(
    out_dir: str | Path, scene: Scene, amap: AccuracyMap, *, force: bool = False,
    pictures: bool = True, inputs: Sequence[str | Path | None] = (),
) -> list[Path]:  # fmt: skip
    """Write DIR/map.npz (:func:`positioning.twin.fingerprint.write_map`), DIR/map.csv, its schema
    DIR/map.json and the PNG heatmaps into a temporary directory beside ``out_dir``, renamed when
    complete (no partial output; :func:`hallray.safe_output.output_dir`: ``force`` replaces an
    earlier accuracy map, never a directory with other files or one holding ``inputs``). Returns
    the files' final paths."""
    from hallray.safe_output import output_dir

    out = Path(out_dir)
    with output_dir(out, command=MAP_COMMAND, force=force, inputs=inputs) as tmp:
        write_map(tmp / "map.npz", amap.fmap)
        write_atomic(tmp / "map.csv", map_csv(amap))
        write_atomic(tmp / "map.json", map_csv_meta(amap))
        names = ["map.npz", "map.csv", "map.json"]
        if pictures:
            for name, png in map_pictures(scene, amap):
                write_atomic(tmp / name, png)
                names.append(name)
    return [out / n for n in names]


#: Lower end of the error pictures' log colour scale, m.
ERR_FLOOR_M = 0.01
#: Pictures of a map: (file, quantity, colour-bar label, colour map, discrete).
PICTURES = (
    ("n_los.png", "n_los", "base stations in line of sight", "viridis", True),
    (
        "n_detected.png",
        "n_detected",
        "base stations detected (noiseless receiver)",
        "viridis",
        True,
    ),
    ("gdop.png", "gdop", "GDOP (2D, TDoA)", "magma_r", False),
    (
        "excess_worst_m.png",
        "excess_worst",
        "largest first-arrival excess delay over BS, m",
        "inferno_r",
        False,
    ),
)


def map_pictures(scene: Scene, amap: AccuracyMap) -> list[tuple[str, bytes]]:
    """The map's PNG heatmaps: :data:`PICTURES`, then ``err_p90_<method>.png`` and
    ``availability_<method>.png`` per method."""
    from ...viz.heatmap import footprints, heatmap_png

    f, g = amap.fmap, amap.grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # cells with no arrival at all
        per_cell = {
            "n_los": f.n_los().astype(float),
            "n_detected": np.isfinite(f.toa_s).sum(axis=1).astype(float),
            "gdop": np.where(np.isfinite(f.gdop), f.gdop, np.nan),
            "excess_worst": np.nanmax(f.excess_m, axis=1),
        }
    jobs = [(name, per_cell[key], label, cmap, disc, 0.0 if disc else None,
             float(f.n_bs) if disc else None, False)
            for name, key, label, cmap, disc in PICTURES]  # fmt: skip
    for k, m in enumerate(f.methods):
        err = f.err_p90_m[k]  # centimetres to tens of metres: a log scale from 1 cm
        top = float(np.nanmax(err)) if np.isfinite(err).any() else 1.0
        jobs.append((f"err_p90_{m}.png", err, f"p90 2D error, {m}, m (log scale)", "turbo",
                     False, ERR_FLOOR_M, max(top, 10 * ERR_FLOOR_M), True))  # fmt: skip
        jobs.append((f"availability_{m}.png", f.availability[k],
                     f"share of draws with a fix, {m}", "cividis", False, 0.0, 1.0, False))  # fmt: skip
    outlines = footprints(scene)
    pts = np.asarray(g.test_xyz, dtype=float).reshape(-1, 3)[:, :2]
    meta = f.meta
    sub = (f"{meta.get('scene', '')} {meta.get('band', '')}, receiver {meta.get('receiver', '')}, "
           f"step {g.step_m:g} m, h {meta.get('height_m', 0):g} m")  # fmt: skip
    out = []
    for name, vals, label, cmap, disc, vmin, vmax, log in jobs:
        png = heatmap_png(scene, g.raster(vals), g.origin_xy, g.step_m, title=f"{label}\n{sub}",
                          label=label, bs_xyz=f.bs_xyz, bs_names=list(f.bs_names), points_xy=pts,
                          cmap=cmap, vmin=vmin, vmax=vmax, discrete=disc, log=log,
                          outlines=outlines)  # fmt: skip
        out.append((name, png))
    return out
