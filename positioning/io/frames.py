"""The project's CSV files as pandas DataFrames: a ToA dataset (:func:`read_dataset`), a method's
fixes (:func:`read_fixes`) and an accuracy map's table (:func:`read_accuracy_map`).

Every file is plain CSV with a header row, so ``pandas.read_csv`` reads it as well; these readers
add what the file alone does not say: the JSON metadata beside it (in ``DataFrame.attrs``), the
columns' types (names as strings, flags as bools, empty cells as NaN) and, for a map written
before its schema version 2, the ``#`` line that version 1 put first.

pandas is an optional dependency (``pip install 'hallray[pandas]'``): it is imported when a
reader is called, and its absence is one line (:class:`~positioning.errors.PositioningError`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import PositioningError

#: The schema of an accuracy map's ``map.csv``: its name and the version written now (version 1
#: had a ``# hallray-accuracy-map-csv v1 ...`` line before the header; version 2 is plain CSV
#: with the schema in ``map.json`` beside it).
MAP_CSV_SCHEMA = "hallray-accuracy-map-csv"
MAP_CSV_VERSION = 2
MAP_CSV_VERSIONS = (1, 2)


def pandas() -> Any:
    """The pandas module, or a one-line error saying how to install it."""
    try:
        import pandas as pd
    except ImportError:
        raise PositioningError(
            "this needs pandas, an optional dependency: pip install 'hallray[pandas]'"
        ) from None
    return pd


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PositioningError(f"{path}: cannot read JSON ({msg})") from None
    if not isinstance(data, dict):
        raise PositioningError(f"{path}: top level must be an object")
    return data


def _read_csv(path: Path, **kwargs: Any) -> Any:
    pd = pandas()
    if not path.is_file():
        raise PositioningError(f"{path}: file not found")
    try:
        return pd.read_csv(path, encoding="utf-8-sig", **kwargs)
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # pandas' parser errors included
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise PositioningError(f"{path}: cannot read CSV ({why})") from None


def read_dataset(directory: str | Path) -> Any:
    """A ToA dataset (``DIR/toa.csv``, docs/dataset.md) as a DataFrame, one row per measurement.

    Parameters
    ----------
    directory : path of the dataset directory (``toa.csv`` and ``meta.json``)

    Returns
    -------
    pandas.DataFrame with the columns of ``toa.csv`` (``epoch, time_s, point, bs, toa_s,
    x_true, ..., first_kind, snr_db, ...``): ``point``, ``bs``, ``first_kind`` and ``lobe_kind``
    as strings, ``los`` as bool, ``toa_s`` NaN where the link had no detectable path.
    ``df.attrs["meta"]`` is the parsed ``meta.json`` (schema version, band, receiver, base
    stations, ...); ``DIR/forklifts.csv`` of a semi-dynamic dataset reads with
    ``pandas.read_csv``.

    Raises
    ------
    PositioningError
        No such directory or file, unreadable CSV or JSON, a missing required column, or a
        ``meta.json`` schema version this reader does not know.
    """
    from .dataset import KNOWN_SCHEMA_VERSIONS, REQUIRED_COLUMNS

    d = Path(directory)
    if not d.is_dir():
        raise PositioningError(f"{d}: dataset directory not found")
    meta_path = d / "meta.json"
    meta = _read_json(meta_path) if meta_path.is_file() else {}
    v = meta.get("schema_version")
    if v is not None and (isinstance(v, bool) or v not in KNOWN_SCHEMA_VERSIONS):
        raise PositioningError(f"{meta_path}: schema_version {v!r} is not one this reader knows "
                               f"({', '.join(map(str, KNOWN_SCHEMA_VERSIONS))})")  # fmt: skip
    text = {"point": str, "bs": str, "first_kind": str, "lobe_kind": str}
    df = _read_csv(d / "toa.csv", dtype=text, keep_default_na=False,
                   na_values={c: [""] for c in ("toa_s", "snr_db", "peak_ratio_db",
                                                "lobe_width", "tx_offset_s")})  # fmt: skip
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise PositioningError(f"{d / 'toa.csv'}: missing columns: {', '.join(missing)}")
    if "los" in df.columns:
        df["los"] = df["los"].astype(bool)
    df.attrs["meta"] = meta
    return df


def read_fixes(path: str | Path) -> Any:
    """A method's fixes (``estimate-positions -o fixes.csv``, docs/positioning.md) as a DataFrame.

    Returns
    -------
    pandas.DataFrame, one row per fix: ``epoch, time_s, point, method, x, y, z, x_true, ...,
    error_m, status, iterations, n_bs, hpl_m, chi2n, flagged`` (and a twin's ``nlos_bs``,
    ``match_m``); positions NaN for an unsolved fix, ``flagged`` as bool, ``status`` and
    ``nlos_bs`` as strings (``nlos_bs`` joins base-station names with ``|``).
    """
    p = Path(path)
    df = _read_csv(p, dtype={"point": str, "method": str, "status": str, "nlos_bs": str},
                   keep_default_na=False, na_values={c: [""] for c in _FIX_NUMBERS})  # fmt: skip
    if "flagged" in df.columns:
        df["flagged"] = df["flagged"].astype(bool)
    return df


_FIX_NUMBERS = ("time_s", "x", "y", "z", "x_true", "y_true", "z_true", "error_m", "hpl_m",
                "chi2n", "match_m")  # fmt: skip


def read_accuracy_map(path: str | Path) -> Any:
    """An accuracy map's table (``accuracy-map -o DIR``: ``DIR/map.csv``, docs/accuracy_map.md)
    as a DataFrame, one row per grid cell.

    Parameters
    ----------
    path : the map's directory or its ``map.csv``; schema version 2 (plain CSV, ``map.json``
        beside it) or version 1 (a ``#`` line before the header)

    Returns
    -------
    pandas.DataFrame with the columns ``cell, i, j, x_m, y_m, z_m, n_los, gdop``, then
    ``BS:los, BS:first_kind, BS:excess_m, BS:toa_s, BS:toa_std_s, BS:detected_fraction`` per
    base station and ``METHOD:err_p90_m, METHOD:err_mean_m, METHOD:availability`` per method;
    ``BS:los`` as bool, ``BS:first_kind`` as strings (``none`` without a path).
    ``df.attrs["meta"]`` is ``map.json`` (version 2: the schema, the map's band, receiver, grid,
    ...) or, for version 1, ``{"schema": ..., "schema_version": 1}``.
    """
    p = Path(path)
    csv_path = p / "map.csv" if p.is_dir() else p
    if not csv_path.is_file():
        raise PositioningError(f"{csv_path}: file not found")
    try:
        with csv_path.open(encoding="utf-8-sig") as fh:
            first = fh.readline()
    except (OSError, UnicodeDecodeError) as exc:
        raise PositioningError(f"{csv_path}: cannot read ({exc})") from None
    if first.startswith("#"):  # version 1: '# hallray-accuracy-map-csv v1; ...'
        words = first[1:].replace(";", " ").split()
        if len(words) < 2 or words[0] != MAP_CSV_SCHEMA or words[1] != "v1":
            raise PositioningError(f"{csv_path}: not a {MAP_CSV_SCHEMA} v1 file ({first[:60]!r})")
        meta: dict[str, Any] = {"schema": MAP_CSV_SCHEMA, "schema_version": 1}
        skip = 1
    else:
        meta_path = csv_path.with_suffix(".json")
        if not meta_path.is_file():
            raise PositioningError(f"{meta_path}: file not found (the schema of {csv_path.name})")
        meta = _read_json(meta_path)
        if meta.get("schema") != MAP_CSV_SCHEMA or meta.get("schema_version") not in (
            MAP_CSV_VERSIONS
        ):
            raise PositioningError(
                f"{meta_path}: not a {MAP_CSV_SCHEMA} file of a version this reader knows "
                f"({', '.join(map(str, MAP_CSV_VERSIONS))}): schema {meta.get('schema')!r}, "
                f"version {meta.get('schema_version')!r}"
            )
        skip = 0
    df = _read_csv(csv_path, skiprows=skip, keep_default_na=False, na_values=["nan", ""])
    for col in df.columns:
        if col.endswith(":los"):
            df[col] = df[col].astype(bool)
        elif col.endswith(":first_kind"):
            df[col] = df[col].astype(str)
    df.attrs["meta"] = meta
    return df
