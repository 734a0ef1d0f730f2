"""What the plain node (ros/node.py) and the managed node (ros/managed_node.py) share: their parameters, the
estimator in force, the latest-only mailbox, the worker loop that answers and publishes, and the statistics and
diagnostics.

:class:`ServingMixin` is written against rclpy's ``Node``, as rclpy's own ``LifecycleNodeMixin`` is, so the same code
serves a ``Node`` and a ``LifecycleNode``: the plain node runs every step in its constructor, the managed node spreads
them over its transitions (configure: `_configure` and `_create_outputs`; activate: `_subscribe` and `_start_stats`).
The subscription callback only drops the message into the :class:`Mailbox`; one worker loop takes the newest cloud,
answers it (`pipeline.messages.answer_message`) and publishes, so a slow estimator skips clouds instead of queueing
them. See docs/NODE.md for threading, reloads, errors and shutdown.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import PointCloud2

from ..core import throughput
from ..core.config.plan import per_kind
from ..core.estimator import NormalEstimator
from ..errors import CheckpointError, CloudFormatError, EstimationCancelled, EstimatorError
from ..pipeline.messages import answer_message
from . import diagnostics
from .health import assess, settings_values
from .mailbox import Mailbox
from .params import K_METHOD_DEFAULT, SPECS, NodeSettings, ParamSpec, apply, needs_reload, validate_all
from .stats import ProcessingStats
from .visuals import NormalVisuals

#: Output history: reliable, but shallow, so a slow subscriber cannot make the node hoard clouds.
OUTPUT_DEPTH = 2
#: Seconds between repeats of the same error or warning in the log.
THROTTLE_S = 5.0
#: How long shutdown waits for the worker; the estimator checks its cancel event between batches.
JOIN_TIMEOUT_S = 1.5
#: How often the worker loop in the main thread looks at the stop event while no cloud waits.
SERVE_POLL_S = 0.1

_PARAM_TYPES = {
    str: Parameter.Type.STRING,
    int: Parameter.Type.INTEGER,
    float: Parameter.Type.DOUBLE,
    bool: Parameter.Type.BOOL,
    list: Parameter.Type.DOUBLE_ARRAY,
}


class ConfigError(RuntimeError):
    """The parameters or the checkpoint cannot make an estimator (bad parameter, missing or corrupt checkpoint): the
    plain node cannot start, the managed node's configure fails."""


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


def describe_error(error: Exception) -> str:
    """One line for a node that cannot start or a transition that failed: the reason alone for what the node
    expects (its own ConfigError, rclpy's parameter and QoS override errors), the type too for anything else."""
    if isinstance(error, ParameterException):
        return _reason(error)
    if isinstance(error, (RuntimeError, ValueError)):
        return str(error)
    return f"{type(error).__name__}: {error}"


def _failure(reason: str) -> SetParametersResult:
    return SetParametersResult(successful=False, reason=reason)


def _k(estimator: NormalEstimator, settings: NodeSettings) -> str:
    """The k in force: the parameter, or the estimator's own default (checkpoint or PCA) when it is 0, for range
    images and other clouds where their checkpoints differ ('32 on range images and 64 otherwise')."""
    if settings.k != K_METHOD_DEFAULT:
        return str(settings.k)
    return per_kind(estimator.own_k(), estimator.own_k(range_image=True))


def package_location() -> str:
    """The package directory this process runs (logged at start-up, so a stale install shows at once)."""
    return os.path.dirname(os.path.dirname(__file__))


