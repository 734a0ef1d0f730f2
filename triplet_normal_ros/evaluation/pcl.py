"""PCL's normal estimators as `bench` anchors, through a small C++ tool that is compiled on first use.

PCL has no Python binding to rely on, so `pcl_normals.cpp` (its top comment gives the file formats and the settings)
does the work. It sits next to this module and ships as package data, not under docs/tools/ with the other tools,
because `bench` runs from the installed package, where docs/ is not. Where PCL's headers are installed
(`apt-get install libpcl-dev`), the first load compiles it with g++ and pkg-config's flags for PCL into a cache folder,
under a name keyed by the source and the flags, so a changed source or PCL builds a new one. Where they are not,
`pcl_anchors` raises ImportError and bench says in one line how to install them: PCL is never a dependency of the
package, its tests or CI.

* **PCL integral image, AVERAGE_3D_GRADIENT** and **COVARIANCE_MATRIX** (organized clouds only):
  `IntegralImageNormalEstimation` with PCL's tutorial settings, MaxDepthChangeFactor 0.02 and NormalSmoothingSize 10.
* **PCL NormalEstimationOMP KNN30**: the 30 nearest points from a KD-tree (`setKSearch(30)`) on every CPU; PCL takes a
  radius or a k, not both, so unlike Open3D's KNN30 no ball caps it.

A process's start and its file IO are no part of an estimator's cost, so the tool times each estimator itself, one
warm-up and `repeats` runs (`anchors.FAST_REPEATS`) around the computation alone, and the anchors report those seconds
(`Anchor.times_itself`). One run of the tool gives every estimator on a cloud, so the anchors of one cloud share it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("pcl_normals.cpp")
#: Where PCL's headers are looked for: Debian's and Ubuntu's libpcl-dev, then a PCL built from source.
INCLUDE_ROOTS = (Path("/usr/include"), Path("/usr/local/include"))
INSTALL = "apt-get install libpcl-dev"
#: The PCL libraries the tool links, by pkg-config name without the version.
MODULES = ("pcl_common", "pcl_features", "pcl_search", "pcl_kdtree")
#: The tool's method names and the anchors they become: (method, table name, organized only, what it calls).
METHODS = (
    ("average_3d_gradient", "PCL integral image, AVERAGE_3D_GRADIENT", True,
     "`IntegralImageNormalEstimation` AVERAGE_3D_GRADIENT, MaxDepthChangeFactor 0.02, NormalSmoothingSize 10"),
    ("covariance_matrix", "PCL integral image, COVARIANCE_MATRIX", True,
     "the same with COVARIANCE_MATRIX"),
    ("omp_knn30", "PCL NormalEstimationOMP KNN30", False,
     "`NormalEstimationOMP` with `setKSearch(30)` on a KD-tree"),
)  # fmt: skip


def cache_dir() -> Path:
    """Where compiled tools are kept: $XDG_CACHE_HOME/triplet_normal_ros, else ~/.cache/triplet_normal_ros."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "triplet_normal_ros"


def pcl_include(roots: Sequence[Path] = INCLUDE_ROOTS) -> Path | None:
    """The newest pcl-X.Y header folder under `roots` that has the integral-image estimator, or None."""
    found = [p.parent.parent.parent for root in roots for p in root.glob("pcl-*/pcl/features/integral_image_normal.h")]
    return max(
        found, key=lambda p: [int(n) for n in p.name.removeprefix("pcl-").split(".") if n.isdigit()], default=None
    )


def compile_flags(version: str) -> list[str]:
    """g++'s flags for PCL `version` (1.13) from pkg-config, OpenMP for NormalEstimationOMP's threads. PCL installs
    pcl_features-1.13.pc; Debian's and Ubuntu's libpcl-dev name it pcl_features.pc."""
    if shutil.which("pkg-config") is None:
        raise ImportError("pkg-config is not on PATH")
    for packages in ([f"{module}-{version}" for module in MODULES], list(MODULES)):
        command = ["pkg-config", "--cflags", "--libs", *packages]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        if done.returncode == 0:
            return ["-O2", "-std=c++17", "-fopenmp", *done.stdout.split()]
    raise ImportError(f"pkg-config does not know PCL {version}'s libraries ({INSTALL})")


