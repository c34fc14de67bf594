"""Paths.to_pandas and Paths.interaction_labels: one row per path, each column against the
path arrays or an independent per-path computation."""

from __future__ import annotations

import numpy as np
import pandas as pd  # the test extra installs it (pip install '.[test]')
import pytest

from raytrace import HallrayError, load_scene, trace
from raytrace.core.constants import C0
from raytrace.viz.interactive import interaction_text

#: Excess delay of a line-of-sight path (float64 delays of metre-scale paths), s.
LOS_EXCESS_TOL_S = 1e-17

TX = np.array([[-5.0, 0.0, 1.5], [5.0, 3.0, 2.0]])
RX = np.array([[5.0, 0.0, 1.0], [0.0, 6.0, 1.5], [-4.0, -6.0, 1.2]])


@pytest.fixture(scope="module")
def traced():
    scene = load_scene("canonical/box_on_floor")
    return scene, trace(scene, TX, RX, 3.775e9)


def test_one_row_per_path_with_the_path_arrays(traced):
    scene, paths = traced
    df = paths.to_pandas(scene.object_names, tx_names=["BS1", "BS2"], rx_names=["P1", "P2", "P3"])
    assert isinstance(df, pd.DataFrame) and len(df) == paths.n_paths > 20
    np.testing.assert_array_equal(df["delay_s"], paths.delay_s)
    np.testing.assert_array_equal(df["gain"], paths.gain)
    np.testing.assert_array_equal(df["power_db"], 20 * np.log10(np.abs(paths.gain)))
    np.testing.assert_array_equal(df["link"], paths.link)
    assert list(df["tx"]) == [["BS1", "BS2"][i] for i in paths.tx_index]
    assert list(df["rx"]) == [["P1", "P2", "P3"][i] for i in paths.rx_index]
    assert list(df["kind"]) == list(paths.kind_label)
    # the interactive view's per-path text is an independent loop over the same arrays
    names = scene.object_names
    assert list(df["interactions"]) == [interaction_text(paths, i, names)
                                        for i in range(paths.n_paths)]  # fmt: skip
    assert (df["interactions"] != "LoS").sum() > 0
    first = paths.first_arrival()
    assert df.index[df["first_arrival"]].tolist() == sorted(first[first >= 0].tolist())


def test_excess_delay_is_the_detour_over_the_straight_line(traced):
    _, paths = traced
    df = paths.to_pandas()
    straight = np.linalg.norm(TX[paths.tx_index] - RX[paths.rx_index], axis=1) / C0
    np.testing.assert_allclose(df["excess_delay_s"], paths.delay_s - straight, rtol=0, atol=0)
    los = paths.los
    assert los.any()
    assert np.abs(df["excess_delay_s"][los]).max() < LOS_EXCESS_TOL_S
    # an interaction is never a shortcut (a grazing diffraction is no detour)
    assert (df["excess_delay_s"][~los] >= -LOS_EXCESS_TOL_S).all()
    assert (df["excess_delay_s"][~los] > 0).mean() > 0.9
    assert list(df["tx"]) == list(paths.tx_index)  # no names: the indices


def test_labels_without_names_give_object_indices(traced):
    _, paths = traced
    labels = paths.interaction_labels()
    for i in np.flatnonzero(~paths.los)[:50]:
        codes = paths.interaction[i][paths.interaction[i] > 0]
        objs = paths.objects[i][paths.interaction[i] > 0]
        want = " ".join(f"{'?RTD'[c]}(#{o})" for c, o in zip(codes, objs))
        assert labels[i] == want


def test_wrong_number_of_names_is_one_line(traced):
    _, paths = traced
    with pytest.raises(HallrayError, match="rx_names has 2 names for 3 positions"):
        paths.to_pandas(rx_names=["P1", "P2"])
