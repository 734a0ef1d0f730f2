"""/diagnostics from a separate process: the installed node, default QoS, a one-second statistics window.

The test process subscribes to /diagnostics beside its ProbeClient and checks what a monitor (rqt_robot_monitor,
diagnostic_aggregator) would see: the status name and hardware id, OK while waiting and while keeping up, the rates
and counts of the clouds it sent, a WARN with the reason for one malformed cloud, and an ERROR when every cloud is
rejected, cleared by the next good one. Every wait is on a status that shows what the test waits for (a count, a
level); the timeouts are hang guards.
"""

from __future__ import annotations

import array
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import NodeProcess, running_node
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from probe_client import ProbeClient, cropped, matched_client
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField

from triplet_normal_ros.ros.health import REJECTED_IN_A_ROW_ERROR
from triplet_normal_ros.ros.tools.replay import load_frame

pytestmark = pytest.mark.slow  # colcon build and a node process

IN, OUT = "/tn_diag/points", "/tn_diag/normals"
NAME = "triplet_normal: normal estimation"
PARAMS = {"method": "pca", "radius": 0.03, "k": 24, "device": "cpu", "stats_period": 1.0}
#: Generous: two cores shared with other test runs.
WAIT_S = 30.0


@dataclass(frozen=True)
class Status:
    level: int
    message: str
    hardware_id: str
    values: dict[str, str]
    stamp_s: float  # the DiagnosticArray's header stamp: when the node closed the window

    def number(self, key: str) -> float:
        return float(self.values[key])


class DiagnosticsListener:
    """Every status of the node's task received on /diagnostics, in order; served by the client's executor."""

    def __init__(self, client: ProbeClient) -> None:
        self.client = client
        self.received: list[Status] = []
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        client.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_array, qos)

    def _on_array(self, msg: DiagnosticArray) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        for s in msg.status:
            if s.name == NAME:
                values = {kv.key: kv.value for kv in s.values}
                self.received.append(Status(s.level[0], s.message, s.hardware_id, values, stamp))

    def wait_for(self, match: Callable[[Status], bool], timeout: float = WAIT_S, after: int = 0) -> Status | None:
        """The first status from index ``after`` on that ``match`` accepts, spinning until ``timeout``."""
        deadline = time.monotonic() + timeout
        while True:
            found = next((s for s in self.received[after:] if match(s)), None)
            if found is not None or time.monotonic() > deadline:
                return found
            self.client.spin_for(0.1)


@pytest.fixture(scope="module")
def node(install_prefix: Path, ros_env: dict[str, str], tmp_path_factory) -> Iterator[NodeProcess]:
    """Default QoS (no override): the small clouds here are what every QoS delivers."""
    folder = tmp_path_factory.mktemp("diag")
    with running_node(install_prefix, ros_env, folder, PARAMS, {"input": IN, "output": OUT}) as process:
        yield process


@pytest.fixture(scope="module")
def client(node: NodeProcess) -> Iterator[ProbeClient]:
    with matched_client(IN, OUT, WAIT_S) as c:
        yield c


@pytest.fixture(scope="module")
def listener(client: ProbeClient) -> DiagnosticsListener:
    return DiagnosticsListener(client)


def small_cloud(client: ProbeClient) -> PointCloud2:
    return cropped(load_frame("table_scene_mug"), 200, 300, 20, 20).to_cloud(client.header())


def answer(client: ProbeClient) -> None:
    """One valid cloud, answered (resent if best effort lost it)."""
    assert client.request_resending(small_cloud(client), timeout=WAIT_S, every=3.0) is not None


