"""Bands: the paper's Table I values, derived OFDM quantities, lookup and user bands from YAML."""

from __future__ import annotations

import dataclasses

import pytest
import yaml

from raytrace.core.constants import C0
from raytrace.core.errors import HallrayError
from raytrace.emulation.bands import BUILTIN_BANDS, Band, band_from_dict, get_band, load_bands

#: Relative tolerance on derived floating-point quantities (pure arithmetic).
REL_TOL = 1e-12


def test_table_one_values():
    c = get_band("c-band")
    assert (c.center_frequency_hz, c.bandwidth_hz, c.subcarrier_spacing_hz) == (
        3.775e9,
        100e6,
        30e3,
    )
    m = get_band("mmwave")
    assert (m.center_frequency_hz, m.bandwidth_hz, m.subcarrier_spacing_hz) == (
        26.85e9,
        400e6,
        120e3,
    )
    assert set(BUILTIN_BANDS) == {"c-band", "mmwave"}


@pytest.mark.parametrize(
    "name, n_sc, symbol_s, sample_s",
    [("c-band", 3333, 1 / 30e3, 1e-8), ("mmwave", 3333, 1 / 120e3, 2.5e-9)],
)
def test_derived_quantities(name, n_sc, symbol_s, sample_s):
    band = get_band(name)
    assert band.n_subcarriers == n_sc  # floor(100e6 / 30e3) = floor(400e6 / 120e3) = 3333
    assert band.symbol_duration_s == pytest.approx(symbol_s, rel=REL_TOL)
    assert band.sample_period_s == pytest.approx(sample_s, rel=REL_TOL)
    assert band.wavelength_m == pytest.approx(C0 / band.center_frequency_hz, rel=REL_TOL)
    assert name in band.describe()


def test_exact_subcarrier_count_is_not_lost_to_rounding():
    # 20 MHz / 15 kHz = 1333.33..; 1.44 MHz / 15 kHz = 96 exactly (float division gives 95.999..)
    assert Band("a", 2e9, 20e6, 15e3).n_subcarriers == 1333
    assert Band("b", 2e9, 1.44e6, 15e3).n_subcarriers == 96


@pytest.mark.parametrize("alias", ["C-Band", "c_band", " c-band ", "MMWAVE", "mmWave"])
def test_names_are_case_and_separator_insensitive(alias):
    assert get_band(alias) in BUILTIN_BANDS.values()


def test_unknown_band_lists_known_ones():
    with pytest.raises(HallrayError) as err:
        get_band("x-band")
    msg = str(err.value)
    assert "x-band" in msg and "c-band" in msg and "mmwave" in msg and "\n" not in msg


def test_band_is_frozen_and_passed_through():
    band = get_band("c-band")
    with pytest.raises(dataclasses.FrozenInstanceError):
        band.bandwidth_hz = 1.0  # type: ignore[misc]
    assert get_band(band) is band


def _write(tmp_path, data, name="bands.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_user_band_from_yaml_file(tmp_path):
    path = _write(
        tmp_path,
        {
            "bands": {
                "Wifi6E": {"frequency_ghz": 6.1, "bandwidth_mhz": 160, "subcarrier_khz": 78.125}
            }
        },
    )
    band = get_band(path)
    assert band.name == "wifi6e"
    assert band.center_frequency_hz == pytest.approx(6.1e9, rel=REL_TOL)
    assert band.bandwidth_hz == pytest.approx(160e6, rel=REL_TOL)
    assert band.subcarrier_spacing_hz == pytest.approx(78.125e3, rel=REL_TOL)
    assert band.n_subcarriers == 2048
    bands = load_bands(path)
    assert set(bands) == {"c-band", "mmwave", "wifi6e"}
    assert get_band("WIFI6E", bands) == band


def test_several_user_bands_need_a_name(tmp_path):
    entry = {"frequency_ghz": 3.5, "bandwidth_mhz": 40, "subcarrier_khz": 30}
    path = _write(tmp_path, {"bands": {"n78a": entry, "n78b": entry}})
    with pytest.raises(HallrayError, match="defines 2 bands .*n78a, n78b"):
        get_band(path)
    assert get_band("n78b", load_bands(path)).bandwidth_hz == pytest.approx(40e6, rel=REL_TOL)


def test_user_band_overrides_builtin():
    bands = load_bands(
        {"bands": {"c-band": {"frequency_ghz": 3.7, "bandwidth_mhz": 50, "subcarrier_khz": 30}}}
    )
    assert bands["c-band"].bandwidth_hz == pytest.approx(50e6, rel=REL_TOL)
    assert BUILTIN_BANDS["c-band"].bandwidth_hz == 100e6  # built-ins untouched


@pytest.mark.parametrize(
    "entry, match",
    [
        ({"frequency_ghz": 3.5, "bandwidth_mhz": 40}, "missing key.*subcarrier_khz"),
        ({"frequency_ghz": 3.5, "bandwidth_mhz": 40, "subcarrier_khz": 30, "bw": 1}, "unknown key"),
        ({"frequency_ghz": "3.5", "bandwidth_mhz": 40, "subcarrier_khz": 30}, "must be a number"),
        ({"frequency_ghz": -3.5, "bandwidth_mhz": 40, "subcarrier_khz": 30}, "positive"),
        ({"frequency_ghz": 3.5, "bandwidth_mhz": 0.01, "subcarrier_khz": 30}, "exceeds"),
        ({"frequency_ghz": float("nan"), "bandwidth_mhz": 40, "subcarrier_khz": 30}, "positive"),
        ([1, 2, 3], "expected a mapping"),
    ],
)
def test_bad_band_entries_are_one_line_errors(entry, match):
    with pytest.raises(HallrayError, match=match) as err:
        band_from_dict("bad", entry)
    assert "\n" not in str(err.value) and "bad" in str(err.value)


def test_bad_files(tmp_path):
    with pytest.raises(HallrayError, match="not found"):
        get_band(tmp_path / "missing.yaml")
    with pytest.raises(HallrayError, match="bands:"):
        get_band(_write(tmp_path, {"materials": {}}))
    with pytest.raises(HallrayError, match="empty"):
        load_bands({"bands": {}})
    bad = tmp_path / "broken.yaml"
    bad.write_text("bands: {a: [unclosed\n")
    with pytest.raises(HallrayError, match="cannot read") as err:
        load_bands(bad)
    assert "\n" not in str(err.value)
