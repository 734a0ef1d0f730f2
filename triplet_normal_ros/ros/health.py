"""The node's health for ``/diagnostics``, without ROS: one statistics :class:`Window` becomes a level, a one-line
message and key/value pairs, the parts of a ``diagnostic_msgs/DiagnosticStatus`` (``ros/diagnostics.py`` builds it).

Kept apart from the message so the rules can be tested on made-up windows. Levels follow diagnostic_updater's
meaning (docs/NODE.md, Diagnostics):

* ERROR: the node produces nothing and will not by itself: the cloud in flight is stuck, or the last
  ``REJECTED_IN_A_ROW_ERROR`` clouds were all rejected (a driver sending a layout the node cannot read).
* WARN: output is lost but the node works: clouds were dropped (input faster than processing) or rejected in the
  window.
* OK otherwise, with a message that tells waiting for the first cloud, an idle input, a long estimate and keeping up
  apart. No input is not a fault of this node (a camera may be triggered on demand); a monitor that expects a rate
  should watch ``input rate (Hz)``.

There is no latency threshold: the node has no target to hold it to, and a node too slow for its input shows up as
drops, which is a WARN.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from .params import NodeSettings
from .stats import Window

#: diagnostic_msgs/DiagnosticStatus levels.
OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}
#: Rejections in a row, none processed in between, that mean the input itself is unusable.
REJECTED_IN_A_ROW_ERROR = 3
#: A cloud in flight longer than this many times the slowest cloud finished so far is taken to be stuck...
STUCK_FACTOR = 10.0
#: ...but never before this many seconds: a first full frame of ``learned`` on a CPU takes about two minutes.
STUCK_MIN_S = 300.0
#: What a value reads when there is nothing to measure (no cloud processed in the window, none in flight).
NOT_AVAILABLE = "n/a"

KeyValues = tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class Health:
    """What one DiagnosticStatus says: level (OK/WARN/ERROR), a one-line message, and (key, value) strings."""

    level: int
    message: str
    values: KeyValues


def assess(window: Window, settings: Sequence[tuple[str, str]] = ()) -> Health:
    """Level and message by the rules above; the window's figures, then ``settings`` (what the node runs with)."""
    level, message = summary(window)
    return Health(level, message, (*stat_values(window), *settings))


def summary(window: Window) -> tuple[int, str]:
    """The highest level found, with its findings joined by '; ' (diagnostic_updater's mergeSummary)."""
    findings = problems(window)
    if not findings:
        return OK, ok_message(window)
    level = max(found for found, _ in findings)
    return level, "; ".join(message for found, message in findings if found == level)


def stuck_after_s(window: Window) -> float:
    """Seconds in flight after which a cloud counts as stuck, scaled by the slowest cloud finished so far."""
    return max(STUCK_MIN_S, STUCK_FACTOR * window.total.max_ms / 1e3)


def problems(window: Window) -> list[tuple[int, str]]:
    """Every WARN or ERROR finding of the window, in a fixed order."""
    w, period = window.window, f"{window.period_s:g} s"
    found = []
    if window.in_flight_s is not None and window.in_flight_s > stuck_after_s(window):
        found.append((ERROR, f"stuck: one cloud in flight for {window.in_flight_s:.0f} s"))
    if window.rejected_in_a_row >= REJECTED_IN_A_ROW_ERROR:
        found.append((ERROR, f"the last {window.rejected_in_a_row} clouds were all rejected"))
    elif w.rejected:
        found.append((WARN, f"{w.rejected} rejected in the last {period}"))
    outrun = window.dropped - w.stopped  # a transition's drops are the operator's doing, no fault
    if outrun:
        found.append((WARN, f"{outrun} dropped in the last {period}: input faster than processing"))
    return found


def ok_message(window: Window) -> str:
    """Tell apart: never had input, no input lately, busy on a long cloud, keeping up."""
    if window.total.arrived == 0 and window.idle:
        return "waiting for input"
    if window.idle:
        return f"no input in the last {window.period_s:g} s"
    if window.in_flight_s is not None and window.window.processed == 0:
        return f"busy: one cloud in flight for {window.in_flight_s:.1f} s"
    return "keeping up"


def stat_values(window: Window) -> KeyValues:
    """The window's figures (rates over the measured window), then the running totals."""
    w, t = window.window, window.total
    return (
        ("input rate (Hz)", f"{window.rate(w.arrived):.3g}"),
        ("output rate (Hz)", f"{window.rate(w.processed):.3g}"),
        ("mean processing time (ms)", _ms(w.mean_ms)),
        ("max processing time (ms)", _ms(w.max_ms if w.processed else None)),
        ("arrived", str(w.arrived)),
        ("processed", str(w.processed)),
        ("dropped", str(window.dropped)),
        ("rejected", str(w.rejected)),
        ("in flight", "0" if window.in_flight_s is None else "1"),
        ("in flight for (s)", NOT_AVAILABLE if window.in_flight_s is None else f"{window.in_flight_s:.1f}"),
        ("rejected in a row", str(window.rejected_in_a_row)),
        ("last rejection", window.last_rejection or NOT_AVAILABLE),
        ("window (s)", f"{window.elapsed_s:.3g}"),
        ("total arrived", str(t.arrived)),
        ("total processed", str(t.processed)),
        ("total dropped", str(window.dropped_total)),
        ("total dropped by deactivate or cleanup", str(t.stopped)),
        ("total rejected", str(t.rejected)),
    )


def settings_values(settings: NodeSettings, device: str, k: int | str, topics: tuple[str, str]) -> KeyValues:
    """What the node runs with: estimator settings, the device in use, the k in force, the resolved topics."""
    return (
        ("method", settings.method),
        ("checkpoint", NOT_AVAILABLE if settings.method == "pca" else settings.checkpoint_in_force()),
        ("device", device),
        ("radius (m)", f"{settings.radius:g}"),
        ("k", str(k)),
        ("neighbours", settings.neighbours),
        ("input topic", topics[0]),
        ("output topic", topics[1]),
    )


def _ms(value: float | None) -> str:
    return NOT_AVAILABLE if value is None else f"{value:.1f}"