def build_tool(include: Path, cache: Path) -> Path:
    """The tool compiled against the PCL of `include`: from `cache` when this source and these flags were built
    before, else compiled now and kept there."""
    if shutil.which("g++") is None:
        raise ImportError("g++ is not on PATH")
    flags = compile_flags(include.name.removeprefix("pcl-"))
    key = hashlib.sha256(SOURCE.read_bytes() + " ".join(flags).encode()).hexdigest()[:16]
    tool = cache / f"pcl_normals-{key}"
    if tool.is_file():
        return tool
    cache.mkdir(parents=True, exist_ok=True)
    partial = cache / f"{tool.name}.{os.getpid()}.partial"  # renamed when done, so no half-written tool is found
    print(f"bench: compiling {SOURCE.name} against {include} into {cache} (once)", file=sys.stderr)
    done = subprocess.run(["g++", str(SOURCE), "-o", str(partial), *flags], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        log = cache / f"{tool.name}.log"
        log.write_text(done.stderr)
        raise ImportError(f"{SOURCE.name} did not compile against {include} (g++'s errors: {log})")
    partial.replace(tool)
    return tool


def run_tool(
    tool: Path, points: np.ndarray, shape: tuple[int, int] | None, threads: int, repeats: int
) -> dict[str, tuple[np.ndarray, list[float]]]:
    """Every estimator of the tool on one cloud: method -> (normals (N, 3) float64 with NaN rows, seconds of each
    timed run). An unorganized cloud (`shape` None) goes as one row, where only the KD-tree estimator runs."""
    height, width = shape if shape is not None else (1, len(points))
    with tempfile.TemporaryDirectory(prefix="pcl_normals-") as folder:
        np.ascontiguousarray(points, np.float32).tofile(f"{folder}/points.f32")
        command = [str(tool), f"{folder}/points.f32", str(height), str(width), str(repeats), str(threads), folder]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"{tool.name} failed: {done.stderr.strip()}")
        seconds = json.loads(done.stdout.strip().splitlines()[-1])["seconds"]
        return {
            method: (np.fromfile(f"{folder}/{method}.f32", np.float32).reshape(-1, 3).astype(np.float64), runs)
            for method, runs in seconds.items()
        }


def tool_version(tool: Path) -> str:
    """PCL's version as the tool reports it, from a run on a three-point cloud."""
    with tempfile.TemporaryDirectory(prefix="pcl_normals-") as folder:
        np.eye(3, dtype=np.float32).tofile(f"{folder}/points.f32")
        command = [str(tool), f"{folder}/points.f32", "1", "3", "0", "1", folder]
        return json.loads(subprocess.run(command, capture_output=True, text=True, check=True).stdout)["pcl"]


class ToolRuns:
    """The tool's run on the last cloud asked for, which every anchor of that cloud reads, so one run serves all."""

    def __init__(self, tool: Path, threads: int, repeats: int) -> None:
        self.tool, self.threads, self.repeats = tool, threads, repeats
        self.key: tuple | None = None
        self.result: dict[str, tuple[np.ndarray, list[float]]] = {}

    def get(self, points: np.ndarray, shape: tuple[int, int] | None, method: str) -> tuple[np.ndarray, list[float]]:
        key = (shape, points.shape, hashlib.blake2b(np.ascontiguousarray(points).tobytes(), digest_size=16).digest())
        if key != self.key:
            self.result, self.key = run_tool(self.tool, points, shape, self.threads, self.repeats), key
        return self.result[method]


def pcl_estimators(
    repeats: int, include_roots: Sequence[Path] = INCLUDE_ROOTS, cache: Path | None = None
) -> list[tuple[str, Callable, bool, str, str]]:
    """(name, estimate, organized_only, version, about) of PCL's integral-image and OMP normals, with the tool
    compiled on first use; each estimate returns (normals, its `repeats` timed runs). ImportError naming
    `apt-get install libpcl-dev` when PCL's headers are not under `include_roots`. `anchors.pcl_anchors` makes
    them anchors."""
    include = pcl_include(include_roots)
    if include is None:
        raise ImportError(f"PCL's headers are not under {', '.join(map(str, include_roots))} ({INSTALL})")
    try:
        tool = build_tool(include, cache or cache_dir())
        version = f"PCL {tool_version(tool)}"
    except (OSError, subprocess.CalledProcessError, ValueError, KeyError) as error:  # built, but does not run
        raise ImportError(f"PCL's tool does not run here ({type(error).__name__}: {error}; {INSTALL})") from None
    threads = os.cpu_count() or 1
    runs = ToolRuns(tool, threads, repeats)

    def estimator(method: str, name: str, organized_only: bool, about: str) -> tuple[str, Callable, bool, str, str]:
        def estimate(points: np.ndarray, shape, radius: float) -> tuple[np.ndarray, list[float]]:
            return runs.get(points, shape, method)

        on_threads = "" if organized_only else f" on {threads} threads"
        timing = ", timed inside the tool around the estimate alone"
        return name, estimate, organized_only, version, about + on_threads + timing

    return [estimator(*method) for method in METHODS]
