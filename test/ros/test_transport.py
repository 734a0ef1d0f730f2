"""Which Fast DDS profile a process of ours picks (ros/transport.py), without rclpy: the user's choice always wins."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from importlib.metadata import version
from pathlib import Path

import pytest

from triplet_normal_ros.ros.transport import (
    CWD_PROFILE,
    CWD_PROFILES,
    LEGACY_CWD_PROFILE,
    LEGACY_PROFILE_ENV,
    OPT_OUT_ENV,
    PROFILE_ENV,
    PROFILE_NAME,
    RMW_PACKAGE,
    choose_profile,
    fast_dds_major,
    ros_prefixes,
    shipped_profile,
)

REPO = Path(__file__).resolve().parents[2]
NS = "{http://www.eprosima.com}"


#: The variable each Fast DDS reads (Kilted's rmw_fastrtps warns on the other one at every start); None: unknown.
VARIABLES = {3: {PROFILE_ENV}, 2: {LEGACY_PROFILE_ENV}, None: {PROFILE_ENV, LEGACY_PROFILE_ENV}}


@pytest.mark.parametrize("major", [3, 2, None])
def test_the_shipped_profile_is_set_in_the_variable_the_running_fast_dds_reads(tmp_path: Path, major) -> None:
    environ: dict[str, str] = {}
    choice = choose_profile(environ, cwd=tmp_path, major=major)
    assert environ == dict.fromkeys(VARIABLES[major], choice.path)
    assert Path(choice.path).name == PROFILE_NAME
    assert not choice.warning and "shipped" in choice.describe("rmw_fastrtps_cpp")


def _prefix(root: Path, fast_dds: str | None) -> Path:
    """An install prefix whose rmw_fastrtps_shared_cpp was built against `fast_dds` (None: no such package)."""
    if fast_dds is not None:
        share = root / "share" / RMW_PACKAGE
        share.mkdir(parents=True)
        depends = f"<build_depend>fastcdr</build_depend><build_export_depend>{fast_dds}</build_export_depend>"
        (share / "package.xml").write_text(f'<package format="3"><name>{RMW_PACKAGE}</name>{depends}</package>')
    return root


def test_the_running_fast_dds_is_read_from_the_first_rmw_fastrtps_on_the_prefixes(tmp_path: Path) -> None:
    kilted, jazzy, other = (_prefix(tmp_path / n, d) for n, d in [("k", "fastdds"), ("j", "fastrtps"), ("o", None)])
    assert fast_dds_major([other, kilted, jazzy]) == 3
    assert fast_dds_major([jazzy, kilted]) == 2
    assert fast_dds_major([other]) is None
    environ = {"AMENT_PREFIX_PATH": f"{jazzy}:{other}"}
    assert ros_prefixes(environ)[:2] == [jazzy, other]  # a sourced workspace comes before the interpreter's prefix


def test_this_environments_fast_dds_is_found() -> None:
    """The PyPI wheels install ROS under the interpreter's prefix: Kilted's rclpy 9 with Fast DDS 3, Jazzy's rclpy 7
    with Fast DDS 2 (the Makefile's pins)."""
    rclpy_major = int(version("ros-rclpy").split(".")[0])
    assert fast_dds_major(ros_prefixes({})) == {9: 3, 7: 2}[rclpy_major]


def test_the_users_profile_file_is_kept(tmp_path: Path) -> None:
    for major in VARIABLES:
        for name in (PROFILE_ENV, LEGACY_PROFILE_ENV):  # a Kilted user's variable or a Jazzy user's
            environ = {name: "/robot/fastdds.xml"}
            choice = choose_profile(environ, cwd=tmp_path, major=major)
            # copied to the one the running Fast DDS reads; the user's own is left as it was
            assert environ == dict.fromkeys(VARIABLES[major] | {name}, "/robot/fastdds.xml")
            expected = f"transport: Fast DDS profile /robot/fastdds.xml (yours, from {name})"
            assert choice.describe("rmw_fastrtps_cpp") == expected


@pytest.mark.parametrize(("major", "loaded"), [(3, CWD_PROFILE), (2, LEGACY_CWD_PROFILE)])
def test_a_profile_in_the_working_directory_is_kept_if_the_running_fast_dds_loads_it(
    tmp_path: Path, major: int, loaded: str
) -> None:
    for name in CWD_PROFILES:  # Fast DDS 3's name, then Fast DDS 2's, each alone in its folder
        folder = tmp_path / name.split("_")[1]
        folder.mkdir()
        (folder / name).write_text("<dds/>")
        environ: dict[str, str] = {}
        choice = choose_profile(environ, cwd=folder, major=major)
        if name == loaded:
            assert choice.path == str(folder / name) and environ == {}
        else:  # the other Fast DDS's file: this one ignores it, so the shipped profile is set
            assert choice.path == str(shipped_profile()) and set(environ) == VARIABLES[major]
    (tmp_path / loaded).write_text("<dds/>")
    environ = {"SKIP_DEFAULT_XML_FILE": "1"}
    assert choose_profile(environ, cwd=tmp_path, major=major).path == str(shipped_profile())


def test_opting_out_leaves_fast_dds_defaults_and_warns(tmp_path: Path) -> None:
    environ = {OPT_OUT_ENV: "off"}
    choice = choose_profile(environ, cwd=tmp_path, major=3)
    assert environ == {OPT_OUT_ENV: "off"} and choice.path is None and choice.warning
    assert "0.5 MB will be lost" in choice.describe("rmw_fastrtps_cpp")


def test_other_middlewares_are_named_not_configured(tmp_path: Path) -> None:
    assert "do not apply" in choose_profile({}, cwd=tmp_path).describe("rmw_cyclonedds_cpp")


def test_the_profile_gives_shared_memory_a_segment_for_full_frames() -> None:
    """A 640x480 XYZRGB frame is 9.8 MB and its answer 14.7 MB; the default segment is 512 kB."""
    root = ET.parse(REPO / "config" / PROFILE_NAME).getroot()
    shm = [d for d in root.iter(f"{NS}transport_descriptor") if d.findtext(f"{NS}type") == "SHM"]
    assert len(shm) == 1 and int(shm[0].findtext(f"{NS}segment_size")) >= 2 * 14_745_600
    participant = root.find(f"{NS}profiles/{NS}participant")
    assert participant.get("is_default_profile") == "true"
    used = [t.text for t in participant.iter(f"{NS}transport_id")]
    assert shm[0].findtext(f"{NS}transport_id") in used and len(used) == 2  # and UDP, for discovery and other hosts
