"""The shared scale rule (hallray.units): the unit a too-large value was most likely given in."""

from __future__ import annotations

import pytest

from hallray.units import MAX_SCENE_M, likely_length_unit, likely_time_unit


@pytest.mark.parametrize(
    "size, expected",
    [
        (60_000.0, (1000.0, "millimetres")),  # a 60 m hall in mm
        (1000.0 * MAX_SCENE_M, (1000.0, "millimetres")),  # the largest hall in mm, at the limit
        (999.0 * 100.0 + 1.0, (1000.0, "millimetres")),  # both fit: the larger factor first
        (5000.0 * 100.0 + 1.0, (1000.0, "millimetres")),
        (2e9, None),  # beyond any unit: 2000 km even in mm
        (0.5, None),  # below 1 m in every unit
    ],
)
def test_likely_length_unit(size, expected):
    assert likely_length_unit(size) == expected


def test_likely_length_unit_takes_the_callers_limit():
    # 800 000 is 800 m in mm and 8 km in cm: within a 1 km limit mm, within 500 m neither
    assert likely_length_unit(800_000.0, limit_m=1000.0) == (1000.0, "millimetres")
    assert likely_length_unit(800_000.0, limit_m=500.0) is None
    # 800 is 0.8 m in mm (below 1 m) and 8 m in cm
    assert likely_length_unit(800.0, limit_m=100.0) == (100.0, "centimetres")


@pytest.mark.parametrize(
    "ratio, unit",
    [(1e3, "milliseconds"), (2e4, "milliseconds"), (4e4, "microseconds"), (1e6, "microseconds"),
     (5e8, "nanoseconds"), (1e12, "nanoseconds")],
)  # fmt: skip
def test_likely_time_unit_is_the_nearest_decade(ratio, unit):
    # nearest factor in log10: 2e4 is 1.3 decades from 1e3 and 1.7 from 1e6
    assert likely_time_unit(ratio)[1] == unit
