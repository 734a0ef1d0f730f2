"""How long the installed node takes to end when SIGINT comes during a first start, and whether it leaves its DDS
shared memory behind.

Each run starts the colcon-installed `node` with the default settings and an empty numba cache (NUMBA_CACHE_DIR) and
home directory, as the first start after a build is, sends SIGINT a given time after the start, and reports the
seconds from the signal to the exit, the exit code, and the Fast DDS segments in /dev/shm that the run left without
an owner. The moments span the start: the imports, rclpy's start, the kernels' compilation and the throughput probe.

Run (after `make demo`):
  .venv/bin/python docs/tools/stop_while_starting.py --prefix out/ws/install/triplet_normal_ros [--out docs/RESULTS.md]
"""

from __future__ import annotations

import argparse
import fcntl
import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from triplet_normal_ros.evaluation.report import tool_block, tool_command, tool_header, update_section
from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node

#: Seconds after the start at which SIGINT is sent.
MOMENTS = (0.0, 1.0, 3.0, 6.0, 12.0)
#: A run not over this long after its signal is killed and reported as such.
GUARD_S = 60.0
SHM = Path("/dev/shm")


def orphans(before: set[str]) -> list[str]:
    """Fast DDS segments in /dev/shm that were not there before the run and whose lock file nobody holds."""
    left = []
    for lock in SHM.glob("fast*_el"):
        segment = lock.name[:-3]
        if segment in before or "port" in segment:
            continue
        try:
            descriptor = os.open(lock, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            left.append(segment)
        except OSError:  # held: a live participant's
            pass
        finally:
            os.close(descriptor)
    return left


def one_run(prefix: Path, moment: float, folder: Path) -> str:
    """Start a cold node, SIGINT it `moment` s later; one table row."""
    env = node_env(prefix)
    env.update(NUMBA_CACHE_DIR=str(folder / "numba"), HOME=str(folder / "home"), ROS_HOME=str(folder / "ros"))
    (folder / "home").mkdir()
    before = {p.name for p in SHM.glob("fast*")}
    node = start_node(prefix, params_file(folder / "params.yaml", {"device": "cpu"}), {}, folder / "node.log", env)
    started = time.monotonic()
    time.sleep(max(0.0, started + moment - time.monotonic()))
    signalled = time.monotonic()
    node.send_signal(signal.SIGINT)
    try:
        code: int | str = node.wait(GUARD_S)
    except subprocess.TimeoutExpired:
        node.kill()
        node.wait()
        code = "killed"
    took = time.monotonic() - signalled
    lines = (folder / "node.log").read_text(errors="replace").strip().splitlines()
    last = lines[-1].split("]: ", 1)[-1][:70] if lines else "(no output)"
    return f"| {moment:.0f} s | {took:.2f} s | {code} | {len(orphans(before))} | {last} |"


def markdown(command: str, load: float, rows: list[str]) -> str:
    """The `stop-while-starting` block: the command, date and load, what a run is, and the table."""
    about = (
        "Each run starts the installed `node` with its defaults and an empty kernel cache (NUMBA_CACHE_DIR) and home, "
        "so it compiles its kernels for half a minute, and sends SIGINT the given time after; *segments left*: Fast "
        "DDS segments in /dev/shm the run left without an owner; *last log line*: the node's, `(no output)` when "
        "Python's default handler ended it before the stopper existed."
    )
    columns = (
        "| SIGINT after | exit after | code | segments left | last log line |\n| ---: | ---: | ---: | ---: | --- |"
    )
    return tool_block(tool_header(command, load), about, columns, rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", type=Path, default=Path("out/ws/install/triplet_normal_ros"))
    parser.add_argument("--moments", type=float, nargs="+", default=MOMENTS, help="seconds after the start")
    parser.add_argument("--out", type=Path, help="results file to write the `stop-while-starting` block into")
    args = parser.parse_args()
    # A shell starts a background job with SIGINT ignored, and the node would inherit that until it takes the signal
    # itself; with a handler here, each node starts with the default, as from a terminal.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    load = os.getloadavg()[0]
    rows = []
    for moment in args.moments:
        with tempfile.TemporaryDirectory(prefix="stop_while_starting_") as folder:
            rows.append(one_run(args.prefix.resolve(), moment, Path(folder)))
            print(rows[-1], flush=True)
    if args.out:
        command = tool_command("docs/tools/stop_while_starting.py")
        print(f"wrote {update_section(args.out, 'stop-while-starting', markdown(command, load, rows))}")


if __name__ == "__main__":
    main()
