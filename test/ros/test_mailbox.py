"""The latest-only mailbox: never blocks the producer, never holds more than one item, counts what it drops."""

from __future__ import annotations

import itertools
import threading
import time

from hypothesis import given
from hypothesis import strategies as st

from triplet_normal_ros.ros.mailbox import Mailbox


def test_get_returns_what_was_put() -> None:
    box: Mailbox[int] = Mailbox()
    assert box.put(1) is False
    assert box.get(timeout=0) == 1
    assert box.get(timeout=0) is None
    assert box.dropped == 0


def test_a_newer_item_replaces_the_waiting_one_and_is_counted() -> None:
    box: Mailbox[str] = Mailbox()
    box.put("old")
    assert box.put("new") is True
    assert box.get(timeout=0) == "new"
    assert box.dropped == 1


def test_memory_stays_one_item_however_fast_the_producer() -> None:
    box: Mailbox[bytes] = Mailbox()
    for i in range(10_000):
        box.put(bytes([i % 256]))
    assert box.dropped == 9_999
    assert box.get(timeout=0) == bytes([9_999 % 256])
    assert box.get(timeout=0) is None


def test_get_waits_for_a_put_from_another_thread() -> None:
    box: Mailbox[int] = Mailbox()
    threading.Timer(0.1, box.put, args=(7,)).start()
    start = time.monotonic()
    assert box.get(timeout=5) == 7
    assert 0.05 < time.monotonic() - start < 4


def test_get_times_out_with_none() -> None:
    start = time.monotonic()
    assert Mailbox().get(timeout=0.05) is None
    assert time.monotonic() - start >= 0.04


def test_close_wakes_a_blocked_get_and_refuses_new_items() -> None:
    box: Mailbox[int] = Mailbox()
    box.put(1)
    got: list[int | None] = []
    box.get(timeout=0)  # empty it, so the thread below blocks
    worker = threading.Thread(target=lambda: got.append(box.get()))
    worker.start()
    time.sleep(0.05)
    box.close()
    worker.join(2)
    assert not worker.is_alive() and got == [None]
    assert box.put(2) is False and box.get(timeout=0) is None and box.closed


def test_close_discards_the_waiting_item() -> None:
    box: Mailbox[int] = Mailbox()
    box.put(1)
    box.close()
    assert box.get(timeout=0) is None


def test_a_consumer_never_sees_an_older_item_after_a_newer_one() -> None:
    box: Mailbox[int] = Mailbox()
    n = 20_000
    seen: list[int] = []

    def consume() -> None:
        while (item := box.get()) is not None:
            seen.append(item)

    consumer = threading.Thread(target=consume)
    consumer.start()
    for i in range(n):
        box.put(i)
    drained = 0
    while box.get(timeout=0) is not None:  # the last item may still be waiting; take it here
        drained += 1
    box.close()
    consumer.join(5)
    assert all(a < b for a, b in itertools.pairwise(seen))
    assert len(seen) + drained + box.dropped == n  # every item was either processed or counted as dropped


@given(st.lists(st.one_of(st.integers(), st.none()), max_size=50))
def test_matches_a_one_slot_model(ops: list[int | None]) -> None:
    """Random put (int) / get (None) sequences against the obvious reference implementation."""
    box: Mailbox[int] = Mailbox()
    slot: int | None = None
    dropped = 0
    for op in ops:
        if op is None:
            assert box.get(timeout=0) == slot
            slot = None
        else:
            assert box.put(op) is (slot is not None)
            dropped += slot is not None
            slot = op
    assert box.dropped == dropped
