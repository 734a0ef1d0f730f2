"""The managed (lifecycle) node ``managed_node``: the plain node's serving (ros/serving.py) behind the ROS 2 node
lifecycle, for stacks that bring their nodes up through a lifecycle manager (nav2_lifecycle_manager).

    configure   declare and validate the parameters, load the checkpoint, measure the expected throughput
    activate    subscribe to ``input``; ``output`` and ``/diagnostics`` publish; statistics every stats_period
    deactivate  unsubscribe and drop the waiting cloud (counted as dropped, reported at once); the estimator stays
                loaded; an estimate in flight finishes unsent and counts as dropped
    cleanup     drop the estimator (the model is freed once no estimate uses it)
    shutdown    stop serving: the process exits 0

A configure that fails (bad parameter, missing checkpoint, a QoS override rclpy rejects) logs ``configure failed:
<reason>`` and returns FAILURE: the node stays unconfigured and alive, and a parameter set then is checked and used by
the next configure. An activate that fails (a QoS override on ``input`` rclpy rejects) logs ``activate failed:
<reason>``, undoes what it began and returns FAILURE: the node stays inactive, estimator loaded. rclpy turns any other
exception of a transition into ERROR without a word and then calls `on_error`, which logs, releases the estimator and
leaves the node unconfigured with nothing subscribed or sending. Same name, parameters, topics, threads and exit codes
as the plain node (docs/NODE.md, "Managed node (lifecycle)").
"""

from __future__ import annotations

import threading
from typing import Any, NoReturn

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from ..core.config.defaults import NODE_NAME
from . import runner
from .serving import ServingMixin, describe_error, package_location


class ManagedNode(ServingMixin, LifecycleNode):
    """``triplet_normal`` as a lifecycle node; starts unconfigured. The worker runs in a thread of its own, or, with
    ``serve_in_caller``, in whoever calls `serve` (the console entry point: the process's main thread)."""

    def __init__(self, serve_in_caller: bool = False, start: bool = True, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.get_logger().info(f"running triplet_normal_ros from {package_location()}")
        self._init_serving()
        self._serve_in_caller = serve_in_caller
        if start:
            self.start()

    def start(self, stop: threading.Event | None = None) -> None:
        """Wait for the configure transition (which does the plain node's warm-up, cancelled by a stop like an
        estimate); `stop` is the console entry point's, as for the plain node."""
        if not self._serve_in_caller:
            self._start_worker()
        self.get_logger().info("unconfigured: waiting for the configure transition")

    def destroy_node(self) -> None:
        """Destroy the lifecycle state machine too. rclpy's LifecycleNode leaves it, and it holds the node's handle,
        so neither the node nor its DDS participant would go before the process's end, and the participant's
        shared-memory segment would stay in /dev/shm after the node's fast exit (docs/NODE.md, Shutdown)."""
        super().destroy_node()
        self._state_machine.destroy_when_not_in_use()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load the estimator; the publishers are made on the first configure and kept (they send nothing while
        inactive), so an estimate still finishing after a cleanup never publishes through a destroyed one."""
        try:
            active = self._configure(self._cancel)
            if self._publisher is None:
                self._create_outputs(self.create_lifecycle_publisher, self.destroy_lifecycle_publisher)
        except Exception as error:  # rclpy would swallow it silently: say why, and stay unconfigured
            return self._failed("configure", error)
        self._active = active
        self.get_logger().info(f"configured: {self._describe(*active)}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Let the publishers send, then subscribe. On failure (e.g. a QoS override on ``input`` rclpy rejects) what
        was begun is undone, so the node stays inactive as it was: silent, unsubscribed, estimator loaded."""
        try:
            result = super().on_activate(state)
            self._subscribe()
            self._start_stats()
            self._visuals.start()
        except Exception as error:  # rclpy would swallow it silently and leave the publishers sending
            self._stop_answering()
            super().on_deactivate(state)
            return self._failed("activate", error)
        self.get_logger().info(f"active: {self._ready_line()}")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop answering: unsubscribe, stop the statistics, drop the cloud waiting in the mailbox and report the
        window with it (log and /diagnostics, while those still publish). An estimate in flight finishes, but its
        answer is not sent: the worker counts it as dropped too, in the next report."""
        self._stop_answering()
        self._discard_waiting()
        self._report_stats()
        self.get_logger().info("inactive: not subscribed; the estimator stays loaded")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._discard_waiting()
        self._active = None
        self.get_logger().info("unconfigured: the estimator is released")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Cancel the estimate in flight and close the mailbox: the serving loop returns and the process exits 0
        once this transition's answer is out (`runner._spin`)."""
        self._stop_answering()
        self.stop()
        self.get_logger().info("shutting down")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised what it did not catch (rclpy logs nothing of it): reset to a clean unconfigured node,
        with nothing subscribed or sending and the estimator released, so that configure can start afresh."""
        self._stop_answering()
        super().on_deactivate(state)
        self._discard_waiting()
        self._active = None
        self.get_logger().error(f"a transition from {state.label} failed; unconfigured, the estimator is released")
        return TransitionCallbackReturn.SUCCESS

    def _failed(self, transition: str, error: Exception) -> TransitionCallbackReturn:
        """Log why `transition` failed, in one line; FAILURE, which takes the node back to the state it came from."""
        self.get_logger().error(f"{transition} failed: {describe_error(error)}")
        return TransitionCallbackReturn.FAILURE

    def _discard_waiting(self) -> None:
        """Drop the cloud waiting in the mailbox, if any, and count it: a transition's drop is a drop all the same."""
        if self._mailbox.discard():
            self._stats.drop()

    def _stop_answering(self) -> None:
        """Unsubscribe, stop the statistics timer and the RViz outputs' drawing thread (deactivate, shutdown, a failed
        activate, an error)."""
        if self._subscription is not None:
            self.destroy_subscription(self._subscription)
            self._subscription = None
        if self._stats_timer is not None:
            self.destroy_timer(self._stats_timer)
            self._stats_timer = None
        if self._visuals is not None:
            self._visuals.stop()


def main(args: list[str] | None = None) -> NoReturn:
    """Console entry point ``managed_node``: exit codes as the plain node's (docs/NODE.md, "Shutdown")."""
    runner.main(ManagedNode, NODE_NAME, args)


if __name__ == "__main__":
    main()
