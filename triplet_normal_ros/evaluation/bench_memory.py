"""`bench`'s memory table: what one estimator costs in resident memory, idle and answering a whole frame, per method.

Each method runs in a fresh Python process, so one method's allocations (torch's caching, numba's compiled code, a
KD-tree) never count against another: the process imports the package, builds the estimator as the node does
(`NormalEstimator` with its checkpoint loaded), reads its resident set (*idle*), estimates the whole frame once and
reads its peak resident set (the kernel's VmHWM: *peak*). The node adds rclpy and its messages to the idle figure;
the frame is the bench's simulated 640x480 depth frame, organized, as a depth camera's driver publishes it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

#: (label, NormalEstimator keyword arguments): the node's defaults on a CPU and the other methods and checkpoints.
METHODS = (
    ("pca (windows)", {"method": "pca"}),
    ("hybrid, range (the node's CPU default)", {"method": "hybrid"}),
    ("hybrid, lite", {"method": "hybrid", "checkpoint": "lite"}),
    ("hybrid, default", {"method": "hybrid", "checkpoint": "default"}),
    ("learned, range", {"method": "learned", "checkpoint": "range"}),
)

_PROBE = """
import json, os, sys
import numpy as np
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation.bench_memory import status_mb
from triplet_normal_ros.simulation.depth_camera import depth_frame

frame = depth_frame(0)
points = frame.points.reshape(-1, 3).astype(np.float64)
estimator = NormalEstimator(device="cpu", radius=0.05, **json.loads(sys.argv[1]))
idle = status_mb(os.getpid(), "VmRSS")
estimator.estimate(points, shape=frame.points.shape[:2])
print(json.dumps({"idle": idle, "peak": status_mb(os.getpid(), "VmHWM")}))
"""


def status_mb(pid: int, field: str = "VmRSS") -> float:
    """A memory field of process `pid` in MB (2^20 bytes), from /proc/<pid>/status: VmRSS, its resident set now, or
    VmHWM, the most it ever held."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {field} for process {pid}")


def measure(options: dict) -> tuple[float, float]:
    """(idle MB, peak MB) of a fresh process holding one estimator built with `options`, around one whole frame."""
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, json.dumps(options)], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"memory probe for {options} failed: {done.stderr.strip().splitlines()[-1:]}")
    found = json.loads(done.stdout.strip().splitlines()[-1])
    return found["idle"], found["peak"]


def memory_rows(method: str | None = None) -> list[tuple[str, float, float]]:
    """(label, idle MB, peak MB) of every method in METHODS, or of those of one `method`."""
    return [(label, *measure(options)) for label, options in METHODS if method in (None, options["method"])]


def memory_markdown(rows: list[tuple[str, float, float]]) -> list[str]:
    """The memory table's lines."""
    return [
        "Resident memory of one estimator on a CPU, each in a fresh process (`bench_memory.py`): *idle* after the "
        "package is imported and the estimator built with its checkpoint, *peak* over one whole 640x480 depth frame. "
        "The node adds rclpy and its messages.",
        "",
        "| method | idle MB | peak MB | peak - idle MB |",
        "| --- | ---: | ---: | ---: |",
        *(f"| {label} | {idle:.0f} | {peak:.0f} | {peak - idle:.0f} |" for label, idle, peak in rows),
    ]
