"""SIGINT and SIGTERM for the whole life of a node's process, from before its heavy imports to its exit.

A stop sets `Stopper.event`, which the main thread checks between the stages of its start and in its serving loop,
and calls what the runner armed for the phase it is in: `cancel` at once (the estimate in flight), and `late`,
`grace` seconds later from a timer thread, for a main thread that has not finished stopping by then: it may be
inside one compile or torch call that no check interrupts (a start with an empty kernel cache compiles the kernels
for half a minute).

Python runs a signal handler in the main thread between bytecodes, which is late when that thread is inside one long
call; so the handler only sets the event, and the signal also wakes a thread of its own (`signal.set_wakeup_fd`) that
does the rest at once. This module imports the standard library only, so that the entry points (ros/entry.py) can
take the signals before importing rclpy, torch and numba, which takes seconds.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading
from collections.abc import Callable
from typing import NoReturn

#: How long after a stop during the start the main thread has to reach its next check before the timer leaves in its
#: place: long enough for a check that is near, short enough to leave room for releasing DDS within the promised 2 s.
START_GRACE_S = 0.3


def exit_now(code: int) -> NoReturn:
    """Leave without interpreter teardown, everything of ours being released already.

    torch's and the DDS library's static destructors take 1-2 s on a busy 2-core CPU, which alone would break the
    promise to exit within 2 s of SIGINT/SIGTERM; and tearing down under a worker stuck inside torch aborts.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _nothing() -> None:
    """What a stop cancels while nothing is in flight."""


class Stopper:
    """The process's stop: `event`, and what a stop does in the current phase (`arm`). Install it once, from the
    main thread, as early as the process can (`install`)."""

    def __init__(self) -> None:
        self.event = threading.Event()
        #: Set by SIGINT or SIGTERM only, not by a stop the process makes itself (a managed node's shutdown).
        self.signalled = threading.Event()
        self._lock = threading.Lock()
        self._cancel: Callable[[], None] = _nothing
        self._late: tuple[float, Callable[[], object]] | None = None
        self._timer: threading.Timer | None = None
        self._installed = False

    def install(self, name: str) -> Stopper:
        """Take SIGINT and SIGTERM (once; from the main thread). Until the runner arms its own, a stop leaves with
        exit code 0 after START_GRACE_S: before rclpy starts, nothing needs releasing. `name`: the node's, for the
        line that says so."""
        if self._installed:
            return self
        self._installed = True
        self._late = (START_GRACE_S, lambda: _leave_before_rclpy(name))
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)
        receiver, sender = socket.socketpair()
        sender.setblocking(False)
        signal.set_wakeup_fd(sender.fileno(), warn_on_full_buffer=False)
        threading.Thread(target=self._wake, args=(receiver, sender), name="stopper", daemon=True).start()
        return self

    def arm(self, grace: float, late: Callable[[], object], cancel: Callable[[], None] = _nothing) -> None:
        """From now on a stop calls `cancel` at once and `late` after `grace` seconds, unless `disarm` comes first.
        A stop that came already is acted on now, by these."""
        with self._lock:
            self._drop_timer()
            self._late, self._cancel = (grace, late), cancel
        if self.event.is_set():
            self.stop()

    def disarm(self) -> None:
        """The main thread is stopping in order: no late action."""
        with self._lock:
            self._drop_timer()
            self._late = None

    def stop(self) -> None:
        """Stop as a signal does (the wakeup thread calls it; so may code that wants the process to end)."""
        self.event.set()
        with self._lock:
            if self._timer is None and self._late is not None:
                grace, late = self._late
                self._timer = threading.Timer(grace, late)
                self._timer.daemon = True
                self._timer.start()
            cancel = self._cancel
        cancel()

    def _on_signal(self, *_: object) -> None:
        """The handler in the main thread: only events, which cannot deadlock with what it interrupted."""
        self.signalled.set()
        self.event.set()

    def _drop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _wake(self, receiver: socket.socket, sender: socket.socket) -> None:
        """Each signal's byte on the wakeup socket stops at once (`sender` is kept open as long)."""
        while receiver.recv(1):
            self.signalled.set()
            self.stop()


def _leave_before_rclpy(name: str) -> NoReturn:
    """A stop before rclpy started: no participant, no segment; say so in the log's format and leave."""
    print(f"[INFO] [{name}]: stopped while starting", file=sys.stderr)
    exit_now(0)


#: The process's one stopper (signal handlers are per process).
STOPPER = Stopper()
