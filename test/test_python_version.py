"""The lowest Python the code needs is stated once per place a user or a tool reads it, and the places agree:
setup.py's python_requires (pip refuses older interpreters), the Makefile's MIN_PYTHON (what `make lint` checks the
code against with vermin) and README; and `make test` runs a subset on it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _python_requires() -> str:
    tree = ast.parse((ROOT / "setup.py").read_text())
    keyword = next(n for n in ast.walk(tree) if isinstance(n, ast.keyword) and n.arg == "python_requires")
    return ast.literal_eval(keyword.value)


def test_setup_py_the_lint_check_and_readme_name_the_same_lowest_python() -> None:
    (lint_target,) = re.findall(r"^MIN_PYTHON := (\S+)$", (ROOT / "Makefile").read_text(), flags=re.M)
    assert _python_requires() == f">={lint_target}"
    assert f"Python ≥ {lint_target}" in " ".join((ROOT / "README.md").read_text().split())
    assert "-t=$(MIN_PYTHON)-" in (ROOT / "Makefile").read_text()  # vermin checks against it in `make lint`


def test_make_test_runs_a_subset_on_the_lowest_python() -> None:
    """What vermin checks statically also runs: `make test-pythons` includes the lowest Python."""
    makefile = (ROOT / "Makefile").read_text()
    (lint_target,) = re.findall(r"^MIN_PYTHON := (\S+)$", makefile, flags=re.M)
    (others,) = re.findall(r"^OTHER_PYTHONS := (.+)$", makefile, flags=re.M)
    assert lint_target in others.split()
    assert re.search(r"^\t@\$\(MAKE\) --no-print-directory test-pythons$", makefile, flags=re.M)  # in `make test`
