"""The statistics line: windowed counts that reset on each report, running totals that do not."""

from triplet_normal_ros.ros.stats import ProcessingStats


def test_window_resets_and_totals_accumulate() -> None:
    stats = ProcessingStats()
    for ms in (10.0, 30.0):
        stats.record(ms)
    stats.reject()
    line = stats.report(5.0, dropped_total=3)
    assert "last 5 s: 2 clouds, mean 20.0 ms, max 30.0 ms, 3 dropped, 1 rejected" in line
    assert line.endswith("total: 2 clouds, 3 dropped, 1 rejected")
    stats.record(50.0)
    line = stats.report(5.0, dropped_total=4)
    assert "1 clouds, mean 50.0 ms, max 50.0 ms, 1 dropped, 0 rejected" in line
    assert line.endswith("total: 3 clouds, 4 dropped, 1 rejected")
    assert stats.processed == 3


def test_an_idle_window_says_so() -> None:
    stats = ProcessingStats()
    stats.record(5.0)
    stats.report(1.0, 0)
    assert stats.report(1.0, 0) == "last 1 s: no input clouds | total: 1 clouds, 0 dropped, 0 rejected"
