"""Soak under overload: flood the colcon-installed node (PCA) with clouds of 3k to 128k points, much faster than it
can process them, and measure its memory, drops, answers and SIGINT exit time.

Run from the repository root:
    .venv/bin/python docs/tools/soak.py [--seconds 120] [--rate 20] [--prefix INSTALL] [--out docs/RESULTS.md]

Without --prefix it colcon-builds the checkout into out/soak_ws first. The node runs on a private, localhost-only ROS
graph; its log goes to out/soak/node.log. The soak itself (the clouds, the checks on every answer, RSS sampling, the
node's drop counts) is ros/tools/overload.py, which test/ros/test_soak.py runs for 100 s. --out writes the
`soak` block of the results file; the figures are printed either way.
"""

from __future__ import annotations

import argparse
import os
import random
import subprocess
import sys
import time
from pathlib import Path

from tqdm import tqdm

from triplet_normal_ros.evaluation.report import tool_command, update_section
from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node, stop_node, wait_for_node
from triplet_normal_ros.ros.tools.overload import (
    FLOOD_DEPTH,
    NODE_PARAMS,
    RSS_EVERY_S,
    OverloadClient,
    SoakResult,
    cloud_pool,
    soak,
)

REPO = Path(__file__).resolve().parents[2]

IN, OUT = "/soak/points", "/soak/normals"


def private_ros_env(folder: Path) -> None:
    """This process on a ROS graph of its own (domains 101-200, apart from the tests' 1-100), ROS logs in `folder`;
    the node inherits it through `node_env`."""
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(101, 200))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["RCUTILS_COLORIZED_OUTPUT"] = "0"
    os.environ["PYTHONUNBUFFERED"] = "1"
    os.environ["ROS_HOME"] = str(folder / "ros")


def colcon_build(workspace: Path) -> Path:
    """`colcon build` this checkout into `workspace`; the package's install prefix."""
    workspace.mkdir(parents=True, exist_ok=True)
    cmd = [str(Path(sys.executable).with_name("colcon")), "--log-base", str(workspace / "log"), "build"]
    cmd += ["--base-paths", str(REPO), "--build-base", str(workspace / "build")]
    cmd += ["--install-base", str(workspace / "install")]
    if subprocess.run(cmd, cwd=workspace).returncode != 0:
        raise SystemExit(f"soak: colcon build failed; see {workspace / 'log'}")
    return workspace / "install" / "triplet_normal_ros"


def timed_stop(node: subprocess.Popen) -> tuple[int | None, float]:
    """SIGINT while the node is still overloaded: (exit code or None if it had to be killed, seconds to exit)."""
    start = time.monotonic()
    code = stop_node(node)
    return code, time.monotonic() - start


def run(prefix: Path, folder: Path, seconds: float, rate: float) -> SoakResult:
    private_ros_env(folder)
    log = folder / "node.log"
    params = params_file(folder / "params.yaml", NODE_PARAMS, reliable_topics=(IN,), depth=FLOOD_DEPTH)
    node = start_node(prefix, params, {"input": IN, "output": OUT}, log, node_env(prefix))
    try:
        with OverloadClient(IN, OUT, cloud_pool()) as client:
            wait_for_node(client, node, log)
            with tqdm(total=round(seconds), unit="s", desc="soak") as bar:
                result = soak(
                    node.pid,
                    lambda: timed_stop(node),
                    lambda: log.read_text(errors="replace"),
                    client,
                    seconds,
                    rate,
                    lambda elapsed: bar.update(min(round(seconds), int(elapsed)) - bar.n),
                )
    finally:
        stop_node(node)
    return result


def markdown(result: SoakResult, command: str, load: tuple[float, float, float]) -> str:
    p = NODE_PARAMS
    return (
        f"### Soak under overload (`docs/tools/soak.py`)\n\n"
        f"Command: `{command}` · {time.strftime('%Y-%m-%d')} · load average at start {load[0]:.1f} "
        f"(2 cores, other engineers' tests running)\n"
        f"The colcon-installed node, method {p['method']}, radius {p['radius']} m, k = {p['k']}, on {p['device']}, "
        f"input QoS overridden to reliable; the clouds cycle through the sizes below (x, y, z, rgb; 16 bytes a "
        f"point) under five frame_ids; MB are 2^20 bytes, RSS is VmRSS of /proc/<pid>/status every "
        f"{RSS_EVERY_S:g} s. Every answer was checked against the cloud its stamp names: frame_id, "
        f"height, width, fields, the xyz bytes, and normals equal to every other answer to that cloud.\n\n"
        f"{result.table()}\n"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="how long to send (default 120)")
    parser.add_argument("--rate", type=float, default=20.0, help="clouds sent per second (default 20)")
    parser.add_argument("--prefix", type=Path, help="a colcon install prefix of triplet_normal_ros (default: build)")
    parser.add_argument("--out", type=Path, help="results file to write the `soak` block into")
    args = parser.parse_args()
    folder = (REPO / "out" / "soak").resolve()
    folder.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()
    prefix = args.prefix.resolve() if args.prefix else colcon_build(REPO / "out" / "soak_ws")
    result = run(prefix, folder, args.seconds, args.rate)
    print(result.table())
    csv = folder / "rss.csv"
    csv.write_text("seconds,rss_mb\n" + "".join(f"{t:.2f},{mb:.1f}\n" for t, mb in result.rss_samples))
    print(f"RSS samples: {csv}")
    if args.out:
        command = tool_command("docs/tools/soak.py")
        print(f"wrote {update_section(args.out, 'soak', markdown(result, command, load))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
