"""The /diagnostics level rules on windows made by the real ProcessingStats with a hand-driven clock (no ROS)."""

from __future__ import annotations

import pytest

from triplet_normal_ros.ros.health import (
    ERROR,
    NOT_AVAILABLE,
    OK,
    REJECTED_IN_A_ROW_ERROR,
    STUCK_FACTOR,
    STUCK_MIN_S,
    WARN,
    Health,
    assess,
    settings_values,
)
from triplet_normal_ros.ros.params import NodeSettings
from triplet_normal_ros.ros.stats import ProcessingStats


class Clocked:
    """ProcessingStats with a clock the test moves, and a report every ``period`` seconds."""

    def __init__(self, period: float = 1.0) -> None:
        self.now, self.period, self.dropped = 0.0, period, 0
        self.stats = ProcessingStats(clock=lambda: self.now)

    def health(self, advance: float | None = None) -> Health:
        self.now += self.period if advance is None else advance
        return assess(self.stats.window(self.period, self.dropped))


def values(health: Health) -> dict[str, str]:
    return dict(health.values)


def test_before_any_input_it_is_ok_and_waiting() -> None:
    health = Clocked().health()
    assert (health.level, health.message) == (OK, "waiting for input")
    v = values(health)
    assert v["input rate (Hz)"] == "0" and v["processed"] == "0" and v["mean processing time (ms)"] == NOT_AVAILABLE


def test_a_node_that_keeps_up_is_ok_with_its_rates_and_times() -> None:
    c = Clocked(period=2.0)
    for ms in (100.0, 300.0):
        c.stats.arrive()
        c.stats.start()
        c.stats.record(ms)
    c.stats.arrive()
    health = c.health()
    assert (health.level, health.message) == (OK, "keeping up")
    v = values(health)
    assert (v["input rate (Hz)"], v["output rate (Hz)"]) == ("1.5", "1")
    assert (v["mean processing time (ms)"], v["max processing time (ms)"]) == ("200.0", "300.0")
    assert (v["arrived"], v["processed"], v["dropped"], v["rejected"], v["in flight"]) == ("3", "2", "0", "0", "0")
    assert v["window (s)"] == "2" and v["total processed"] == "2"


def test_no_input_after_some_is_ok_and_says_so() -> None:
    c = Clocked()
    c.stats.arrive()
    c.stats.record(5.0)
    assert c.health().message == "keeping up"
    health = c.health()
    assert (health.level, health.message) == (OK, "no input in the last 1 s")
    assert values(health)["total arrived"] == "1"


def test_a_long_estimate_is_busy_not_silent() -> None:
    c = Clocked()
    c.stats.arrive()
    c.stats.start()
    health = c.health(advance=12.5)
    assert (health.level, health.message) == (OK, "busy: one cloud in flight for 12.5 s")
    assert (values(health)["in flight"], values(health)["in flight for (s)"]) == ("1", "12.5")


@pytest.mark.parametrize(
    ("slowest_ms", "in_flight_s", "level"),
    [
        (None, STUCK_MIN_S - 1, OK),  # a first full frame may take minutes
        (None, STUCK_MIN_S + 1, ERROR),
        (60_000.0, STUCK_MIN_S + 1, OK),  # a 60 s cloud finished before: 10x that is allowed
        (60_000.0, STUCK_FACTOR * 60 + 1, ERROR),
    ],
)
def test_a_cloud_in_flight_far_longer_than_any_before_is_stuck(
    slowest_ms: float | None, in_flight_s: float, level: int
) -> None:
    c = Clocked()
    if slowest_ms is not None:
        c.stats.record(slowest_ms)
    c.stats.start()
    health = c.health(advance=in_flight_s)
    assert health.level == level
    assert ("stuck" in health.message) == (level == ERROR)


def test_one_malformed_cloud_is_a_warning_with_its_reason() -> None:
    c = Clocked()
    c.stats.arrive()
    c.stats.reject("missing field z")
    health = c.health()
    assert (health.level, health.message) == (WARN, "1 rejected in the last 1 s")
    v = values(health)
    assert (v["rejected"], v["rejected in a row"], v["last rejection"]) == ("1", "1", "missing field z")
    assert c.health().level == OK  # the next window has no rejection


