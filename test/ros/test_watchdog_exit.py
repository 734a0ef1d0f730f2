"""The shutdown watchdog: a worker still inside an uncancellable step JOIN_TIMEOUT_S after SIGTERM makes the process
exit with its own code (2), after an error line, instead of 0, and without leaving its DDS shared memory behind.

Not driven through a real estimate: what the watchdog guards against is one torch or scipy call that runs longer than
JOIN_TIMEOUT_S between two cancel checks (the estimator checks between neighbour-search chunks and network batches,
`core.kernels`), and no cloud is certain to do that on every machine: a fast GPU finishes any one step a test could
afford to send in time, and the test would then pass or fail with the machine's speed. So the process below is the
node's own start-up (rclpy, the real node, the real stop handlers that start the real watchdog) with its main thread,
where the node serves, blocked on a lock nobody releases: a serving loop that is certain never to reach a cancel check.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import STARTUP_S, left_behind, shm_segments

from triplet_normal_ros.ros.runner import EXIT_ABANDONED, JOIN_TIMEOUT_S

pytestmark = pytest.mark.slow  # a node process

#: Built as the installed node builds itself, then stuck where `serve` would run: Event().wait() takes a lock that
#: nothing releases. The signal handler and the wakeup thread both run; only the watchdog can end the process.
STUCK_NODE = """
import sys, threading
import rclpy
from rclpy.signals import SignalHandlerOptions
from triplet_normal_ros.ros.node import TripletNormalNode
from triplet_normal_ros.ros.runner import guard_serving
from triplet_normal_ros.ros.stopper import STOPPER

STOPPER.install("triplet_normal")
rclpy.init(args=sys.argv, signal_handler_options=SignalHandlerOptions.NO)
served = TripletNormalNode(serve_in_caller=True)
guard_serving(STOPPER, served)
print("serving: blocked", flush=True)
threading.Event().wait()
"""
#: A hang guard only: a process not gone this long after SIGTERM is stuck, however slow the machine. (Its start-up,
#: which may compile the CPU kernels first, gets conftest's STARTUP_S.)
EXIT_GUARD_S = 60.0


def test_a_worker_stuck_past_the_watchdog_exits_2_with_an_error_and_releases_its_shared_memory(
    ros_env: dict[str, str], tmp_path: Path
) -> None:
    log_path = tmp_path / "stuck.log"
    args = [sys.executable, "-c", STUCK_NODE, "--ros-args", "-p", "method:=pca", "-p", "device:=cpu"]
    with log_path.open("w") as log:
        proc = subprocess.Popen(args, env=ros_env, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
    try:
        deadline = time.monotonic() + STARTUP_S
        while "serving: blocked" not in log_path.read_text() and proc.poll() is None:
            assert time.monotonic() < deadline, log_path.read_text()
            time.sleep(0.05)
        assert proc.poll() is None, log_path.read_text()
        segments = shm_segments(proc.pid)
        signalled = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(EXIT_GUARD_S)
        waited = time.monotonic() - signalled
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    text = log_path.read_text()
    assert code == EXIT_ABANDONED, text
    # The watchdog's timer starts when the signal arrives, so the process cannot have left before it ran out.
    assert waited >= JOIN_TIMEOUT_S, f"exited {waited:.2f} s after SIGTERM: not the watchdog"
    (line,) = [line for line in text.splitlines() if "worker still busy" in line]
    assert line.startswith("[ERROR]") and f"after {JOIN_TIMEOUT_S} s; exiting {EXIT_ABANDONED}" in line, line
    assert "Traceback" not in text
    # Its participant's segment (35 MB under the shipped profile) went with it, though the process skipped teardown.
    assert segments and not left_behind(segments), segments
