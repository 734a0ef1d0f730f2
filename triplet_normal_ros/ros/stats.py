"""Processing statistics the node reports every ``stats_period`` seconds: arrivals, throughput, latency, drops,
rejections and the cloud in flight.

Counts are windowed (since the last report) with running totals, because an operator watching the log wants to know
whether the node keeps up *now*, and how much it has skipped overall. Arrivals and the cloud in flight are counted
too: a node busy on a slow frame must not look like a node that receives nothing (which sends users debugging QoS).
One :class:`Window` per report feeds both the log line and ``/diagnostics`` (``ros/health.py``), so the two never
disagree.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace


@dataclass
class Counts:
    """Cloud counts and processing times (milliseconds) over some stretch of time."""

    processed: int = 0
    total_ms: float = 0.0
    max_ms: float = 0.0
    rejected: int = 0
    arrived: int = 0
    stopped: int = 0  # dropped by a managed node's transition (deactivate, cleanup): taken or waiting, never answered

    @property
    def mean_ms(self) -> float | None:
        """Mean processing time, None when nothing was processed (0 ms would read as "instant")."""
        return self.total_ms / self.processed if self.processed else None


@dataclass(frozen=True)
class Window:
    """One report: the window just closed, the running totals, and what is going on right now."""

    period_s: float  # the configured stats period (what the log line names)
    elapsed_s: float  # measured since the previous report (what the rates divide by: timers run late under load)
    window: Counts
    total: Counts
    dropped: int  # replaced in the mailbox, and `window.stopped`
    dropped_total: int
    in_flight_s: float | None = None  # seconds the worker has spent on its current cloud, None when idle
    rejected_in_a_row: int = 0  # rejections since the last cloud that was processed
    last_rejection: str = ""  # why the latest rejected cloud was rejected

    @property
    def idle(self) -> bool:
        """Nothing arrived, finished or failed in the window and nothing is in flight."""
        w = self.window
        return w.arrived == 0 and w.processed == 0 and w.rejected == 0 and self.in_flight_s is None

    def rate(self, count: int) -> float:
        """``count`` events over the measured window, per second."""
        return count / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def line(self) -> str:
        """The one-line log summary."""
        w, t = self.window, self.total
        total = f"total: {t.arrived} arrived, {t.processed} clouds, {self.dropped_total} dropped, {t.rejected} rejected"
        if self.idle:
            return f"last {self.period_s:g} s: no input clouds | {total}"
        flight = "" if self.in_flight_s is None else f", 1 in flight for {self.in_flight_s:.1f} s"
        timing = f", mean {w.mean_ms:.1f} ms, max {w.max_ms:.1f} ms" if w.processed else ""
        return (
            f"last {self.period_s:g} s: {w.arrived} arrived, {w.processed} clouds{timing}, {self.dropped} dropped, "
            f"{w.rejected} rejected{flight} | {total}"
        )


class ProcessingStats:
    """Thread-safe: the subscription counts arrivals, the worker records, the stats timer reports."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._clock = clock
        self._window = Counts()
        self._total = Counts()
        self._window_start = clock()
        self._dropped_at_report = 0
        self._in_flight_since: float | None = None
        self._rejected_in_a_row = 0
        self._last_rejection = ""

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
            self._rejected_in_a_row = 0
            for c in (self._window, self._total):
                c.processed += 1
                c.total_ms += ms
                c.max_ms = max(c.max_ms, ms)

    def reject(self, reason: str = "") -> None:
        """One malformed cloud skipped (or a cloud that failed), and why: nothing is in flight any more."""
        with self._lock:
            self._in_flight_since = None
            self._rejected_in_a_row += 1
            self._last_rejection = reason or self._last_rejection
            self._window.rejected += 1
            self._total.rejected += 1

    def drop(self) -> None:
        """One cloud a transition stopped (a managed node's deactivate or cleanup): the one waiting, or the one in
        flight whose answer can no longer be sent. Counted as dropped, apart from the input outrunning the node."""
        with self._lock:
            self._in_flight_since = None
            self._window.stopped += 1
            self._total.stopped += 1

    @property
    def processed(self) -> int:
        with self._lock:
            return self._total.processed

    def window(self, period_s: float, dropped_total: int) -> Window:
        """Close the window since the last report and start a new one; ``dropped_total`` is the mailbox's count, to
        which the clouds a transition dropped are added."""
        with self._lock:
            now = self._clock()
            closed = Window(
                period_s=period_s,
                elapsed_s=now - self._window_start,
                window=self._window,
                total=replace(self._total),
                dropped=dropped_total - self._dropped_at_report + self._window.stopped,
                dropped_total=dropped_total + self._total.stopped,
                in_flight_s=None if self._in_flight_since is None else now - self._in_flight_since,
                rejected_in_a_row=self._rejected_in_a_row,
                last_rejection=self._last_rejection,
            )
            self._window, self._window_start, self._dropped_at_report = Counts(), now, dropped_total
        return closed
