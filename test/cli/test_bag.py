"""`triplet-normal bag` end to end on rosbag2 bags the tests write (sqlite3 and MCAP, organized and unorganized clouds).

The output is read back and compared with NormalEstimator on the same clouds, oriented towards the viewpoint as
the node does: normals and curvature exactly, xyz and the other fields byte for byte, receive timestamps and header
stamps unchanged, the other topics copied through, those of types the bag does not define too; every kind of bag
rosbag2 writes (a Humble recording with a schema-less /rosout among them) gives an OUT that rosbags' AnyReader opens,
holding every message. Also: storage
conversion, --no-copy, --start/--end/--limit, --keep-zeros, a hybrid run, a malformed cloud skipped with a warning,
refusal to overwrite, resume after Ctrl-C (and its refusal to go on with other options), and every failure as one line.
"""

from __future__ import annotations

import argparse
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import faces_viewpoint
from rosbag_files import (
    BLOB,
    CLOUD,
    CUSTOM_HASH,
    LOG,
    OPAQUE,
    RECORDINGS,
    STRING,
    UNDESCRIBED,
    Record,
    cloud,
    connections,
    organized_points,
    raw_of,
    read_bag,
    read_raw,
    recording_records,
    scattered_points,
    stamp_ns,
    storage_of,
    string,
    undescribed_records,
    write_bag,
)
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat

from triplet_normal_ros.cli import bag as bag_command
from triplet_normal_ros.cli.main import main
from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.orientation import orient_towards_viewpoint
from triplet_normal_ros.io import bag_output
from triplet_normal_ros.io.bag_output import partial_path
from triplet_normal_ros.io.bags import InputBag
from triplet_normal_ros.io.pointcloud2 import read_field, read_xyz
from triplet_normal_ros.ros.params import NodeSettings

SCRIPT = Path(sys.executable).with_name("triplet-normal")
RADIUS = 0.15
PCA = ["--method", "pca", "--radius", str(RADIUS), "--device", "cpu"]
SHAPE = (30, 40)
#: The first message of `timeline_records`' bag (ns): --start and --end count from here.
T0 = 50 * 10**9
SECOND = 10**9


def mixed_records() -> list[Record]:
    """Two organized clouds (with NaN holes), an unorganized one and an empty one on /points; /chatter between."""
    clouds = [
        cloud(organized_points(*SHAPE, phase=0.0), 10_000_000_001, height=SHAPE[0]),
        cloud(scattered_points(2000, seed=2), 10_100_000_002),
        cloud(organized_points(*SHAPE, phase=1.0), 10_200_000_003, height=SHAPE[0]),
        cloud(np.empty((0, 3)), 10_300_000_004, height=1),
    ]
    records = []
    for i, msg in enumerate(clouds):
        records.append(Record("/points", CLOUD, 1_000_000 * (i + 1), msg))
        records.append(Record("/chatter", STRING, 1_000_000 * (i + 1) + 500, string(f"message {i}")))
    return records


