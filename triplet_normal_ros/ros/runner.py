"""The process around either node (``node`` and ``managed_node``): rclpy without its signal handlers, the executor in
a thread of its own, the worker loop in the main thread, SIGINT/SIGTERM, the watchdog, and the exit code.

The worker serves in the process's main thread, where torch's OpenMP teams run faster (docs/RESULTS.md, "Organized
clouds", the node's overhead). See docs/NODE.md, "Shutdown", for the order of a shutdown and the exit codes.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading
from collections.abc import Callable
from typing import NoReturn, Protocol

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import MultiThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from .serving import JOIN_TIMEOUT_S, describe_error
from .transport import ProfileChoice, choose_profile

#: How long shutdown waits for the executor thread (one spin timeout and its own shutdown, with room to spare).
EXECUTOR_JOIN_S = 2.0
#: The process's exit codes, so that a supervisor can tell them apart: an orderly shutdown (SIGINT, SIGTERM, or a
#: managed node's shutdown transition); a node that could not start (or whose executor failed); a worker still inside
#: an uncancellable step JOIN_TIMEOUT_S after the signal, left behind by the watchdog.
EXIT_OK, EXIT_FAILED, EXIT_ABANDONED = 0, 1, 2


class Served(Protocol):
    """What the process needs of a node besides rclpy's ``Node`` (ros/serving.py's ServingMixin has it)."""

    def serve(self, stop: threading.Event) -> None: ...

    def cancel(self) -> None: ...

    def stop(self, timeout: float = JOIN_TIMEOUT_S) -> bool: ...


def main(make_node: Callable[..., Node], name: str, args: list[str] | None = None) -> NoReturn:
    """A console entry point: run `make_node(serve_in_caller=True)` until a signal (or its own shutdown) and exit
    with `EXIT_OK`, `EXIT_FAILED` or, from the watchdog, `EXIT_ABANDONED`."""
    exit_now(run(make_node, name, args))


def run(make_node: Callable[..., Node], name: str, args: list[str] | None) -> int:
    """Start rclpy and the node, serve in this thread until stopped; the exit code."""
    stop = threading.Event()
    _install_stop_handlers(stop)
    profile = choose_profile()  # before rclpy.init: Fast DDS reads its profile when the participant is created
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # rcl rejects malformed --ros-args with its own exception type
        print(f"[FATAL] [{name}]: cannot start: {error}", file=sys.stderr)
        return EXIT_FAILED
    _log_transport(profile, name)
    node = None
    spinner: threading.Thread | None = None
    failed: list[BaseException] = []
    try:
        node = make_node(serve_in_caller=True)
        _install_stop_handlers(stop, node)
        spinner = threading.Thread(target=_spin, args=(node, stop, failed), name=f"{name}_executor", daemon=True)
        spinner.start()
        node.serve(stop)  # estimates in this, the main, thread until a signal or the node's own shutdown
        _cancel_watchdog()  # the loop has returned: what follows is the orderly shutdown
        stop.set()
        spinner.join(EXECUTOR_JOIN_S)
        return EXIT_FAILED if failed else EXIT_OK
    except (RuntimeError, ValueError, ParameterException) as error:  # a ConfigError, or a QoS override rclpy rejects
        get_logger(name).fatal(f"cannot start: {describe_error(error)}")
        return EXIT_FAILED
    finally:
        stop.set()
        _cancel_watchdog()
        if spinner is not None:
            spinner.join(EXECUTOR_JOIN_S)
        if node is not None:
            _shut_down(node)
        rclpy.try_shutdown()


def _install_stop_handlers(stop: threading.Event, node: Served | None = None) -> None:
    """SIGINT and SIGTERM set ``stop`` and cancel the estimate in flight; the serving loop then ends at its next check,
    and a watchdog leaves without it if it is still inside an uncancellable step after JOIN_TIMEOUT_S.

    Python runs a signal handler in the main thread between bytecodes, which is late when that thread is inside one
    long torch or scipy call; so with a node, the signal also wakes a thread of its own (`signal.set_wakeup_fd`) that
    acts at once."""

    def on_stop() -> None:
        stop.set()
        if node is not None:
            node.cancel()
            _start_watchdog(node)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: on_stop())
    if node is not None:
        receiver, sender = socket.socketpair()
        sender.setblocking(False)
        signal.set_wakeup_fd(sender.fileno(), warn_on_full_buffer=False)
        threading.Thread(target=_wake_on_signal, args=(receiver, on_stop, sender), daemon=True).start()


def _wake_on_signal(receiver: socket.socket, on_stop: Callable[[], None], sender: socket.socket) -> None:
    """Block until a signal's byte arrives on the wakeup socket, then stop (`sender` is kept open as long)."""
    if receiver.recv(1):
        on_stop()


