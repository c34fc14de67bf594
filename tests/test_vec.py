"""raytrace.core.vec: the component-wise cross product and norm are bitwise numpy's."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.core.vec import cross, norm


@pytest.mark.parametrize("shape", [(3,), (1000, 3), (40, 7, 3)])
def test_cross_and_norm_bitwise_as_numpy(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(14)
    scale = 10.0 ** rng.integers(-9, 9, size=shape[:-1] + (1,))
    a = rng.normal(size=shape) * scale
    b = rng.normal(size=shape)
    a[..., 1][rng.random(shape[:-1]) < 0.2] = -0.0  # signed zeros
    assert np.array_equal(cross(a, b), np.cross(a, b))
    assert np.array_equal(norm(a), np.linalg.norm(a, axis=-1))
    assert np.array_equal(norm(np.asfortranarray(a)), np.linalg.norm(a, axis=-1))
    # broadcasting one vector against many
    assert np.array_equal(
        cross(a, b[..., :1, :] if a.ndim > 1 else b),
        np.cross(a, b[..., :1, :] if a.ndim > 1 else b),
    )


def test_cross_of_parallel_vectors_is_zero() -> None:
    a = np.array([[1.0, 2.0, 3.0]])
    assert np.array_equal(cross(a, 2.0 * a), np.zeros((1, 3)))
    assert norm(np.array([3.0, 4.0, 12.0])) == 13.0
