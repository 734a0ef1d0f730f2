"""The ROS 2 node ``triplet_normal``: PointCloud2 in, the same cloud plus normals and curvature out.

A thin wrapper around :class:`NormalEstimator`. The subscription callback only drops the message into a latest-only
:class:`Mailbox`; one worker loop takes the newest cloud, answers it (`pipeline.messages.answer_message`) and
publishes, so a slow estimator skips clouds instead of queueing them. The installed node runs that loop in the
process's main thread and spins the executor in another. See docs/NODE.md for threading, reloads, errors and shutdown.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading
import time
from typing import Any, NoReturn

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.executors import MultiThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2

from ..core import throughput
from ..core.estimator import NormalEstimator
from ..errors import CheckpointError, CloudFormatError, EstimationCancelled, EstimatorError
from ..pipeline.messages import answer_message
from . import diagnostics
from .health import assess, settings_values
from .mailbox import Mailbox
from .params import K_METHOD_DEFAULT, SPECS, NodeSettings, ParamSpec, apply, needs_reload, validate_all
from .stats import ProcessingStats
from .transport import ProfileChoice, choose_profile

NODE_NAME = "triplet_normal"
#: Output history: reliable, but shallow, so a slow subscriber cannot make the node hoard clouds.
OUTPUT_DEPTH = 2
#: Seconds between repeats of the same error or warning in the log.
THROTTLE_S = 5.0
#: How long shutdown waits for the worker; the estimator checks its cancel event between batches.
JOIN_TIMEOUT_S = 1.5
#: How often the worker loop in the main thread looks at the stop event while no cloud waits.
SERVE_POLL_S = 0.1
#: How long shutdown waits for the executor thread (one spin timeout and its own shutdown, with room to spare).
EXECUTOR_JOIN_S = 2.0
#: The process's exit codes, so that a supervisor can tell them apart: an orderly shutdown after SIGINT or SIGTERM; a
#: node that could not start (or whose executor failed); a worker still inside an uncancellable step JOIN_TIMEOUT_S
#: after the signal, left behind by the watchdog.
EXIT_OK, EXIT_FAILED, EXIT_ABANDONED = 0, 1, 2

_PARAM_TYPES = {
    str: Parameter.Type.STRING,
    int: Parameter.Type.INTEGER,
    float: Parameter.Type.DOUBLE,
    bool: Parameter.Type.BOOL,
    list: Parameter.Type.DOUBLE_ARRAY,
}


class StartupError(RuntimeError):
    """The node cannot start (bad parameter, missing or corrupt checkpoint); main() prints it and exits 1."""


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    d = ParameterDescriptor(
        name=spec.name,
        type=_PARAM_TYPES[spec.kind].value,
        description=spec.description,
        additional_constraints=spec.constraints,
        read_only=spec.read_only,
    )
    if spec.bounds is not None and spec.kind is int:
        d.integer_range = [IntegerRange(from_value=int(spec.bounds[0]), to_value=int(spec.bounds[1]), step=1)]
    elif spec.bounds is not None:
        d.floating_point_range = [FloatingPointRange(from_value=spec.bounds[0], to_value=spec.bounds[1], step=0.0)]
    return d


def _reason(error: ParameterException) -> str:
    """rclpy's parameter exceptions carry (message, name) in args; make one readable line of them."""
    message, *names = (str(a) for a in error.args)
    return f"parameter {', '.join(names)}: {message}" if names else message


def _failure(reason: str) -> SetParametersResult:
    return SetParametersResult(successful=False, reason=reason)


def _k(estimator: NormalEstimator, settings: NodeSettings) -> int:
    """The k in force: the parameter, or the estimator's own default (checkpoint or PCA) when it is 0."""
    return estimator.default_k if settings.k == K_METHOD_DEFAULT else settings.k


