"""Per-wedge frames (utd.wedge_frames) taken per diffraction give bitwise wedge_geometry."""

from __future__ import annotations

import dataclasses

import numpy as np

from raytrace.physics import utd


def _random_wedges(rng: np.random.Generator, n_wedges: int):
    """Edges along random directions with face normals at random angles (convex and sheets)."""
    e = rng.normal(size=(n_wedges, 3))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    helper = np.cross(e, rng.normal(size=(n_wedges, 3)))
    u = helper / np.linalg.norm(helper, axis=1, keepdims=True)
    v = np.cross(e, u)
    ang = rng.uniform(0.1, np.pi - 0.1, n_wedges)
    n0 = u
    nn = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    sheet = rng.random(n_wedges) < 0.3
    nn[sheet] = -n0[sheet]
    face0 = np.cross(n0, e)  # into face 0 for both kinds
    return e, n0, nn, face0


def test_framed_geometry_and_validity_bitwise_as_wedge_geometry() -> None:
    rng = np.random.default_rng(14)
    e, n0, nn, face0 = _random_wedges(rng, 20)
    frames = utd.wedge_frames(e, n0, nn, face0)
    idx = rng.integers(0, 20, 500)
    start = rng.normal(size=(20, 3))
    src = rng.normal(size=(500, 3)) * 10
    dst = rng.normal(size=(500, 3)) * 10
    kp = utd.keller_points(src, dst, start[idx], start[idx] + 5 * e[idx])
    point = np.where(kp.on_edge[:, None], kp.point, start[idx])
    ref = utd.wedge_geometry(src, dst, point, e[idx], n0[idx], nn[idx], face0[idx])
    got = utd.framed_wedge_geometry(frames.take(idx), src, dst, point)
    for f in dataclasses.fields(ref):
        a, b = getattr(ref, f.name), getattr(got, f.name)
        assert np.array_equal(a, b, equal_nan=True), f.name
    assert 0 < ref.valid.sum() < len(idx)  # both outcomes are exercised
    assert np.array_equal(utd.diffraction_valid(frames.take(idx), src, dst, point), ref.valid)
