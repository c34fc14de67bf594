"""A scene's hall facts (raytrace.scene.facts): floor level, hall outline, service area, floor
and ceiling, on small scenes whose answers are known by construction."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box

from raytrace.physics.materials import MaterialLibrary
from raytrace.scene.facts import SceneFacts, floor_level, hall_xy, service_area
from raytrace.scene.io import load_scene
from raytrace.scene.metadata import SceneMetadata
from raytrace.scene.model import Scene

#: Areas of the outlines against the shoelace area of the construction, relative.
AREA_RTOL = 1e-9
#: Heights and corners, m (simplified rings of metre-scale boxes).
LENGTH_TOL_M = 1e-9


def _scene(objects, block=None) -> Scene:
    meta = {"hallray": block} if block is not None else {}
    return Scene.from_meshes(list(objects), MaterialLibrary.itu(), metadata=meta)


def _area(ring) -> float:
    x, y = np.asarray(ring, dtype=float).T
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


@pytest.fixture(scope="module")
def slab_hall() -> Scene:
    """A 10 x 8 m slab with its top at z = 0.5, a full-height wall along y = 0 .. 0.5, a small
    low machine, and a hall size of 10 x 8 x 3 m in its metadata."""
    objects = [
        ("floor", box((0, 0, 0.2), (10, 8, 0.5)), "concrete"),
        ("wall", box((0, 0, 0.5), (10, 0.5, 4.0)), "concrete"),
        ("machine", box((4, 4, 0.5), (5, 5, 1.0)), "metal"),
    ]
    return _scene(objects, {"hall": {"size": [10, 8, 3]}})


def test_floor_level_is_the_lowest_large_upward_face(slab_hall):
    # the slab's top (80 m^2); the wall's top (5 m^2, above) and the machine's (1 m^2, below 5 %
    # of the largest) do not count
    assert floor_level(slab_hall) == pytest.approx(0.5, abs=LENGTH_TOL_M)
    # a wall alone: its top is the only upward face
    wall = _scene([("wall", box((0, 0, 0), (6, 0.2, 3)), "concrete")])
    assert floor_level(wall) == pytest.approx(3.0, abs=LENGTH_TOL_M)


def test_service_area_is_the_floor_inside_the_walls(slab_hall):
    block = SceneMetadata.from_scene(slab_hall).block
    area = service_area(slab_hall, block)
    assert area["source"] == "floor outline of the scene inside its walls"
    assert _area(area["polygon"]) == pytest.approx(10 * 7.5, rel=AREA_RTOL)
    assert min(y for _, y in area["polygon"]) == pytest.approx(0.5, abs=LENGTH_TOL_M)
    assert hall_xy(slab_hall, block) == [[0.0, 0.0], [10.0, 8.0]]


def test_without_a_floor_the_hall_size_then_the_bounds():
    walls = [("wall", box((1, 2, 0), (7, 2.2, 3)), "concrete")]
    sized = _scene(walls, {"hall": {"size": [6, 4]}})  # width and depth are enough here
    area = service_area(sized, SceneMetadata.from_scene(sized).block)
    assert area == {"polygon": [[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]],
                    "source": "hall size"}  # fmt: skip
    assert hall_xy(sized, {"hall": {"size": [6, 4]}}) == [[0.0, 0.0], [6.0, 4.0]]
    bare = _scene(walls)
    assert service_area(bare, {}) is None
    assert hall_xy(bare, {}) == [[1.0, 2.0], [7.0, 2.2]]
    facts = SceneFacts.of(bare)
    assert facts.service_area is None and facts.hall_xy == [[1.0, 2.0], [7.0, 2.2]]
    np.testing.assert_allclose(facts.area_xy, [[1, 2], [7, 2], [7, 2.2], [1, 2.2]],
                               atol=LENGTH_TOL_M)  # fmt: skip


def test_height_range(slab_hall):
    # floor 0.5 m; the top of the scene (4 m) lowered to the floor plus the hall height (3 m)
    floor, top = SceneFacts.of(slab_hall).height_range
    assert (floor, top) == pytest.approx((0.5, 3.5), abs=LENGTH_TOL_M)
    # no floor: open below (the bottom of the scene), even though the wall's top faces up;
    # a hall size without a height leaves the top of the scene
    sized = _scene([("wall", box((0, 0, -1), (6, 0.5, 3)), "concrete")], {"hall": {"size": [6, 4]}})
    assert floor_level(sized) == pytest.approx(3.0, abs=LENGTH_TOL_M)
    assert SceneFacts.of(sized).height_range == pytest.approx((-1.0, 3.0), abs=LENGTH_TOL_M)


def test_facts_of_the_bundled_hall_are_the_functions():
    hall = load_scene("hall")
    block = SceneMetadata.from_scene(hall).block
    facts = SceneFacts.of(hall)
    assert facts.sha256 == hall.content_hash()
    assert facts.service_area == service_area(hall, block)
    assert facts.hall_xy == hall_xy(hall, block)
    assert facts.height_range[0] == floor_level(hall)
    np.testing.assert_array_equal(facts.area_xy, np.asarray(facts.service_area["polygon"]))
