"""The latest-only mailbox: never blocks the producer, never holds more than one item, counts what it drops."""

from __future__ import annotations

import itertools
import sys
import threading
import time

from hypothesis import given
from hypothesis import strategies as st

from triplet_normal_ros.ros import mailbox
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


def _parked_in_get(thread: threading.Thread) -> bool:
    """Whether `thread` is waiting on the mailbox's condition inside ``Mailbox.get`` right now (read off its stack)."""
    frame = sys._current_frames().get(thread.ident)
    waiting = False
    while frame is not None:
        code = frame.f_code
        waiting |= code.co_name == "wait" and code.co_filename == threading.__file__
        if code.co_name == "get" and code.co_filename == mailbox.__file__:
            return waiting
        frame = frame.f_back
    return False


def _blocked_getter(box: Mailbox[int]) -> tuple[threading.Thread, list[int | None]]:
    """A thread calling ``box.get()`` once it is parked in it, and the list that receives what get returns."""
    got: list[int | None] = []
    getter = threading.Thread(target=lambda: got.append(box.get()), daemon=True)
    getter.start()
    deadline = time.monotonic() + 5
    while not _parked_in_get(getter) and getter.is_alive() and time.monotonic() < deadline:
        time.sleep(0.001)  # polling the getter's stack for the state, not waiting for a result
    assert _parked_in_get(getter), f"get on an empty mailbox did not wait (it returned {got})"
    assert got == []
    return getter, got


def test_get_blocks_until_another_thread_puts_and_returns_that_item() -> None:
    box: Mailbox[int] = Mailbox()
    getter, got = _blocked_getter(box)
    box.put(7)
    getter.join(5)
    assert not getter.is_alive() and got == [7]
    assert box.get(timeout=0) is None  # the item was taken, not copied


def test_get_times_out_with_none() -> None:
    start = time.monotonic()
    assert Mailbox().get(timeout=0.05) is None
    assert time.monotonic() - start >= 0.04


def test_close_wakes_a_blocked_get_and_refuses_new_items() -> None:
    box: Mailbox[int] = Mailbox()
    box.put(1)
    box.get(timeout=0)  # empty it, so the thread below blocks
    worker, got = _blocked_getter(box)
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


def test_discard_empties_the_slot_and_says_whether_a_cloud_waited() -> None:
    box: Mailbox[int] = Mailbox()
    assert box.discard() is False
    box.put(1)
    assert box.discard() is True and box.get(timeout=0) is None
    assert box.dropped == 0  # the discarding node counts it, as dropped by its transition
    box.put(2)
    assert box.get(timeout=0) == 2  # still open
