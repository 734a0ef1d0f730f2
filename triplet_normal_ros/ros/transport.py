"""Which Fast DDS profile a process of ours runs with: the shipped large-data profile, unless the user chose one.

Fast DDS's default shared-memory segment (512 kB per process) loses best-effort clouds above about 0.5 MB, so a
640x480 cloud from a camera driver never arrives (docs/RESULTS.md, "Full-size clouds over DDS"). The shipped profile,
``config/fastdds_large_data.xml``, gives the segment 32 MB. Fast DDS reads its profile file's variable once per
process, when rclpy.init creates the first participant, so :func:`choose_profile` must run before that. Fast DDS 3
(Kilted) reads ``FASTDDS_DEFAULT_PROFILES_FILE``, and its rmw_fastrtps warns on every start that the old
``FASTRTPS_DEFAULT_PROFILES_FILE`` is deprecated; Fast DDS 2 (Jazzy, Humble) reads only the old one. So only the
variable of the Fast DDS that rmw_fastrtps was built against is set (`fast_dds_major`, from its package.xml), and both
only when that cannot be found. It changes nothing when the user has chosen: either variable (copied to the one the
running Fast DDS reads), that Fast DDS's default profile file in the working directory (which it loads by itself), or
``TRIPLET_NORMAL_FASTDDS_PROFILE=off``. No rclpy here: the node, the demo's replay client and the tests' process all
call it.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from collections.abc import Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "triplet_normal_ros"
PROFILE_NAME = "fastdds_large_data.xml"
#: What Fast DDS 3 (rmw_fastrtps_cpp 9.x, Kilted) reads for its XML profiles ...
PROFILE_ENV = "FASTDDS_DEFAULT_PROFILES_FILE"
#: ... and what Fast DDS 2 (rmw_fastrtps_cpp 8.x, Jazzy) reads.
LEGACY_PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
PROFILE_ENVS = (PROFILE_ENV, LEGACY_PROFILE_ENV)
#: ``off`` leaves Fast DDS at its defaults.
OPT_OUT_ENV = "TRIPLET_NORMAL_FASTDDS_PROFILE"
#: Fast DDS also loads this file from the working directory, unless SKIP_DEFAULT_XML_FILE=1 (Fast DDS 2: the second).
CWD_PROFILE = "DEFAULT_FASTDDS_PROFILES.xml"
LEGACY_CWD_PROFILE = "DEFAULT_FASTRTPS_PROFILES.xml"
CWD_PROFILES = (CWD_PROFILE, LEGACY_CWD_PROFILE)
#: What each major version of Fast DDS reads: its profile variable and its working-directory file.
READS = {3: (PROFILE_ENV, CWD_PROFILE), 2: (LEGACY_PROFILE_ENV, LEGACY_CWD_PROFILE)}
#: The rmw package whose package.xml names the Fast DDS it was built against: `fastdds` (3) or `fastrtps` (2).
RMW_PACKAGE = "rmw_fastrtps_shared_cpp"
FAST_DDS_PACKAGES = {"fastdds": 3, "fastrtps": 2}
#: `choose_profile`'s default: find the running Fast DDS's major version with `fast_dds_major`.
DETECT = -1


@dataclass(frozen=True)
class ProfileChoice:
    """The profile in force and why; ``warning`` when full-size best-effort clouds will be lost."""

    path: str | None
    source: str
    warning: bool = False

    def describe(self, rmw: str) -> str:
        """One log line; ``rmw`` is the implementation rclpy loaded (a profile only matters to Fast DDS)."""
        if not rmw.startswith("rmw_fastrtps"):
            return f"transport: {rmw}; Fast DDS profiles do not apply"
        if self.path is None:
            return f"transport: Fast DDS defaults ({self.source}); best-effort clouds above about 0.5 MB will be lost"
        return f"transport: Fast DDS profile {self.path} ({self.source})"


def _share_dir() -> Path | None:
    """This package's share/ folder through the ament index (a sourced colcon install), if there is one."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

        return Path(get_package_share_directory(PACKAGE))
    except (ImportError, PackageNotFoundError, OSError):  # OSError: AMENT_PREFIX_PATH is not set
        return None


