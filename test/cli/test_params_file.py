"""`--params-file` of `estimate`, `bag` and `bags`: the node's ROS 2 parameter file, or a shipped preset by name.

A preset gives exactly what its values typed out as options give (the outputs are compared byte for byte, on clouds
reaching past the range where config/lidar.yaml's range_scale grows the ball, and a run without that value differs);
an option on the command line wins over the file, one given with its default value too; a bad value in the file is
one line naming the file, in the node's own words (`ros.params.validate`); a missing file, an unknown parameter, a
file without the node's section are one line each; the node's own parameters (statistics, RViz outputs, QoS
overrides) are left alone. The presets are found in the checkout and in a colcon install.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import PACKAGE, REPO, installed_env, params_yaml
from rosbag_files import CLOUD, Record, cloud, read_raw, write_bag

from triplet_normal_ros.cli import args as checks
from triplet_normal_ros.cli.main import main
from triplet_normal_ros.ros.params import SPEC_BY_NAME, validate

#: config/lidar.yaml typed out as options (zeros_are_no_returns and orient true are the options' defaults).
LIDAR_TYPED = ["--method", "hybrid", "--radius", "0.25", "--range-scale", "0.03", "--neighbours", "auto"]
LIDAR_VIEWPOINT = ["--viewpoint", "0", "0", "0"]


def far_points(n: int, seed: int) -> np.ndarray:
    """A bumpy sphere of radius 12 m around the sensor: beyond 8.3 m, where lidar.yaml's range_scale (0.03) makes the
    ball larger than its radius (0.25 m), so the value changes the normals."""
    rng = np.random.default_rng(seed)
    unit = rng.normal(size=(n, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    return unit * (12.0 + 0.05 * np.sin(5 * unit[:, :1]))


@pytest.fixture
def xyz(tmp_path: Path) -> Path:
    path = tmp_path / "cloud.xyz"
    np.savetxt(path, far_points(3000, seed=1))
    return path


@pytest.fixture
def bag_in(tmp_path: Path) -> Path:
    records = [Record("/points", CLOUD, 1_000 * (i + 1), cloud(far_points(2000, seed=2 + i), i)) for i in range(2)]
    return write_bag(tmp_path / "in", "mcap", records)


def run_ok(capsys, argv: list) -> str:
    status = main([str(a) for a in argv])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    return captured.out


def summary_without_timing(line: str, *paths: Path) -> str:
    """A summary line with its seconds and the given paths blanked: what two runs with the same settings share."""
    for path in paths:
        line = line.replace(str(path), "PATH")
    return re.sub(r"\d+\.\d+ s", "T s", line)


def estimate(capsys, xyz: Path, out: Path, *options: str) -> tuple[str, bytes]:
    line = run_ok(capsys, ["estimate", xyz, "--out", out, "--device", "cpu", *options])
    return summary_without_timing(line, out), out.read_bytes()


def bag(capsys, source: Path, out: Path, *options: str) -> tuple[str, list]:
    line = run_ok(capsys, ["bag", source, out, "--topic", "/points", "--device", "cpu", *options])
    return summary_without_timing(line, out), read_raw(out)


def test_the_lidar_preset_is_its_values_typed_out_for_estimate(tmp_path: Path, capsys, xyz: Path) -> None:
    preset = estimate(capsys, xyz, tmp_path / "preset.normals", "--params-file", "lidar")
    typed = estimate(capsys, xyz, tmp_path / "typed.normals", *LIDAR_TYPED, *LIDAR_VIEWPOINT)
    assert preset == typed
    assert "(hybrid, " in preset[0] and "radius 0.25, cpu" in preset[0]
    without = estimate(capsys, xyz, tmp_path / "without.normals", *LIDAR_TYPED[:-4], *LIDAR_VIEWPOINT)
    assert without[1] != preset[1]  # the preset's range_scale was used: without it the normals differ


def test_the_lidar_preset_is_its_values_typed_out_for_bag(tmp_path: Path, capsys, bag_in: Path) -> None:
    preset = bag(capsys, bag_in, tmp_path / "preset", "--params-file", "lidar")
    typed = bag(capsys, bag_in, tmp_path / "typed", *LIDAR_TYPED, *LIDAR_VIEWPOINT)
    assert preset == typed
    assert "hybrid, checkpoint lite, radius 0.25 m, cpu" in preset[0]
    without = bag(capsys, bag_in, tmp_path / "without", *LIDAR_TYPED[:-4])
    assert without[1] != preset[1]


def test_an_option_on_the_command_line_wins_over_the_file(tmp_path: Path, capsys, bag_in: Path) -> None:
    overridden = bag(capsys, bag_in, tmp_path / "a", "--params-file", "lidar", "--radius", "0.4", "--method", "pca")
    typed = bag(capsys, bag_in, tmp_path / "b", "--method", "pca", "--radius", "0.4", "--range-scale", "0.03")
    assert overridden == typed and "pca, radius 0.4 m" in typed[0]
    # An option given with its default value wins too: range_scale 0.03 from the file is overridden by 0.
    at_default = bag(capsys, bag_in, tmp_path / "c", "--params-file", "lidar", "--range-scale", "0", "--method", "pca")
    plain = bag(capsys, bag_in, tmp_path / "d", "--method", "pca", "--radius", "0.25")
    assert at_default == plain


def test_a_flag_wins_over_the_files_orientation(tmp_path: Path, capsys, xyz: Path) -> None:
    """The node's orient: false leaves estimate's normals as estimated; --viewpoint on the command line orients."""
    unoriented = params_yaml(tmp_path / "unoriented.yaml", {"method": "pca", "radius": 0.5, "orient": False})
    as_estimated = estimate(capsys, xyz, tmp_path / "a.normals", "--params-file", str(unoriented))
    assert as_estimated == estimate(capsys, xyz, tmp_path / "b.normals", "--method", "pca", "--radius", "0.5")
    oriented = estimate(capsys, xyz, tmp_path / "c.normals", "--params-file", str(unoriented), *LIDAR_VIEWPOINT)
    typed = estimate(capsys, xyz, tmp_path / "d.normals", "--method", "pca", "--radius", "0.5", *LIDAR_VIEWPOINT)
    assert oriented == typed and oriented[1] != as_estimated[1]


@pytest.mark.parametrize("preset", checks.PRESETS)
def test_every_shipped_preset_is_taken_whole_node_only_parameters_included(
    tmp_path: Path, capsys, xyz: Path, preset: str
) -> None:
    """config/params.yaml also names the node's statistics period and RViz outputs: they are the node's alone."""
    values = yaml.safe_load((REPO / "config" / f"{preset}.yaml").read_text())["/**"]["ros__parameters"]
    summary, _ = estimate(capsys, xyz, tmp_path / "out.normals", "--params-file", preset, "--method", "pca")
    assert f"radius {values['radius']:g}, cpu" in summary


def test_the_nodes_own_sections_and_qos_overrides(tmp_path: Path, capsys, xyz: Path) -> None:
    """Sections for other nodes are theirs; the node's by name and under a namespace merge in file order; rclpy's
    QoS overrides (nested mappings) are the node's alone."""
    path = tmp_path / "launch_params.yaml"
    sections = {
        "camera_driver": {"ros__parameters": {"radius": -5.0, "fps": 30}},
        "/**": {"ros__parameters": {"method": "pca", "radius": 0.3, "use_sim_time": True}},
        "/robot/triplet_normal": {
            "ros__parameters": {
                "radius": 0.6,
                "qos_overrides": {"/points": {"subscription": {"reliability": "reliable", "depth": 1}}},
            }
        },
    }
    path.write_text(yaml.safe_dump(sections, sort_keys=False))
    summary, _ = estimate(capsys, xyz, tmp_path / "out.normals", "--params-file", str(path))
    assert "(pca, radius 0.6, cpu" in summary


