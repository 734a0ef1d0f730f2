"""Refresh test/data/rosdistro/keys.json: what ros/rosdistro says of every key package.xml declares.

For each key: the ROS distributions whose distribution.yaml releases a package of that name (Jazzy, Kilted), or, for a
system key, whether rosdep/base.yaml or rosdep/python.yaml resolves it on Ubuntu 24.04 (noble, the platform both
distributions release for). test/test_package_xml.py checks package.xml against the snapshot, so a key that does not
exist fails a test instead of a user's `rosdep install`.

Run: .venv/bin/python docs/tools/rosdep_snapshot.py ROSDISTRO_CHECKOUT   (a git clone of github.com/ros/rosdistro)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "test" / "data" / "rosdistro" / "keys.json"
DISTRIBUTIONS = ("jazzy", "kilted")
PLATFORM = ("ubuntu", "noble")
DEPENDS = ("depend", "build_depend", "exec_depend", "test_depend", "buildtool_depend", "build_export_depend")


def declared_keys(package_xml: Path = ROOT / "package.xml") -> list[str]:
    """Every dependency key package.xml declares, once each, in file order."""
    root = ET.parse(package_xml).getroot()
    keys = [element.text.strip() for tag in DEPENDS for element in root.iter(tag) if element.text]
    return list(dict.fromkeys(keys))


def released_packages(checkout: Path, distribution: str) -> set[str]:
    """The package names `distribution` releases: each repository's release packages, or the repository's name."""
    data = yaml.safe_load((checkout / distribution / "distribution.yaml").read_text())
    names: set[str] = set()
    for repository, entry in (data.get("repositories") or {}).items():
        release = (entry or {}).get("release")
        if release:
            names.update(release.get("packages") or [repository])
    return names


def resolves(rule: object, os_name: str, version: str) -> bool:
    """Whether a rosdep rule installs something on (os_name, version): a package list, a pip rule, or a version map
    whose entry for `version` (or '*') does."""
    if not isinstance(rule, dict) or os_name not in rule:
        return False
    entry = rule[os_name]
    if isinstance(entry, list):
        return bool(entry)
    if isinstance(entry, dict):
        if "pip" in entry or "packages" in entry:
            return True
        for key in (version, "*"):
            if key in entry:
                value = entry[key]
                return bool(value) and (not isinstance(value, dict) or "pip" in value or "packages" in value)
    return False


def snapshot(checkout: Path) -> dict:
    rules: dict[str, object] = {}
    for name in ("base.yaml", "python.yaml"):
        rules.update(yaml.safe_load((checkout / "rosdep" / name).read_text()))
    released = {distribution: released_packages(checkout, distribution) for distribution in DISTRIBUTIONS}
    commit, date = subprocess.run(
        ["git", "-C", str(checkout), "log", "-1", "--format=%H %cI"], capture_output=True, text=True, check=True
    ).stdout.split()
    keys = {}
    for key in declared_keys():
        keys[key] = {
            "released_in": [d for d in DISTRIBUTIONS if key in released[d]],
            "rosdep_" + "_".join(PLATFORM): resolves(rules.get(key), *PLATFORM),
        }
    return {"rosdistro_commit": commit, "rosdistro_date": date, "platform": "/".join(PLATFORM), "keys": keys}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkout", type=Path, help="a git clone of github.com/ros/rosdistro")
    args = parser.parse_args()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(snapshot(args.checkout), indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
