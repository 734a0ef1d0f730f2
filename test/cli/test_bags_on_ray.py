"""`triplet-normal bags` on Ray: every bag under a directory (bag directories at any depth and bare files, both
storages) written exactly as `triplet-normal bag` writes it in one process; local Ray with two workers, a real cluster
started with `ray start --head`, a worker killed mid-bag (Ray restarts it and the bag continues its own partial
output), a corrupt bag that fails alone in one line, --resume, and an unreachable --address."""

from __future__ import annotations

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from rosbag_files import CLOUD, STRING, Record, cloud, read_raw, scattered_points, string, write_bag

from triplet_normal_ros.cli.bags import find_bags, target_for
from triplet_normal_ros.cli.main import main
from triplet_normal_ros.io.bag_output import partial_path

pytestmark = pytest.mark.slow  # Ray starts its own processes
BIN = Path(sys.executable).parent
#: A closed segment of an OUT.partial (io/bag_output.py): input messages [first, last) written whole.
CLOSED = re.compile(r"^\d{12}-\d{12}$")
OPTIONS = ["--topic", "/points", "--method", "pca", "--radius", "0.3", "--device", "cpu"]


def records(seed: int, clouds: int = 3, points: int = 1500) -> list[Record]:
    out = []
    for k in range(clouds):
        out.append(Record("/points", CLOUD, (seed * 100 + k + 1) * 10**8, cloud(scattered_points(points, seed + k), k)))
        out.append(Record("/chatter", STRING, (seed * 100 + k + 1) * 10**8 + 5, string(f"{seed}.{k}")))
    return out


def fleet(root: Path) -> list[Path]:
    """Four bags: two directories (one nested), and two bare files (MCAP and sqlite3)."""
    bags = [
        write_bag(root / "robot_a" / "day1", "sqlite3", records(1)),
        write_bag(root / "robot_a" / "deep" / "day2", "mcap", records(2)),
    ]
    for name, storage, seed in (("robot_b_run1", "mcap", 3), ("robot_b_run2", "sqlite3", 4)):
        folder = write_bag(root / "scratch" / name, storage, records(seed))
        bare = next(folder.glob("*.mcap" if storage == "mcap" else "*.db3"))
        target = root / "robot_b" / f"{name}{bare.suffix}"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(bare, target)
        shutil.rmtree(folder)
        bags.append(target)
    shutil.rmtree(root / "scratch")
    return bags


def one_process(bags: list[Path], root: Path, out: Path) -> dict[Path, list]:
    """What `triplet-normal bag` writes for each bag, one after another in this process."""
    expected = {}
    for source in bags:
        target = target_for(root, out, source)
        target.parent.mkdir(parents=True, exist_ok=True)
        assert main(["bag", str(source), str(target), *OPTIONS]) == 0
        expected[target.relative_to(out)] = read_raw(target)
    return expected


def test_find_bags_takes_directories_and_bare_files_at_any_depth(tmp_path: Path) -> None:
    bags = fleet(tmp_path / "in")
    assert find_bags(tmp_path / "in") == sorted(bags)
    assert target_for(tmp_path / "in", tmp_path / "out", bags[-1]) == tmp_path / "out" / "robot_b" / "robot_b_run2"


