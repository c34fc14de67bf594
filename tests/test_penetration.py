"""Penetration bookkeeping of segment_crossings against closed-form chords."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import box, make_scene, quad

from raytrace.physics.materials import MaterialLibrary
from raytrace.solver.penetration import segment_crossings

#: Embree hits are float32 (about 1e-7 relative at a few metres); chords are differences of two.
CHORD_TOL_M = 2e-6


def _stack():
    """Three solids stacked on each other (touching faces at z = 1 and z = 2)."""
    return make_scene(
        [
            ("A", box((0, 0, 0), (1, 1, 1)), "wood"),
            ("B", box((0, 0, 1), (1, 1, 2)), "wood"),
            ("C", box((0, 0, 2), (1, 1, 2.5)), "glass"),
        ]
    )


@pytest.mark.parametrize("downward", [True, False])
def test_touching_solids_each_get_their_own_chord(downward):
    """A segment through stacked boxes crosses each one through its full height: the entry into
    the next box through the face it shares with the previous one is not lost."""
    sc = _stack()
    top, bottom = np.array([0.3, 0.4, 3.0]), np.array([0.6, 0.55, -0.3])
    a, b = (top, bottom) if downward else (bottom, top)
    cr = segment_crossings(sc, a[None], b[None], 4)
    assert cr.count[0] == 3 and not cr.exceeded[0]
    objs = cr.object[0, :3]
    np.testing.assert_array_equal(objs, [2, 1, 0] if downward else [0, 1, 2])
    # equivalent slab thickness = chord x cos(incidence) = the box's height
    height = {0: 1.0, 1: 1.0, 2: 0.5}
    np.testing.assert_allclose(cr.thickness[0, :3], [height[o] for o in objs], atol=CHORD_TOL_M)
    # entry points on the entry faces
    z_entry = {0: 1.0, 1: 2.0, 2: 2.5} if downward else {0: 0.0, 1: 1.0, 2: 2.0}
    np.testing.assert_allclose(cr.point[0, :3, 2], [z_entry[o] for o in objs], atol=CHORD_TOL_M)


def test_segment_from_a_face_under_a_solid_crosses_it_from_its_start():
    """A reflection point on a slab's top face, under a box standing on it: the segment leaving
    it upwards crosses the box from its start to the box's top."""
    sc = make_scene(
        [
            ("slab", box((-2, -2, -0.2), (3, 3, 0.0)), "concrete"),
            ("crate", box((0, 0, 0), (1, 1, 0.8)), "wood"),
        ]
    )
    a = np.array([[0.5, 0.5, 0.0]])  # on the slab, under the crate
    b = np.array([[0.9, 0.7, 2.0]])
    cr = segment_crossings(sc, a, b, 2, end_objects=np.array([[0, -1]]))
    assert cr.count[0] == 1 and cr.object[0, 0] == 1
    np.testing.assert_allclose(cr.thickness[0, 0], 0.8, atol=CHORD_TOL_M)


def test_sheet_thickness_and_limit():
    lib = MaterialLibrary.itu()
    sheets = [
        (f"s{i}", quad((float(i), -1.0, -1.0), (0, 2, 0), (0, 0, 2)), "glass") for i in (1, 2, 3)
    ]
    sc = make_scene(sheets, lib)
    a, b = np.array([[0.0, 0.1, 0.2]]), np.array([[4.0, -0.1, 0.1]])
    cr = segment_crossings(sc, a, b, 3)
    assert cr.count[0] == 3 and not cr.exceeded[0]
    np.testing.assert_allclose(cr.thickness[0], lib["glass"].thickness_m)
    # one fewer allowed: the segment is marked as exceeding the limit
    assert segment_crossings(sc, a, b, 2).exceeded[0]


def test_overlapping_solids_split_the_chord():
    """Two interpenetrating boxes: the chord is split where the second one is entered."""
    sc = make_scene(
        [
            ("A", box((0, 0, 0), (2, 1, 1)), "wood"),
            ("B", box((1.5, 0, 0), (3, 1, 1)), "concrete"),
        ]
    )
    a, b = np.array([[-1.0, 0.5, 0.5]]), np.array([[4.0, 0.5, 0.5]])
    cr = segment_crossings(sc, a, b, 3)
    assert cr.count[0] == 2
    np.testing.assert_array_equal(cr.object[0, :2], [0, 1])
    np.testing.assert_allclose(cr.thickness[0, :2], [1.5, 1.5], atol=CHORD_TOL_M)