#: The watchdog started by the first stop signal (at most one).
_WATCHDOG: list[threading.Timer] = []
_WATCHDOG_LOCK = threading.Lock()


def _start_watchdog(node: Node) -> None:
    """Start the watchdog once: the signal handler and the wakeup thread may both ask for it."""
    with _WATCHDOG_LOCK:
        if not _WATCHDOG:
            timer = threading.Timer(JOIN_TIMEOUT_S, _abandon, args=(node,))
            timer.daemon = True
            _WATCHDOG.append(timer)
            timer.start()


def _cancel_watchdog() -> None:
    with _WATCHDOG_LOCK:
        for timer in _WATCHDOG:
            timer.cancel()


def _abandon(node: Node) -> NoReturn:
    """The estimate did not reach a cancel check in time: say so and leave without waiting for it, with a code of
    its own, since an estimate was cut off unfinished and nothing else was shut down in order."""
    node.get_logger().error(
        f"worker still busy after {JOIN_TIMEOUT_S} s; exiting {EXIT_ABANDONED} without waiting for it"
    )
    _release_dds(node)
    exit_now(EXIT_ABANDONED)


#: How long the watchdog waits for the node's destruction and rclpy's shutdown before it leaves anyway.
RELEASE_DDS_S = 1.0


def _release_dds(node: Node) -> None:
    """Destroy the node and shut rclpy down, which deletes the DDS participant and with it the participant's
    shared-memory segment in /dev/shm (35 MB under the shipped large-data profile): an exit without it leaves the
    segment behind until ``fastdds shm clean``. The node is destroyed first because the participant goes with the
    context's last node, and Jazzy's rclpy shutdown does not destroy nodes itself. Bounded, in a thread of its own,
    so that a destruction that hangs cannot hold the exit."""

    def release() -> None:
        node.destroy_node()
        rclpy.try_shutdown()

    releasing = threading.Thread(target=release, name="release_dds", daemon=True)
    releasing.start()
    releasing.join(RELEASE_DDS_S)


def _spin(node: Node, stop: threading.Event, failed: list[BaseException]) -> None:
    """The executor's loop (a thread of its own beside the serving main thread). If a callback raises, the node can no
    longer hear anything: the error is logged, kept in `failed`, and the node stops. Its shutdown waits for the
    callbacks in flight, so the answer to a managed node's shutdown transition goes out before the process ends."""
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except Exception as error:
        failed.append(error)
        node.get_logger().fatal(f"the executor failed: {type(error).__name__}: {error}")
    finally:
        stop.set()
        node.cancel()
        executor.shutdown(timeout_sec=0.5)


def _log_transport(profile: ProfileChoice, name: str) -> None:
    """Say which DDS profile carries the clouds: full-size best-effort clouds depend on it (docs/NODE.md, Transport)."""
    line = profile.describe(rclpy.get_rmw_implementation_identifier())
    (get_logger(name).warning if profile.warning else get_logger(name).info)(line)


def _shut_down(node: Node) -> None:
    """Cancel and join the worker, then destroy the node; a worker stuck in an uncancellable step is left behind."""
    if node.stop():
        node.get_logger().info("shut down")
        node.destroy_node()
    else:
        node.get_logger().warning(f"worker still busy after {JOIN_TIMEOUT_S} s; exiting without waiting for it")


def exit_now(code: int) -> NoReturn:
    """Leave without interpreter teardown, everything of ours being released already.

    torch's and the DDS library's static destructors take 1-2 s on a busy 2-core CPU, which alone would break the
    promise to exit within 2 s of SIGINT/SIGTERM; and tearing down under a worker stuck inside torch aborts.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
