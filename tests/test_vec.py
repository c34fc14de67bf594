"""raytrace.core.vec: the component-wise cross product and norm are bitwise numpy's, and so are row
selections (rows, index)."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.core.vec import cross, index, norm, rows


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


@pytest.mark.parametrize("shape", [(0,), (7,), (50, 3), (50, 4, 3), (50, 2)])
def test_rows_equal_numpy_indexing(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=shape)
    n = shape[0]
    for sel in (rng.random(n) < 0.5, np.ones(n, bool), np.zeros(n, bool),
                rng.integers(0, max(n, 1), size=2 * n) if n else np.zeros(0, np.int64)):  # fmt: skip
        got = rows(x, sel)
        want = x[sel]
        assert got.shape == want.shape and got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(index(np.array([True, False, True])), [0, 2])
    np.testing.assert_array_equal(index(np.array([2, 0])), [2, 0])


def test_broadcast_rows_are_numpys_broadcast_flat_writable_and_quiet():
    """Each array broadcast to the common shape, flat, contiguous and writable (what the kernels
    take), equal to np.broadcast_arrays'; an array already of the shape is not copied; and no
    numpy 2 FutureWarning when the kernels ask whether the rows are writable."""
    import warnings

    from raytrace.core.jit import carray
    from raytrace.core.vec import broadcast_rows

    a, b, c = np.asarray(1.5), np.arange(6.0).reshape(2, 3), np.array([[1.0], [2.0]])
    shape, rows = broadcast_rows(a, b, c)
    assert shape == (2, 3)
    for got, want in zip(rows, np.broadcast_arrays(a, b, c), strict=True):
        np.testing.assert_array_equal(got, want.reshape(-1))
        assert got.flags.c_contiguous and got.flags.writeable
    assert np.shares_memory(rows[1], b)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for r in broadcast_rows(np.asarray(2.0), np.array([0.3]))[1]:
            carray(r)
