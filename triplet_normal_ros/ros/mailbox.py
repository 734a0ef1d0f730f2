"""A one-slot, latest-only mailbox between the subscription callback and the worker loop (the installed node runs it in
the process's main thread).

A depth camera publishes faster than a CPU can estimate normals. A queue would make the node fall further behind and
grow without bound; this slot keeps only the newest cloud, so the worker always processes the freshest data and the
callback never blocks. Replaced items are counted, so the node can report how many clouds it skipped.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Mailbox(Generic[T]):
    """Holds at most one item; ``put`` never blocks and replaces a waiting item; ``get`` blocks until one arrives."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: T | None = None
        self._full = False
        self._closed = False
        self._dropped = 0

    def put(self, item: T) -> bool:
        """Leave ``item`` for the worker; True when it replaced (dropped) an unprocessed one. No-op once closed."""
        with self._cond:
            if self._closed:
                return False
            replaced = self._full
            self._dropped += int(replaced)
            self._item, self._full = item, True
            self._cond.notify()
            return replaced

    def get(self, timeout: float | None = None) -> T | None:
        """The waiting item (emptying the slot), or None after ``timeout`` seconds or once the mailbox is closed."""
        with self._cond:
            self._cond.wait_for(lambda: self._full or self._closed, timeout)
            if not self._full or self._closed:
                return None
            item, self._item, self._full = self._item, None, False
            return item

    def discard(self) -> bool:
        """Empty the slot without handing the item to anyone; True when one was waiting. Not counted in `dropped`
        (replacements only): whoever discards counts it (the managed node, as dropped by its transition)."""
        with self._cond:
            waiting = self._full
            self._item, self._full = None, False
            return waiting

    def close(self) -> None:
        """Wake every waiting ``get`` with None and refuse further items; the waiting item is discarded."""
        with self._cond:
            self._closed = True
            self._item, self._full = None, False
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def dropped(self) -> int:
        """Items replaced before the worker took them, since construction."""
        with self._cond:
            return self._dropped
