"""The managed (lifecycle) node across processes: the colcon-installed ``managed_node`` driven through every
transition by the real lifecycle services (``/triplet_normal/change_state`` and ``get_state``, lifecycle_msgs) from
an rclpy client in this process, which also publishes clouds and listens for the answers. While the node is not
active its input has no subscriber, a graph state this process waits for.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import STARTUP_S, NodeProcess, left_behind, shm_segments
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from probe_client import ProbeClient, cropped
from sensor_msgs.msg import PointCloud2

from triplet_normal_ros.io.pointcloud2 import NORMAL_FIELDS, read_field
from triplet_normal_ros.ros import diagnostics
from triplet_normal_ros.ros.managed_node import NODE_NAME
from triplet_normal_ros.ros.tools.replay import Frame, load_frame

pytestmark = pytest.mark.slow  # colcon build and a node process

IN, OUT = "/tn_life/points", "/tn_life/normals"
PCA_PARAMS = {"method": "pca", "radius": 0.03, "k": 24, "device": "cpu", "stats_period": 1.0}
EXECUTABLE = "managed_node"
#: Hang guards only: a transition or an answer not back in this long is not coming, however slow the machine.
WAIT_S = STARTUP_S


#: A full frame with the 500 nearest points from the KD-tree: an estimate that stays in flight for seconds (7-30 s
#: on two cores), long enough to deactivate while a second cloud waits behind it.
SLOW_PARAMS = {**PCA_PARAMS, "radius": 0.05, "k": 500, "neighbours": "kdtree"}


class LifecycleProbe(ProbeClient):
    """A ProbeClient that also calls the node's lifecycle services and keeps what it hears on /diagnostics."""

    def __init__(self) -> None:
        super().__init__(IN, OUT)
        self._change = self.node.create_client(ChangeState, f"/{NODE_NAME}/change_state")
        self._get = self.node.create_client(GetState, f"/{NODE_NAME}/get_state")
        self.diagnostics: list[dict[str, str]] = []
        self.node.create_subscription(DiagnosticArray, diagnostics.TOPIC, self._on_diagnostics, diagnostics.DEPTH)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.diagnostics += [{kv.key: kv.value for kv in status.values} for status in msg.status if status.values]

    def _call(self, client, request):
        assert client.wait_for_service(WAIT_S), f"no {client.srv_name} service"
        future = client.call_async(request)
        assert self.spin_until(future.done, WAIT_S), f"no answer from {client.srv_name}"
        return future.result()

    def change(self, transition: int) -> bool:
        return self._call(self._change, ChangeState.Request(transition=Transition(id=transition))).success

    def state(self) -> str:
        return self._call(self._get, GetState.Request()).current_state.label

    def subscribed(self, expected: bool) -> bool:
        """Wait until the node's input subscription is (or is no longer) in the graph."""
        return self.spin_until(lambda: (self._publisher.get_subscription_count() > 0) == expected, WAIT_S)

    def output_publishers(self) -> int:
        return self._subscription.get_publisher_count()


def _cloud(probe: LifecycleProbe, frame: Frame) -> PointCloud2:
    return cropped(frame, 200, 300, 20, 20).to_cloud(probe.header())


def _answer(probe: LifecycleProbe, frame: Frame) -> PointCloud2 | None:
    """A fresh cloud's answer; resent while unanswered (the node's best-effort input may lose the first sample)."""
    return probe.request_resending(_cloud(probe, frame), timeout=WAIT_S, every=5.0)


def _has_normals(answer: PointCloud2 | None) -> bool:
    if answer is None or [f.name for f in answer.fields][-len(NORMAL_FIELDS) :] != list(NORMAL_FIELDS):
        return False
    return bool(np.isfinite(read_field(answer, "normal_x")).sum() > 300)


def _start(start_node, params: dict) -> NodeProcess:
    node = start_node(params, {"input": IN, "output": OUT}, executable=EXECUTABLE)
    assert node.wait_for_log("unconfigured: waiting", WAIT_S), node.log
    return node


