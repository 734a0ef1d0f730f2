"""Processing statistics the node logs every ``stats_period`` seconds: throughput, latency, drops and rejections.

Counts are windowed (since the last report) with running totals, because an operator watching the log wants to know
whether the node keeps up *now*, and how much it has skipped overall.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass


@dataclass
class _Counts:
    processed: int = 0
    total_ms: float = 0.0
    max_ms: float = 0.0
    rejected: int = 0


class ProcessingStats:
    """Thread-safe: the worker records, the stats timer reports."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._window = _Counts()
        self._total = _Counts()
        self._dropped_at_report = 0

    def record(self, ms: float) -> None:
        """One cloud processed and published in ``ms`` milliseconds."""
        with self._lock:
            for c in (self._window, self._total):
                c.processed += 1
                c.total_ms += ms
                c.max_ms = max(c.max_ms, ms)

    def reject(self) -> None:
        """One malformed cloud skipped."""
        with self._lock:
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
        total = f"total: {t.processed} clouds, {dropped_total} dropped, {t.rejected} rejected"
        if w.processed == 0 and dropped == 0 and w.rejected == 0:
            return f"last {period_s:g} s: no input clouds | {total}"
        mean = w.total_ms / w.processed if w.processed else 0.0
        return (
            f"last {period_s:g} s: {w.processed} clouds, mean {mean:.1f} ms, max {w.max_ms:.1f} ms, "
            f"{dropped} dropped, {w.rejected} rejected | {total}"
        )
