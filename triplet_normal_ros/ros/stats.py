"""Processing statistics the node logs every ``stats_period`` seconds: arrivals, throughput, latency, drops,
rejections and the cloud in flight.

Counts are windowed (since the last report) with running totals, because an operator watching the log wants to know
whether the node keeps up *now*, and how much it has skipped overall. Arrivals and the cloud in flight are counted
too: a node busy on a slow frame must not look like a node that receives nothing (which sends users debugging QoS).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass
class _Counts:
    processed: int = 0
    total_ms: float = 0.0
    max_ms: float = 0.0
    rejected: int = 0
    arrived: int = 0


class ProcessingStats:
    """Thread-safe: the subscription counts arrivals, the worker records, the stats timer reports."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._clock = clock
        self._window = _Counts()
        self._total = _Counts()
        self._dropped_at_report = 0
        self._in_flight_since: float | None = None

    def arrive(self) -> bool:
        """One cloud received; True for the very first (the node logs that one)."""
        with self._lock:
            self._window.arrived += 1
            self._total.arrived += 1
            return self._total.arrived == 1

    def start(self) -> None:
        """The worker took a cloud and is working on it."""
        with self._lock:
            self._in_flight_since = self._clock()

    def record(self, ms: float) -> None:
        """One cloud processed and published in ``ms`` milliseconds."""
        with self._lock:
            self._in_flight_since = None
            for c in (self._window, self._total):
                c.processed += 1
                c.total_ms += ms
                c.max_ms = max(c.max_ms, ms)

    def reject(self) -> None:
        """One malformed cloud skipped (or a cloud that failed): nothing is in flight any more."""
        with self._lock:
            self._in_flight_since = None
            self._window.rejected += 1
            self._total.rejected += 1

    @property
    def processed(self) -> int:
        with self._lock:
            return self._total.processed

    def report(self, period_s: float, dropped_total: int) -> str:
        """A one-line summary of the window since the last report, which it then resets."""
        with self._lock:
            w, t = self._window, self._total
            dropped = dropped_total - self._dropped_at_report
            self._dropped_at_report = dropped_total
            self._window = _Counts()
            busy = None if self._in_flight_since is None else self._clock() - self._in_flight_since
        total = f"total: {t.arrived} arrived, {t.processed} clouds, {dropped_total} dropped, {t.rejected} rejected"
        flight = "" if busy is None else f", 1 in flight for {busy:.1f} s"
        if w.arrived == 0 and w.processed == 0 and w.rejected == 0 and busy is None:
            return f"last {period_s:g} s: no input clouds | {total}"
        mean = w.total_ms / w.processed if w.processed else 0.0
        timing = f", mean {mean:.1f} ms, max {w.max_ms:.1f} ms" if w.processed else ""
        return (
            f"last {period_s:g} s: {w.arrived} arrived, {w.processed} clouds{timing}, {dropped} dropped, "
            f"{w.rejected} rejected{flight} | {total}"
        )
