"""Soak under a flood: the installed node is sent clouds of 3k to 128k points at 20 Hz for 100 s (on the 2-core
development machine several times faster than it processes them with PCA, on a faster one perhaps not). Whatever the
machine's speed, it must answer every cloud it answers with that cloud's own header, size and data and with the
normals plain PCA of the k nearest gives; account for every arrival as processed or dropped; answer the last cloud of
the flood (the one-slot mailbox never drops the newest); keep its memory flat; and exit cleanly on SIGINT.

docs/tools/soak.py runs the same flood (triplet_normal_ros/ros/tools/overload.py) for longer and writes the figures to
docs/RESULTS.md.
"""

from __future__ import annotations

import re
import signal
from dataclasses import dataclass

import numpy as np
import pytest
from conftest import STARTUP_S, NodeProcess, installed_env, params_yaml
from helpers import angles_deg, ball_pca
from sensor_msgs.msg import PointCloud2

from triplet_normal_ros.io.pointcloud2 import NORMAL_FIELDS, read_field, read_xyz
from triplet_normal_ros.ros.tools.overload import (
    FLOOD_DEPTH,
    NODE_PARAMS,
    NodeTotals,
    OverloadClient,
    SoakResult,
    cloud_pool,
    last_totals,
    soak,
)

pytestmark = pytest.mark.slow  # a node process flooded for 100 s

IN, OUT = "/tn_soak/points", "/tn_soak/normals"
SECONDS, RATE_HZ = 100.0, 20.0
#: Seconds of flooding left out of the flatness check: in docs/tools/soak.py's 300 s runs RSS climbed for the first
#: 40-70 s, then stayed within a step or two of about 9 MB (allocator growth) for the rest of the run.
WARMUP_S = 40.0
#: Hang guards only: the node answers the flood's last cloud, and exits after SIGINT, long before these.
SETTLE_GUARD_S = 120.0
EXIT_GUARD_S = 60.0
#: How far the largest (and the median) RSS of the last third after warm-up may exceed the first third's. A third's
#: maximum is taken with a large cloud in flight (18 MB above the median in docs/tools/soak.py's runs), freed blocks
#: stay with the allocator, and RSS can still step up by ~9 MB once or twice after warm-up (up to 23 MB of growth
#: between thirds seen with a 22 s warm-up, 1 MB with 40 s), so healthy thirds can differ by tens of MB under load.
#: Keeping the clouds it receives would add hundreds of MB (checked below; a patched install that kept the clouds
#: the mailbox drops grew 320 MB between the thirds of a 40 s run).
FLAT_MB = 50.0
#: The node's statistics line, which ends with its running totals.
STATS_LINE = re.compile(r"\| total: \d+ arrived")


class CheckedClient(OverloadClient):
    """The flood's client, also keeping which stamps were answered and the first answer to each pool cloud."""

    def __init__(self, *args, **kwargs) -> None:
        self.answered_stamps: set[tuple[int, int]] = set()
        self.first_answers: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # pool index -> (normals, curvature)
        super().__init__(*args, **kwargs)

    def _on_output(self, msg: PointCloud2) -> None:
        super()._on_output(msg)
        key = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        sent = self.flood.sent.get(key)
        if sent is None:
            return
        self.answered_stamps.add(key)
        if sent.pool not in self.first_answers:
            normals = np.stack([read_field(msg, f) for f in NORMAL_FIELDS[:3]], axis=1)
            self.first_answers[sent.pool] = (normals, read_field(msg, "curvature"))

    def spin_until(self, done, timeout: float) -> bool:
        return self._spin_until(done, timeout)


@dataclass(frozen=True)
class AfterFlood:
    """The state once the flood has settled, just before SIGINT."""

    last_answered: bool  # the answer to the last cloud sent arrived
    totals: NodeTotals | None  # the node's first statistics line after that answer with nothing pending
    alive: bool  # the node process was still running


@dataclass(frozen=True)
class Outcome:
    soak: SoakResult
    after: AfterFlood
    client: CheckedClient
    log: str


@pytest.fixture(scope="module")
def outcome(install_prefix, ros_env, tmp_path_factory) -> Outcome:
    """One flood for the module's checks: the figures are the product, each test reads one aspect of them."""
    folder = tmp_path_factory.mktemp("soak")
    # 2 MB clouds, sent faster than they are answered: reliable and queued (docs/NODE.md, "Topics and QoS";
    # overload.FLOOD_DEPTH)
    params = params_yaml(folder / "params.yaml", NODE_PARAMS, reliable_topics=(IN,), depth=FLOOD_DEPTH)
    node = NodeProcess(
        install_prefix,
        installed_env(install_prefix, ros_env),
        params,
        {"input": IN, "output": OUT},
        folder / "node.log",
    )
    settled: list[AfterFlood] = []
    try:
        assert node.wait_for_log("ready:", STARTUP_S), node.log
        with CheckedClient(IN, OUT, cloud_pool()) as client:
            assert client.wait_for_node(60), "the node's topics and parameter services never matched"

            def settle_then_stop() -> tuple[int | None, float]:
                settled.append(_settle(client, node))
                return node.stop(signal.SIGINT, timeout=EXIT_GUARD_S)

            result = soak(node.proc.pid, settle_then_stop, lambda: node.log, client, SECONDS, RATE_HZ, None, WARMUP_S)
        print(f"\n{result.table()}")  # the figures, for `pytest -s`
        log = node.log
    finally:
        node.close()
    return Outcome(result, settled[0], client, log)