def test_two_local_workers_write_what_bag_writes_and_a_corrupt_bag_fails_alone(tmp_path: Path, capsys) -> None:
    root = tmp_path / "in"
    bags = fleet(root)
    broken = root / "robot_c" / "broken.mcap"
    broken.parent.mkdir()
    broken.write_bytes(b"\x89MCAP0\r\n not really")
    expected = one_process(bags, root, tmp_path / "reference")
    capsys.readouterr()
    assert main(["bags", str(root), str(tmp_path / "out"), "--workers", "2", *OPTIONS]) == 1
    captured = capsys.readouterr()
    errors = [line for line in captured.err.splitlines() if line.startswith("triplet-normal: error:")]
    assert len(errors) == 1 and str(broken) in errors[0], captured.err
    assert "4 of 5 bags (12 clouds) written, 0 already finished, 1 failed; 2 workers on this machine" in captured.out
    for relative, messages in expected.items():
        assert read_raw(tmp_path / "out" / relative) == messages, relative

    # Run again: the outputs are there, so it refuses in one line; with --resume the finished ones stay.
    assert main(["bags", str(root), str(tmp_path / "out"), "--workers", "2", *OPTIONS]) == 2
    assert "pass --resume" in capsys.readouterr().err
    shutil.rmtree(tmp_path / "out" / "robot_a" / "day1")
    assert main(["bags", str(root), str(tmp_path / "out"), "--workers", "2", "--resume", *OPTIONS]) == 1
    assert "1 of 2 bags (3 clouds) written, 3 already finished, 1 failed" in capsys.readouterr().out
    assert read_raw(tmp_path / "out" / "robot_a" / "day1") == expected[Path("robot_a/day1")]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def cluster(tmp_path: Path):
    """A real Ray cluster of one head node, started as users start one (`ray start --head`, with --block so that the
    command stays in the foreground and owns what it starts) in a temp dir of its own. Afterwards only the processes
    it started are stopped: other Ray sessions of this user keep running."""
    port = free_port()
    temp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths must fit in 107 bytes
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0"}
    start = [str(BIN / "ray"), "start", "--head", "--block", f"--port={port}", "--num-cpus=2"]
    start += ["--include-dashboard=false", f"--temp-dir={temp}"]
    log = tmp_path / "ray_head.log"
    with log.open("w") as sink:
        head = subprocess.Popen(start, env=env, stdout=sink, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while "Ray runtime started" not in log.read_text() and head.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)  # polling the head's log for the line that says it is up
        assert "Ray runtime started" in log.read_text() and head.poll() is None, log.read_text()
        yield f"127.0.0.1:{port}"
    finally:
        started = [(pid, _start_time(pid)) for pid in _descendants(head.pid)]
        head.terminate()  # `ray start --block` stops the processes it started on SIGTERM
        head.wait(120)
        for pid, since in started:  # any that outlived it, by PID and start time (never a reused PID)
            if since is not None and _start_time(pid) == since:
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(temp, ignore_errors=True)


def test_bags_join_a_running_cluster_by_address(tmp_path: Path, capsys, cluster: str) -> None:
    root = tmp_path / "in"
    bags = fleet(root)
    expected = one_process(bags, root, tmp_path / "reference")
    capsys.readouterr()
    assert main(["bags", str(root), str(tmp_path / "out"), "--address", cluster, *OPTIONS]) == 0
    assert f"on the cluster at {cluster}" in capsys.readouterr().out
    for relative, messages in expected.items():
        assert read_raw(tmp_path / "out" / relative) == messages


def test_a_worker_killed_mid_bag_is_restarted_and_nothing_is_lost_or_written_twice(tmp_path: Path) -> None:
    root = tmp_path / "in"
    clouds = 24
    source = write_bag(root / "long", "mcap", records(7, clouds=clouds, points=10_000))
    messages = 2 * clouds  # input messages: each cloud and its string
    options = [*OPTIONS, "--segment-seconds", "0"]  # a segment closes after each input message
    reference = tmp_path / "reference"
    assert main(["bag", str(source), str(reference), *options]) == 0
    out = tmp_path / "out"
    command = [str(BIN / "triplet-normal"), "bags", str(root), str(out), "--workers", "1", *options]
    run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        strike = _strike_mid_bag(run.pid, out / "long", deadline=time.monotonic() + 300)
    finally:
        stdout, stderr = run.communicate(timeout=600)
    assert strike is not None, f"the bag ended before its worker could be struck; make it longer: {stdout} {stderr}"
    done, complete = strike
    # At the strike the worker was frozen with work left: some input messages kept in closed segments, not all.
    assert 0 < done < messages and not complete, strike
    assert run.returncode == 0, stderr
    # The retried bag continued its own partial output exactly where the killed worker left it.
    assert f"resumed at input message {done}," in stdout, stdout
    assert f"1 of 1 bags ({clouds} clouds) written" in stdout
    got, want = read_raw(out / "long"), read_raw(reference)
    assert len(got) == 3 * clouds and got == want  # each cloud, its string and its answer, once