def timeline_records() -> list[Record]:
    """A cloud on /points every second from T0 (at 0, 1, ..., 5 s) and a string on /chatter half a second after each."""
    records = []
    for k in range(6):
        records.append(Record("/points", CLOUD, T0 + k * SECOND, cloud(scattered_points(2000, seed=10 + k), k)))
        records.append(Record("/chatter", STRING, T0 + k * SECOND + SECOND // 2, string(f"{k}.5 s")))
    return records


def expected(msg, method: str = "pca", radius: float = RADIUS, **options) -> tuple[np.ndarray, np.ndarray]:
    """What the node publishes for `msg`: NormalEstimator's normals oriented towards the origin, and curvature."""
    points = read_xyz(msg)
    estimator = NormalEstimator(method=method, radius=radius, device="cpu", **options)
    normals, curvature = estimator.estimate(points, shape=(msg.height, msg.width))
    return orient_towards_viewpoint(points, normals, (0.0, 0.0, 0.0)), curvature


def assert_normals_match(out: Record, source: Record, **options) -> None:
    """Same receive time, header, points and other fields as `source`; normals and curvature as the estimator's."""
    assert out.timestamp == source.timestamp
    assert (stamp_ns(out.msg), out.msg.header.frame_id) == (stamp_ns(source.msg), source.msg.header.frame_id)
    assert (out.msg.height, out.msg.width) == (source.msg.height, source.msg.width)
    np.testing.assert_array_equal(read_xyz(out.msg), read_xyz(source.msg))
    np.testing.assert_array_equal(read_field(out.msg, "intensity"), read_field(source.msg, "intensity"))
    if source.msg.height * source.msg.width == 0:
        assert "normal_x" in [f.name for f in out.msg.fields]
        return
    normals, curvature = expected(source.msg, **options)
    got = np.stack([read_field(out.msg, f"normal_{a}") for a in "xyz"], axis=1)
    np.testing.assert_array_equal(got, normals)
    np.testing.assert_array_equal(read_field(out.msg, "curvature"), curvature)
    finite = np.isfinite(got).all(axis=1)
    assert finite.sum() > 0.9 * np.isfinite(read_xyz(source.msg)).all(axis=1).sum()
    points = read_xyz(source.msg)[finite]
    assert faces_viewpoint(points, got[finite]).all()  # facing the sensor at the origin


def run_ok(capsys, argv: list) -> str:
    status = main(["bag", *map(str, argv)])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    return captured.out


def run_fails(capsys, argv: list, status: int = 1) -> str:
    """The command fails with exactly one line `triplet-normal: error: ...` and nothing on stdout."""
    got = main(["bag", *map(str, argv)])
    captured = capsys.readouterr()
    assert got == status, captured.err
    assert captured.out == "" and "Traceback" not in captured.err
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("triplet-normal: error: "), captured.err
    return lines[0]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_normals_match_the_estimator_and_everything_else_is_copied(tmp_path: Path, capsys, storage: str) -> None:
    records = mixed_records()
    source = write_bag(tmp_path / "in", storage, records)
    summary = run_ok(capsys, [source, tmp_path / "out", "--topic", "/points", *PCA])
    assert summary.startswith(f"{source}: 4 clouds on /points (0 skipped), 2 topics copied; pca, radius 0.15 m, cpu")
    assert summary.rstrip().endswith(f" s -> {tmp_path / 'out'} ({storage}, /points/normals)")
    out = tmp_path / "out"
    assert storage_of(out) == storage
    raw = read_raw(out)
    assert [r for r in raw if r[0] != "/points/normals"] == read_raw(source)  # copied byte for byte, same times
    normals = [r for r in read_bag(out) if r.topic == "/points/normals"]
    clouds = [r for r in records if r.topic == "/points"]
    assert len(normals) == len(clouds)
    for got, source_record in zip(normals, clouds, strict=True):
        assert got.msgtype == CLOUD
        assert_normals_match(got, source_record)
    assert not partial_path(out).exists()


def test_converts_storage_and_writes_only_the_output_with_no_copy(tmp_path: Path, capsys) -> None:
    records = mixed_records()[:4]
    source = write_bag(tmp_path / "in", "mcap", records)
    out = tmp_path / "out"
    options = ["--storage", "sqlite3", "--no-copy", "--output-topic", "/n", *PCA]
    run_ok(capsys, [source, out, "--topic", "/points", *options])
    assert storage_of(out) == "sqlite3"
    got = read_bag(out)
    assert [r.topic for r in got] == ["/n", "/n"]
    for record, source_record in zip(got, [r for r in records if r.topic == "/points"], strict=True):
        assert_normals_match(record, source_record)


@pytest.mark.parametrize(("storage", "output_storage"), [("sqlite3", "sqlite3"), ("mcap", "mcap"), ("mcap", "sqlite3"),
                                                         ("sqlite3", "mcap")])  # fmt: skip
def test_topics_the_bag_does_not_define_are_copied_raw_with_a_note(
    tmp_path: Path, capsys, storage: str, output_storage: str
) -> None:
    records = undescribed_records()
    source = write_bag(tmp_path / "in", storage, records, UNDESCRIBED)
    out = tmp_path / "out"
    status = main(["bag", str(source), str(out), "--topic", "/points", "--storage", output_storage, *PCA])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert captured.err.splitlines() == [
        f"triplet-normal: note: topic /blob ({BLOB}): no message definition in the bag; copied as raw messages",
    ]  # /opaque's empty definition is that of a type without fields
    assert "2 clouds on /points (0 skipped), 3 topics copied" in captured.out
    assert storage_of(out) == output_storage
    assert [(t, ts, raw) for t, _, ts, raw in read_raw(out) if t != "/points/normals"] == [
        (r.topic, r.timestamp, raw_of(r)) for r in records
    ]  # byte for byte, same times
    declared = connections(out)
    assert [(declared[t].msgtype, declared[t].msgdef, declared[t].digest) for t in ("/blob", "/opaque")] == [
        (BLOB, (MessageDefinitionFormat.NONE, ""), ""),  # as rosbag2 declares a type it has no definition of
        (OPAQUE, (MessageDefinitionFormat.MSG, ""), CUSTOM_HASH),  # as IN declares it
    ]
    normals = read_bag(out, {"/points/normals"})
    clouds = [r for r in records if r.topic == "/points"]
    assert len(normals) == len(clouds) == 2
    for got, source_record in zip(normals, clouds, strict=True):
        assert_normals_match(got, source_record)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("kind", RECORDINGS)
def test_every_bag_rosbag2_writes_gives_an_out_anyreader_opens_with_every_message(
    tmp_path: Path, capsys, kind: str, storage: str
) -> None:
    """Among them a Humble recording (metadata version 5, no type hashes) whose /rosout has no definition: its OUT
    declared /rosout with an all-zero type hash, and AnyReader refused it for not being the hash of the empty
    definition declared beside it."""
    records = recording_records()
    source = RECORDINGS[kind](tmp_path / "in", storage, records)
    out = tmp_path / "out"
    status = main(["bag", str(source), str(out), "--topic", "/points", *PCA])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert captured.err.splitlines() == [
        f"triplet-normal: note: topic /rosout ({LOG}): no message definition in the bag; copied as raw messages"
    ]
    with AnyReader([out]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        got = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
        normals = [
            Record(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages([c for c in reader.connections if c.topic == "/points/normals"])
        ]
    assert counts == {"/points": 2, "/rosout": 2, "/chatter": 2, "/idle": 0, "/points/normals": 2}
    assert [m for m in got if m[0] != "/points/normals"] == [(r.topic, r.timestamp, raw_of(r)) for r in records]
    clouds = [r for r in records if r.topic == "/points"]
    for got_cloud, source_record in zip(normals, clouds, strict=True):
        assert_normals_match(got_cloud, source_record)


@pytest.mark.parametrize(
    ("storage", "part", "window", "words"),
    [
        ("sqlite3", ["--start", "2", "--end", "4"], (2, 4), "from 2 s to 4 s"),  # a cloud at each end: 2 in, 4 out
        ("mcap", ["--start", "4.5"], (4.5, 6), "from 4.5 s to its end"),  # a string at the start, exactly
        ("mcap", ["--end", "1"], (0, 1), "from 0 s to 1 s"),
    ],
)
def test_start_and_end_read_only_the_messages_between(
    tmp_path: Path, capsys, storage: str, part: list[str], window: tuple[float, float], words: str
) -> None:
    records = timeline_records()
    source = write_bag(tmp_path / "in", storage, records)
    out = tmp_path / "out"
    summary = run_ok(capsys, [source, out, "--topic", "/points", *part, *PCA])
    inside = [r for r in records if window[0] * SECOND <= r.timestamp - T0 < window[1] * SECOND]
    clouds = [r for r in inside if r.topic == "/points"]
    assert summary.startswith(f"{source} ({words}): {len(clouds)} clouds on /points (0 skipped), 2 topics copied;")
    copied = [r for r in read_raw(out) if r[0] != "/points/normals"]
    assert copied == [r for r in read_raw(source) if (r[0], r[2]) in {(i.topic, i.timestamp) for i in inside}]
    assert [(r[0], r[2]) for r in copied] == [(r.topic, r.timestamp) for r in inside]
    normals = [r for r in read_bag(out) if r.topic == "/points/normals"]
    assert len(normals) == len(clouds) > 0
    for got, source_record in zip(normals, clouds, strict=True):
        assert_normals_match(got, source_record)


def test_limit_ends_the_output_at_the_nth_cloud(tmp_path: Path, capsys) -> None:
    records = timeline_records()
    source = write_bag(tmp_path / "in", "mcap", records)
    out = tmp_path / "out"
    summary = run_ok(capsys, [source, out, "--topic", "/points", "--start", "1", "--limit", "2", *PCA])
    assert summary.startswith(f"{source} (from 1 s to its end, at most 2 clouds): 2 clouds on /points (0 skipped)")
    got = read_bag(out)
    at = [T0 + SECOND, T0 + 3 * SECOND // 2, T0 + 2 * SECOND]  # the clouds at 1 s and 2 s, the string between
    assert [(r.topic, r.timestamp) for r in got] == [
        ("/points", at[0]), ("/points/normals", at[0]), ("/chatter", at[1]),
        ("/points", at[2]), ("/points/normals", at[2]),
    ]  # fmt: skip
    assert_normals_match(got[4], records[4])


def test_points_at_the_origin_are_no_returns_unless_keep_zeros(tmp_path: Path, capsys) -> None:
    u, v = np.meshgrid(np.arange(-10, 11) * 0.05, np.arange(-10, 11) * 0.05)
    points = np.stack([u, v, 0.2 * u + 0.1 * v], axis=-1).reshape(-1, 3)  # a plane through the origin
    origin = ~points.any(axis=1)
    assert origin.sum() == 1
    source = write_bag(tmp_path / "in", "sqlite3", [Record("/points", CLOUD, 1, cloud(points, 1, height=21))])
    for keep_zeros in (False, True):
        out = tmp_path / f"out_{keep_zeros}"
        option = ["--keep-zeros"] if keep_zeros else []
        run_ok(capsys, [source, out, "--topic", "/points", "--no-copy", *PCA, *option])
        (got,) = read_bag(out)
        normals = np.stack([read_field(got.msg, f"normal_{a}") for a in "xyz"], axis=1)
        assert np.isfinite(normals[~origin]).all()
        assert np.isfinite(normals[origin]).all() == keep_zeros


def test_no_orient_keeps_the_estimators_signs(tmp_path: Path, capsys) -> None:
    msg = cloud(scattered_points(2000, seed=6), 3)
    source = write_bag(tmp_path / "in", "sqlite3", [Record("/points", CLOUD, 3, msg)])
    run_ok(capsys, [source, tmp_path / "out", "--topic", "/points", "--no-copy", "--no-orient", *PCA])
    (got,) = read_bag(tmp_path / "out")
    normals, _ = NormalEstimator(method="pca", radius=RADIUS, device="cpu").estimate(read_xyz(msg), shape=(1, 2000))
    np.testing.assert_array_equal(np.stack([read_field(got.msg, f"normal_{a}") for a in "xyz"], axis=1), normals)
    oriented, _ = expected(msg)
    assert (oriented != normals).any()  # orientation would have flipped some: the option made a difference


def test_hybrid_matches_the_estimator(tmp_path: Path, capsys) -> None:
    msg = cloud(organized_points(*SHAPE), 42, height=SHAPE[0])
    source = write_bag(tmp_path / "in", "mcap", [Record("/cam/points", CLOUD, 7, msg)])
    options = ["--method", "hybrid", "--checkpoint", "lite", "--radius", str(RADIUS), "--device", "cpu"]
    run_ok(capsys, [source, tmp_path / "out", "--topic", "/cam/points", *options])
    (_, got) = read_bag(tmp_path / "out")
    assert got.topic == "/cam/points/normals"
    estimator = NormalEstimator(method="hybrid", checkpoint="lite", radius=RADIUS, device="cpu")
    estimator.estimate(read_xyz(msg), shape=SHAPE)
    assert estimator.last_run.network > 0  # the crease goes through the network, so the learned path is compared
    assert_normals_match(got, Record("/cam/points", CLOUD, 7, msg), method="hybrid", checkpoint="lite")


def test_without_a_checkpoint_each_cloud_gets_the_nodes_choice_on_a_cpu(tmp_path: Path, capsys) -> None:
    """No --checkpoint: the organized frame is answered by the range checkpoint and the unorganized cloud by lite, as
    the node's estimator answers them, and the run's job records both."""
    image = cloud(organized_points(*SHAPE), 42, height=SHAPE[0])
    scattered = cloud(scattered_points(2000, seed=8), 43)
    records = [Record("/cam/points", CLOUD, 7, image), Record("/cam/points", CLOUD, 8, scattered)]
    source = write_bag(tmp_path / "in", "mcap", records)
    options = ["--method", "hybrid", "--radius", str(RADIUS), "--device", "cpu", "--no-copy"]
    run_ok(capsys, [source, tmp_path / "out", "--topic", "/cam/points", *options])
    got = read_bag(tmp_path / "out")
    for out, record, checkpoint in zip(got, records, ("range", "lite"), strict=True):
        assert_normals_match(out, record, method="hybrid", checkpoint=checkpoint)
    lite_answer, _ = expected(image, method="hybrid", checkpoint="lite")
    assert not np.array_equal(lite_answer, expected(image, method="hybrid", checkpoint="range")[0], equal_nan=True)
    fields = ("topic", "no_copy", "radius", "k", "gate", "bend", "neighbours", "no_orient", "keep_zeros", "range_scale")
    chosen = argparse.Namespace(input=source, checkpoint=None, method="hybrid", device="cpu", start=None, end=None,
                                limit=None, viewpoint=(0.0, 0.0, 0.0), **dict.fromkeys(fields))  # fmt: skip
    with InputBag(source) as opened:
        job = bag_command._job(chosen, opened, "/n", "mcap")  # what the run records, and --resume compares
    assert job["checkpoint"] == "range on range images and lite otherwise"


def test_the_summary_line_names_the_checkpoints_that_served(tmp_path: Path) -> None:
    """The installed command, on a CPU without --checkpoint: range answers the range image, lite the other cloud, and
    the one summary line on stdout says so."""
    image = cloud(organized_points(*SHAPE), 42, height=SHAPE[0])
    scattered = cloud(scattered_points(2000, seed=8), 43)
    records = [Record("/cam/points", CLOUD, 7, image), Record("/cam/points", CLOUD, 8, scattered)]
    source = write_bag(tmp_path / "in", "mcap", records)
    options = ["--method", "hybrid", "--radius", str(RADIUS), "--device", "cpu", "--no-copy"]
    argv = [SCRIPT, "bag", source, tmp_path / "out", "--topic", "/cam/points", *options]
    done = subprocess.run(list(map(str, argv)), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (line,) = done.stdout.splitlines()
    assert "; hybrid, checkpoints range and lite, radius 0.15 m, cpu; " in line, line


def test_a_malformed_cloud_is_skipped_with_a_warning(tmp_path: Path, capsys) -> None:
    good = cloud(scattered_points(2000, seed=4), 5)
    bad = cloud(scattered_points(500, seed=5), 6)
    bad.fields = bad.fields[:2] + bad.fields[3:]  # no 'z'
    records = [Record("/points", CLOUD, 1, bad), Record("/points", CLOUD, 2, good)]
    source = write_bag(tmp_path / "in", "sqlite3", records)
    status = main(["bag", str(source), str(tmp_path / "out"), "--topic", "/points", *PCA])
    captured = capsys.readouterr()
    assert status == 0
    assert "(1 skipped)" in captured.out
    assert captured.err.splitlines() == [
        "triplet-normal: warning: skipped the cloud at 1 ns: PointCloud2 has no 'z' field (fields: x, y, intensity)"
    ]
    got = read_bag(tmp_path / "out")
    assert [(r.topic, r.timestamp) for r in got] == [("/points", 1), ("/points", 2), ("/points/normals", 2)]
    assert_normals_match(got[2], records[1])


def test_refuses_to_overwrite_unless_told(tmp_path: Path, capsys) -> None:
    source = write_bag(tmp_path / "in", "mcap", mixed_records()[:2])
    out = tmp_path / "out"
    run_ok(capsys, [source, out, "--topic", "/points", *PCA])
    before = read_raw(out)
    line = run_fails(capsys, [source, out, "--topic", "/points", *PCA, "--output-topic", "/other"])
    assert line == f"triplet-normal: error: {out} already exists; pass --overwrite to replace it"
    assert read_raw(out) == before and not partial_path(out).exists()
    run_ok(capsys, [source, out, "--topic", "/points", *PCA, "--output-topic", "/other", "--overwrite"])
    assert {r[0] for r in read_raw(out)} == {"/points", "/chatter", "/other"}


def test_overwrite_refuses_a_symlinked_output_before_any_work(tmp_path: Path, capsys) -> None:
    source = write_bag(tmp_path / "in", "sqlite3", mixed_records()[:2])
    run_ok(capsys, [source, tmp_path / "real", "--topic", "/points", *PCA])
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "real")
    line = run_fails(capsys, [source, link, "--topic", "/points", *PCA, "--overwrite"])
    assert line == f"triplet-normal: error: {link} is a symbolic link; not replacing it (give the real directory)"
    assert link.is_symlink() and not partial_path(link).exists()


def _written(segments: Path) -> int:
    """How many input messages the closed segments of OUT.partial hold (0 before the first is closed)."""
    ends = [int(m[2]) for p in segments.iterdir() if (m := re.match(r"^(\d{12})-(\d{12})$", p.name))]
    return max(ends, default=0)


@pytest.mark.slow
def test_resumes_after_ctrl_c(tmp_path: Path, capsys) -> None:
    """Interrupted after its first crash-safe segment, the run keeps its work; --resume finishes the rest.

    As soon as a closed segment shows the run estimating, it is paused (SIGSTOP), checked to have input messages
    left, sent SIGINT and continued: however fast the machine, the Ctrl-C lands in the middle of the work.
    """
    records = [
        Record("/points", CLOUD, 1_000 * (i + 1), cloud(organized_points(*SHAPE, phase=0.1 * i), i, height=SHAPE[0]))
        for i in range(30)
    ]
    source = write_bag(tmp_path / "in", "mcap", records)
    out = tmp_path / "out"
    argv = [str(source), str(out), "--topic", "/points", *PCA, "--segment-seconds", "0"]
    process = subprocess.Popen([SCRIPT, "bag", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    segments = partial_path(out) / "segments"
    deadline = time.monotonic() + 120  # a hang guard: the first segment closes after the first cloud
    while not (segments.is_dir() and _written(segments) > 0):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.005)
    process.send_signal(signal.SIGSTOP)
    try:
        written = _written(segments)
        assert written < len(records) and process.poll() is None and not out.exists(), "the run finished first"
        process.send_signal(signal.SIGINT)
    finally:
        process.send_signal(signal.SIGCONT)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, (stdout, stderr)
    assert stderr.splitlines()[-1] == (
        f"triplet-normal: error: interrupted; finished work is kept in {partial_path(out)}: rerun with --resume"
    )
    assert not out.exists()
    line = run_fails(capsys, [*argv, "--radius", "0.2", "--resume"])
    assert line.endswith(
        f"{partial_path(out)} was started with radius = 0.15, not 0.2; resume with the same input "
        "and options, or pass --overwrite to start again"
    )
    for other, started in ((["--end", "1"], "end = None, not 1.0"), (["--limit", "5"], "limit = None, not 5"),
                           (["--keep-zeros"], "keep_zeros = False, not True")):  # fmt: skip
        assert f"was started with {started}; resume" in run_fails(capsys, [*argv, *other, "--resume"])
    summary = run_ok(capsys, [*argv, "--resume"])
    resumed_at = int(summary.split("resumed at input message ")[1].split(",")[0])
    assert written <= resumed_at < len(records)  # the kept work is reused, and there was work left
    got = read_bag(out)
    assert [r.timestamp for r in got if r.topic == "/points"] == [r.timestamp for r in records]
    normals = [r for r in got if r.topic == "/points/normals"]
    assert len(normals) == len(records)
    for record, source_record in zip(normals, records, strict=True):
        assert_normals_match(record, source_record)


def test_resume_of_a_finished_run_refuses(tmp_path: Path, capsys) -> None:
    source = write_bag(tmp_path / "in", "sqlite3", mixed_records()[:2])
    out = tmp_path / "out"
    args = [source, out, "--topic", "/points", *PCA, "--segment-seconds", "0"]
    run_ok(capsys, args)
    line = run_fails(capsys, [*args, "--resume"])
    assert line == f"triplet-normal: error: {out} already exists; pass --overwrite to replace it"
    assert not partial_path(out).exists()


def test_defaults_are_the_nodes() -> None:
    node = NodeSettings()
    assert (node.method, node.radius) == (defaults.METHOD, defaults.RADIUS)
    assert tuple(node.viewpoint) == defaults.VIEWPOINT and node.orient
    assert bag_command.SEGMENT_SECONDS == bag_output.SEGMENT_SECONDS


# ---------------------------------------------------------------- one-line errors


@pytest.fixture
def small_bag(tmp_path: Path) -> Path:
    return write_bag(tmp_path / "in", "mcap", mixed_records()[:2])


def test_missing_topic_names_the_topics(small_bag: Path, tmp_path: Path, capsys) -> None:
    line = run_fails(capsys, [small_bag, tmp_path / "out", "--topic", "/lidar", *PCA])
    assert line == (
        f"triplet-normal: error: {small_bag}: no topic /lidar; topics: /chatter (std_msgs/msg/String), "
        "/points (sensor_msgs/msg/PointCloud2)"
    )
    assert not (tmp_path / "out").exists() and not partial_path(tmp_path / "out").exists()


def test_wrong_message_type(small_bag: Path, tmp_path: Path, capsys) -> None:
    line = run_fails(capsys, [small_bag, tmp_path / "out", "--topic", "/chatter", *PCA])
    assert line.endswith("topic /chatter holds std_msgs/msg/String, not sensor_msgs/msg/PointCloud2")


def test_missing_input(tmp_path: Path, capsys) -> None:
    line = run_fails(capsys, [tmp_path / "none", tmp_path / "out", "--topic", "/points", *PCA])
    assert line == f"triplet-normal: error: {tmp_path / 'none'}: no such bag (a rosbag2 directory, .mcap or .db3 file)"


def test_output_topic_that_exists_in_the_input(small_bag: Path, tmp_path: Path, capsys) -> None:
    line = run_fails(capsys, [small_bag, tmp_path / "out", "--topic", "/points", "--output-topic", "/chatter"], 2)
    assert line.endswith(f"--output-topic /chatter is a topic of {small_bag}; choose another")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--radius", "0"], "--radius must be a finite number > 0"),
        (["--k", "2"], "--k must be an integer >= 3"),
        (["--segment-seconds", "-1"], "--segment-seconds must be a finite number >= 0"),
        (["--viewpoint", "0", "nan", "0"], "--viewpoint must be three finite numbers"),
        (["--overwrite", "--resume"], "argument --resume: not allowed with argument --overwrite"),
        (["--method", "magic"], "argument --method: invalid choice"),
        (["--start", "-1"], "--start must be a finite number >= 0, got -1.0"),
        (["--end", "inf"], "--end must be a finite number >= 0, got inf"),
        (["--start", "2", "--end", "2"], "--end must be greater than --start (2 s), got 2"),
        (["--end", "0"], "--end must be greater than --start (0 s), got 0"),
        (["--limit", "0"], "--limit must be >= 1, got 0"),
        (["--limit", "1.5"], "argument --limit: invalid int value: '1.5'"),
    ],
)
def test_bad_options(small_bag: Path, tmp_path: Path, capsys, extra: list[str], message: str) -> None:
    assert message in run_fails(capsys, [small_bag, tmp_path / "out", "--topic", "/points", *extra], 2)


def test_a_window_after_the_last_message_is_refused(small_bag: Path, tmp_path: Path, capsys) -> None:
    line = run_fails(capsys, [small_bag, tmp_path / "out", "--topic", "/points", "--start", "1", *PCA], 2)
    assert line == (
        f"triplet-normal: error: the window starts at 1 s, not before the end of {small_bag} (its messages span "
        "0.000 s)"
    )
    assert not (tmp_path / "out").exists() and not partial_path(tmp_path / "out").exists()


def test_out_inside_in_or_in_inside_out(small_bag: Path, tmp_path: Path, capsys) -> None:
    for out in (small_bag, small_bag / "sub", tmp_path):
        line = run_fails(capsys, [small_bag, out, "--topic", "/points", *PCA], 2)
        assert line.endswith(f"must lie outside IN {small_bag} and not contain it")


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_corrupt_bag_is_one_line_from_the_console_script(tmp_path: Path, storage: str) -> None:
    source = write_bag(tmp_path / "in", storage, mixed_records()[:2])
    (storage_file,) = [p for p in source.iterdir() if p.suffix in (".mcap", ".db3")]
    storage_file.write_bytes(storage_file.read_bytes()[:300])
    argv = [SCRIPT, "bag", source, tmp_path / "out", "--topic", "/points", *PCA]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"triplet-normal: error: {source}: not a readable rosbag2: "), lines
    assert not (tmp_path / "out").exists() and not partial_path(tmp_path / "out").exists()
