"""Shared fixtures: a colcon-built install of this package and a way to run its installed ``node`` as a process.

The ROS graph is kept private to the test run: localhost-only discovery and a random domain id, so parallel runs and
other ROS users on the machine do not see each other. Caches (generated training shapes, matplotlib, torch, ROS logs)
go to the repository's git-ignored ``.cache/``, never under $HOME. ``slow`` marks what ``make test-fast`` skips.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import random
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest

from triplet_normal_ros.ros.tools.node_process import params_file, stop_node
from triplet_normal_ros.ros.transport import PROFILE_ENVS, choose_profile

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "triplet_normal_ros"
#: How long a node may take to say "ready:". It returns as soon as it does; a fresh install first compiles the CPU
#: kernels at start-up (6-20 s on a quiet 2-core machine, minutes when other processes load the cores), and a run
#: must not fail because the machine was busy.
STARTUP_S = 300.0
COLCON = Path(sys.executable).with_name("colcon")
#: How long a test's node gets to exit on SIGINT when the test is done with it (it promises 2 s; the rest is room for a
#: loaded machine) before it is killed.
CLOSE_S = 30.0
#: Where Fast DDS keeps a participant's shared-memory transport on Linux: a segment file per participant (fastdds_ on
#: Fast DDS 3, fastrtps_ on 2.x, so Jazzy) beside an ``_el`` lock file that the owner holds while it lives.
SHM_DIR = Path("/dev/shm")
_SEGMENT = re.compile(r"fast(dds|rtps)_[0-9a-f]{16}")
#: A lock file younger than this may belong to a participant still starting: it creates the file, then locks it.
LOCK_GRACE_S = 30.0
#: Where the tests keep what they cache between runs: inside the repository, git-ignored (.gitignore has .cache/).
TEST_CACHE = REPO / ".cache"


#: Caches the tests (and the processes they start) would otherwise fill under $HOME, redirected under TEST_CACHE.
#: The generated-data cache persists there between runs, so only the first run pays for generating the shapes.
PRIVATE_CACHES = {
    "TRIPLET_NORMAL_CACHE": "test-data",  # simulation.cache.default_cache_dir
    "MPLCONFIGDIR": "test-matplotlib",
    "TORCH_HOME": "test-torch",
    "XDG_CACHE_HOME": "test-xdg",
    "ROS_HOME": "test-ros",  # rcl's file logs (ROS_HOME/log)
}
_ENV_PATCH = pytest.MonkeyPatch()
#: The Fast DDS profile this file set for the test process (empty when the user had chosen one: then nodes keep it).
_PROFILE_SET_HERE: list[str] = []


def pytest_configure(config: pytest.Config) -> None:
    """Register ``slow``; redirect the caches; release what killed DDS processes left in shared memory. This runs
    before collection, which a session fixture would not: matplotlib reads MPLCONFIGDIR once, at import, and test
    modules import it at collection time."""
    config.addinivalue_line(
        "markers",
        "slow: colcon builds, node processes, training runs, accuracy checks of the shipped checkpoint, eval --quick "
        "and subprocesses (make test-fast deselects them; make test runs everything)",
    )
    for name, folder in PRIVATE_CACHES.items():
        (TEST_CACHE / folder).mkdir(parents=True, exist_ok=True)
        _ENV_PATCH.setenv(name, str(TEST_CACHE / folder))
    # This process plays the camera driver. Fast DDS reads its profile once per process, at the first participant,
    # so the shipped one is set here, before any test's rclpy context (docs/NODE.md, Transport).
    environ = dict(os.environ)
    choose_profile(environ)
    for name in PROFILE_ENVS:
        if name in environ and name not in os.environ:
            _ENV_PATCH.setenv(name, environ[name])
            _PROFILE_SET_HERE.append(environ[name])
    release_dead_segments()


def pytest_unconfigure(config: pytest.Config) -> None:
    _ENV_PATCH.undo()
    release_dead_segments()


def shm_segments(pid: int) -> set[Path]:
    """The Fast DDS segments process `pid` owns (it holds their lock files): what its orderly exit must remove from
    /dev/shm. A process also maps its peers' segments, which are not its to remove."""
    held: set[tuple[int, int]] = set()
    for line in Path("/proc/locks").read_text().splitlines():
        fields = line.split()  # "1: FLOCK  ADVISORY  WRITE <pid> <major>:<minor>:<inode> 0 EOF"
        if len(fields) > 5 and fields[1] == "FLOCK" and fields[4] == str(pid):
            major, minor, inode = fields[5].split(":")
            held.add((os.makedev(int(major, 16), int(minor, 16)), int(inode)))
    return {lock.with_name(lock.name[:-3]) for lock in _segment_locks() if _file_id(lock) in held}


