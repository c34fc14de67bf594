"""Reader of the ToA dataset format (``DIR/toa.csv`` + ``DIR/meta.json``, schema version 1).

``toa.csv`` has one row per (epoch, point, base station)::

    epoch,time_s,point,bs,toa_s,x_true,y_true,z_true,distance_m,los,first_kind,snr_db,
    tx_offset_s,clock_offset_s

``toa_s`` is empty when the link had no detectable path. One *fix* is one (epoch, point) pair.
Only ``epoch, point, bs, toa_s, x_true, y_true, z_true`` are required; ``tx_offset_s`` is taken
from the row when present and non-empty, else from ``meta.json`` ``schedule_s``, else 0;
``time_s`` is optional. ``meta.json`` must list ``base_stations`` (name, xyz); ``scenario``,
``band``, ``points``, ``hall_xy`` and ``obstacles_2d`` are used when present.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hallray import strict_json
from hallray.errors import brief

from ..errors import PositioningError
from ..model.area import ServiceArea, area_from_meta
from ..model.problem import LinkInfo

REQUIRED_COLUMNS = ("epoch", "point", "bs", "toa_s", "x_true", "y_true", "z_true")


@dataclass(frozen=True)
class ToaDataset:
    """A ToA dataset pivoted to one row per fix (F fixes, N base stations).

    Attributes
    ----------
    path : Path -- the dataset directory
    meta : dict -- parsed ``meta.json``
    bs_names : list of N str; bs_xyz : (N, 3) float, metres (order of ``meta.json``)
    epoch : (F,) int; time_s : (F,) float, seconds (NaN if absent); point : (F,) str
    true_xyz : (F, 3) float, metres
    toa_s : (F, N) float, seconds, device clock, NaN = not received
    tx_offset_s : (F, N) float, seconds -- transmission schedule of each measurement
    distance_m : (F, N) float, metres, or None -- the optional ``distance_m`` column (NaN where
        empty), checked against the stations and true positions
    """

    path: Path
    meta: dict[str, Any]
    bs_names: list[str]
    bs_xyz: np.ndarray
    epoch: np.ndarray
    time_s: np.ndarray
    point: np.ndarray
    true_xyz: np.ndarray
    toa_s: np.ndarray
    tx_offset_s: np.ndarray
    distance_m: np.ndarray | None = None

    @property
    def n_fixes(self) -> int:
        return int(self.epoch.size)

    @property
    def scenario(self) -> str:
        return str(self.meta.get("scenario", "unknown"))

    @property
    def band(self) -> str:
        return str(self.meta.get("band", "unknown"))

    @property
    def name(self) -> str:
        return self.path.resolve().name

    @property
    def toa_unscheduled_s(self) -> np.ndarray:
        """(F, N) ToAs with each measurement's schedule offset removed, seconds."""
        return self.toa_s - self.tx_offset_s


def _float(text: str, what: str, line: int, allow_empty: bool = False) -> float:
    t = text.strip()
    if t == "" and allow_empty:
        return math.nan
    try:
        v = float(t)
    except ValueError:
        raise PositioningError(f"toa.csv line {line}: bad number in {what}: {brief(text)}") from None
    if not math.isfinite(v):
        raise PositioningError(f"toa.csv line {line}: non-finite {what}: {brief(text)}")
    return v


