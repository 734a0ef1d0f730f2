"""The cross-process tests and the demo must exercise the colcon-installed copy, never the checkout behind it.

The venv holds an editable install of this repository. setuptools' default editable mode adds a meta-path finder that
hands any ``triplet_normal_ros.<module>`` an installed copy lacks to the source tree, so a module left out of the
install would still import, from the checkout, and every test would pass. ``make venv`` therefore installs in
``editable_mode=compat`` (a plain .pth path entry, which PYTHONPATH precedes and which adds nothing beyond it).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import PACKAGE, REPO, STARTUP_S, site_packages

from triplet_normal_ros.ros.tools.node_process import node_env


@pytest.mark.slow  # colcon build and a node process
def test_the_node_process_imports_the_installed_package(start_node, install_prefix: Path) -> None:
    node = start_node({"method": "pca"}, {"input": "/tn_copy/in", "output": "/tn_copy/out"})
    assert node.wait_for_log("ready:", STARTUP_S), node.log
    found = re.search(r"running triplet_normal_ros from (\S+)", node.log)
    assert found, node.log
    assert Path(found[1]) == site_packages(install_prefix) / PACKAGE
    assert not Path(found[1]).resolve().is_relative_to(REPO)


def test_a_module_missing_from_an_install_is_not_taken_from_the_checkout(tmp_path: Path) -> None:
    """A stand-in install holding only the package's ``__init__.py``: its ``io`` subpackage must not import."""
    (tmp_path / PACKAGE).mkdir()
    (tmp_path / PACKAGE / "__init__.py").write_text((REPO / PACKAGE / "__init__.py").read_text())
    code = f"import {PACKAGE}; print({PACKAGE}.__file__); import {PACKAGE}.io"
    done = subprocess.run(
        [sys.executable, "-c", code], env={"PYTHONPATH": str(tmp_path)}, capture_output=True, text=True, cwd=tmp_path
    )
    assert done.stdout.strip() == str(tmp_path / PACKAGE / "__init__.py"), done.stderr
    assert done.returncode == 1 and f"No module named '{PACKAGE}.io'" in done.stderr, done.stderr


def test_the_demo_gives_the_node_the_install_first(tmp_path: Path) -> None:
    env = node_env(tmp_path)
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(site_packages(tmp_path))