def left_behind(segments: set[Path]) -> list[Path]:
    """Those of `segments` still in /dev/shm."""
    return [path for path in segments if path.exists()]


def _segment_locks() -> list[Path]:
    """The ``_el`` lock files of Fast DDS segments (not of its ports)."""
    locks = SHM_DIR.glob("fast*_el") if SHM_DIR.is_dir() else ()
    return [lock for lock in locks if _SEGMENT.fullmatch(lock.name[:-3])]


def _file_id(path: Path) -> tuple[int, int] | None:
    try:
        status = path.stat()
    except OSError:  # removed since it was listed
        return None
    return status.st_dev, status.st_ino


def release_dead_segments(grace_s: float = LOCK_GRACE_S) -> None:
    """Remove the segments of processes that died without shutting DDS down, as ``fastdds shm clean`` does: a
    segment whose lock file nobody holds has no owner. The tests kill node processes on purpose, and each such
    segment is 35 MB with the shipped large-data profile, in a tmpfs that counts as used memory (Ray's memory monitor
    starts killing workers at 95 %). Segments of live processes, this run's or anyone's, are left alone, and so is a
    lock file younger than `grace_s`, which a participant may have created and not yet locked."""
    for lock in _segment_locks():
        try:
            if time.time() - lock.stat().st_mtime < grace_s:
                continue
            descriptor = os.open(lock, os.O_RDONLY)
        except OSError:  # already gone
            continue
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # held by a live participant
            continue
        finally:
            os.close(descriptor)
        with contextlib.suppress(OSError):  # gone meanwhile, or another user's in the sticky /dev/shm
            lock.with_name(lock.name[:-3]).unlink()
            lock.unlink()


@pytest.fixture(scope="session")
def ros_env() -> Iterator[dict[str, str]]:
    """Process environment for this run's private ROS graph; also applied to the test process itself."""
    saved = dict(os.environ)
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 100))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["RCUTILS_COLORIZED_OUTPUT"] = "0"
    os.environ["PYTHONUNBUFFERED"] = "1"
    yield dict(os.environ)
    os.environ.clear()
    os.environ.update(saved)


def colcon_build(workspace: Path, *extra: str) -> Path:
    """``colcon build`` this repository into ``workspace``; returns the package's install prefix."""
    workspace.mkdir(parents=True, exist_ok=True)
    cmd = [str(COLCON), "--log-base", str(workspace / "log"), "build", "--base-paths", str(REPO)]
    cmd += ["--build-base", str(workspace / "build"), "--install-base", str(workspace / "install"), *extra]
    done = subprocess.run(cmd, cwd=workspace, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"colcon build failed:\n{done.stdout[-4000:]}\n{done.stderr[-4000:]}"
    return workspace / "install" / PACKAGE


@pytest.fixture(scope="session")
def install_prefix(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A plain (copying) colcon install, built once per session."""
    return colcon_build(tmp_path_factory.mktemp("ws"))


@pytest.fixture(scope="session")
def symlink_install_prefix(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ``--symlink-install`` colcon install, built once per session."""
    return colcon_build(tmp_path_factory.mktemp("ws_symlink"), "--symlink-install")


def site_packages(prefix: Path) -> Path:
    return prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"


def installed_env(prefix: Path, ros_env: Mapping[str, str]) -> dict[str, str]:
    """What ``source install/setup.bash`` would give a Python package: the install's site-packages first."""
    env = dict(ros_env)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site_packages(prefix)), env.get("PYTHONPATH")) if p)
    return env


