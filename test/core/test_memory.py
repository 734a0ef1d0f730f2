"""The estimator keeps the memory a frame frees for the next frame: once it is made, estimating the same 640×480
frame again faults (almost) no fresh page in, where an allocator that maps large arrays afresh faults thousands a
frame.

Each case runs in a fresh interpreter, since the allocator's settings are the process's and last for its life."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from triplet_normal_ros.core.config import memory

#: Estimate a simulated 640×480 depth frame by window `pca` five times and print whether the estimator kept freed
#: memory and the fewest minor page faults of the last three calls (the fewest: a page the system reclaims from an
#: idle process, or a thread's first stack, faults once and says nothing of the frames' arrays). With `force_fresh`,
#: large requests are first set to fresh pages (glibc's starting threshold of 128 KiB, its adjustment off), the
#: behaviour the estimator replaces.
_PROGRAM = """
import ctypes, json, resource, sys
if sys.argv[1] == "force_fresh":
    ctypes.CDLL(None).mallopt(-3, 128 * 1024)
from triplet_normal_ros.core.config.memory import keep_freed_memory
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.simulation.depth_camera import depth_frame
frame = depth_frame(1)
points, shape = frame.points.reshape(-1, 3), frame.points.shape[:2]
estimator = NormalEstimator(method="pca", radius=0.05, device="cpu")
for _ in range(2):
    estimator.estimate(points, shape=shape)
faults = []
for _ in range(3):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    estimator.estimate(points, shape=shape)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps({"kept": keep_freed_memory(), "faults": min(faults)}))
"""


def _later_frames(mode: str, keep: str = "1") -> dict:
    env = {**os.environ, "TRIPLET_NORMAL_KEEP_MEMORY": keep}
    done = subprocess.run([sys.executable, "-c", _PROGRAM, mode], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_frame_after_the_first_faults_no_fresh_pages_in() -> None:
    fresh = _later_frames("force_fresh", keep="0")
    kept = _later_frames("force_fresh")
    assert not fresh["kept"] and kept["kept"]
    # a 640x480 frame's arrays span thousands of pages; kept, each frame reuses the one before's
    assert fresh["faults"] > 2000, fresh
    assert kept["faults"] < fresh["faults"] / 10, (kept, fresh)


def test_the_environment_variable_leaves_the_allocator_alone() -> None:
    assert _later_frames("plain", keep="0")["kept"] is False


class _CLibrary:
    """A C library's mallopt that takes mmap thresholds up to `largest` and records what it was told."""

    def __init__(self, largest: int) -> None:
        self.largest, self.told = largest, []

    def mallopt(self, parameter: int, value: int) -> int:
        self.told.append((parameter, value))
        return int(parameter != -3 or value <= self.largest)


def test_a_glibc_that_refuses_256_mib_gets_the_documented_32_and_nothing_without_an_mmap_threshold() -> None:
    """Older glibc versions refuse an mmap threshold above 32 MiB: the setting falls back to it. A library that takes
    neither leaves the trim threshold alone too (alone it would turn glibc's adaptive thresholds off)."""
    recent, older, neither = _CLibrary(1 << 40), _CLibrary(32 << 20), _CLibrary(0)
    assert memory.set_thresholds(recent.mallopt) == memory.KEEP_BYTES
    assert memory.set_thresholds(older.mallopt) == memory.DOCUMENTED_MMAP_MAX == 32 << 20
    assert older.told == [(-3, memory.KEEP_BYTES), (-3, 32 << 20), (-1, memory.KEEP_BYTES)]
    assert memory.set_thresholds(neither.mallopt) == 0 and all(parameter == -3 for parameter, _ in neither.told)
