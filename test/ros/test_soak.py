"""Soak under overload (issue #11 item 5): the installed node, flooded with clouds of 3k to 128k points at 20 Hz
(it processes one or two a second with PCA), must keep its memory flat, count what it drops, answer every cloud it
answers with that cloud's own header, size and data, and still exit within 2 s of SIGINT.

docs/tools/soak.py runs the same soak (test/ros/overload.py) for longer and writes the figures to docs/RESULTS.md.
"""

from __future__ import annotations

import signal

import pytest
from conftest import NodeProcess, installed_env, params_yaml
from overload import NODE_PARAMS, OverloadClient, SoakResult, cloud_pool, soak

pytestmark = pytest.mark.slow  # a node process flooded for 100 s

IN, OUT = "/tn_soak/points", "/tn_soak/normals"
SECONDS, RATE_HZ = 100.0, 20.0
#: Seconds of flooding left out of the flatness check: in docs/tools/soak.py's 300 s runs RSS climbed for the first
#: 40-70 s, then stayed within a step or two of about 9 MB (allocator growth) for the rest of the run.
WARMUP_S = 40.0
SHUTDOWN_S = 2.0
#: How far the largest (and the median) RSS of the last third after warm-up may exceed the first third's. A third's
#: maximum is taken with a large cloud in flight (18 MB above the median in docs/tools/soak.py's runs), freed blocks
#: stay with the allocator, and RSS can still step up by ~9 MB once or twice after warm-up (up to 23 MB of growth
#: between thirds seen with a 22 s warm-up, 1 MB with 40 s), so healthy thirds can differ by tens of MB under load.
#: Leaking the clouds the mailbox drops would add hundreds of MB (checked below; a patched install that kept them
#: grew 320 MB between the thirds of a 40 s run).
FLAT_MB = 50.0


@pytest.fixture(scope="module")
def result(install_prefix, ros_env, tmp_path_factory) -> SoakResult:
    """One soak for the module's checks: the figures are the product, each test reads one aspect of them."""
    folder = tmp_path_factory.mktemp("soak")
    params = params_yaml(folder / "params.yaml", NODE_PARAMS, reliable_topics=(IN,))  # 2 MB clouds: see README, QoS
    node = NodeProcess(
        install_prefix,
        installed_env(install_prefix, ros_env),
        params,
        {"input": IN, "output": OUT},
        folder / "node.log",
    )
    try:
        assert node.wait_for_log("ready:", 120), node.log
        with OverloadClient(IN, OUT, cloud_pool()) as client:
            assert client.wait_for_node(60), "the node's topics and parameter services never matched"
            stop, log = (lambda: node.stop(signal.SIGINT)), (lambda: node.log)
            outcome = soak(node.proc.pid, stop, log, client, SECONDS, RATE_HZ, warmup_s=WARMUP_S)
        print(f"\n{outcome.table()}")  # the figures, for `pytest -s`
        outcome_log = node.log
    finally:
        node.close()
    assert "Traceback" not in outcome_log, outcome_log[-3000:]
    return outcome


def test_the_node_is_overloaded_and_counts_its_drops(result: SoakResult) -> None:
    f, t = result.flood, result.totals
    assert result.sent >= 0.5 * SECONDS * RATE_HZ, f"the client sent only {result.sent} clouds"
    assert f.answered >= 10, f"only {f.answered} answers"
    assert f.answered < result.sent / 2, "not an overload: the node kept up"  # 537 of 2000 on a quiet machine
    assert t.dropped > t.processed and t.rejected == 0, t  # most arrivals are dropped, not queued
    # Every cloud that arrived is accounted for: processed, dropped, or still pending (in flight, in the slot, or
    # counted on arrival a moment before the line was written).
    assert 0 <= t.pending <= 3, t
    assert t.arrived <= result.sent and t.processed <= t.arrived
    assert t.arrived >= 0.9 * result.sent, f"reliable input lost clouds: {t.arrived} of {result.sent} arrived"


def test_every_answer_matches_the_cloud_it_answers(result: SoakResult) -> None:
    f = result.flood
    assert not f.mismatches, "\n".join(f.mismatches[:20])
    assert len(f.answered_per_pool) >= 3, f"answers came for too few cloud sizes: {f.answered_per_pool}"


def test_memory_stays_flat(result: SoakResult) -> None:
    r = result.rss
    assert r.growth <= FLAT_MB and r.median_growth <= FLAT_MB, result.table()
    # The bound must be able to fail: a leak of one average-size cloud per dropped cloud, over the drops between the
    # middles of the first and last thirds after warm-up (two thirds of that stretch), would exceed it fourfold.
    mean_mb = sum(p.nbytes for p in result.pool) / len(result.pool) / 2**20
    drops_between = result.totals.dropped * (1 - WARMUP_S / SECONDS) * 2 / 3
    assert mean_mb * drops_between > 4 * FLAT_MB, (mean_mb, drops_between)


def test_sigint_while_overloaded_exits_within_2_s(result: SoakResult) -> None:
    assert result.totals.pending >= 1, "nothing was in flight at the last statistics line: not overloaded"
    assert result.exit_code == 0, result.table()
    assert result.exit_s < SHUTDOWN_S, f"took {result.exit_s:.2f} s"