def params_yaml(
    path: Path, params: Mapping[str, Any], reliable_topics: tuple[str, ...] = (), depth: int | None = None
) -> Path:
    """A ROS 2 parameter file for every node (``/**``); ``reliable_topics`` get a subscription QoS override."""
    return params_file(path, params, reliable_topics, depth)


class NodeProcess:
    """An installed executable (``node`` unless told) running in its own process, its output captured to a file;
    ``extra_args`` follow the parameter file and remaps inside ``--ros-args``."""

    def __init__(
        self,
        prefix: Path,
        env: Mapping[str, str],
        params_file: Path,
        remaps: Mapping[str, str],
        log_path: Path,
        extra_args: Sequence[str] = (),
        executable: str = "node",
    ) -> None:
        self.executable = prefix / "lib" / PACKAGE / executable
        self.log_path = log_path
        args = [str(self.executable), "--ros-args", "--params-file", str(params_file)]
        for name, target in remaps.items():
            args += ["-r", f"{name}:={target}"]
        args += extra_args
        self._log = self.log_path.open("w")
        # The node picks its Fast DDS profile itself, unless the user chose one for the whole run.
        node_env = {k: v for k, v in env.items() if not (k in PROFILE_ENVS and v in _PROFILE_SET_HERE)}
        self.proc = subprocess.Popen(
            args, env=node_env, stdout=self._log, stderr=subprocess.STDOUT, cwd=log_path.parent
        )

    @property
    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait_for_log(self, text: str, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.log:
                return True
            if self.proc.poll() is not None:
                return text in self.log
            time.sleep(0.05)
        return False

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> tuple[int | None, float]:
        """Send ``sig``; (exit code or None if still running after ``timeout``, seconds until exit)."""
        start = time.monotonic()
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            code = None
        return code, time.monotonic() - start

    def close(self) -> None:
        """Stop the node as Ctrl-C would, which also removes its DDS shared-memory segment; kill it only if it is
        still running CLOSE_S later."""
        stop_node(self.proc, timeout=CLOSE_S)
        self._log.close()


@contextlib.contextmanager
def running_node(
    prefix: Path,
    ros_env: Mapping[str, str],
    folder: Path,
    params: Mapping[str, Any],
    remaps: Mapping[str, str],
    reliable_topics: tuple[str, ...] = (),
) -> Iterator[NodeProcess]:
    """A node for a module-scoped fixture: its parameter file and log in ``folder``, ready when yielded, then closed."""
    path = params_yaml(folder / "params.yaml", params, reliable_topics)
    node = NodeProcess(prefix, installed_env(prefix, ros_env), path, remaps, path.with_suffix(".log"))
    try:
        assert node.wait_for_log("ready:", STARTUP_S), node.log
        yield node
    finally:
        node.close()


@pytest.fixture
def start_node(install_prefix: Path, ros_env: dict[str, str], tmp_path: Path) -> Iterator[Any]:
    """Factory: start_node(params | params_file, remaps, reliable_topics=(), extra_args=(), executable="node") ->
    NodeProcess; all killed afterwards."""
    started: list[NodeProcess] = []

    def start(
        params: Mapping[str, Any] | Path,
        remaps: Mapping[str, str],
        reliable_topics: tuple[str, ...] = (),
        extra_args: Sequence[str] = (),
        executable: str = "node",
    ) -> NodeProcess:
        name = f"node_{len(started)}"
        path = params if isinstance(params, Path) else params_yaml(tmp_path / f"{name}.yaml", params, reliable_topics)
        env = installed_env(install_prefix, ros_env)
        node = NodeProcess(install_prefix, env, path, remaps, tmp_path / f"{name}.log", extra_args, executable)
        started.append(node)
        return node

    yield start
    for node in started:
        node.close()