class ServingMixin:
    """Parameters, estimator, mailbox, worker loop, statistics and diagnostics for a class that is also an rclpy
    ``Node`` (or ``LifecycleNode``). ``_active`` is the (estimator, settings) snapshot the next cloud gets, swapped in
    one assignment; None while a managed node is not configured."""

    def _init_serving(self) -> None:
        """The state both nodes have from construction on: nothing configured, nothing published yet."""
        self._active: tuple[NormalEstimator, NodeSettings] | None = None
        self._watching_parameters = False
        self._rejected: dict[str, str] = {}  # parameter -> why rclpy rejected its start-up value, until it is set
        self._mailbox: Mailbox[PointCloud2] = Mailbox()
        self._stats = ProcessingStats()
        self._cancel = threading.Event()
        self._paths_noted: set[tuple[str, str]] = set()  # each path a cloud took, said once (`_note_plan`)
        self._publisher: Publisher | None = None
        self._subscription = None
        self._input_topic = ""
        self._diagnostics: Publisher | None = None
        self._visuals: NormalVisuals | None = None
        self._stats_timer = None
        self._worker: threading.Thread | None = None

    def _start_worker(self) -> None:
        """The worker loop in a thread of its own (for nodes built in a process that does not call `serve`)."""
        self._worker = threading.Thread(target=self._work, name="triplet_normal_worker", daemon=True)
        self._worker.start()

    # -- parameters and the estimator -------------------------------------------------------------------------------

    def _configure(self, stop: threading.Event | None = None) -> tuple[NormalEstimator, NodeSettings]:
        """Parameters to an estimator: declare and validate them, build it, say what a frame will cost; ConfigError
        with the reason when that cannot be done, EstimationCancelled between stages once `stop` is set (the warm-up
        compiles the kernels for half a minute where their cache is empty)."""
        settings = self._declare_parameters()
        estimator = self._build(settings, ConfigError)
        self._log_expected_throughput(estimator, stop)  # before the worker sees it: the probe uses the estimator alone
        return estimator, settings

    def _declare_parameters(self) -> NodeSettings:
        """Declare every parameter not declared yet, each on its own, then validate the values in force. A start-up
        value rclpy rejects (wrong type, out of range) is declared with its default instead and refused here until the
        parameter is set right, so one bad value neither hides the others nor leaves a managed node that no
        `ros2 param set` can fix. The on-set callback is added after the declarations."""
        values = {spec.name: self._declared(spec).value for spec in SPECS}
        if not self._watching_parameters:
            self.add_on_set_parameters_callback(self._on_set_parameters)
            self._watching_parameters = True
        reason = "; ".join(self._rejected.values()) or validate_all(values)
        if reason:
            raise ConfigError(reason)
        return apply(NodeSettings(), values)

    def _declared(self, spec: ParamSpec) -> Parameter:
        """The parameter `spec` names, declared now if it is not yet; its default, with the reason kept in
        `_rejected`, when rclpy rejects the start-up value."""
        if self.has_parameter(spec.name):
            return self.get_parameter(spec.name)
        try:
            return self.declare_parameter(spec.name, spec.default, _descriptor(spec))
        except ParameterException as error:
            self._rejected[spec.name] = _reason(error)
            return self.declare_parameter(spec.name, spec.default, _descriptor(spec), ignore_override=True)

    def _build(self, settings: NodeSettings, error_type: type[Exception]) -> NormalEstimator:
        try:
            return NormalEstimator(**settings.estimator_args())
        except (CheckpointError, EstimatorError) as error:
            raise error_type(str(error)) from None
        except RuntimeError as error:  # torch itself, e.g. CUDA out of memory while moving the model
            raise error_type(f"could not build the estimator: {error}") from None

    def _log_expected_throughput(self, estimator: NormalEstimator, stop: threading.Event | None = None) -> None:
        """Measure the estimator on a small probe cloud and say what a full frame will cost on this device; a stop
        ends the probe (EstimationCancelled)."""
        # Said before the probe: on a CPU with an empty kernel cache it compiles the kernels, for half a minute.
        self.get_logger().info(f"measuring the expected throughput on {estimator.device}")
        try:
            rate = throughput.measure(estimator, cancel=stop)
        except EstimationCancelled:
            raise
        except Exception as error:  # a probe failure must never stop the node; the first real cloud will tell
            self.get_logger().warning(f"could not measure the expected throughput: {error}")
            return
        self.get_logger().info(rate.describe(str(estimator.device)))

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate; rebuild the estimator for method/checkpoint/device; swap in one assignment for the next cloud.
        Without an estimator (a managed node not configured) the values only wait for the next configure."""
        values = {p.name: p.value for p in params}
        reason = validate_all(values)
        if reason:
            return _failure(reason)
        for name in values:  # set right now: the start-up value rclpy rejected no longer stands in the way
            self._rejected.pop(name, None)
        if self._active is None:
            return SetParametersResult(successful=True)
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

    def _ready_line(self) -> str:
        """The topics and every setting in force (docs/NODE.md, "Start-up lines")."""
        assert self._subscription is not None and self._publisher is not None and self._active is not None
        return f"{self._subscription.topic_name} -> {self._publisher.topic_name}, {self._describe(*self._active)}"

    # -- topics -----------------------------------------------------------------------------------------------------

    def _create_outputs(self, create: Callable[..., Publisher], destroy: Callable[[Publisher], object]) -> None:
        """The output, /diagnostics and RViz publishers, made by `create`: the node's ``create_publisher``, or a
        managed node's ``create_lifecycle_publisher`` (which sends nothing while the node is inactive). All or
        nothing: if one cannot be made (a QoS override rclpy rejects), those made are destroyed with `destroy` and
        the node holds none, so the next configure makes them all again instead of serving with some missing."""
        made: list[Publisher] = []

        def recorded(*args: Any, **kwargs: Any) -> Publisher:
            made.append(create(*args, **kwargs))
            return made[-1]

        qos = QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        options = QoSOverridingOptions.with_default_policies()
        try:
            output = recorded(PointCloud2, "output", qos, qos_overriding_options=options)
            diagnostics_publisher = recorded(DiagnosticArray, diagnostics.TOPIC, diagnostics.DEPTH)
            visuals = NormalVisuals(self, recorded)  # normals_markers and normal_image, for RViz
        except Exception:
            for publisher in made:
                destroy(publisher)
            raise
        self._publisher, self._diagnostics, self._visuals = output, diagnostics_publisher, visuals
        self._diagnostic_name = diagnostics.status_name(self.get_fully_qualified_name())

    def _subscribe(self) -> None:
        self._subscription = self.create_subscription(
            PointCloud2,
            "input",
            self._on_cloud,
            qos_profile_sensor_data,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            callback_group=MutuallyExclusiveCallbackGroup(),
        )
        self._input_topic = self._subscription.topic_name  # kept for the report a deactivate makes after unsubscribing

    def _start_stats(self) -> None:
        """The statistics timer, every `stats_period` seconds of the node's clock."""
        assert self._active is not None
        self._stats_timer = self.create_timer(self._active[1].stats_period, self._report_stats)

    # -- worker -----------------------------------------------------------------------------------------------------

    def _work(self) -> None:
        """The worker thread: take the newest cloud, estimate, publish, until the mailbox closes."""
        while (msg := self._mailbox.get()) is not None:
            if not self._handle(msg):
                return

    def serve(self, stop: threading.Event) -> None:
        """The worker loop in the calling thread, until `stop` is set or the node stops (the mailbox closes)."""
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
        """Answer one cloud with the snapshot in force when it is taken (`answer_message`), publish, time it. A
        managed node cleaned up since the cloud arrived has no snapshot, and one deactivated while it estimated can
        no longer send: either way the cloud is counted as dropped."""
        active, publisher = self._active, self._publisher
        if active is None or publisher is None:
            self._stats.drop()
            return
        self._stats.start()
        start = time.perf_counter()
        estimator, settings = active
        answer = answer_message(msg, estimator, settings.message_settings(), self._cancel)
        if not getattr(publisher, "is_activated", True):  # a lifecycle publisher, deactivated meanwhile
            self._stats.drop()
            self.get_logger().info("dropped the answer to the cloud in flight: the node was deactivated")
            return
        if answer.points and not answer.finite:
            self.get_logger().warning(
                "cloud has no finite points; publishing NaN normals", throttle_duration_sec=THROTTLE_S
            )
        publisher.publish(answer.message)
        self._visuals.publish(answer.message, settings)  # hands the answer to the drawing thread; nothing is built here
        self._stats.record((time.perf_counter() - start) * 1e3)
        self._note_plan(estimator)

    def _note_plan(self, estimator: NormalEstimator) -> None:
        """Say once per path which path and checkpoint answered a cloud, so that a user who names no checkpoint
        learns which one served (a CPU's default differs between range images and other clouds), and say why a
        grid was not trusted (not a range image), which explains its pool path's cost."""
        plan = estimator.last_run.plan
        if plan is None or (plan.steps, plan.note) in self._paths_noted:
            return
        self._paths_noted.add((plan.steps, plan.note))
        line = f"first answer on this path: {plan.describe()}"
        if plan.note:
            self.get_logger().warning(f"{line}; {plan.note}")
        else:
            self.get_logger().info(line)

    def _report_stats(self) -> None:
        """Close the statistics window: log its line and publish its health on /diagnostics, with the RViz outputs'
        status while one is on. The timer runs only while the node subscribes and publishes (a managed node: while
        active)."""
        if self._active is None:
            return
        estimator, settings = self._active
        window = self._stats.window(settings.stats_period, self._mailbox.dropped)
        self.get_logger().info(window.line())
        device = str(estimator.device)
        topics = (self._input_topic, self._publisher.topic_name)
        health = assess(window, settings_values(settings, device, _k(estimator, settings), topics))
        stamp = self.get_clock().now().to_msg()
        rviz = self._visuals.status(settings.visual_settings())  # the RViz outputs' own status, while one is on
        more = [rviz] if rviz is not None else []
        self._diagnostics.publish(diagnostics.diagnostic_array(health, self._diagnostic_name, device, stamp, more))

    # -- shutdown ---------------------------------------------------------------------------------------------------

    def cancel(self) -> None:
        """Ask the estimate in flight to stop at its next chunk: one Event.set, safe from a signal handler."""
        self._cancel.set()

    def stop(self, timeout: float = JOIN_TIMEOUT_S) -> bool:
        """Cancel the estimate in flight, close the mailbox and join the worker; False if it did not finish in time."""
        self._cancel.set()
        self._mailbox.close()
        if self._visuals is not None:  # before the node and its publishers are destroyed
            self._visuals.stop()
        if self._worker is None:  # served by the caller, who has returned from `serve`
            return True
        self._worker.join(timeout)
        return not self._worker.is_alive()
