"""Which PointCloud2 sizes reach a best-effort (sensor data) subscription in another process, per Fast DDS setup.

Run from the repository root: .venv/bin/python docs/tools/large_cloud_delivery.py [--sizes MB ...] [--count N]
[--out docs/RESULTS.md]

Each case starts two fresh processes of this script: a "node" that subscribes with ``qos_profile_sensor_data`` (the
node's default) and a "driver" that publishes ``--count`` clouds of each size one at a time, ``--gap`` s apart, with a
best-effort or a reliable writer. Each side gets its own environment (with or without the shipped Fast DDS profile),
because a camera driver in another process keeps its own settings. Delivered = clouds the subscriber received.
Both processes use a random ROS_DOMAIN_ID; ``--range`` sets ROS_AUTOMATIC_DISCOVERY_RANGE (the tests use LOCALHOST,
a fresh ROS 2 install defaults to SUBNET).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from triplet_normal_ros.evaluation.report import tool_command, update_section

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "config" / "fastdds_large_data.xml"
TOPIC = "/large_cloud_delivery/points"
#: Bytes per point, as in a 640x480 XYZRGB frame published the way PCL lays it out (9.8 MB a frame).
POINT_STEP = 32


#: Fast DDS setups of one process, by name: the environment it gets on top of the base one.
SETUPS = {
    "default": {},
    "profile": {"FASTDDS_DEFAULT_PROFILES_FILE": str(PROFILE)},
    "LARGE_DATA": {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"},
    "SHM": {"FASTDDS_BUILTIN_TRANSPORTS": "SHM"},
}
_CLEARED = ("FASTDDS_DEFAULT_PROFILES_FILE", "RMW_FASTRTPS_USE_QOS_FROM_XML", "FASTDDS_BUILTIN_TRANSPORTS")


@dataclass(frozen=True)
class Case:
    """One row of the table: the publisher's reliability and each side's Fast DDS setup."""

    reliability: str  # "best_effort" | "reliable"
    node: str
    driver: str

    def label(self) -> str:
        return f"{self.reliability} | {self.node} | {self.driver}"


def _env(base: dict[str, str], setup: str) -> dict[str, str]:
    env = {k: v for k, v in base.items() if k not in _CLEARED}
    env.update(SETUPS[setup])
    return env


def run_case(case: Case, sizes_mb: list[float], count: int, gap: float, base: dict[str, str]) -> dict[float, int]:
    """Start the subscriber, then the publisher; return {size: delivered} from the subscriber's output."""
    node_env = _env(base, case.node)
    driver_env = _env(base, case.driver)
    node = subprocess.Popen(
        [sys.executable, __file__, "--role", "node"], env=node_env, stdout=subprocess.PIPE, text=True
    )
    try:
        assert node.stdout is not None
        if node.stdout.readline().strip() != "ready":
            raise SystemExit("subscriber did not start")
        args = [sys.executable, __file__, "--role", "driver", "--reliability", case.reliability, "--count", str(count)]
        args += ["--gap", str(gap), "--sizes", *map(str, sizes_mb)]
        subprocess.run(args, env=driver_env, check=True, timeout=120 + len(sizes_mb) * count * (gap + 5))
        time.sleep(2.0)
    finally:
        node.send_signal(signal.SIGINT)
        try:
            out, _ = node.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
            out, _ = node.communicate()
    got = [line.split()[1] for line in out.splitlines() if line.startswith("got ")]
    return {s: sum(1 for g in got if g.startswith(f"{s}:")) for s in sizes_mb}


