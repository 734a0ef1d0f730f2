"""The statistics line: windowed counts that reset on each report, running totals that do not."""

from triplet_normal_ros.ros.stats import ProcessingStats


def test_window_resets_and_totals_accumulate() -> None:
    stats = ProcessingStats()
    for ms in (10.0, 30.0):
        stats.record(ms)
    stats.reject()
    line = stats.window(5.0, dropped_total=3).line()
    assert "last 5 s: 0 arrived, 2 clouds, mean 20.0 ms, max 30.0 ms, 3 dropped, 1 rejected" in line
    assert line.endswith("total: 0 arrived, 2 clouds, 3 dropped, 1 rejected")
    stats.record(50.0)
    line = stats.window(5.0, dropped_total=4).line()
    assert "1 clouds, mean 50.0 ms, max 50.0 ms, 1 dropped, 0 rejected" in line
    assert line.endswith("total: 0 arrived, 3 clouds, 4 dropped, 1 rejected")
    assert stats.processed == 3


def test_an_idle_window_says_so() -> None:
    stats = ProcessingStats()
    stats.record(5.0)
    stats.window(1.0, 0)
    line = stats.window(1.0, 0).line()
    assert line == "last 1 s: no input clouds | total: 0 arrived, 1 clouds, 0 dropped, 0 rejected"


def test_a_busy_node_reports_arrivals_and_the_cloud_in_flight_not_silence() -> None:
    now = [100.0]
    stats = ProcessingStats(clock=lambda: now[0])
    assert stats.arrive() is True and stats.arrive() is False  # only the first arrival is announced
    stats.start()
    now[0] = 112.5
    line = stats.window(5.0, dropped_total=1).line()
    assert line.startswith("last 5 s: 2 arrived, 0 clouds, 1 dropped, 0 rejected, 1 in flight for 12.5 s")
    assert "no input" not in line and "mean" not in line
    now[0] = 115.0
    assert "1 in flight for 15.0 s" in stats.window(5.0, dropped_total=1).line()  # still busy, nothing new arrived
    stats.record(15_000.0)
    line = stats.window(5.0, dropped_total=1).line()
    assert "in flight" not in line and "1 clouds, mean 15000.0 ms" in line


def test_a_rejected_cloud_is_no_longer_in_flight() -> None:
    stats = ProcessingStats(clock=lambda: 0.0)
    stats.arrive()
    stats.start()
    stats.reject()
    assert "in flight" not in stats.window(1.0, 0).line()


def test_a_window_measures_its_own_length_for_the_rates() -> None:
    """Timers fire late under load: rates divide by the measured window, the log line names the configured one."""
    now = [10.0]
    stats = ProcessingStats(clock=lambda: now[0])
    for _ in range(5):
        stats.arrive()
    stats.record(1.0)
    now[0] = 12.5
    window = stats.window(2.0, dropped_total=0)
    assert window.elapsed_s == 2.5 and window.period_s == 2.0
    assert window.rate(window.window.arrived) == 2.0 and window.rate(window.window.processed) == 0.4
    assert window.line().startswith("last 2 s: 5 arrived, 1 clouds")
    now[0] = 13.0
    assert stats.window(2.0, dropped_total=0).elapsed_s == 0.5  # the next window starts where this one ended


def test_rejections_in_a_row_reset_on_a_processed_cloud_and_keep_the_latest_reason() -> None:
    stats = ProcessingStats(clock=lambda: 0.0)
    stats.reject("missing field z")
    stats.reject("point_step 4 is smaller than the fields")
    window = stats.window(1.0, 0)
    assert (window.rejected_in_a_row, window.last_rejection) == (2, "point_step 4 is smaller than the fields")
    stats.record(3.0)
    window = stats.window(1.0, 0)
    assert window.rejected_in_a_row == 0 and window.last_rejection == "point_step 4 is smaller than the fields"
    assert (window.window.rejected, window.total.rejected) == (0, 2)


def test_a_closed_window_is_a_snapshot() -> None:
    """Counting on after a report must not change the totals the report already handed out."""
    stats = ProcessingStats(clock=lambda: 0.0)
    stats.record(1.0)
    window = stats.window(1.0, 0)
    stats.record(2.0)
    assert window.total.processed == 1 and window.window.processed == 1


def test_clouds_a_transition_dropped_count_as_dropped_in_the_window_and_the_totals() -> None:
    stats = ProcessingStats()
    stats.arrive()
    stats.start()
    stats.drop()  # the cloud in flight, its answer no longer sendable
    window = stats.window(5.0, dropped_total=2)  # and two the mailbox replaced
    assert (window.dropped, window.dropped_total, window.window.stopped, window.in_flight_s) == (3, 3, 1, None)
    stats.drop()  # the waiting cloud, discarded by a deactivate
    window = stats.window(5.0, dropped_total=2)
    assert (window.dropped, window.dropped_total, window.total.stopped) == (1, 4, 2)
    assert window.line().endswith("total: 1 arrived, 0 clouds, 4 dropped, 0 rejected")