def short_cloud(client: ProbeClient) -> PointCloud2:
    """Four xyz points declared, three and a half sent: rejected as malformed."""
    fields = [PointField(name=a, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, a in enumerate("xyz")]
    msg = PointCloud2(header=client.header(), height=1, width=4, fields=fields, point_step=12, row_step=48)
    msg.data = array.array("B", bytes(42))
    return msg


def send_malformed(client: ProbeClient, listener: DiagnosticsListener, count: int) -> None:
    """``count`` malformed clouds, each sent once /diagnostics counts the one before it as rejected (so none is
    replaced in the mailbox by the next)."""
    assert listener.wait_for(lambda s: True) is not None, "nothing on /diagnostics"
    for _ in range(count):
        rejected = listener.received[-1].number("total rejected")
        start = len(listener.received)
        client.send(short_cloud(client))
        counted = listener.wait_for(lambda s: s.number("total rejected") > rejected, after=start)  # noqa: B023
        assert counted is not None, "a malformed cloud was never counted as rejected"


def test_a_status_per_period_ok_while_waiting_for_input(listener: DiagnosticsListener) -> None:
    first = listener.wait_for(lambda s: True)
    assert first is not None, "nothing on /diagnostics"
    assert (first.level, first.message) == (DiagnosticStatus.OK[0], "waiting for input")
    assert first.hardware_id == "cpu"
    v = first.values
    assert (v["method"], v["device"], v["radius (m)"], v["k"]) == ("pca", "cpu", "0.03", "24")
    assert (v["input topic"], v["output topic"]) == (IN, OUT)
    start = len(listener.received)
    assert listener.wait_for(lambda s: True, after=start + 5) is not None, "the reports stopped"
    later = listener.received[start:]
    windows = [s.number("window (s)") for s in later]
    # Each window covers the time since the one before it: the windows after the first add up to the time between
    # the first and the last stamp. Each stamp is taken a few statements after its window closes, so the two differ
    # only by the lateness of those two stamps, however many windows lie between; a window that missed or repeated
    # time would add up one window's error per report.
    span = later[-1].stamp_s - later[0].stamp_s
    assert all(w > 0 for w in windows) and sum(windows[1:]) == pytest.approx(span, rel=0.25), (windows, span)
    # The timer runs on the 1 s stats_period: a busy machine can only make it late, never early, and a late report
    # shortens the next window.
    assert np.mean(windows) > 0.5, f"stats_period is 1 s, windows were {windows}"


def test_processed_clouds_are_counted_with_rates_and_times(client: ProbeClient, listener: DiagnosticsListener) -> None:
    assert listener.wait_for(lambda s: True) is not None
    start = len(listener.received)
    before = listener.received[-1].number("total processed")
    sent = 6
    for _ in range(sent):
        answer(client)
    done = listener.wait_for(lambda s: s.number("total processed") >= before + sent, after=start)
    assert done is not None, f"total processed never reached {before + sent}"
    windows = listener.received[start : listener.received.index(done) + 1]
    # Each cloud in exactly one window (a resend over best effort may add one answered twice, never lose one).
    assert sum(s.number("processed") for s in windows) == done.number("total processed") - before >= sent
    busy = [s for s in windows if s.number("processed") > 0]
    for s in busy:
        assert s.level == DiagnosticStatus.OK[0] and s.message == "keeping up", (s.level, s.message)
        rate = s.number("processed") / s.number("window (s)")
        assert s.number("output rate (Hz)") == pytest.approx(rate, rel=0.01)
        assert 0 < s.number("mean processing time (ms)") <= s.number("max processing time (ms)")
    # A cloud may arrive in one window and finish in the next, so arrivals are checked over all the windows.
    for s in windows:
        rate = s.number("arrived") / s.number("window (s)")
        assert s.number("input rate (Hz)") == pytest.approx(rate, rel=0.01, abs=1e-9)
    assert sum(s.number("arrived") for s in windows) >= sent
    assert done.values["rejected"] == "0" and done.values["in flight"] == "0"


def test_one_malformed_cloud_is_a_warn_with_its_reason(client: ProbeClient, listener: DiagnosticsListener) -> None:
    answer(client)  # a processed cloud: no earlier rejection streak
    start = len(listener.received)
    send_malformed(client, listener, 1)
    answer(client)
    warned = listener.wait_for(lambda s: s.values["rejected"] != "0", after=start)
    assert warned is not None, "the rejection never showed on /diagnostics"
    assert warned.values["rejected"] == "1"
    assert (warned.level, warned.message) == (DiagnosticStatus.WARN[0], "1 rejected in the last 1 s")
    assert "fewer than height*row_step" in warned.values["last rejection"]
    index = listener.received.index(warned)
    assert listener.wait_for(lambda s: s.level == DiagnosticStatus.OK[0], after=index + 1) is not None


def test_only_rejected_clouds_are_an_error_until_a_good_one(client: ProbeClient, listener: DiagnosticsListener) -> None:
    answer(client)
    start = len(listener.received)
    send_malformed(client, listener, REJECTED_IN_A_ROW_ERROR)
    error = listener.wait_for(lambda s: s.level == DiagnosticStatus.ERROR[0], after=start)
    assert error is not None, [(s.level, s.message) for s in listener.received[start:]]
    assert error.message == f"the last {REJECTED_IN_A_ROW_ERROR} clouds were all rejected"
    assert error.values["rejected in a row"] == str(REJECTED_IN_A_ROW_ERROR)
    index = len(listener.received)
    answer(client)
    recovered = listener.wait_for(lambda s: s.level == DiagnosticStatus.OK[0], after=index)
    assert recovered is not None and recovered.values["rejected in a row"] == "0"