def test_every_transition_through_the_lifecycle_services(start_node) -> None:
    node = _start(start_node, PCA_PARAMS)
    frame = load_frame("table_scene_mug")
    with LifecycleProbe() as probe:
        assert probe.state() == "unconfigured"
        # configure: the estimator is loaded and the output exists, but nothing is subscribed.
        assert probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.state() == "inactive"
        assert probe.spin_until(lambda: probe.output_publishers() > 0, WAIT_S), "configure made no output"
        assert probe.subscribed(False)
        # activate: subscribed, and a cloud is answered with normals.
        assert probe.change(Transition.TRANSITION_ACTIVATE)
        assert probe.state() == "active"
        assert probe.subscribed(True)
        assert _has_normals(_answer(probe, frame)), node.log[-3000:]
        # deactivate: unsubscribed; the model stays, so activating again answers at once, without a configure.
        assert probe.change(Transition.TRANSITION_DEACTIVATE)
        assert probe.state() == "inactive"
        assert probe.subscribed(False)
        assert probe.change(Transition.TRANSITION_ACTIVATE)
        assert _has_normals(_answer(probe, frame)), node.log[-3000:]
        # cleanup: back to unconfigured; configure again works.
        assert probe.change(Transition.TRANSITION_DEACTIVATE)
        assert probe.change(Transition.TRANSITION_CLEANUP)
        assert probe.state() == "unconfigured"
        assert probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.change(Transition.TRANSITION_ACTIVATE)
        assert probe.state() == "active"
        assert _has_normals(_answer(probe, frame)), node.log[-3000:]
        # shutdown: the transition is answered, then the process exits 0, its DDS shared memory released.
        segments = shm_segments(node.proc.pid)
        assert probe.change(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    code = node.proc.wait(WAIT_S)
    assert code == 0, node.log[-3000:]
    assert segments and not left_behind(segments), segments
    for line in ("configured: method=pca", f"active: {IN} -> {OUT}", "inactive:", "the estimator is released"):
        assert line in node.log, line
    assert node.log.count("configured: method=pca") == 2
    assert "shut down" in node.log and "Traceback" not in node.log


def _totals_line(node: NodeProcess, totals: str) -> bool:
    """Wait for a statistics line whose running totals read `totals` ('2 arrived, 0 clouds, 1 dropped')."""
    return node.wait_for_log(f"| total: {totals}, 0 rejected", WAIT_S)


def _dropped_heard(probe: LifecycleProbe, total: int) -> bool:
    """Wait for a /diagnostics status that counts `total` dropped clouds, all of them by deactivate or cleanup."""
    return probe.spin_until(
        lambda: any(
            d.get("total dropped") == str(total) and d.get("total dropped by deactivate or cleanup") == str(total)
            for d in probe.diagnostics
        ),
        WAIT_S,
    )


def test_clouds_dropped_by_deactivate_and_cleanup_are_counted_in_the_log_and_diagnostics(start_node) -> None:
    """A full frame in flight and a small cloud waiting behind it: deactivate drops the waiting one and reports it
    at once; the frame in flight finishes after the cleanup that follows and is not sent. Both count as dropped, in
    the statistics line and on /diagnostics, as soon as the node reports again."""
    node = _start(start_node, SLOW_PARAMS)
    frame = load_frame("table_scene_mug")
    with LifecycleProbe() as probe:
        assert probe.change(Transition.TRANSITION_CONFIGURE) and probe.change(Transition.TRANSITION_ACTIVATE)
        assert probe.subscribed(True)
        probe.send(frame.to_cloud(probe.header()))
        assert node.wait_for_log(", 1 in flight for ", WAIT_S), node.log[-3000:]
        probe.send(_cloud(probe, frame))
        assert _totals_line(node, "2 arrived, 0 clouds, 0 dropped"), node.log[-3000:]  # the small one waits
        assert probe.change(Transition.TRANSITION_DEACTIVATE)
        assert _totals_line(node, "2 arrived, 0 clouds, 1 dropped"), node.log[-3000:]  # reported by the deactivate
        assert _dropped_heard(probe, 1), probe.diagnostics[-1:]
        assert probe.change(Transition.TRANSITION_CLEANUP)
        assert node.wait_for_log("dropped the answer to the cloud in flight", WAIT_S), node.log[-3000:]
        assert probe.change(Transition.TRANSITION_CONFIGURE) and probe.change(Transition.TRANSITION_ACTIVATE)
        assert _totals_line(node, "2 arrived, 0 clouds, 2 dropped"), node.log[-3000:]
        assert _dropped_heard(probe, 2), probe.diagnostics[-1:]
        assert probe.answers_received == 0
        assert probe.change(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    assert node.proc.wait(WAIT_S) == 0, node.log[-3000:]
    assert "input faster than processing" not in node.log and "Traceback" not in node.log


def test_a_failed_configure_leaves_the_node_unconfigured_alive_and_fixable(start_node) -> None:
    params = {**PCA_PARAMS, "method": "learned", "checkpoint": "/nonexistent/weights.safetensors"}
    node = _start(start_node, params)
    with LifecycleProbe() as probe:
        assert not probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.state() == "unconfigured"
        assert node.proc.poll() is None, "the process died with its configure"
        (line,) = [line for line in node.log.splitlines() if "configure failed" in line]
        assert line.startswith("[ERROR]") and "checkpoint not found" in line, line
        # The parameters were declared by the failed configure: setting one now is checked, and the next configure
        # uses it.
        assert not probe.set_parameters({"radius": -1.0})[0]
        ok, why = probe.set_parameters({"method": "pca", "checkpoint": ""})
        assert ok, why
        assert probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.state() == "inactive"
        assert probe.change(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert node.proc.wait(WAIT_S) == 0, node.log[-3000:]
    assert "configured: method=pca" in node.log and "Traceback" not in node.log


def test_a_failed_activate_says_why_and_leaves_the_node_inactive_and_alive(start_node) -> None:
    """A QoS override rclpy rejects only when the input is subscribed: activate fails with its reason in the log
    (rclpy alone would return ERROR without a word and drop the node to unconfigured), the node stays inactive with
    nothing subscribed, and it still obeys its transitions."""
    bad = f"qos_overrides.{IN}.subscription.reliability:=sometimes"
    node = start_node(PCA_PARAMS, {"input": IN, "output": OUT}, extra_args=["-p", bad], executable=EXECUTABLE)
    assert node.wait_for_log("unconfigured: waiting", WAIT_S), node.log
    with LifecycleProbe() as probe:
        assert probe.change(Transition.TRANSITION_CONFIGURE)
        assert not probe.change(Transition.TRANSITION_ACTIVATE)
        assert probe.state() == "inactive"
        assert node.proc.poll() is None, "the process died with its activate"
        (line,) = [line for line in node.log.splitlines() if "activate failed" in line]
        assert line.startswith("[ERROR]") and "sometimes" in line, line
        assert probe.subscribed(False)
        assert probe.change(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert node.proc.wait(WAIT_S) == 0, node.log[-3000:]
    assert "Traceback" not in node.log


@pytest.mark.parametrize("topic", [OUT, "/normals_markers"])
def test_a_wrongly_typed_output_qos_override_fails_every_configure_with_its_reason(start_node, topic: str) -> None:
    """rclpy raises a ParameterException for it while configure makes the outputs (the first one made, or one made
    after the output exists): configure fails with the reason and the node stays unconfigured and alive; and so does
    the next configure, which must not find half the outputs made and serve without the rest."""
    bad = f"qos_overrides.{topic}.publisher.depth:=deep"
    node = start_node(PCA_PARAMS, {"input": IN, "output": OUT}, extra_args=["-p", bad], executable=EXECUTABLE)
    assert node.wait_for_log("unconfigured: waiting", WAIT_S), node.log
    with LifecycleProbe() as probe:
        for _ in range(2):
            assert not probe.change(Transition.TRANSITION_CONFIGURE)
            assert probe.state() == "unconfigured"
        assert node.proc.poll() is None, "the process died with its configure"
        lines = [line for line in node.log.splitlines() if "configure failed" in line]
        assert len(lines) == 2 and all(line.startswith("[ERROR]") and "deep" in line for line in lines), lines
        assert probe.change(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert node.proc.wait(WAIT_S) == 0, node.log[-3000:]
    assert "Traceback" not in node.log


def test_a_start_up_value_rclpy_rejects_fails_configure_until_the_parameter_is_set_right(start_node) -> None:
    """``radius: 1`` (an integer for a double) in the params file: rclpy refuses to declare it. Configure fails with
    that reason, the parameters after it are still declared with their overrides, and once radius is set to a good
    value through the parameter service, configure succeeds without a restart."""
    node = _start(start_node, {**PCA_PARAMS, "radius": 1})
    with LifecycleProbe() as probe:
        assert not probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.state() == "unconfigured"
        (line,) = [line for line in node.log.splitlines() if "configure failed" in line]
        assert "radius" in line and "INTEGER" in line, line
        assert not probe.change(Transition.TRANSITION_CONFIGURE)  # still refused: the value was never set right
        ok, why = probe.set_parameters({"radius": 0.05})
        assert ok, why
        assert probe.change(Transition.TRANSITION_CONFIGURE)
        assert probe.state() == "inactive"
        assert probe.change(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert node.proc.wait(WAIT_S) == 0, node.log[-3000:]
    (configured,) = [line for line in node.log.splitlines() if "configured: method=pca" in line]
    assert "radius=0.05 m, k=24" in configured, configured  # k, declared after radius, kept its start-up value
    assert "Traceback" not in node.log