class TripletNormalNode(Node):
    """Subscribes to ``input``, publishes ``output``; raises StartupError when it cannot run.

    The worker runs in a thread of its own, or, with ``serve_in_caller``, in whoever calls `serve` (the console node
    calls it from the process's main thread, where torch's OpenMP teams run faster: docs/RESULTS.md, "Organized
    clouds", the node's overhead).
    """

    def __init__(self, serve_in_caller: bool = False, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.get_logger().info(f"running triplet_normal_ros from {os.path.dirname(os.path.dirname(__file__))}")
        settings = self._declare_parameters()
        estimator = self._build(settings, StartupError)
        self._log_expected_throughput(estimator)  # before the worker exists: the probe uses the estimator alone
        self._active: tuple[NormalEstimator, NodeSettings] = (estimator, settings)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._mailbox: Mailbox[PointCloud2] = Mailbox()
        self._stats = ProcessingStats()
        self._cancel = threading.Event()
        self._grid_noted = False  # a grid that is not a range image is reported once (`Plan.note`)
        self._publisher = self.create_publisher(
            PointCloud2,
            "output",
            QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE),
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        self._subscription = self.create_subscription(
            PointCloud2,
            "input",
            self._on_cloud,
            qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            callback_group=MutuallyExclusiveCallbackGroup(),
        )
        self._diagnostics = self.create_publisher(DiagnosticArray, diagnostics.TOPIC, diagnostics.DEPTH)
        self._diagnostic_name = diagnostics.status_name(self.get_fully_qualified_name())
        self._stats_timer = self.create_timer(settings.stats_period, self._report_stats)
        self._worker: threading.Thread | None = None
        if not serve_in_caller:
            self._worker = threading.Thread(target=self._work, name="triplet_normal_worker", daemon=True)
            self._worker.start()
        self.get_logger().info(
            f"ready: {self._subscription.topic_name} -> {self._publisher.topic_name}, {self._describe(*self._active)}"
        )

    def _log_expected_throughput(self, estimator: NormalEstimator) -> None:
        """Measure the estimator on a small probe cloud and say what a full frame will cost on this device."""
        try:
            rate = throughput.measure(estimator)
        except Exception as error:  # a probe failure must never stop the node; the first real cloud will tell
            self.get_logger().warning(f"could not measure the expected throughput: {error}")
            return
        self.get_logger().info(rate.describe(str(estimator.device)))

    # -- parameters -------------------------------------------------------------------------------------------------

    def _declare_parameters(self) -> NodeSettings:
        """Declare every parameter with its default and descriptor; validate the values given at start-up."""
        values: dict[str, Any] = {}
        try:
            for spec in SPECS:
                values[spec.name] = self.declare_parameter(spec.name, spec.default, _descriptor(spec)).value
        except ParameterException as error:
            raise StartupError(_reason(error)) from None
        reason = validate_all(values)
        if reason:
            raise StartupError(reason)
        return apply(NodeSettings(), values)

    def _build(self, settings: NodeSettings, error_type: type[Exception]) -> NormalEstimator:
        try:
            return NormalEstimator(**settings.estimator_args())
        except (CheckpointError, EstimatorError) as error:
            raise error_type(str(error)) from None
        except RuntimeError as error:  # torch itself, e.g. CUDA out of memory while moving the model
            raise error_type(f"could not build the estimator: {error}") from None

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate; rebuild the estimator for method/checkpoint/device; swap in one assignment for the next cloud."""
        values = {p.name: p.value for p in params}
        reason = validate_all(values)
        if reason:
            return _failure(reason)
        estimator, settings = self._active
        new_settings = apply(settings, values)
        if needs_reload(values):
            try:
                estimator = self._build(new_settings, ValueError)
            except ValueError as error:
                return _failure(f"kept the running estimator: {error}")
            self.get_logger().info(f"reloaded: {self._describe(estimator, new_settings)}")
        self._active = (estimator, new_settings)
        return SetParametersResult(successful=True)

    @staticmethod
    def _describe(estimator: NormalEstimator, s: NodeSettings) -> str:
        source = "" if s.method == "pca" else f", checkpoint={s.checkpoint_in_force()}"
        return (
            f"method={s.method}{source}, device={estimator.device}, radius={s.radius:g} m, k={_k(estimator, s)}, "
            f"batch_size={s.batch_size}, gate={s.gate:g}, bend={s.bend:g}, neighbours={s.neighbours}, "
            f"range_scale={s.range_scale:g}, zeros_are_no_returns={str(s.zeros_are_no_returns).lower()}, "
            f"orient={s.orient}, viewpoint={list(s.viewpoint)}"
        )

    # -- worker -----------------------------------------------------------------------------------------------------

    def _work(self) -> None:
        """The worker thread: take the newest cloud, estimate, publish, until the mailbox closes."""
        while (msg := self._mailbox.get()) is not None:
            if not self._handle(msg):
                return

    def serve(self, stop: threading.Event) -> None:
        """The worker loop in the calling thread, until `stop` is set or the node stops (`serve_in_caller`)."""
        while not stop.is_set():
            msg = self._mailbox.get(timeout=SERVE_POLL_S)
            if msg is None:
                if self._mailbox.closed:
                    return
                continue
            if not self._handle(msg):
                return

    def _handle(self, msg: PointCloud2) -> bool:
        """Estimate and publish one cloud; bad clouds are logged and skipped, never fatal. False once stopping."""
        log = self.get_logger()
        try:
            self._process(msg)
        except (CloudFormatError, EstimatorError) as error:
            self._stats.reject(str(error))
            log.error(f"skipped a malformed cloud: {error}", throttle_duration_sec=THROTTLE_S)
        except EstimationCancelled:
            return False
        except Exception as error:  # the worker must outlive any one cloud; shutdown races end here too
            if self._cancel.is_set():
                return False
            self._stats.reject(f"{type(error).__name__}: {error}")
            log.error(f"failed on a cloud: {type(error).__name__}: {error}", throttle_duration_sec=THROTTLE_S)
        return True

    def _on_cloud(self, msg: PointCloud2) -> None:
        """Subscription callback: count the arrival (log the first one), leave the cloud for the worker."""
        if self._stats.arrive():
            self.get_logger().info(
                f"first cloud received: {msg.width}x{msg.height} in frame '{msg.header.frame_id}'; estimating"
            )
        self._mailbox.put(msg)

    def _process(self, msg: PointCloud2) -> None:
        """Answer one cloud with the snapshot in force when it is taken (`answer_message`), publish, time it."""
        self._stats.start()
        start = time.perf_counter()
        estimator, settings = self._active
        answer = answer_message(msg, estimator, settings.message_settings(), self._cancel)
        if answer.points and not answer.finite:
            self.get_logger().warning(
                "cloud has no finite points; publishing NaN normals", throttle_duration_sec=THROTTLE_S
            )
        self._publisher.publish(answer.message)
        self._stats.record((time.perf_counter() - start) * 1e3)
        self._note_plan(estimator)

    def _note_plan(self, estimator: NormalEstimator) -> None:
        """Say once when a cloud's grid was not trusted (not a range image), so its pool path's cost is explained."""
        plan = estimator.last_run.plan
        if plan is not None and plan.note and not self._grid_noted:
            self._grid_noted = True
            self.get_logger().warning(plan.note)

    def _report_stats(self) -> None:
        """Close the statistics window: log its line and publish its health on /diagnostics."""
        estimator, settings = self._active
        window = self._stats.window(settings.stats_period, self._mailbox.dropped)
        self.get_logger().info(window.line())
        device = str(estimator.device)
        topics = (self._subscription.topic_name, self._publisher.topic_name)
        health = assess(window, settings_values(settings, device, _k(estimator, settings), topics))
        stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(diagnostics.diagnostic_array(health, self._diagnostic_name, device, stamp))

    # -- shutdown ---------------------------------------------------------------------------------------------------

    def cancel(self) -> None:
        """Ask the estimate in flight to stop at its next chunk: one Event.set, safe from a signal handler."""
        self._cancel.set()

    def stop(self, timeout: float = JOIN_TIMEOUT_S) -> bool:
        """Cancel the estimate in flight, close the mailbox and join the worker; False if it did not finish in time."""
        self._cancel.set()
        self._mailbox.close()
        if self._worker is None:  # served by the caller, who has returned from `serve`
            return True
        self._worker.join(timeout)
        return not self._worker.is_alive()


def _install_stop_handlers(stop: threading.Event, node: TripletNormalNode | None = None) -> None:
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


def _wake_on_signal(receiver: socket.socket, on_stop, sender: socket.socket) -> None:
    """Block until a signal's byte arrives on the wakeup socket, then stop (`sender` is kept open as long)."""
    if receiver.recv(1):
        on_stop()


#: The watchdog started by the first stop signal (at most one).
_WATCHDOG: list[threading.Timer] = []
_WATCHDOG_LOCK = threading.Lock()


def _start_watchdog(node: TripletNormalNode) -> None:
    """Start the watchdog once: the signal handler and the wakeup thread may both ask for it."""
    with _WATCHDOG_LOCK:
        if not _WATCHDOG:
            timer = threading.Timer(JOIN_TIMEOUT_S, _abandon, args=(node,))
            timer.daemon = True
            _WATCHDOG.append(timer)
            timer.start()


def _abandon(node: TripletNormalNode) -> NoReturn:
    """The estimate did not reach a cancel check in time: say so and leave without waiting for it, with a code of
    its own, since an estimate was cut off unfinished and nothing was shut down in order."""
    node.get_logger().error(
        f"worker still busy after {JOIN_TIMEOUT_S} s; exiting {EXIT_ABANDONED} without waiting for it"
    )
    _exit_now(EXIT_ABANDONED)


def _spin(node: TripletNormalNode, stop: threading.Event, failed: list[BaseException]) -> None:
    """The executor's loop (a thread of its own beside the serving main thread). If a callback raises, the node can no
    longer hear anything: the error is logged, kept in `failed`, and the node stops."""
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


def main(args: list[str] | None = None) -> NoReturn:
    """Console entry point ``node``: exit 0 after a signal-driven shutdown, 1 when the node cannot start, 2 when the
    watchdog left a busy worker behind (`EXIT_OK`, `EXIT_FAILED`, `EXIT_ABANDONED`)."""
    _exit_now(_run(args))


def _run(args: list[str] | None) -> int:
    stop = threading.Event()
    _install_stop_handlers(stop)
    profile = choose_profile()  # before rclpy.init: Fast DDS reads its profile when the participant is created
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # rcl rejects malformed --ros-args with its own exception type
        print(f"[FATAL] [{NODE_NAME}]: cannot start: {error}", file=sys.stderr)
        return EXIT_FAILED
    _log_transport(profile)
    node: TripletNormalNode | None = None
    spinner: threading.Thread | None = None
    failed: list[BaseException] = []
    try:
        node = TripletNormalNode(serve_in_caller=True)
        _install_stop_handlers(stop, node)
        spinner = threading.Thread(
            target=_spin, args=(node, stop, failed), name="triplet_normal_executor", daemon=True
        )
        spinner.start()
        node.serve(stop)  # estimates in this, the main, thread until a signal
        spinner.join(EXECUTOR_JOIN_S)
        return EXIT_FAILED if failed else EXIT_OK
    except StartupError as error:
        get_logger(NODE_NAME).fatal(f"cannot start: {error}")
        return EXIT_FAILED
    except (RuntimeError, ValueError) as error:  # e.g. rclpy rejecting a QoS override given on the command line
        get_logger(NODE_NAME).fatal(f"cannot start: {error}")
        return EXIT_FAILED
    finally:
        stop.set()
        for timer in _WATCHDOG:
            timer.cancel()  # the loop has returned: what follows is the orderly shutdown
        if spinner is not None:
            spinner.join(EXECUTOR_JOIN_S)
        if node is not None:
            _shut_down(node)
        rclpy.try_shutdown()


def _log_transport(profile: ProfileChoice) -> None:
    """Say which DDS profile carries the clouds: full-size best-effort clouds depend on it (docs/NODE.md, Transport)."""
    line = profile.describe(rclpy.get_rmw_implementation_identifier())
    (get_logger(NODE_NAME).warning if profile.warning else get_logger(NODE_NAME).info)(line)


def _shut_down(node: TripletNormalNode) -> None:
    """Cancel and join the worker, then destroy the node; a worker stuck in an uncancellable step is left behind."""
    if node.stop():
        node.get_logger().info("shut down")
        node.destroy_node()
    else:
        node.get_logger().warning(f"worker still busy after {JOIN_TIMEOUT_S} s; exiting without waiting for it")


def _exit_now(code: int) -> NoReturn:
    """Leave without interpreter teardown, everything of ours being released already.

    torch's and the DDS library's static destructors take 1-2 s on a busy 2-core CPU, which alone would break the
    promise to exit within 2 s of SIGINT/SIGTERM; and tearing down under a worker stuck inside torch aborts.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
