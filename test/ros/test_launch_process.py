"""The launch file's arguments on the real node: the colcon-installed ``node`` started with the command line
launch_ros would give it for ``namespace``, ``use_sim_time``, ``log_level``, ``preset`` and ``params_file``
(``test_launch.launched``, from the launch file's own ``generate_launch_description``), talked to over DDS.
"""

from __future__ import annotations

import signal
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import STARTUP_S
from probe_client import ProbeClient, cropped
from rclpy.parameter_client import AsyncParameterClient
from test_launch import OWN, PARAMS_FILE, PRESET, applied, launched, own_params

from triplet_normal_ros.ros.tools.replay import load_frame


@pytest.mark.slow  # colcon build and a node process
def test_the_installed_node_runs_as_launched_in_a_namespace_on_sim_time_at_debug_level(
    start_node, install_prefix: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The installed node started with what the launch file gives for namespace:=robot1 use_sim_time:=true
    log_level:=debug preset:=lidar params_file:=<own> (``Launched.command_line``): its topics are /robot1/input ->
    /robot1/output and a cloud sent there is answered, use_sim_time is true, debug lines are logged, and its settings
    are the user file's keys over the lidar preset's."""
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(install_prefix))
    own = own_params(tmp_path / "mine.yaml")
    arguments = {"namespace": "robot1", "use_sim_time": "true", "log_level": "debug", PRESET: "lidar"}
    given = launched(monkeypatch, {**arguments, PARAMS_FILE: str(own)})
    preset, *rest = given.parameters
    node = start_node(Path(preset), {}, extra_args=replace(given, parameters=tuple(rest)).command_line())
    assert node.wait_for_log("ready:", STARTUP_S), node.log
    (ready,) = [line for line in node.log.splitlines() if "ready:" in line]
    assert "ready: /robot1/input -> /robot1/output," in ready, ready
    lidar = applied([preset])
    assert "method=pca," in ready and f"radius={OWN['radius']:g} m," in ready, ready  # the user's keys ...
    assert f"range_scale={lidar['range_scale']:g}," in ready, ready  # ... and the preset's where it sets none
    assert "[DEBUG]" in node.log
    with ProbeClient("/robot1/input", "/robot1/output", node_name="/robot1/triplet_normal") as client:
        assert client.wait_for_node(30), "the namespaced topics and parameter services never matched"
        sim_time = AsyncParameterClient(client.node, "/robot1/triplet_normal").get_parameters(["use_sim_time"])
        assert client.spin_until(sim_time.done, 30)
        assert [v.bool_value for v in sim_time.result().values] == [True]
        cloud = cropped(load_frame("table_scene_mug"), 200, 300, 20, 20).to_cloud(client.header())
        answer = client.request_resending(cloud, timeout=60, every=5.0)  # the best-effort input may lose one
        assert answer is not None and answer.header == cloud.header
        assert "normal_x" in [f.name for f in answer.fields]
    code, _ = node.stop(signal.SIGINT, timeout=60)
    assert code == 0, node.log[-2000:]
