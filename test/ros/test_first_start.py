"""The first start after `colcon build` loads the CPU kernels the build compiled, instead of compiling them itself.

colcon build runs `triplet-normal warm` against the installed copy (setup.py), so the install's `__pycache__` folders
hold every kernel. The installed node, started as on a robot's first boot after a deploy (an empty home and ROS home,
no NUMBA_CACHE_DIR), must report in its warm-up line that it loaded them and compiled none, and then answer a real
full Kinect frame. How long that takes is docs/RESULTS.md's ("The first start", `docs/tools/first_frame.py`); what
this test checks, the cache that makes it short, holds on any machine.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import PACKAGE, STARTUP_S, NodeProcess, colcon_build, installed_env, params_yaml, site_packages
from probe_client import matched_client

from triplet_normal_ros.io.pointcloud2 import NORMAL_FIELDS, read_field
from triplet_normal_ros.ros.tools.replay import load_frame

pytestmark = pytest.mark.slow  # a colcon build (with the kernels) and a node process on a full frame

IN, OUT = "/tn_first/points", "/tn_first/normals"
#: A hang guard only: under a second of estimation on a quiet machine.
ANSWER_TIMEOUT_S = 300.0


@pytest.fixture(scope="module")
def install_prefix(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon install of its own: the session's shared one may hold caches that other tests' nodes wrote."""
    return colcon_build(tmp_path_factory.mktemp("ws_first_start"))


def test_the_build_compiled_the_kernels_into_the_install(install_prefix: Path) -> None:
    core = site_packages(install_prefix) / PACKAGE / "core"
    indexed = {path.parent.parent.name for path in core.rglob("__pycache__/*.nbi")}
    assert {"learned", "pca", "range_image", "search"} <= indexed, indexed


def test_a_first_start_with_an_empty_home_loads_every_kernel_and_answers_a_full_frame(
    install_prefix: Path, ros_env: dict[str, str], tmp_path: Path
) -> None:
    env = {k: v for k, v in installed_env(install_prefix, ros_env).items() if k != "NUMBA_CACHE_DIR"}
    env.update(HOME=str(tmp_path / "home"), ROS_HOME=str(tmp_path / "ros"))
    (tmp_path / "home").mkdir()
    params = params_yaml(tmp_path / "params.yaml", {"device": "cpu"}, (IN,))
    node = NodeProcess(install_prefix, env, params, {"input": IN, "output": OUT}, tmp_path / "node.log")
    try:
        assert node.wait_for_log("ready:", STARTUP_S), node.log
        warm = re.search(r"warm-up [\d.]+ s, (\d+) kernels loaded from the cache, (\d+) compiled", node.log)
        assert warm, node.log
        assert int(warm[1]) > 0 and int(warm[2]) == 0, warm[0]
        frame = load_frame("table_scene_mug")
        with matched_client(IN, OUT, 60) as client:
            out = client.request(frame.to_cloud(client.header()), timeout=ANSWER_TIMEOUT_S)
        assert out is not None, "no answer to a full Kinect frame"
        assert (out.height, out.width) == (480, 640)
        normals = np.stack([read_field(out, f) for f in NORMAL_FIELDS[:3]], axis=1)
        returns = np.isfinite(frame.xyz.reshape(-1, 3)).all(axis=1)
        assert np.isfinite(normals).all(axis=1)[returns].mean() > 0.9
    finally:
        node.close()
