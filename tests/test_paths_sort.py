"""Paths.sorted: the canonical order is one lexsort by link, delay, kinds, objects, elements."""

from __future__ import annotations

import numpy as np

from raytrace.solver.paths import Paths


def _random_paths(
    rng: np.random.Generator, n: int, depth: int, tied: bool, n_links: int = 4
) -> Paths:
    # tied: few distinct delays (and signed zeros), so many paths of a link share one
    delay = rng.choice([1e-8, 2e-8, -0.0, 0.0, 3e-8, np.nan], n) if tied else rng.random(n)
    return Paths(
        tx=np.zeros((1, 3)),
        rx=np.ones((4, 3)),
        frequency_hz=1e9,
        link=rng.integers(0, n_links, n),
        tx_index=np.zeros(n, np.int64),
        rx_index=np.zeros(n, np.int64),
        delay_s=delay,
        gain=rng.normal(size=n) + 0j,  # distinct: identifies each path
        n_reflections=np.zeros(n, np.int16),
        n_penetrations=np.zeros(n, np.int16),
        n_diffractions=np.zeros(n, np.int16),
        interaction=rng.integers(0, 3, (n, depth)).astype(np.int8),
        points=rng.normal(size=(n, depth, 3)),
        objects=rng.integers(-1, 3, (n, depth)),
        elements=rng.integers(-1, 3, (n, depth)),
    )


def test_sorted_is_the_full_lexsort() -> None:
    rng = np.random.default_rng(14)
    for trial in range(210):
        # a few large sets too: the delay sort is not stable there (and need not be); and link
        # indices beyond 16 bits (sorted otherwise than the radix sort of 16-bit keys)
        n = int(rng.integers(0, 60)) if trial < 200 else int(rng.integers(5_000, 20_000))
        n_links = 4 if trial < 206 else [65_536, 65_537, 200_000, 2][trial - 206]
        depth = int(rng.integers(1, 4))
        p = _random_paths(rng, n, depth, tied=bool(trial % 2), n_links=n_links)
        cols = range(depth - 1, -1, -1)
        keys = [p.elements[:, i] for i in cols] + [p.objects[:, i] for i in cols]
        keys += [p.interaction[:, i].astype(np.int64) for i in cols]
        ref = np.lexsort((*keys, p.delay_s, p.link))
        assert np.array_equal(p.sorted().gain, p.gain[ref]), trial