def role_node() -> None:
    """The subscriber: sensor-data QoS, prints one line per cloud received."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    rclpy.init()
    node = rclpy.create_node("large_cloud_node")
    node.create_subscription(
        PointCloud2,
        TOPIC,
        lambda m: print(f"got {m.header.frame_id} {len(m.data)}", flush=True),
        qos_profile_sensor_data,
    )
    print("ready", flush=True)
    with contextlib.suppress(KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        rclpy.spin(node)


def role_driver(reliability: str, sizes_mb: list[float], count: int, gap: float) -> None:
    """The publisher: waits for the match, then sends ``count`` clouds per size, ``gap`` s apart."""
    import numpy as np
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2, PointField

    rclpy.init()
    node = rclpy.create_node("large_cloud_driver")
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy[reliability.upper()])
    pub = node.create_publisher(PointCloud2, TOPIC, qos)
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    time.sleep(1.0)
    fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")]
    for size in sizes_mb:
        n = int(size * 1e6) // POINT_STEP
        data = np.random.default_rng(0).random(n * POINT_STEP // 4, dtype=np.float32).tobytes()
        for i in range(count):
            msg = PointCloud2(height=1, width=n, fields=fields, point_step=POINT_STEP, row_step=n * POINT_STEP)
            msg.header.frame_id = f"{size}:{i}"
            msg.data = data
            pub.publish(msg)
            time.sleep(gap)
    node.destroy_node()
    rclpy.shutdown()


#: Rows by name: (node setup, driver setup), each with a best-effort and a reliable driver.
PAIRS = {
    "default": ("default", "default"),
    "node-profile": ("profile", "default"),
    "both-profile": ("profile", "profile"),
    "both-LARGE_DATA": ("LARGE_DATA", "LARGE_DATA"),
    "both-SHM": ("SHM", "SHM"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=["table", "node", "driver"], default="table")
    parser.add_argument("--reliability", choices=["best_effort", "reliable"], default="best_effort")
    parser.add_argument("--sizes", nargs="+", type=float, default=[0.4, 1.0, 2.5, 5.0, 9.8], help="MB per cloud")
    parser.add_argument("--count", type=int, default=10, help="clouds per size")
    parser.add_argument("--gap", type=float, default=0.5, help="seconds between clouds")
    parser.add_argument("--range", default="LOCALHOST", help="ROS_AUTOMATIC_DISCOVERY_RANGE for both processes")
    cases = ["default", "node-profile", "both-profile", "both-LARGE_DATA"]
    parser.add_argument("--cases", nargs="+", choices=list(PAIRS), default=cases)
    parser.add_argument("--out", type=Path, help="results file to write the `large-clouds` block into")
    args = parser.parse_args()
    if args.role == "node":
        return role_node()
    if args.role == "driver":
        return role_driver(args.reliability, args.sizes, args.count, args.gap)
    base = dict(os.environ)
    base["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
    base["ROS_AUTOMATIC_DISCOVERY_RANGE"] = args.range
    load = os.getloadavg()[0]
    rows = [
        f"| publisher | node | driver | {' | '.join(f'{s:g} MB' for s in args.sizes)} |",
        f"| --- | --- | --- | {' | '.join('---' for _ in args.sizes)} |",
    ]
    print("\n".join(rows))
    for name in args.cases:
        for case in (Case(r, *PAIRS[name]) for r in ("best_effort", "reliable")):
            got = run_case(case, args.sizes, args.count, args.gap, base)
            rows.append(f"| {case.label()} | {' | '.join(f'{got[s]}/{args.count}' for s in args.sizes)} |")
            print(rows[-1], flush=True)
    if args.out:
        text = markdown(tool_command("docs/tools/large_cloud_delivery.py"), load, args, rows)
        print(f"wrote {update_section(args.out, 'large-clouds', text)}")


def markdown(command: str, load: float, args: argparse.Namespace, rows: list[str]) -> str:
    """The `large-clouds` block: the command, date, Fast DDS version and load, what a row is, and the table."""
    return (
        f"Command: `{command}` · {time.strftime('%Y-%m-%d')} · rmw_fastrtps_cpp {version('ros-rmw-fastrtps-cpp')} "
        f"(Fast DDS {version('ros-fastdds')}) · load average at start {load:.1f} (2 cores) · "
        f"`ROS_AUTOMATIC_DISCOVERY_RANGE={args.range}`\n\n"
        "Two fresh processes per row, on one host and a random domain id: a *node* subscribing with "
        "`qos_profile_sensor_data` (best effort, keep last 5: the node's default) and a *driver* publishing "
        f"{args.count} bare PointCloud2 messages of each size, {args.gap:g} s apart, with a best-effort or a reliable "
        "writer. Each side gets its own Fast DDS setup: `default` (nothing set), `profile` "
        "(`FASTDDS_DEFAULT_PROFILES_FILE=config/fastdds_large_data.xml`), `LARGE_DATA` and `SHM` "
        "(`FASTDDS_BUILTIN_TRANSPORTS`). Delivered = messages the subscriber received; MB = 10^6 bytes.\n\n"
        + "\n".join(rows)
        + "\n"
    )


def version(distribution: str) -> str:
    """An installed distribution's version, or `?` where pip did not install it (a system ROS)."""
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    main()
