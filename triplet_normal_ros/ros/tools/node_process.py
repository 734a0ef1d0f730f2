"""The colcon-installed node as a separate process: its environment, parameter file, start, readiness and stop.

`make demo` and the measuring tools under docs/tools/ all drive the node the way a robot runs it, from its install,
in a process of its own, on a private ROS graph; this is that harness once, so each of them measures the same thing.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path

from .replay import ReplayClient

PACKAGE = "triplet_normal_ros"


def node_env(prefix: Path) -> dict[str, str]:
    """What sourcing the install gives a Python package, on a private localhost-only ROS graph.

    The install's site-packages comes first on PYTHONPATH so the node runs the installed copy, never a checkout
    behind it; a ROS_DOMAIN_ID already set is kept, so a caller can choose the graph.
    """
    env = dict(os.environ)
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH")) if p)
    env.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


def params_file(
    path: Path, params: Mapping[str, object], reliable_topics: tuple[str, ...] = (), depth: int | None = None
) -> Path:
    """A parameter file for the node; `reliable_topics` get a reliable subscription QoS override (and a history of
    `depth` clouds, when given).

    Without an override full frames take the default, best-effort path (docs/NODE.md, "Topics and QoS"), as from a
    camera driver; a tool that publishes faster than the node answers makes its input reliable so that what it sends
    arrives.
    """
    lines = ["/**:", "  ros__parameters:"] + [f"    {k}: {yaml_value(v)}" for k, v in params.items()]
    if reliable_topics:
        lines.append("    qos_overrides:")
        for topic in reliable_topics:
            lines += [f"      {topic}:", "        subscription:", "          reliability: reliable"]
            lines += [] if depth is None else [f"          depth: {depth}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def yaml_value(value: object) -> str:
    """`value` as ROS 2 parameter YAML: typed as rclpy will declare it (a bool stays a bool, a float keeps its point,
    a string is quoted so that 'true' or '0' stay strings)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    return repr(value)


def start_node(
    prefix: Path, params: Path, remaps: Mapping[str, str], log: Path, env: Mapping[str, str]
) -> subprocess.Popen:
    """The installed `node` executable with `params` and `remaps`, its output in `log` (and its working directory
    `log`'s folder, where ROS writes nothing else)."""
    executable = prefix / "lib" / PACKAGE / "node"
    if not executable.is_file():
        raise SystemExit(f"no installed node at {executable}; run colcon build first (make demo does)")
    args = [str(executable), "--ros-args", "--params-file", str(params)]
    for name, target in remaps.items():
        args += ["-r", f"{name}:={target}"]
    with log.open("w") as out:  # the child keeps its own descriptor
        return subprocess.Popen(args, env=dict(env), stdout=out, stderr=subprocess.STDOUT, cwd=log.parent)


def wait_for_node(client: ReplayClient, node: subprocess.Popen, log: Path, timeout: float = 120.0) -> None:
    """Until the node's topics and services match; fail fast (with its own last log line) if it exits instead."""
    deadline = time.monotonic() + timeout
    while not client.wait_for_node(1.0):
        if node.poll() is not None or time.monotonic() > deadline:
            lines = log.read_text(errors="replace").strip().splitlines()
            raise SystemExit(f"the node did not come up: {lines[-1] if lines else 'no output'} (log: {log})")


def stop_node(node: subprocess.Popen, timeout: float = 10.0) -> int | None:
    """SIGINT, as Ctrl-C would; the exit code, or None when it had to be killed after `timeout` s."""
    if node.poll() is None:
        node.send_signal(signal.SIGINT)
    try:
        return node.wait(timeout)
    except subprocess.TimeoutExpired:
        node.kill()
        node.wait()
        return None
