"""Soak under overload: flood the running node with clouds of varying size, much faster than it can process them,
and record what it does. test/ros/test_soak.py checks a 100 s soak; docs/tools/soak.py runs a longer one for the
results file, so both measure the same thing.

A fixed pool of clouds (organized crops and unorganized subsets of a shipped Kinect frame, 3k to 128k points) is sent
round-robin, each time under a fresh stamp and one of several frame_ids. Every answer is checked against the cloud it
claims to answer (by stamp): frame_id, height, width, layout, the xyz bytes, and normals equal to those of every other
answer to the same pool cloud (a node that mixed up clouds, or answered one with another's data, fails here). The
node's memory is sampled from /proc while it runs; its drop counts come from its own statistics line.
"""

from __future__ import annotations

import re
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from ...evaluation.bench_memory import status_mb
from ...io.pointcloud2 import NORMAL_FIELDS, make_cloud, read_field, read_xyz
from .replay import Frame, ReplayClient, load_frame

#: The node's settings: PCA over the nearest 24 (a pool search, whatever the cloud), a 3 cm ball, stats every second.
NODE_PARAMS = {"method": "pca", "radius": 0.03, "k": 24, "device": "cpu", "stats_period": 1.0}
#: Organized crops (height, width) of the frame and unorganized subsets (point counts) of its finite points.
CROPS = ((48, 64), (120, 160), (240, 320), (320, 400))
SUBSETS = (8_000, 40_000, 100_000)
FRAME_IDS = tuple(f"soak_sensor_{i}" for i in range(5))
#: Clouds queued on both ends of the flood's reliable input (the client's publisher and, through the parameter file's
#: QoS override, the node's subscription): a second of the flood. The node's executor thread waits for the
#: interpreter while the estimate holds it, and a history of 2 lost 13 % of the clouds in DDS on a busier machine; the
#: flood is there to overload the node's mailbox, which must be what drops.
FLOOD_DEPTH = 20
FLOOD_INPUT = QoSProfile(depth=FLOOD_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
#: Seconds of the soak counted as warm-up: allocator pools, DDS buffers and torch's caches reach their size.
WARMUP_FRACTION = 0.25
#: RSS sampling period, seconds.
RSS_EVERY_S = 0.5
_TOTALS = re.compile(r"total: (\d+) arrived, (\d+) clouds, (\d+) dropped, (\d+) rejected")


# -- the clouds -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PoolCloud:
    """One cloud of the pool: the message (its header is replaced on every send) and the digest of its xyz."""

    label: str
    cloud: PointCloud2
    xyz_crc: int

    @property
    def points(self) -> int:
        return self.cloud.height * self.cloud.width

    @property
    def nbytes(self) -> int:
        return len(self.cloud.data)


def _xyz_crc(msg: PointCloud2) -> int:
    return zlib.crc32(np.ascontiguousarray(read_xyz(msg)).tobytes())


def _pool_cloud(label: str, xyz: np.ndarray, rgb: np.ndarray, height: int, width: int) -> PoolCloud:
    fields = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rgb": rgb.view(np.float32)}
    cloud = make_cloud(Header(), fields, height, width)
    return PoolCloud(label, cloud, _xyz_crc(cloud))


def cloud_pool(frame: Frame | None = None) -> list[PoolCloud]:
    """Organized crops and unorganized subsets of the frame, smallest to largest (x, y, z, rgb: 16 bytes a point)."""
    frame = frame or load_frame("table_scene_mug")
    pool = []
    for h, w in CROPS:
        top, left = (frame.shape[0] - h) // 2, (frame.shape[1] - w) // 2
        xyz = frame.xyz[top : top + h, left : left + w].reshape(-1, 3)
        pool.append(_pool_cloud(f"{w}x{h} organized", xyz, frame.rgb[top : top + h, left : left + w].ravel(), h, w))
    finite = np.flatnonzero(np.isfinite(frame.xyz.reshape(-1, 3)).all(axis=1))
    rng = np.random.default_rng(0)
    for n in SUBSETS:
        rows = np.sort(rng.choice(finite, n, replace=False))
        pool.append(_pool_cloud(f"{n} unorganized", frame.xyz.reshape(-1, 3)[rows], frame.rgb.ravel()[rows], 1, n))
    return sorted(pool, key=lambda p: p.points)


# -- memory ---------------------------------------------------------------------------------------------------------


class RssSampler:
    """Samples a process's RSS every ``every`` s on a thread: (seconds since start, MB)."""

    def __init__(self, pid: int, every: float = RSS_EVERY_S) -> None:
        self.pid, self.every = pid, every
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss_sampler", daemon=True)

    def _run(self) -> None:
        start = time.monotonic()
        while not self._stop.is_set():
            try:
                self.samples.append((time.monotonic() - start, status_mb(self.pid)))
            except (OSError, RuntimeError):  # the process is gone
                return
            self._stop.wait(self.every)

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)