def _read_meta(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise PositioningError(f"{path}: file not found")
    try:
        meta = strict_json.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # bad JSON, a duplicate key
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PositioningError(f"{path}: cannot read JSON ({msg})") from None
    if not isinstance(meta, dict):
        raise PositioningError(f"{path}: top level must be an object")
    _check_schema(meta, path)
    bss = meta.get("base_stations")
    if not isinstance(bss, list) or not bss:
        raise PositioningError(f"{path}: 'base_stations' must be a non-empty list")
    for i, b in enumerate(bss):
        ok = isinstance(b, dict) and isinstance(b.get("name"), str)
        xyz = b.get("xyz") if isinstance(b, dict) else None
        ok = ok and isinstance(xyz, list) and len(xyz) == 3
        if ok:
            try:
                ok = all(math.isfinite(float(v)) for v in xyz)
            except (TypeError, ValueError):
                ok = False
        if not ok:
            raise PositioningError(
                f"{path}: base_stations[{i}] needs a 'name' and a finite 'xyz' [x, y, z]"
            )
    names = [b["name"] for b in bss]
    if len(set(names)) != len(names):
        raise PositioningError(f"{path}: duplicate base-station names")
    return meta


def load_dataset(directory: str | Path) -> ToaDataset:
    """Read and validate a dataset directory.

    Raises
    ------
    PositioningError
        Missing directory or file, unreadable JSON, missing columns, bad numbers, unknown
        base-station names, duplicate (epoch, point, bs) rows, or no rows at all.
    """
    d = Path(directory)
    if not d.is_dir():
        raise PositioningError(f"{d}: dataset directory not found")
    meta = _read_meta(d / "meta.json")
    bs_names = [b["name"] for b in meta["base_stations"]]
    bs_xyz = np.array([[float(v) for v in b["xyz"]] for b in meta["base_stations"]])
    csv_path = d / "toa.csv"
    if not csv_path.is_file():
        raise PositioningError(f"{csv_path}: file not found")
    rows = _Rows(bs_names, meta.get("schedule_s") or {})
    try:
        with csv_path.open(newline="", encoding="utf-8-sig") as fh:  # a BOM is fine
            rows.read(csv.reader(fh), csv_path)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PositioningError(f"{csv_path}: cannot read ({exc})") from None
    if not rows.epochs:
        raise PositioningError(f"{csv_path}: no data rows")
    _check_row_count(meta, len(rows.seen), csv_path)
    ds = ToaDataset(
        path=d,
        meta=meta,
        bs_names=bs_names,
        bs_xyz=bs_xyz,
        epoch=np.array(rows.epochs, dtype=np.int64),
        time_s=np.array(rows.times, dtype=float),
        point=np.array(rows.points, dtype=object),
        true_xyz=np.array(rows.truth, dtype=float),
        toa_s=np.array(rows.toa, dtype=float),
        tx_offset_s=np.array(rows.offsets, dtype=float),
        distance_m=np.array(rows.distances, dtype=float) if rows.has_distance else None,
    )
    from .scale import check_dataset

    check_dataset(ds)  # the scale rule: stations in mm, ToAs in ms
    return ds


class _Rows:
    """The rows of ``toa.csv`` pivoted to one row per fix while they are read (:meth:`read`)."""

    def __init__(self, bs_names: list[str], schedule: dict[str, Any]) -> None:
        self.col = {n: i for i, n in enumerate(bs_names)}
        self.n_bs = len(bs_names)
        self.schedule = schedule
        self.fixes: dict[tuple[int, str], int] = {}
        self.epochs: list[int] = []
        self.times: list[float] = []
        self.points: list[str] = []
        self.truth: list[tuple[float, ...]] = []
        self.toa: list[list[float]] = []
        self.offsets: list[list[float]] = []
        self.distances: list[list[float]] = []
        self.has_distance = False
        self.seen: set[tuple[int, int]] = set()

    def read(self, reader: Any, csv_path: Path) -> None:
        """Check the header, then add every non-empty row."""
        header = next(reader, None)
        if header is None:
            raise PositioningError(f"{csv_path}: empty file")
        header = [h.strip() for h in header]
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise PositioningError(f"{csv_path}: missing columns: {', '.join(missing)}")
        ix = {h: i for i, h in enumerate(header)}
        self.has_distance = "distance_m" in ix
        for line, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise PositioningError(
                    f"toa.csv line {line}: {len(row)} fields, header has {len(header)}"
                )
            self.add(row, ix, line)

    def add(self, row: list[str], ix: dict[str, int], line: int) -> None:
        """One measurement: its fix (a new one at the first row of an (epoch, point)), its ToA
        and schedule offset."""
        i_time = ix.get("time_s")
        i_off = ix.get("tx_offset_s")
        try:
            ep = int(row[ix["epoch"]].strip())
        except ValueError:
            raise PositioningError(f"toa.csv line {line}: bad epoch {brief(row[ix['epoch']])}") from None
        pt = row[ix["point"]].strip()
        bsn = row[ix["bs"]].strip()
        if bsn not in self.col:
            raise PositioningError(f"toa.csv line {line}: base station {brief(bsn)} is not in meta.json")
        toa = _float(row[ix["toa_s"]], "toa_s", line, allow_empty=True)
        off = math.nan
        if i_off is not None:
            off = _float(row[i_off], "tx_offset_s", line, allow_empty=True)
        if math.isnan(off):
            off = float(self.schedule.get(bsn, 0.0))
        key = (ep, pt)
        f = self.fixes.get(key)
        if f is not None:
            _check_truth(self.truth[f], row, ix, line, key)
        if f is None:
            f = self.fixes[key] = len(self.epochs)
            self.epochs.append(ep)
            t = math.nan
            if i_time is not None:
                t = _float(row[i_time], "time_s", line, allow_empty=True)
            self.times.append(t)
            self.points.append(pt)
            self.truth.append(
                tuple(_float(row[ix[c]], c, line) for c in ("x_true", "y_true", "z_true"))
            )
            self.toa.append([math.nan] * self.n_bs)
            self.offsets.append([0.0] * self.n_bs)
            self.distances.append([math.nan] * self.n_bs)
        j = self.col[bsn]
        if (f, j) in self.seen:
            raise PositioningError(
                f"toa.csv line {line}: duplicate row for epoch {ep}, point {brief(pt)}, bs {brief(bsn)}"
            )
        self.seen.add((f, j))
        self.toa[f][j] = toa
        self.offsets[f][j] = off
        if self.has_distance:
            self.distances[f][j] = _float(row[ix["distance_m"]], "distance_m", line, allow_empty=True)


#: ``meta.json`` ``schema_version`` values this reader understands (absent: hand-made, fine).
KNOWN_SCHEMA_VERSIONS = (1, 2)


def _check_schema(meta: dict[str, Any], path: Path) -> None:
    v = meta.get("schema_version")
    if v is not None and (isinstance(v, bool) or v not in KNOWN_SCHEMA_VERSIONS):
        raise PositioningError(
            f"{path}: schema_version {brief(v)} is not one this reader knows "
            f"({', '.join(map(str, KNOWN_SCHEMA_VERSIONS))}): update hallray or regenerate it"
        )


def _check_row_count(meta: dict[str, Any], n_rows: int, csv_path: Path) -> None:
    """A truncated toa.csv reads as valid CSV: compare with ``meta.json`` ``summary.rows``."""
    summary = meta.get("summary")
    expected = summary.get("rows") if isinstance(summary, dict) else None
    if isinstance(expected, int) and not isinstance(expected, bool) and expected != n_rows:
        raise PositioningError(
            f"{csv_path}: {n_rows} data rows, meta.json says {expected} (truncated or edited file?)"
        )


def _check_truth(first: tuple[float, ...], row: list[str], ix: dict[str, int], line: int,
                 key: tuple[int, str]) -> None:  # fmt: skip
    """Every row of one fix must carry the same true position (1 mm)."""
    cols = ("x_true", "y_true", "z_true")
    here = tuple(_float(row[ix[c]], c, line) for c in cols)
    if max(abs(a - b) for a, b in zip(first, here)) > 1e-3:
        raise PositioningError(
            f"toa.csv line {line}: true position {list(here)} of epoch {key[0]}, point "
            f"{brief(key[1])} differs from its first row's {list(first)}"
        )


# ----------------------------------------------------------------------------------------------
# service area and receiver reports (kept apart from load_dataset: optional extras of a dataset)

#: Optional per-measurement receiver reports read by :func:`link_reports`.
REPORT_COLUMNS = ("snr_db", "peak_ratio_db", "lobe_width")


def dataset_area(ds: ToaDataset) -> ServiceArea | None:
    """The dataset's service area: ``meta.json`` ``service_area``, else ``hall_xy``, else None."""
    return area_from_meta(ds.meta)


def _meta_float(meta: dict[str, Any], *keys: str) -> float | None:
    v: Any = meta
    for k in keys:
        if not isinstance(v, dict) or k not in v:
            return None
        v = v[k]
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def link_budget_offset_db(meta: dict[str, Any]) -> float | None:
    """``P_tx + G_t + G_r - N`` (dB) from ``link_budget`` and ``band_parameters``, with the
    thermal noise ``N = -174 dBm/Hz + 10 log10(B) + NF + 10 log10(T / 290 K)``; None if a value
    is missing."""
    p = _meta_float(meta, "link_budget", "tx_power_dbm")
    nf = _meta_float(meta, "link_budget", "noise_figure_db")
    B = _meta_float(meta, "band_parameters", "bandwidth_hz")
    if p is None or nf is None or B is None or B <= 0:
        return None
    gt = _meta_float(meta, "link_budget", "tx_antenna_gain_dbi") or 0.0
    gr = _meta_float(meta, "link_budget", "rx_antenna_gain_dbi") or 0.0
    T = _meta_float(meta, "link_budget", "temperature_k") or 290.0
    noise = -174.0 + 10.0 * math.log10(B) + nf + 10.0 * math.log10(T / 290.0)
    return p + gt + gr - noise


def link_reports(ds: ToaDataset) -> LinkInfo:
    """What the receiver reported per measurement (``snr_db``, ``peak_ratio_db``,
    ``lobe_width``; NaN where a column is absent or empty) and the band, from ``meta.json``
    (``band_parameters``, ``link_budget``, ``toa_method``)."""
    idx = {(int(e), str(p)): i for i, (e, p) in enumerate(zip(ds.epoch, ds.point, strict=True))}
    col = {n: j for j, n in enumerate(ds.bs_names)}
    out = {c: np.full(ds.toa_s.shape, np.nan) for c in REPORT_COLUMNS}
    csv_path = ds.path / "toa.csv"
    try:
        with csv_path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            present = [c for c in REPORT_COLUMNS if c in (reader.fieldnames or [])]
            for line, row in enumerate(reader, start=2):
                if not present:
                    break
                try:
                    f = idx[(int(row["epoch"].strip()), row["point"].strip())]
                    j = col[row["bs"].strip()]
                except (KeyError, ValueError, AttributeError):
                    continue
                for c in present:
                    out[c][f, j] = _float(row[c] or "", c, line, allow_empty=True)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise PositioningError(f"{csv_path}: cannot read ({exc})") from None
    meta = ds.meta
    method = meta.get("toa_method")
    return LinkInfo(
        snr_db=out["snr_db"],
        peak_ratio_db=out["peak_ratio_db"],
        lobe_width=out["lobe_width"],
        bandwidth_hz=_meta_float(meta, "band_parameters", "bandwidth_hz"),
        center_frequency_hz=_meta_float(meta, "band_parameters", "center_frequency_hz"),
        receiver=str(method) if isinstance(method, str) else "unknown",
        snr_offset_db=link_budget_offset_db(meta),
        subcarrier_spacing_hz=_meta_float(meta, "band_parameters", "subcarrier_spacing_hz"),
    )