def run_fails(capsys, argv: list) -> str:
    assert main([str(a) for a in argv]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert captured.out == "" and len(lines) == 1 and lines[0].startswith("triplet-normal: error: "), captured.err
    return lines[0].removeprefix("triplet-normal: error: ")


def where(command: str, tmp_path: Path) -> list:
    """The arguments of each command before its options (nothing is read before the parameter file is)."""
    return {
        "estimate": ["estimate", tmp_path / "cloud.xyz"],
        "bag": ["bag", tmp_path / "in", tmp_path / "out", "--topic", "/points"],
        "bags": ["bags", tmp_path, tmp_path / "out", "--topic", "/points"],
    }[command]


@pytest.mark.parametrize("command", ["estimate", "bag", "bags"])
@pytest.mark.parametrize(
    ("name", "value"),
    [("radius", -1.0), ("k", 2), ("method", "magic"), ("orient", "yes"), ("viewpoint", [0.0, 1.0]),
     ("range_scale", 2.0), ("batch_size", 0)],
)  # fmt: skip
def test_a_bad_value_in_the_file_is_one_line_naming_the_file_in_the_nodes_words(
    tmp_path: Path, capsys, command: str, name: str, value: object
) -> None:
    path = params_yaml(tmp_path / "mine.yaml", {"radius": 0.1, name: value})
    node_words = validate(name, value)
    assert node_words and node_words.startswith(f"{name} ")
    assert run_fails(capsys, [*where(command, tmp_path), "--params-file", path]) == f"{path}: {node_words}"


@pytest.mark.parametrize("command", ["estimate", "bag", "bags"])
def test_missing_file_unknown_parameter_and_no_section_are_one_line_each(tmp_path: Path, capsys, command: str) -> None:
    missing = tmp_path / "nope.yaml"
    assert run_fails(capsys, [*where(command, tmp_path), "--params-file", missing]) == (
        f"--params-file {missing}: no such file (nor a preset: params, depth_camera, lidar)"
    )
    typo = params_yaml(tmp_path / "typo.yaml", {"radios": 0.1})
    assert run_fails(capsys, [*where(command, tmp_path), "--params-file", typo]) == (
        f"{typo}: radios is no parameter of the triplet_normal node"
    )
    other = tmp_path / "other.yaml"
    other.write_text("camera_driver:\n  ros__parameters:\n    fps: 30\n")
    assert run_fails(capsys, [*where(command, tmp_path), "--params-file", other]) == (
        f"{other}: no parameters for the triplet_normal node (sections: camera_driver)"
    )
    broken = tmp_path / "broken.yaml"
    broken.write_text("/**: {ros__parameters: [")
    assert run_fails(capsys, [*where(command, tmp_path), "--params-file", broken]).startswith(
        f"{broken}: not a ROS 2 parameter file: "
    )


def test_the_commands_know_every_parameter_of_the_node() -> None:
    """Each node parameter either sets an option or is the node's alone: a new parameter must be one or the other,
    or every parameter file that names it would be refused."""
    assert set(checks.FILE_OPTIONS) <= set(SPEC_BY_NAME)
    assert set(SPEC_BY_NAME) <= set(checks.FILE_OPTIONS) | checks.NODE_ONLY


@pytest.mark.slow  # colcon build
def test_the_presets_are_found_in_a_colcon_install(install_prefix: Path, ros_env: dict[str, str]) -> None:
    code = (
        f"import {PACKAGE}; from {PACKAGE}.cli.args import params_file_path; "
        f"print({PACKAGE}.__file__); print(params_file_path('lidar'))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], env=installed_env(install_prefix, ros_env), capture_output=True, text=True,
        cwd=install_prefix, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    package, preset = done.stdout.split()
    assert not Path(package).resolve().is_relative_to(REPO)  # the installed copy, not the checkout
    assert Path(preset) == install_prefix / "share" / PACKAGE / "config" / "lidar.yaml"
