"""``diagnostic_msgs`` for the node's health: the DiagnosticArray that diagnostic_updater's ``Updater`` would publish
for one task, built from a ROS-free :class:`~.health.Health`.

The node does not depend on diagnostic_updater (it is not on PyPI); this module reproduces the parts a monitor relies
on: the topic ``/diagnostics``, a status named ``<node's fully qualified name without the leading slash>: <task>``
(what the C++ Updater does; the aggregator and rqt_robot_monitor group by it), the hardware id, and the level as a
one-byte value.
"""

from __future__ import annotations

from collections.abc import Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from .health import Health

#: The absolute topic every ROS diagnostics tool listens to (not remapped with the node's own topics).
TOPIC = "/diagnostics"
#: diagnostic_updater publishes with a history of one: only the latest status matters.
DEPTH = 1
#: The task this node reports, the part of the status name after the node's name.
TASK = "normal estimation"


def status_name(node_fully_qualified_name: str, task: str = TASK) -> str:
    """'triplet_normal: normal estimation' at the root, 'robot/triplet_normal: ...' in namespace /robot."""
    return f"{node_fully_qualified_name.lstrip('/')}: {task}"


def status(health: Health, name: str, hardware_id: str) -> DiagnosticStatus:
    """One DiagnosticStatus; ``level`` is a byte field, hence ``bytes([level])``."""
    return DiagnosticStatus(
        level=bytes([health.level]),
        name=name,
        message=health.message,
        hardware_id=hardware_id,
        values=[KeyValue(key=key, value=value) for key, value in health.values],
    )


def diagnostic_array(
    health: Health, name: str, hardware_id: str, stamp: Time, more: Sequence[DiagnosticStatus] = ()
) -> DiagnosticArray:
    """The message for ``/diagnostics``: the node's status and `more` of its tasks' (as one Updater sends all its
    tasks' in one array), stamped with the node's clock."""
    array = DiagnosticArray(status=[status(health, name, hardware_id), *more])
    array.header.stamp = stamp
    return array
