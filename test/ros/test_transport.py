"""Which Fast DDS profile a process of ours picks (ros/transport.py), without rclpy: the user's choice always wins."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from triplet_normal_ros.ros.transport import (
    CWD_PROFILE,
    CWD_PROFILES,
    LEGACY_PROFILE_ENV,
    OPT_OUT_ENV,
    PROFILE_ENV,
    PROFILE_NAME,
    choose_profile,
    shipped_profile,
)

REPO = Path(__file__).resolve().parents[2]
NS = "{http://www.eprosima.com}"


def test_the_shipped_profile_is_found_and_set(tmp_path: Path) -> None:
    environ: dict[str, str] = {}
    choice = choose_profile(environ, cwd=tmp_path)
    # Fast DDS 3 (Kilted) reads the first variable, Fast DDS 2 (Jazzy) the second: both name the shipped file
    assert environ == {PROFILE_ENV: choice.path, LEGACY_PROFILE_ENV: choice.path}
    assert Path(choice.path).name == PROFILE_NAME
    assert not choice.warning and "shipped" in choice.describe("rmw_fastrtps_cpp")


def test_the_users_profile_file_is_kept(tmp_path: Path) -> None:
    for name in (PROFILE_ENV, LEGACY_PROFILE_ENV):  # a Kilted user's variable or a Jazzy user's
        environ = {name: "/robot/fastdds.xml"}
        choice = choose_profile(environ, cwd=tmp_path)
        assert environ == {PROFILE_ENV: "/robot/fastdds.xml", LEGACY_PROFILE_ENV: "/robot/fastdds.xml"}
        expected = f"transport: Fast DDS profile /robot/fastdds.xml (yours, from {name})"
        assert choice.describe("rmw_fastrtps_cpp") == expected


def test_a_profile_in_the_working_directory_is_kept_unless_fast_dds_skips_it(tmp_path: Path) -> None:
    for name in CWD_PROFILES:  # Fast DDS 3's name, then Fast DDS 2's, each alone in its folder
        folder = tmp_path / name.split("_")[1]
        folder.mkdir()
        (folder / name).write_text("<dds/>")
        environ: dict[str, str] = {}
        assert choose_profile(environ, cwd=folder).path == str(folder / name) and environ == {}
    (tmp_path / CWD_PROFILE).write_text("<dds/>")
    environ = {"SKIP_DEFAULT_XML_FILE": "1"}
    assert choose_profile(environ, cwd=tmp_path).path == str(shipped_profile())


def test_opting_out_leaves_fast_dds_defaults_and_warns(tmp_path: Path) -> None:
    environ = {OPT_OUT_ENV: "off"}
    choice = choose_profile(environ, cwd=tmp_path)
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