@dataclass(frozen=True)
class RssFigures:
    """RSS in MB: before the flood, the first and last third after warm-up, the end and the peak.

    A third's maximum is the node with a large cloud in flight; its median is closer to what stays resident between
    clouds, so a slow leak shows in the medians first.
    """

    start: float
    first_third_max: float
    last_third_max: float
    first_third_median: float
    last_third_median: float
    end: float
    peak: float
    slope_mb_per_min: float  # least-squares slope over the samples after warm-up

    @property
    def growth(self) -> float:
        return self.last_third_max - self.first_third_max

    @property
    def median_growth(self) -> float:
        return self.last_third_median - self.first_third_median


def rss_figures(samples: list[tuple[float, float]], warmup_s: float) -> RssFigures:
    after = [(t, mb) for t, mb in samples if t >= warmup_s]
    if len(after) < 6:
        raise ValueError(f"only {len(after)} RSS samples after warm-up; the soak was too short")
    third = len(after) // 3
    t, mb = np.array(after).T
    slope = float(np.polyfit(t, mb, 1)[0]) * 60
    first, last = mb[:third], mb[-third:]
    medians = float(np.median(first)), float(np.median(last))
    return RssFigures(
        samples[0][1], first.max(), last.max(), *medians, samples[-1][1], max(m for _, m in samples), slope
    )


# -- the flood ------------------------------------------------------------------------------------------------------


@dataclass
class _Sent:
    pool: int
    frame_id: str
    at: float


@dataclass
class Flood:
    """What was sent and answered, and every way an answer failed to match the cloud it answers."""

    sent: dict[tuple[int, int], _Sent] = field(default_factory=dict)
    answered: int = 0
    latencies_s: list[float] = field(default_factory=list)
    answered_per_pool: dict[int, int] = field(default_factory=dict)
    mismatches: list[str] = field(default_factory=list)
    send_s: float = 0.0


class OverloadClient(ReplayClient):
    """Publishes the pool round-robin at a fixed rate and checks each answer on arrival."""

    def __init__(self, input_topic: str, output_topic: str, pool: list[PoolCloud]) -> None:
        self.pool = pool
        self.flood = Flood()
        self._normals: dict[int, np.ndarray] = {}  # pool index -> normals of its first answer
        super().__init__(input_topic, output_topic, input_qos=FLOOD_INPUT)

    def _on_output(self, msg: PointCloud2) -> None:
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        sent = self.flood.sent.get(key)
        if sent is None:
            self.flood.mismatches.append(f"an answer with stamp {key} that was never sent")
            return
        self.flood.answered += 1
        self.flood.latencies_s.append(time.monotonic() - sent.at)
        self.flood.answered_per_pool[sent.pool] = self.flood.answered_per_pool.get(sent.pool, 0) + 1
        problem = self._mismatch(msg, sent)
        if problem:
            self.flood.mismatches.append(f"stamp {key} ({self.pool[sent.pool].label}): {problem}")

    def _mismatch(self, msg: PointCloud2, sent: _Sent) -> str | None:
        """Why ``msg`` is not the answer to ``sent``, or None."""
        cloud = self.pool[sent.pool].cloud
        if msg.header.frame_id != sent.frame_id:
            return f"frame_id {msg.header.frame_id!r}, sent {sent.frame_id!r}"
        if (msg.height, msg.width) != (cloud.height, cloud.width):
            return f"{msg.width}x{msg.height}, sent {cloud.width}x{cloud.height}"
        names = [f.name for f in msg.fields]
        if names != [f.name for f in cloud.fields] + list(NORMAL_FIELDS):
            return f"fields {names}"
        if len(msg.data) != msg.height * msg.row_step or msg.point_step != cloud.point_step + 16:
            return f"{len(msg.data)} bytes at point_step {msg.point_step}"
        if _xyz_crc(msg) != self.pool[sent.pool].xyz_crc:
            return "xyz differs from the cloud sent"
        normals = np.stack([read_field(msg, f) for f in NORMAL_FIELDS[:3]], axis=1)
        first = self._normals.setdefault(sent.pool, normals)
        if not np.allclose(normals, first, atol=1e-5, equal_nan=True):
            return "normals differ from an earlier answer to the same cloud"
        return None

    def _fresh_stamp(self, previous: tuple[int, int] | None) -> Header:
        header = self.header()
        if previous is not None and (header.stamp.sec, header.stamp.nanosec) <= previous:
            sec, nsec = previous[0], previous[1] + 1
            header.stamp.sec, header.stamp.nanosec = sec + nsec // 1_000_000_000, nsec % 1_000_000_000
        return header

    def run(self, seconds: float, rate_hz: float, tick: Callable[[float], None] | None = None) -> Flood:
        """Send for ``seconds`` at ``rate_hz``, serving answers in between; ``tick(elapsed)`` after each send."""
        start = time.monotonic()
        period, last = 1.0 / rate_hz, None
        i = 0
        while (now := time.monotonic()) - start < seconds:
            due = start + i * period
            if now >= due:
                last = self._send(i, last)
                i += 1
                if tick:
                    tick(time.monotonic() - start)
            self._executor.spin_once(timeout_sec=max(0.0, min(0.005, due + period - time.monotonic())))
        self.flood.send_s = time.monotonic() - start
        return self.flood

    def _send(self, i: int, last: tuple[int, int] | None) -> tuple[int, int]:
        """Publish pool cloud ``i mod len(pool)`` under a stamp later than ``last``; returns its stamp."""
        index, frame_id = i % len(self.pool), FRAME_IDS[i % len(FRAME_IDS)]
        cloud = self.pool[index].cloud
        cloud.header = self._fresh_stamp(last)
        cloud.header.frame_id = frame_id
        key = (cloud.header.stamp.sec, cloud.header.stamp.nanosec)
        self.flood.sent[key] = _Sent(index, frame_id, time.monotonic())
        self._publisher.publish(cloud)
        return key

    def drain(self, seconds: float) -> None:
        """Keep receiving answers for ``seconds`` without sending."""
        self._spin_until(lambda: False, seconds)


