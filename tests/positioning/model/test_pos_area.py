"""The service area: containment, projection and grid of a convex and an L-shaped polygon
(closed forms), and the area a dataset's meta gives (positioning.model.area)."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import PositioningError
from positioning.model.area import ServiceArea, area_from_meta

BOX = ServiceArea.box((0.0, 0.0), (30.0, 26.0))


#: An L-shaped hall: the square (12, 12)-(30, 26) is not floor.
L_SHAPE = ServiceArea(
    np.array([[0, 0], [30, 0], [30, 12], [12, 12], [12, 26], [0, 26]], dtype=float), "L"
)


def test_contains_and_project_closed_forms():
    pts = np.array([[5, 5], [20, 20], [12, 12], [31, 5], [-1, -1], [20, 13], [np.nan, 1.0]])
    assert L_SHAPE.contains(pts).tolist() == [True, False, True, False, False, False, False]
    assert BOX.contains(pts).tolist() == [True, True, True, False, False, True, False]
    proj = L_SHAPE.project(np.array([[20.0, 20.0], [-3.0, 5.0], [35.0, -4.0], [5.0, 5.0]]))
    # (20, 20) is nearest to the inner edge x = 12 (8 m) and y = 12 (8 m): a tie, either is right
    assert np.min(np.abs(proj[0] - [[12.0, 20.0], [20.0, 12.0]]).sum(axis=1)) < 1e-12
    np.testing.assert_allclose(proj[1:], [[0.0, 5.0], [30.0, 0.0], [5.0, 5.0]], atol=1e-12)
    assert L_SHAPE.contains(proj).all()
    g = L_SHAPE.grid(1.0)
    assert g.shape[0] == 30 * 12 + 12 * 14  # unit cells of the L: 360 + 168


def test_area_from_meta_fallbacks():
    poly = [[0, 0], [10, 0], [10, 5], [0, 5]]
    a = area_from_meta(
        {"service_area": {"polygon": poly, "source": "scene"}, "hall_xy": [[0, 0], [1, 1]]}
    )
    assert a is not None and a.source == "scene" and a.polygon.shape == (4, 2)
    b = area_from_meta({"hall_xy": [[0, 0], [42, 46]]})
    assert b is not None and b.contains(np.array([[41.9, 45.9]])).all()
    assert area_from_meta({}) is None
    for bad in ({"service_area": {"polygon": [[0, 0], [1, 1]]}}, {"hall_xy": [[0, 0]]}):
        with pytest.raises(PositioningError):
            area_from_meta(bad)


def test_project_is_the_point_inside_and_the_nearest_outline_point_outside_bit_for_bit():
    """project() measures the outline distances once: the same bits as contains() and
    nearest_on_outline() called separately, for points inside, outside, on the outline and
    not finite."""
    area = ServiceArea(np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 12.0], [18.0, 25.0],
                                 [0.0, 25.0]]))  # fmt: skip
    rng = np.random.default_rng(4)
    xy = rng.uniform(-5.0, 35.0, (5000, 2))
    xy[:10] = area.polygon[rng.integers(0, 5, 10)] + rng.normal(0.0, 1e-8, (10, 2))
    xy[10, 0] = np.nan
    xy[11] = np.inf
    inside = area.contains(xy)
    foot, _ = area.nearest_on_outline(np.where(np.isfinite(xy), xy, 0.0))
    want = np.where(inside[:, None], xy, foot)
    got = area.project(xy)
    np.testing.assert_array_equal(got, want)
    assert inside.any() and (~inside).any() and not inside[10:12].any()
