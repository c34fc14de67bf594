"""The one top-view plotter (raytrace.viz.topview): what it draws of a hall description and of a
scene's triangles, counted against the construction."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pytest
from conftest import box, make_scene, quad

from raytrace.halls.spec import load_hall_spec
from raytrace.viz.topview import Footprint, SceneView, draw_footprints, plot_top_view

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HALL_YAML = Path(__file__).resolve().parent.parent / "scenes" / "hall.yaml"


@pytest.fixture(scope="module")
def hall():
    return load_hall_spec(HALL_YAML)


@pytest.fixture
def ax():
    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def test_a_hall_draws_every_obstacle_and_site(hall, ax):
    n = plot_top_view(ax, hall)
    assert n == len(hall.objects)
    markers = [ln.get_marker() for ln in ax.get_lines()]
    assert markers.count("^") == len(hall.base_stations)
    assert markers.count("s") == len(hall.points)
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"metal", "plastic", "glass", "wood", "concrete", "area of interest"} <= set(labels)


def test_object_names_are_written_when_asked(hall, ax):
    plot_top_view(ax, hall, show_points=False, show_routes=False, show_legend=False,
                  label_objects=True)  # fmt: skip
    texts = {t.get_text() for t in ax.texts}
    assert {o.name for o in hall.objects} <= texts


def test_footprint_kinds(ax):
    tri = np.array([[[0, 0], [1, 0], [0, 1]], [[1, 0], [1, 1], [0, 1]]], dtype=float)
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    draw_footprints(ax, [
        Footprint(tri, [(1, 0, 0, 1)] * 2, [(0, 0, 0, 1)], 0.5, 1.0),
        Footprint(np.array([[0, 0], [3, 0]], dtype=float), None, "k", 2.2, 1.1),
        Footprint(square, None, "b", 0.8, 1.2, hatch="///"),
        Footprint(square + 5, "g", "0.15", 0.4, 1.3, label="machine"),
    ])  # fmt: skip
    assert len(ax.collections) == 1 and len(ax.collections[0].get_paths()) == 2
    assert len(ax.get_lines()) == 1
    hatched, filled = ax.patches
    assert hatched.get_hatch() == "///" and not hatched.get_fill()
    assert filled.get_fill() and [t.get_text() for t in ax.texts] == ["machine"]
    np.testing.assert_allclose(ax.texts[0].get_position(), (6.0, 6.0))


def test_a_scene_draws_the_faces_seen_from_above_below_the_cut(ax):
    # closed boxes show their top and side faces (10 of 12 triangles); the open ceiling sheet
    # lies above the default cut (90 % of the way from the floor to the top) and is left out
    scene = make_scene([
        ("floor", box((0, 0, -0.2), (10, 8, 0)), "concrete"),
        ("machine", box((2, 2, 0), (4, 3, 1.5)), "metal"),
        ("ceiling", quad((0, 0, 4), (10, 0, 0), (0, 8, 0)), "concrete"),
    ])  # fmt: skip
    view = SceneView.of(scene, None)
    assert view.floor == pytest.approx(0.0) and view.cut == pytest.approx(0.9 * 4)
    assert plot_top_view(ax, scene) == 10 + 10
    assert len(ax.collections) == 2
    # a cut below the machine's base leaves the floor alone; a cut above all draws the sheet too
    fig, ax2 = plt.subplots()
    assert plot_top_view(ax2, SceneView.of(scene, -0.1)) == 10
    assert plot_top_view(ax2, scene, cut_height_m=10.0) == 10 + 10 + 2
    plt.close(fig)
