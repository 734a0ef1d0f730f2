"""The statistics line: windowed counts that reset on each report, running totals that do not."""

from triplet_normal_ros.ros.stats import ProcessingStats


def test_window_resets_and_totals_accumulate() -> None:
    stats = ProcessingStats()
    for ms in (10.0, 30.0):
        stats.record(ms)
    stats.reject()
    line = stats.report(5.0, dropped_total=3)
    assert "last 5 s: 0 arrived, 2 clouds, mean 20.0 ms, max 30.0 ms, 3 dropped, 1 rejected" in line
    assert line.endswith("total: 0 arrived, 2 clouds, 3 dropped, 1 rejected")
    stats.record(50.0)
    line = stats.report(5.0, dropped_total=4)
    assert "1 clouds, mean 50.0 ms, max 50.0 ms, 1 dropped, 0 rejected" in line
    assert line.endswith("total: 0 arrived, 3 clouds, 4 dropped, 1 rejected")
    assert stats.processed == 3


def test_an_idle_window_says_so() -> None:
    stats = ProcessingStats()
    stats.record(5.0)
    stats.report(1.0, 0)
    assert stats.report(1.0, 0) == "last 1 s: no input clouds | total: 0 arrived, 1 clouds, 0 dropped, 0 rejected"


def test_a_busy_node_reports_arrivals_and_the_cloud_in_flight_not_silence() -> None:
    now = [100.0]
    stats = ProcessingStats(clock=lambda: now[0])
    assert stats.arrive() is True and stats.arrive() is False  # only the first arrival is announced
    stats.start()
    now[0] = 112.5
    line = stats.report(5.0, dropped_total=1)
    assert line.startswith("last 5 s: 2 arrived, 0 clouds, 1 dropped, 0 rejected, 1 in flight for 12.5 s")
    assert "no input" not in line and "mean" not in line
    now[0] = 115.0
    assert "1 in flight for 15.0 s" in stats.report(5.0, dropped_total=1)  # still busy, nothing new arrived
    stats.record(15_000.0)
    line = stats.report(5.0, dropped_total=1)
    assert "in flight" not in line and "1 clouds, mean 15000.0 ms" in line


def test_a_rejected_cloud_is_no_longer_in_flight() -> None:
    stats = ProcessingStats(clock=lambda: 0.0)
    stats.arrive()
    stats.start()
    stats.reject()
    assert "in flight" not in stats.report(1.0, 0)