def _settle(client: CheckedClient, node: NodeProcess) -> AfterFlood:
    """Wait for the answer to the flood's last cloud, then for a statistics line that accounts for every arrival."""
    last = max(client.flood.sent)
    answered = client.spin_until(lambda: last in client.answered_stamps, SETTLE_GUARD_S)
    lines = len(STATS_LINE.findall(node.log))

    def accounted() -> bool:
        totals = last_totals(node.log)
        return len(STATS_LINE.findall(node.log)) > lines and totals is not None and totals.pending == 0

    client.spin_until(accounted, SETTLE_GUARD_S)
    return AfterFlood(answered, last_totals(node.log), node.proc.poll() is None)


def test_the_flood_reached_the_node(outcome: Outcome) -> None:
    result, totals = outcome.soak, outcome.after.totals
    # How many clouds the client manages in SECONDS depends on the machine; a flood is more than the node's reliable
    # input queue holds. Whether it was long enough for the memory check to see a leak, that check says itself.
    assert result.sent > FLOOD_DEPTH, f"the client sent only {result.sent} clouds"
    assert totals is not None and totals.arrived <= result.sent
    # Reliable with a bounded history (KEEP_LAST, FLOOD_DEPTH): a writer whose queue is full of unacknowledged clouds
    # overwrites the oldest, so under a flood some loss is DDS's, not the node's. On this 2-core machine 89-99 % arrived
    # across five full test runs (the node's executor shares the CPU with the worker); a node that stopped taking
    # clouds would lose most of them.
    assert totals.arrived >= 0.8 * result.sent, f"reliable input lost clouds: {totals.arrived} of {result.sent}"


def test_every_arrival_is_processed_or_dropped_and_the_last_cloud_is_answered(outcome: Outcome) -> None:
    after, flood = outcome.after, outcome.soak.flood
    assert after.alive, "the node died during the flood"
    assert after.last_answered, "the last cloud of the flood was never answered"
    t = after.totals
    assert t is not None and t.pending == 0, t  # nothing in flight, nothing waiting, nothing unaccounted for
    assert t.rejected == 0 and t.processed + t.dropped == t.arrived, t
    assert 1 <= flood.answered <= t.processed, (flood.answered, t)  # each answer is one processed cloud


def test_every_answer_is_the_right_one_for_the_cloud_it_answers(outcome: Outcome) -> None:
    f, client = outcome.soak.flood, outcome.client
    assert not f.mismatches, "\n".join(f.mismatches[:20])  # header, size, layout, xyz; same normals every time
    assert len(f.answered_per_pool) >= 3, f"answers came for too few cloud sizes: {f.answered_per_pool}"
    # The normals are plain PCA of each point's k nearest within the radius (helpers.ball_pca, written in the test), at
    # 1000 answered points of each cloud (so all the answers to it are, by the check above). Measured on every pool
    # cloud: a median angle of at most 0.002 deg, 0.014 deg at the 95th percentile, at most 0.7 % of the points beyond
    # 0.1 deg (ties at the k-th distance in the quantized depth); curvature within 2e-9 at the 95th percentile.
    radius, k = NODE_PARAMS["radius"], NODE_PARAMS["k"]
    for index, (normals, curvature) in client.first_answers.items():
        points, label = read_xyz(client.pool[index].cloud), client.pool[index].label
        answered = np.flatnonzero(np.isfinite(normals).all(axis=1))
        sample = np.sort(np.random.default_rng(index).choice(answered, min(1000, len(answered)), replace=False))
        ref_normals, ref_curvature = ball_pca(points, sample, radius, k=k)
        assert np.isfinite(ref_normals).all(), label
        angles = angles_deg(normals[sample], ref_normals, signed=True)
        assert np.median(angles) < 0.005 and np.quantile(angles, 0.95) < 0.05, label
        assert (angles > 0.1).mean() < 0.03, label
        assert np.quantile(np.abs(curvature[sample] - ref_curvature), 0.95) < 1e-6, label


def test_memory_stays_flat(outcome: Outcome) -> None:
    result = outcome.soak
    r = result.rss
    assert r.growth <= FLAT_MB and r.median_growth <= FLAT_MB, result.table()
    # The bound must be able to fail, on any machine: keeping every cloud that arrives (processed or dropped) over the
    # arrivals between the middles of the first and last thirds after warm-up (two thirds of that stretch) would
    # exceed it fourfold.
    mean_mb = sum(p.nbytes for p in result.pool) / len(result.pool) / 2**20
    arrivals_between = result.totals.arrived * (1 - WARMUP_S / SECONDS) * 2 / 3
    assert mean_mb * arrivals_between > 4 * FLAT_MB, (mean_mb, arrivals_between)


def test_sigint_after_the_flood_exits_cleanly(outcome: Outcome) -> None:
    result, log = outcome.soak, outcome.log
    assert result.exit_code == 0, result.table()
    assert "shut down" in log and "still busy" not in log, log[-3000:]
    assert "Traceback" not in log, log[-3000:]
