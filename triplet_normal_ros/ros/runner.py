"""The process around either node (``node`` and ``managed_node``): rclpy without its signal handlers, the node's
start, the executor in a thread of its own, the worker loop in the main thread, SIGINT/SIGTERM, the watchdog, and the
exit code.

The stop signals belong to `stopper.STOPPER` from before rclpy starts (from before the node's imports, through
ros/entry.py). A stop while the node starts (with an empty kernel cache it compiles the kernels for half a minute)
ends the process with exit code 0 within 2 s: the node is built without starting, its `start` checks the stop
between stages, and a main thread inside one long compile is left behind by the stopper's timer; either way the node
and rclpy are shut down first, which removes the DDS shared-memory segment. The worker serves in the process's main
thread, where torch's OpenMP teams run faster (docs/HISTORY.md, "Organized clouds", the node's overhead). See
docs/NODE.md, "Shutdown", for the order of a shutdown and the exit codes.
"""

from __future__ import annotations

import inspect
import sys
import threading
from collections.abc import Callable
from functools import partial
from typing import NoReturn, Protocol

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import MultiThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..errors import EstimationCancelled
from .serving import JOIN_TIMEOUT_S, describe_error
from .stopper import START_GRACE_S, STOPPER, Stopper, exit_now
from .transport import ProfileChoice, choose_profile

#: How long shutdown waits for the executor thread (one spin timeout and its own shutdown, with room to spare).
EXECUTOR_JOIN_S = 2.0
#: The process's exit codes, so that a supervisor can tell them apart: an orderly shutdown (SIGINT, SIGTERM, or a
#: managed node's shutdown transition), a stop during the start included; a node that could not start (or whose
#: executor failed); a worker still inside an uncancellable step JOIN_TIMEOUT_S after the signal, left behind by the
#: watchdog.
EXIT_OK, EXIT_FAILED, EXIT_ABANDONED = 0, 1, 2
#: How long a stop during the start waits for a node still being constructed (participant, parameter services), so
#: that its participant is destroyed too rather than left with its segment.
MAKE_WAIT_S = 0.5
#: How to tell rclpy's MultiThreadedExecutor.shutdown not to wait for its callbacks in flight: Kilted's rclpy 9 waits
#: unless told; Jazzy's rclpy 7 has no such argument, and its multi-threaded executor does not wait for them anyway.
_SHUTDOWN_NO_WAIT = (
    {"wait_for_threads": False}
    if "wait_for_threads" in inspect.signature(MultiThreadedExecutor.shutdown).parameters
    else {}
)


class Served(Protocol):
    """What the process needs of a node besides rclpy's ``Node`` (ros/serving.py's ServingMixin has it)."""

    def start(self, stop: threading.Event) -> None: ...

    def serve(self, stop: threading.Event) -> None: ...

    def cancel(self) -> None: ...

    def stop(self, timeout: float = JOIN_TIMEOUT_S) -> bool: ...


def main(make_node: Callable[..., Node], name: str, args: list[str] | None = None) -> NoReturn:
    """A console entry point: run `make_node(serve_in_caller=True, start=False)`, start it, serve until a signal (or
    its own shutdown) and exit with `EXIT_OK`, `EXIT_FAILED` or, from the watchdog, `EXIT_ABANDONED`."""
    exit_now(run(make_node, name, args))


def run(make_node: Callable[..., Node], name: str, args: list[str] | None) -> int:
    """Start rclpy and the node, serve in this thread until stopped; the exit code (or the process ends here, with
    code 0, when a stop comes before the node serves)."""
    stopper = STOPPER.install(name)
    profile = choose_profile()  # before rclpy.init: Fast DDS reads its profile when the participant is created
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # rcl rejects malformed --ros-args with its own exception type
        print(f"[FATAL] [{name}]: cannot start: {error}", file=sys.stderr)
        return EXIT_FAILED
    starting = Starting(name)
    stopper.arm(START_GRACE_S, starting.leave)
    _log_transport(profile, name)
    node = None
    try:
        node = starting.make(make_node)
        node.start(stopper.event)  # the warm-up: EstimationCancelled when a stop comes
        if stopper.event.is_set():
            starting.leave()
        guard_serving(stopper, node)
        return _serve(node, stopper, name)
    except EstimationCancelled:
        starting.leave()
    except (RuntimeError, ValueError, ParameterException) as error:  # a ConfigError, or a QoS override rclpy rejects
        if stopper.event.is_set():  # a stop in the middle of a stage may surface as that stage's error
            starting.leave()
        get_logger(name).fatal(f"cannot start: {describe_error(error)}")
        return EXIT_FAILED
    finally:
        stopper.disarm()
        if node is not None:
            _shut_down(node)
        rclpy.try_shutdown()


def _serve(node: Served, stopper: Stopper, name: str) -> int:
    """Serve in this, the main, thread until a signal or the node's own shutdown, with the executor in another."""
    failed: list[BaseException] = []
    spinner = threading.Thread(target=_spin, args=(node, stopper, failed), name=f"{name}_executor", daemon=True)
    spinner.start()
    try:
        node.serve(stopper.event)
    finally:
        stopper.disarm()  # the loop has returned: what follows is the orderly shutdown
        stopper.event.set()
        spinner.join(EXECUTOR_JOIN_S)
    return EXIT_FAILED if failed else EXIT_OK


def guard_serving(stopper: Stopper, node: Served) -> None:
    """While `node` serves, a stop cancels the estimate in flight at once, and the watchdog leaves without the worker
    if it is still inside an uncancellable step JOIN_TIMEOUT_S later."""
    stopper.arm(JOIN_TIMEOUT_S, partial(_abandon, node), node.cancel)


class Starting:
    """The node being started, and the way out for a stop before it serves: from the main thread at a check, or from
    the stopper's timer while the main thread is still inside a stage. Whichever comes first leaves; the other waits
    for the exit."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.node: Node | None = None
        self._making = threading.Event()
        self._made = threading.Event()
        self._leaving = threading.Lock()

    def make(self, make_node: Callable[..., Node]) -> Node:
        """The node, constructed without starting (cheap: its participant, parameters and services)."""
        self._making.set()
        try:
            self.node = make_node(serve_in_caller=True, start=False)
            return self.node
        finally:
            self._made.set()

    def leave(self) -> NoReturn:
        """Say so, destroy the node and shut rclpy down (which removes the participant's shared memory), exit 0."""
        with self._leaving:
            if self._making.is_set():
                self._made.wait(MAKE_WAIT_S)
            get_logger(self.name).info("stopped while starting")
            if self.node is not None:
                _release_dds(self.node)
            else:
                rclpy.try_shutdown()
            exit_now(EXIT_OK)


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


def _spin(node: Node, stopper: Stopper, failed: list[BaseException]) -> None:
    """The executor's loop (a thread of its own beside the serving main thread). If a callback raises, the node can no
    longer hear anything: the error is logged, kept in `failed`, and the node stops. Its shutdown waits for the
    callbacks in flight, so the answer to a managed node's shutdown transition goes out before the process ends;
    after a signal, where rclpy allows, it does not: no one waits for an answer then, and a callback in flight (a
    configure compiling the kernels) would hold the exit for its whole length."""
    stop = stopper.event
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
        executor.shutdown(timeout_sec=0.5, **(_SHUTDOWN_NO_WAIT if stopper.signalled.is_set() else {}))


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