# -- the node's own account ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NodeTotals:
    """The running totals of the node's latest statistics line."""

    arrived: int
    processed: int
    dropped: int
    rejected: int

    @property
    def pending(self) -> int:
        """Arrivals not (yet) accounted for: the cloud in flight and the one waiting in the slot."""
        return self.arrived - self.processed - self.dropped - self.rejected


def last_totals(log: str) -> NodeTotals | None:
    found = _TOTALS.findall(log)
    return NodeTotals(*map(int, found[-1])) if found else None


# -- the whole run --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SoakResult:
    duration_s: float
    rate_hz: float
    pool: list[PoolCloud]
    flood: Flood
    rss: RssFigures
    warmup_s: float  # on the RSS samples' clock: about 1 s of the idle node, then the flood
    totals: NodeTotals
    exit_code: int | None
    exit_s: float
    rss_samples: list[tuple[float, float]]  # (seconds since sampling began, MB), up to the end of sending

    @property
    def sent(self) -> int:
        return len(self.flood.sent)

    def table(self) -> str:
        f, r, t = self.flood, self.rss, self.totals
        lat = np.array(f.latencies_s) if f.latencies_s else np.zeros(1)
        rows = [
            ("run", f"{self.duration_s:.0f} s of sending, warm-up {self.warmup_s:.0f} s"),
            ("sent", f"{self.sent} clouds, {self.sent / f.send_s:.1f} per s (target {self.rate_hz:g})"),
            ("sizes", ", ".join(f"{p.label} ({p.nbytes / 2**20:.2f} MB)" for p in self.pool)),
            ("answered", f"{f.answered} ({f.answered / f.send_s:.2f} per s), {len(f.mismatches)} mismatched"),
            (
                "node's totals",
                f"{t.arrived} arrived, {t.processed} processed, {t.dropped} dropped, "
                f"{t.rejected} rejected, {t.pending} pending",
            ),
            ("latency (send to answer)", f"median {np.median(lat):.1f} s, max {lat.max():.1f} s"),
            ("RSS start / end / peak", f"{r.start:.0f} / {r.end:.0f} / {r.peak:.0f} MB"),
            (
                "RSS max, first / last third after warm-up",
                f"{r.first_third_max:.0f} / {r.last_third_max:.0f} MB (growth {r.growth:+.0f} MB)",
            ),
            (
                "RSS median, first / last third after warm-up",
                f"{r.first_third_median:.0f} / {r.last_third_median:.0f} MB (growth {r.median_growth:+.0f} MB)",
            ),
            ("RSS slope after warm-up", f"{r.slope_mb_per_min:+.1f} MB/min"),
            ("SIGINT while overloaded", f"exit code {self.exit_code} after {self.exit_s:.2f} s"),
        ]
        return "| figure | value |\n| --- | --- |\n" + "\n".join(f"| {a} | {b} |" for a, b in rows)


def soak(
    node_pid: int,
    stop: Callable[[], tuple[int | None, float]],
    log: Callable[[], str],
    client: OverloadClient,
    seconds: float,
    rate_hz: float,
    tick: Callable[[float], None] | None = None,
    warmup_s: float | None = None,
) -> SoakResult:
    """Flood the node (``node_pid``) for ``seconds``, then ``stop()`` it (SIGINT) while it is still overloaded.

    The first ``warmup_s`` seconds of flooding (default: WARMUP_FRACTION of them) are left out of the flatness figures.
    """
    with RssSampler(node_pid) as sampler:
        sampler_start = time.monotonic()
        time.sleep(2 * RSS_EVERY_S)  # the idle node's RSS first
        flood_start = time.monotonic() - sampler_start
        flood = client.run(seconds, rate_hz, tick)
        totals = last_totals(log())
        code, exit_s = stop()
    client.drain(1.0)  # answers already on the wire
    warmup_s = flood_start + (WARMUP_FRACTION * seconds if warmup_s is None else warmup_s)
    samples = [(t, mb) for t, mb in sampler.samples if t <= flood_start + flood.send_s]
    if totals is None:
        raise RuntimeError("the node logged no statistics line during the soak")
    rss = rss_figures(samples, warmup_s)
    return SoakResult(seconds, rate_hz, client.pool, flood, rss, warmup_s, totals, code, exit_s, samples)
