"""SIGINT during a first start ends the installed node within 2 s, with exit code 0, and leaves no DDS shared-memory
segment behind: right after the process starts, once rclpy is up, and while the kernels compile for the throughput
probe; and the managed node, while its first configure compiles them. An empty numba cache (NUMBA_CACHE_DIR) and home
make each start a first start, as after a fresh build."""

from __future__ import annotations

import fcntl
import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SHM_DIR, STARTUP_S, NodeProcess, installed_env, left_behind, params_yaml, shm_segments
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from probe_client import ProbeClient

from triplet_normal_ros.ros.managed_node import NODE_NAME

pytestmark = pytest.mark.slow  # node processes

#: What the node promises from the signal to its exit.
EXIT_S = 2.0
#: A hang guard only: how long a process gets after the signal before it is killed and the test fails.
GUARD_S = 30.0


@pytest.fixture(autouse=True)
def default_sigint() -> Iterator[None]:
    """A handler here, so each node starts with SIGINT's default disposition even when this run was started with it
    ignored (a shell's background job): exec resets a handled signal to its default but keeps an ignored one."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def cold_node(prefix: Path, ros_env: dict[str, str], folder: Path, executable: str = "node") -> NodeProcess:
    """The installed node with the default settings, an empty numba cache and an empty home: a first start."""
    env = installed_env(prefix, ros_env)
    env.update(NUMBA_CACHE_DIR=str(folder / "numba"), HOME=str(folder / "home"))
    (folder / "home").mkdir()
    params = params_yaml(folder / "params.yaml", {"device": "cpu"})
    return NodeProcess(prefix, env, params, {}, folder / "node.log", executable=executable)


def orphans(before: set[str]) -> list[str]:
    """Fast DDS segments in /dev/shm that were not there before and whose lock file no process holds."""
    found = []
    for lock in SHM_DIR.glob("fast*_el"):
        if lock.name[:-3] in before or "port" in lock.name:
            continue
        descriptor = os.open(lock, os.O_RDONLY)
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            found.append(lock.name[:-3])
        except OSError:  # held by a live participant
            pass
        finally:
            os.close(descriptor)
    return found


@pytest.mark.parametrize(
    "line",
    [
        "transport:",  # rclpy is up, the node not made yet
        "measuring the expected throughput",  # the kernels compile, for half a minute on a first start
    ],
)
def test_sigint_during_a_first_start_exits_0_within_2_s_and_releases_the_shared_memory(
    install_prefix: Path, ros_env: dict[str, str], tmp_path: Path, line: str
) -> None:
    before = {path.name for path in SHM_DIR.glob("fast*")}
    node = cold_node(install_prefix, ros_env, tmp_path)
    try:
        assert node.wait_for_log(line, STARTUP_S), node.log
        assert "ready:" not in node.log, "the node was ready before the signal: not a stop during the start"
        segments = shm_segments(node.proc.pid)
        code, took = node.stop(signal.SIGINT, GUARD_S)
    finally:
        node.close()
    assert code == 0, node.log
    assert took < EXIT_S, f"exited {took:.2f} s after SIGINT\n{node.log}"
    assert "stopped while starting" in node.log and "Traceback" not in node.log, node.log
    assert not left_behind(segments) and not orphans(before), node.log


def test_sigint_right_after_the_process_starts_ends_it_within_2_s_without_shared_memory(
    install_prefix: Path, ros_env: dict[str, str], tmp_path: Path
) -> None:
    """Before the stopper takes the signal (Python's first tenths of a second), the default handler ends it."""
    before = {path.name for path in SHM_DIR.glob("fast*")}
    node = cold_node(install_prefix, ros_env, tmp_path)
    try:
        code, took = node.stop(signal.SIGINT, GUARD_S)
    finally:
        node.close()
    assert code is not None and took < EXIT_S, f"exited {took:.2f} s after SIGINT (code {code})\n{node.log}"
    assert not orphans(before), node.log


def test_sigint_during_a_managed_nodes_first_configure_exits_0_within_2_s_and_releases_the_shared_memory(
    install_prefix: Path, ros_env: dict[str, str], tmp_path: Path
) -> None:
    """The configure runs in the executor's thread while the main thread serves: the serving shutdown, which must not
    wait for the configure's compilation."""
    before = {path.name for path in SHM_DIR.glob("fast*")}
    node = cold_node(install_prefix, ros_env, tmp_path, "managed_node")
    try:
        assert node.wait_for_log("unconfigured: waiting", STARTUP_S), node.log
        with ProbeClient("/stop_while_starting/in", "/stop_while_starting/out") as probe:
            change = probe.node.create_client(ChangeState, f"/{NODE_NAME}/change_state")
            assert change.wait_for_service(STARTUP_S), "no change_state service"
            change.call_async(ChangeState.Request(transition=Transition(id=Transition.TRANSITION_CONFIGURE)))
            assert probe.spin_until(lambda: "measuring the expected throughput" in node.log, STARTUP_S), node.log
        assert "points/s" not in node.log, "the configure was over before the signal"
        segments = shm_segments(node.proc.pid)
        code, took = node.stop(signal.SIGINT, GUARD_S)
    finally:
        node.close()
    print(f"managed node, SIGINT during its first configure: exit code {code} after {took:.2f} s")
    assert code == 0, node.log
    assert took < EXIT_S, f"exited {took:.2f} s after SIGINT\n{node.log}"
    assert "Traceback" not in node.log, node.log
    assert not left_behind(segments) and not orphans(before), node.log