def _strike_mid_bag(root: int, target: Path, deadline: float) -> tuple[int, bool] | None:
    """Once a segment of `target` has closed, freeze the Ray worker (started under `root`) that is running the bag,
    note what it has kept (the end of its closed segments, and whether `target` is complete), and SIGKILL it.

    Returns (end, complete) of the struck bag, or None if the bag ended first."""
    segments = partial_path(target) / "segments"
    while time.monotonic() < deadline and _alive(root):
        worker = _bag_worker(root) if _kept(segments) else None
        if worker is not None:
            os.kill(worker, signal.SIGSTOP)
            while _state(worker) not in ("T", None):  # stopped (or already gone)
                time.sleep(0.001)
            kept = _kept(segments), target.exists()
            os.kill(worker, signal.SIGKILL)
            return kept
        time.sleep(0.01)  # polling the file system for the moment to strike, not waiting for a result
    return None


def _kept(segments: Path) -> int:
    """The end of the closed segments (the input messages [0, end) kept), 0 if none."""
    try:
        names = [p.name for p in segments.iterdir()]
    except FileNotFoundError:  # not yet made, or already merged into OUT
        return 0
    return max((int(name.split("-")[1]) for name in names if CLOSED.match(name)), default=0)


def _bag_worker(root: int) -> int | None:
    """The Ray worker process, started under `root`, that is running a bag now, if there is one."""
    for pid in _descendants(root):
        try:
            title = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"ray::_Worker.bag" in title:
            return pid
    return None


def _stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (state first), or None if there is no such process."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    except OSError:
        return None


def _state(pid: int) -> str | None:
    fields = _stat(pid)
    return None if fields is None else fields[0]


def _alive(pid: int) -> bool:
    return _state(pid) not in (None, "Z")


def _start_time(pid: int) -> int | None:
    fields = _stat(pid)
    return None if fields is None else int(fields[19])  # field 22 of stat: start time in clock ticks after boot