def test_every_cloud_rejected_in_a_row_is_an_error_until_one_is_processed() -> None:
    c = Clocked()
    for _ in range(REJECTED_IN_A_ROW_ERROR - 1):
        c.stats.reject("x is int16")
    assert c.health().level == WARN
    c.stats.reject("x is int16")
    health = c.health()
    assert (health.level, health.message) == (ERROR, f"the last {REJECTED_IN_A_ROW_ERROR} clouds were all rejected")
    assert c.health().level == ERROR, "still nothing processed: the input is still unusable"
    c.stats.record(4.0)
    assert c.health().level == OK


def test_drops_are_a_warning() -> None:
    c = Clocked()
    c.stats.record(900.0)
    c.dropped = 4
    health = c.health()
    assert (health.level, health.message) == (WARN, "4 dropped in the last 1 s: input faster than processing")
    assert (values(health)["dropped"], values(health)["total dropped"]) == ("4", "4")
    c.stats.record(900.0)
    assert c.health().level == OK, "drops are counted per window"


def test_drops_by_deactivate_or_cleanup_are_counted_but_no_warning() -> None:
    """The operator's transition dropped them, not an input faster than the node: counted, and said apart."""
    c = Clocked()
    c.stats.record(900.0)
    c.stats.drop()
    c.dropped = 1  # and one the input outran
    health = c.health()
    assert (health.level, health.message) == (WARN, "1 dropped in the last 1 s: input faster than processing")
    assert (values(health)["dropped"], values(health)["total dropped"]) == ("2", "2")
    assert values(health)["total dropped by deactivate or cleanup"] == "1"
    c.stats.drop()
    health = c.health()
    assert health.level == OK and values(health)["total dropped by deactivate or cleanup"] == "2"


def test_findings_of_the_highest_level_are_joined_and_lower_ones_left_out() -> None:
    c = Clocked()
    c.stats.record(1.0)
    c.stats.reject("bad")
    c.dropped = 2
    health = c.health()
    assert health.level == WARN
    assert health.message == "1 rejected in the last 1 s; 2 dropped in the last 1 s: input faster than processing"
    for _ in range(REJECTED_IN_A_ROW_ERROR):
        c.stats.reject("bad")
    c.dropped = 3
    health = c.health()
    in_a_row = REJECTED_IN_A_ROW_ERROR + 1  # the earlier rejection counts too: nothing was processed since
    assert (health.level, health.message) == (ERROR, f"the last {in_a_row} clouds were all rejected")


def test_settings_follow_the_figures_and_every_key_is_unique() -> None:
    settings = settings_values(NodeSettings(method="pca", radius=0.03), "cuda:0", 24, ("/cam/points", "/cam/normals"))
    health = assess(Clocked().stats.window(1.0, 0), settings)
    keys = [k for k, _ in health.values]
    assert len(keys) == len(set(keys))
    assert health.values[-len(settings) :] == settings
    assert all(isinstance(v, str) for _, v in health.values)
    v = values(health)
    assert (v["method"], v["device"], v["radius (m)"], v["k"]) == ("pca", "cuda:0", "0.03", "24")
    assert (v["checkpoint"], v["input topic"], v["output topic"]) == (NOT_AVAILABLE, "/cam/points", "/cam/normals")
    on_cpu = NodeSettings(method="hybrid", device="cpu")
    on_gpu = NodeSettings(method="hybrid", device="cuda:0")
    shipped = "range on range images and lite otherwise"  # the shipped ones for the device
    assert dict(settings_values(on_cpu, "cpu", 64, ("a", "b")))["checkpoint"] == shipped
    assert dict(settings_values(on_gpu, "cuda:0", 128, ("a", "b")))["checkpoint"] == "default"
    chosen = NodeSettings(method="hybrid", device="cpu", checkpoint="default")
    assert dict(settings_values(chosen, "cpu", 128, ("a", "b")))["checkpoint"] == "default"
