"""How long the installed node takes from its start to its first answered full frame: the first start after a fresh
`colcon build`, a second start, and a start whose kernel cache is empty.

A camera driver is already publishing when the node starts, as on a robot after a deploy: this process publishes a
real 640x480 Kinect frame (`table_scene_mug`, shipped) best effort every `--every` s, and the time counted runs from
starting the node's process to the first answer. Every start has an empty home and ROS home. The cases:
- `first start after build`: a fresh `colcon build` into a new workspace, then the installed node, as after a deploy
  (the build compiles the kernels into the install: setup.py, `triplet-normal warm`);
- `second start`: the same install again;
- `empty kernel cache`: NUMBA_CACHE_DIR set to an empty folder, so the node compiles its kernels as every first start
  did before the build compiled them (what a read-only install without a prepared cache still gets).
Each row also gives the node's own "ready" moment and its warm-up line.

Run: .venv/bin/python docs/tools/first_frame.py [--out docs/RESULTS.md]   (about 2 minutes: a build and three starts)
--out writes the `first-start` block of that file.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from triplet_normal_ros.evaluation.report import tool_command, tool_header, update_section
from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node, stop_node
from triplet_normal_ros.ros.tools.replay import SENSOR_INPUT, ReplayClient, load_frame

REPO = Path(__file__).resolve().parents[2]
COLCON = Path(sys.executable).with_name("colcon")
#: A start that has not answered after this long is reported as such.
GUARD_S = 180.0
INPUT, OUTPUT = "/camera/depth/points", "/camera/depth/points_normals"


def build(workspace: Path) -> tuple[Path, float]:
    """A fresh `colcon build` of this repository into `workspace`: the package's install prefix and the seconds."""
    workspace.mkdir()
    start = time.monotonic()
    cmd = [str(COLCON), "--log-base", str(workspace / "log"), "build", "--base-paths", str(REPO)]
    cmd += ["--build-base", str(workspace / "build"), "--install-base", str(workspace / "install")]
    done = subprocess.run(cmd, cwd=workspace, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"colcon build failed: {done.stdout[-2000:]}{done.stderr[-2000:]}")
    return workspace / "install" / "triplet_normal_ros", time.monotonic() - start


def log_moment(log: Path, pattern: str) -> str:
    """The first log line matching `pattern`, without its logger prefix ('' when there is none)."""
    for line in log.read_text(errors="replace").splitlines():
        if re.search(pattern, line):
            return line.split("]: ", 1)[-1]
    return ""


def one_start(case: str, prefix: Path, folder: Path, client: ReplayClient, every: float, cache: Path | None) -> str:
    """Start the node with an empty home (and, given `cache`, that NUMBA_CACHE_DIR), publish the frame until it
    answers; one table row."""
    env = node_env(prefix)
    env.update(HOME=str(folder / "home"), ROS_HOME=str(folder / "ros"), ROS_DOMAIN_ID=client.domain)
    (folder / "home").mkdir()
    if cache is not None:
        cache.mkdir()
        env["NUMBA_CACHE_DIR"] = str(cache)
    cloud = load_frame("table_scene_mug").to_cloud(client.header())
    log = folder / "node.log"
    started = time.monotonic()
    params = params_file(folder / "params.yaml", {"device": "cpu"})
    node = start_node(prefix, params, {"input": INPUT, "output": OUTPUT}, log, env)
    try:
        answer = client.request_resending(cloud, timeout=GUARD_S, every=every)
        took = time.monotonic() - started
    finally:
        stop_node(node)
    first = f"{took:.1f} s" if answer is not None else f"none in {GUARD_S:.0f} s"
    warm = re.search(r"warm-up ([\d.]+ s, [^;)]*)", log_moment(log, "warm-up"))
    return f"| {case} | {first} | {warm.group(1) if warm else '(no warm-up line)'} |"


class Client(ReplayClient):
    """The replay client on a domain of its own, which each node joins."""

    def __init__(self, domain: str) -> None:
        os.environ["ROS_DOMAIN_ID"] = domain
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.domain = domain
        super().__init__(INPUT, OUTPUT, input_qos=SENSOR_INPUT)


def markdown(command: str, load: float, build_s: float, every: float, rows: list[str]) -> str:
    return (
        f"{tool_header(command, load)}\n\n"
        f"A fresh `colcon build` of the checkout took {build_s:.1f} s, the kernels' compilation included. Each time "
        "runs from starting the installed node's process, with its default parameters and an empty home and ROS "
        "home, to the first answer to a full 640x480 Kinect frame (`table_scene_mug`) that a driver already running "
        f"publishes best effort every {every:g} s.\n\n"
        "| start | first full frame answered after | warm-up (node's log) |\n| --- | ---: | --- |\n"
        + "\n".join(rows)
        + "\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=float, default=0.25, help="seconds between the driver's frames")
    parser.add_argument("--domain", default="77", help="ROS_DOMAIN_ID of the run")
    parser.add_argument("--out", type=Path, help="results file to write the `first-start` block into")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="first_frame_") as tmp:
        root = Path(tmp)
        prefix, build_s = build(root / "ws")
        print(f"colcon build (with the kernels): {build_s:.1f} s")
        rows = []
        with Client(args.domain) as client:
            cases = (("first start after build", None), ("second start", None), ("empty kernel cache", root / "numba"))
            for i, (case, cache) in enumerate(cases):
                folder = root / f"start{i}"
                folder.mkdir()
                rows.append(one_start(case, prefix, folder, client, args.every, cache))
                print(rows[-1], flush=True)
    if args.out:
        command = tool_command("docs/tools/first_frame.py")
        print(f"wrote {update_section(args.out, 'first-start', markdown(command, load, build_s, args.every, rows))}")


if __name__ == "__main__":
    main()
