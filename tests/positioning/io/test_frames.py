"""The project's CSV files as pandas DataFrames (positioning.io.frames): each reader against the
project's own reader of the same file, the map table's two schema versions, bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pandas as pd  # the test extra installs it (pip install '.[test]')
import pytest
from pos_synth import write_dataset

from positioning import PositioningError, read_accuracy_map, read_dataset, read_fixes
from positioning.cli.estimate import estimate_positions_main
from positioning.io.dataset import load_dataset
from positioning.io.frames import MAP_CSV_SCHEMA, MAP_CSV_VERSION

POINTS = np.array([[5.0, 6.0, 1.0], [14.0, 12.0, 1.0], [22.0, 19.0, 1.0]])
#: A map's table: 2 base stations, 1 method.
MAP_HEADER = ["cell", "i", "j", "x_m", "y_m", "z_m", "n_los", "gdop",
              *(f"{b}:{k}" for b in ("BS1", "BS2")
                for k in ("los", "first_kind", "excess_m", "toa_s", "toa_std_s",
                          "detected_fraction")),
              "ls:err_p90_m", "ls:err_mean_m", "ls:availability"]  # fmt: skip
MAP_ROWS = [
    [0, 0, 0, 1.0, 1.0, 1.0, 2, 1.5, 1, "LoS", 0, 1.2e-8, 1e-10, 1, 0, "DR", 3.5, "nan", "nan", 0,
     0.4, 0.2, 1],
    [1, 1, 0, 3.0, 1.0, 1.0, 1, "nan", 0, "none", "nan", "nan", "nan", 0, 1, "LoS", 0, 2e-8,
     2e-10, 1, "nan", "nan", 0],
]  # fmt: skip


@pytest.fixture()
def dataset(tmp_path):
    return write_dataset(tmp_path / "d", points=POINTS, n_epochs=2, missing=[(1, 2, 3)],
                         nlos={(0, 1): 4.0})  # fmt: skip


def test_dataset_frame_has_every_row_and_the_readers_numbers(dataset):
    df = read_dataset(dataset)
    ds = load_dataset(dataset)
    assert len(df) == 2 * len(POINTS) * 4  # one row per (epoch, point, base station)
    assert df.attrs["meta"] == json.loads((dataset / "meta.json").read_text())
    assert df["los"].dtype == bool and df["point"].iloc[0] == "P01"
    # the pivoted reader's ToA of fix (epoch 1, point P03) from BS4 is the missing one: NaN
    row = df[(df.epoch == 1) & (df.point == "P03") & (df.bs == "BS4")]
    assert len(row) == 1 and np.isnan(row.toa_s.iloc[0])
    for f in range(ds.n_fixes):
        sel = df[(df.epoch == ds.epoch[f]) & (df.point == ds.point[f])].set_index("bs")
        got = sel.loc[ds.bs_names, "toa_s"].to_numpy()
        np.testing.assert_array_equal(got, ds.toa_s[f])  # bitwise: both parse the same text
    assert set(df.first_kind) == {"LoS", "R"}


def test_fixes_frame_matches_the_fixes_file(dataset, tmp_path):
    out = tmp_path / "fixes.csv"
    assert estimate_positions_main([str(dataset), "--method", "irls", "-o", str(out)]) == 0
    df = read_fixes(out)
    with out.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(df) == len(rows) == 2 * len(POINTS)
    np.testing.assert_array_equal(df["x"].to_numpy(), [float(r["x"]) for r in rows])
    np.testing.assert_array_equal(df["error_m"].to_numpy(), [float(r["error_m"]) for r in rows])
    assert df["flagged"].dtype == bool
    assert list(df["flagged"]) == [r["flagged"] == "1" for r in rows]
    assert set(df["method"]) == {"irls"}


def _write_map(folder, version):
    folder.mkdir()
    with (folder / "map.csv").open("w", newline="") as fh:
        if version == 1:
            fh.write(f"# {MAP_CSV_SCHEMA} v1; one row per cell; units SI (m, s)\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(MAP_HEADER)
        w.writerows(MAP_ROWS)
    if version == 2:
        meta = {"schema": MAP_CSV_SCHEMA, "schema_version": 2, "columns": MAP_HEADER,
                "map": {"band": "c-band"}}  # fmt: skip
        (folder / "map.json").write_text(json.dumps(meta))
    return folder


@pytest.mark.parametrize("version", [1, MAP_CSV_VERSION])
def test_map_table_of_either_schema_version(tmp_path, version):
    folder = _write_map(tmp_path / "map", version)
    for where in (folder, folder / "map.csv"):
        df = read_accuracy_map(where)
        assert list(df.columns) == MAP_HEADER
        assert len(df) == 2
        assert df.attrs["meta"]["schema_version"] == version
        assert df["BS1:los"].tolist() == [True, False]
        assert df["BS1:first_kind"].tolist() == ["LoS", "none"]
        assert np.isnan(df["gdop"].iloc[1]) and df["gdop"].iloc[0] == 1.5
        assert df["BS2:toa_s"].iloc[1] == 2e-8
    if version == 2:  # plain CSV: pandas alone reads the same table
        plain = pd.read_csv(folder / "map.csv")
        assert list(plain.columns) == MAP_HEADER


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("no-json", "map.json: file not found"),
        ("other-schema", "not a hallray-accuracy-map-csv file"),
        ("other-comment", "not a hallray-accuracy-map-csv v1 file"),
        ("missing", "map.csv: file not found"),
    ],
)
def test_map_table_bad_input_is_one_line(tmp_path, setup, message):
    folder = _write_map(tmp_path / "map", 2)
    if setup == "no-json":
        (folder / "map.json").unlink()
    elif setup == "other-schema":
        (folder / "map.json").write_text(json.dumps({"schema": "x", "schema_version": 2}))
    elif setup == "other-comment":
        text = (folder / "map.csv").read_text()
        (folder / "map.csv").write_text("# something else\n" + text)
    else:
        (folder / "map.csv").unlink()
    with pytest.raises(PositioningError, match=message) as exc:
        read_accuracy_map(folder)
    assert "\n" not in str(exc.value)


def test_dataset_bad_input_is_one_line(tmp_path, dataset):
    with pytest.raises(PositioningError, match="dataset directory not found"):
        read_dataset(tmp_path / "nowhere")
    meta = json.loads((dataset / "meta.json").read_text())
    (dataset / "meta.json").write_text(json.dumps({**meta, "schema_version": 99}))
    with pytest.raises(PositioningError, match="schema_version 99"):
        read_dataset(dataset)
    (dataset / "meta.json").write_text(json.dumps(meta))
    (dataset / "toa.csv").write_text("epoch,point\n0,P01\n")
    with pytest.raises(PositioningError, match="missing columns: bs, toa_s"):
        read_dataset(dataset)


def test_without_pandas_the_error_says_how_to_install_it(monkeypatch, dataset):
    import builtins

    real = builtins.__import__

    def no_pandas(name, *args, **kwargs):
        if name == "pandas" or name.startswith("pandas."):
            raise ImportError("No module named 'pandas'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pandas)
    with pytest.raises(PositioningError, match=r"pip install 'hallray\[pandas\]'"):
        read_dataset(dataset)