def shipped_profile() -> Path | None:
    """The profile from this package's share/ (ament index, or beside this install) or from a source checkout."""
    here = Path(__file__).resolve()
    share = _share_dir()
    candidates = [share / "config" / PROFILE_NAME] if share is not None else []
    if len(here.parents) > 5:  # <prefix>/lib/pythonX.Y/site-packages/triplet_normal_ros/ros/transport.py
        candidates.append(here.parents[5] / "share" / PACKAGE / "config" / PROFILE_NAME)
    candidates.append(here.parents[2] / "config" / PROFILE_NAME)  # a checkout: <repo>/triplet_normal_ros/ros/
    return next((p for p in candidates if p.is_file()), None)


def ros_prefixes(environ: Mapping[str, str]) -> list[Path]:
    """Where ROS packages are installed: a sourced setup.bash's AMENT_PREFIX_PATH, in its order, then this
    interpreter's prefix (the PyPI wheels install ROS there and set no AMENT_PREFIX_PATH)."""
    listed = [Path(p) for p in environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return [*listed, Path(sys.prefix)]


def fast_dds_major(prefixes: Sequence[Path]) -> int | None:
    """The major version of the Fast DDS that rmw_fastrtps loads (3 on Kilted, 2 on Jazzy and Humble), read from the
    first rmw_fastrtps_shared_cpp package.xml of `prefixes` that names `fastdds` or `fastrtps`; None when none does."""
    for prefix in prefixes:
        manifest = prefix / "share" / RMW_PACKAGE / "package.xml"
        try:
            root = ET.parse(manifest).getroot()
        except (OSError, ET.ParseError):
            continue
        depends = {element.text.strip() for element in root if element.tag.endswith("depend") and element.text}
        for package, major in FAST_DDS_PACKAGES.items():
            if package in depends:
                return major
    return None


def read_by(major: int | None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(profile variables, working-directory files) Fast DDS `major` reads; every one of each when it is unknown."""
    return ((READS[major][0],), (READS[major][1],)) if major in READS else (PROFILE_ENVS, CWD_PROFILES)


def _users_choice(environ: MutableMapping[str, str], cwd: Path, major: int | None) -> ProfileChoice | None:
    """The profile the user chose, if any; their variable is copied to the one the running Fast DDS reads."""
    if environ.get(OPT_OUT_ENV, "").lower() in ("off", "0", "false", "no"):
        return ProfileChoice(None, f"{OPT_OUT_ENV}={environ[OPT_OUT_ENV]}", warning=True)
    variables, files = read_by(major)
    for name in PROFILE_ENVS:
        if environ.get(name):
            path = environ[name]
            for other in variables:
                environ.setdefault(other, path)
            return ProfileChoice(path, f"yours, from {name}")
    for name in files:
        if environ.get("SKIP_DEFAULT_XML_FILE") != "1" and (cwd / name).is_file():
            return ProfileChoice(str(cwd / name), "yours, from the working directory")
    return None


def choose_profile(
    environ: MutableMapping[str, str] | None = None, cwd: Path | None = None, major: int | None = DETECT
) -> ProfileChoice:
    """Point ``environ`` (the process environment) at the shipped profile unless the user chose; say what is used.
    ``major``: the running Fast DDS's major version (None: unknown), found on ``environ``'s prefixes by default."""
    environ = os.environ if environ is None else environ
    major = fast_dds_major(ros_prefixes(environ)) if major == DETECT else major
    choice = _users_choice(environ, Path.cwd() if cwd is None else cwd, major)
    if choice is not None:
        return choice
    path = shipped_profile()
    if path is None:
        return ProfileChoice(None, f"the shipped {PROFILE_NAME} was not found", warning=True)
    for name in read_by(major)[0]:
        environ[name] = str(path)
    return ProfileChoice(
        str(path), "shipped; a best-effort driver needs it too for clouds over 0.5 MB, see docs/NODE.md, Transport"
    )
