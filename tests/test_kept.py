"""raytrace.core.kept: a bounded first-in-first-out store shared by threads."""

from __future__ import annotations

import threading

from raytrace.core.kept import keep


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
