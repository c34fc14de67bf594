"""raytrace.core.kept: a first-in-first-out store shared by threads, bounded in entries and
bytes."""

from __future__ import annotations

import threading

import numpy as np

from raytrace.core.kept import keep, nbytes


def test_oldest_entries_go_first_and_a_key_is_kept_once():
    store: dict = {}
    for i in range(5):
        assert keep(store, i, i * 10, limit=3) == i * 10
    assert list(store) == [2, 3, 4]
    keep(store, 3, 33, limit=3)  # re-kept: now the newest
    assert list(store) == [2, 4, 3] and store[3] == 33
    keep(store, 9, 90, limit=3)
    assert list(store) == [4, 3, 9]


def test_threads_keeping_into_one_store_never_fail_nor_overfill():
    store: dict = {}
    errors = []

    def work(seed: int) -> None:
        try:
            for i in range(2000):
                keep(store, (seed, i % 37), i, limit=16)
                assert len(store) <= 16
        except Exception as exc:  # noqa: BLE001 (reported below)
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(s,)) for s in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(store) <= 16


def test_nbytes_counts_arrays_once_through_views_and_nesting():
    a = np.zeros(100)  # 800 bytes
    b = np.zeros((10, 3), np.int8)  # 30 bytes
    assert nbytes(a) == 800
    assert nbytes((a, a[:10], a.reshape(10, 10).T, [b, {"x": b[1:]}], 7, "s")) == 830


def test_a_byte_bound_drops_the_oldest_and_refuses_what_cannot_fit():
    store: dict = {}
    mb = lambda: np.zeros(1 << 17)  # noqa: E731 (1 MiB)
    for i in range(3):
        keep(store, i, (mb(),), limit=16, max_bytes=(5 << 20) // 2)  # 2.5 MiB
    assert list(store) == [1, 2]  # two fit: the oldest went
    big = (mb(), mb(), mb())
    assert keep(store, "big", big, limit=16, max_bytes=(5 << 20) // 2) is big
    assert "big" not in store and list(store) == [1, 2]  # too large alone: not kept, none dropped
    keep(store, 1, (np.zeros(8),), limit=16, max_bytes=1 << 20)
    assert list(store) == [1]  # re-kept under a tighter bound: the old entry made room
