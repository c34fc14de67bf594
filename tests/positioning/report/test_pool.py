"""positioning.report.pool: which datasets go to which worker."""

from __future__ import annotations

import pytest

from positioning.report.pool import groups_by_map


def _twin(path: str) -> dict:
    return {"twin": {"map": path}}


def test_groups_by_map_keeps_a_bands_datasets_together_in_order():
    params = [_twin("c.npz"), _twin("mm.npz"), _twin("c.npz"), _twin("mm.npz")]
    assert groups_by_map(params, 2) == [[0, 2], [1, 3]]
    # more maps than workers: still one group per map (the groups queue for the workers)
    params3 = [*params, _twin("x.npz")]
    assert groups_by_map(params3, 2) == [[0, 2], [1, 3], [4]]


@pytest.mark.parametrize(
    ("n", "workers", "expected"),
    [
        (4, 2, [[0, 2], [1, 3]]),
        (3, 2, [[0, 2], [1]]),
        (1, 2, [[0]]),
        (2, 5, [[0], [1]]),
    ],
)
def test_groups_without_maps_round_robin(n, workers, expected):
    groups = groups_by_map([{}] * n, workers)
    assert groups == expected
    assert sorted(i for g in groups for i in g) == list(range(n))


def test_fewer_maps_than_workers_round_robin():
    params = [_twin("c.npz")] * 3
    assert groups_by_map(params, 2) == [[0, 2], [1]]
