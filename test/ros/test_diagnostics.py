"""The DiagnosticArray the node publishes, built from a Health (no node needed: diagnostic_msgs alone)."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus

from triplet_normal_ros.ros.diagnostics import TASK, diagnostic_array, status_name
from triplet_normal_ros.ros.health import ERROR, OK, WARN, Health


def test_status_names_follow_diagnostic_updater() -> None:
    """'<node's fully qualified name without the leading slash>: <task>', as the C++ Updater names them."""
    assert status_name("/triplet_normal") == f"triplet_normal: {TASK}" == "triplet_normal: normal estimation"
    assert status_name("/robot/front/triplet_normal") == "robot/front/triplet_normal: normal estimation"


def test_the_array_carries_one_status_with_level_byte_hardware_id_and_values_in_order() -> None:
    health = Health(WARN, "1 rejected in the last 1 s", (("input rate (Hz)", "2.5"), ("device", "cuda:0")))
    msg = diagnostic_array(health, "triplet_normal: normal estimation", "cuda:0", Time(sec=12, nanosec=5))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 5)
    (status,) = msg.status
    assert status.level == DiagnosticStatus.WARN
    assert (status.name, status.message, status.hardware_id) == (
        "triplet_normal: normal estimation",
        "1 rejected in the last 1 s",
        "cuda:0",
    )
    assert [(kv.key, kv.value) for kv in status.values] == list(health.values)


def test_levels_match_the_message_constants() -> None:
    """health's plain ints are the message's byte constants."""
    for level, constant in ((OK, DiagnosticStatus.OK), (WARN, DiagnosticStatus.WARN), (ERROR, DiagnosticStatus.ERROR)):
        assert diagnostic_array(Health(level, "", ()), "n", "cpu", Time()).status[0].level == constant