def _descendants(root: int) -> list[int]:
    """Every process under `root` now, children before grandchildren."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        fields = _stat(int(entry.name)) if entry.name.isdigit() else None
        if fields is not None:
            children.setdefault(int(fields[1]), []).append(int(entry.name))
    found, todo = [], [root]
    while todo:
        for child in children.get(todo.pop(0), []):
            found.append(child)
            todo.append(child)
    return found


def test_a_worker_the_memory_monitor_kills_is_one_line_that_says_so(tmp_path: Path) -> None:
    """Ray kills workers once the machine's memory passes its threshold; here the threshold is set below what any
    worker needs, so every start of the worker is killed and the bag fails after Ray's retries, in one line that
    says what happened and which setting moves the line (Ray's own message ends in advice that never says it)."""
    root = tmp_path / "in"
    source = write_bag(root / "one", "mcap", records(1))
    env = {**os.environ, "RAY_memory_usage_threshold": "0.001", "RAY_memory_monitor_refresh_ms": "100"}
    command = [str(BIN / "triplet-normal"), "bags", str(root), str(tmp_path / "out"), "--workers", "1", *OPTIONS]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 1, done.stderr
    (line,) = [line for line in done.stderr.splitlines() if line.startswith("triplet-normal: error:")]
    assert line.startswith(f"triplet-normal: error: {source}: Ray's memory monitor killed the worker: "), line
    assert re.search(r"memory was [\d.]+GB used / [\d.]+GB limit, over Ray's 0\.1 % threshold", line), line
    assert "RAY_memory_usage_threshold" in line and "Refer to the documentation" not in line


def test_an_unreachable_address_is_one_line_and_exit_1(tmp_path: Path, capsys) -> None:
    root = tmp_path / "in"
    write_bag(root / "one", "mcap", records(1))
    began = time.monotonic()
    assert main(["bags", str(root), str(tmp_path / "out"), "--address", f"127.0.0.1:{free_port()}", *OPTIONS]) == 1
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and "cannot join the Ray cluster" in captured.err
    assert time.monotonic() - began < 60


def test_tiled_estimate_of_a_million_points_is_the_one_process_answer(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(0)
    n = 1_000_000
    u, v = rng.uniform(0, 40, n), rng.uniform(0, 40, n)
    cloud_points = np.c_[u, v, 0.2 * np.sin(u) * np.cos(v) + rng.normal(scale=0.005, size=n)]
    path = tmp_path / "map.npy"
    np.save(path, cloud_points)
    common = ["--method", "pca", "--k", "30", "--radius", "0.3", "--device", "cpu"]
    assert main(["estimate", str(path), "--out", str(tmp_path / "one.npy"), *common]) == 0
    tiled = ["--workers", "2", "--tile-points", "200000"]
    assert main(["estimate", str(path), "--out", str(tmp_path / "tiled.npy"), *common, *tiled]) == 0
    one, parts = np.load(tmp_path / "one.npy"), np.load(tmp_path / "tiled.npy")
    assert one.shape == parts.shape
    # Exact where nothing is computed: the points, and which of them get a normal (a tile finds each interior point's
    # neighbours in the whole cloud, so the same count of them).
    np.testing.assert_array_equal(parts[:, :3], one[:, :3])
    answered = np.isfinite(one[:, 3:]).all(axis=1)
    np.testing.assert_array_equal(np.isfinite(parts[:, 3:]).all(axis=1), answered)
    assert answered.mean() > 0.99
    # The same neighbours, but gathered in the tile's order and summed on the worker's thread count: the covariance
    # may be rounded differently. A 30-point fit of this gentle surface has its smallest eigenvalue far below the
    # others, so that roundoff turns a normal by far less than 1e-3 degrees, and a wrong neighbour or tile by far
    # more. The angle comes from the cross product: arccos of a float32 normal's dot product cannot resolve it.
    a, b = parts[answered, 3:6], one[answered, 3:6]
    # Signed: with no --viewpoint the sign is the solver's, which the same covariance to roundoff does not flip.
    sine, cosine = np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)
    assert np.degrees(np.arctan2(sine, cosine)).max() < 1e-3
    np.testing.assert_allclose(parts[answered, 6], one[answered, 6], rtol=0, atol=1e-6)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--workers", "2"], "is organized (4 rows)"),
        (["--tile-points", "100"], "--tile-points cuts the cloud for --workers or --address"),
        (["--workers", "0"], "--workers must be an integer >= 1"),
    ],
)
def test_estimate_on_ray_refuses_what_it_cannot_tile_in_one_line(tmp_path: Path, capsys, extra, message) -> None:
    """Refused before Ray starts: an organized cloud (one sensor frame), --tile-points alone, no workers."""
    from triplet_normal_ros.io.cloud_files import write_normals

    grid = np.stack(np.meshgrid(np.arange(5.0), np.arange(4.0)), axis=-1).reshape(-1, 2)
    path = tmp_path / "frame.pcd"  # an organized PCD, as a depth camera's frame is saved
    write_normals(path, np.c_[grid * 0.01, np.full(20, 1.0)], np.zeros((20, 3)), np.zeros(20), organized=(4, 5))
    status = main(["estimate", str(path), "--out", str(tmp_path / "n.npy"), "--method", "pca", *extra])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and message in err, err  # a usage error, refused before any work


def test_two_bags_that_would_share_an_output_are_refused_before_any_work(tmp_path: Path, capsys) -> None:
    root = tmp_path / "in"
    folder = write_bag(root / "run", "mcap", records(1))
    shutil.copy(next(folder.glob("*.mcap")), root / "run.mcap")  # a bare file beside a bag directory of its name
    assert main(["bags", str(root), str(tmp_path / "out"), "--workers", "1", *OPTIONS]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "would both be written to" in err
    assert not (tmp_path / "out").exists()
