"""The package's layering: imports run downward only, there are no cycles, and only ros/ needs rclpy.

Layer order: errors < core, io < simulation, pipeline < training < evaluation < cli < ros. core and io share a layer
but do not import each other; io does not import torch (message and file conversion stay light), and neither does
simulation (sensor simulation is numpy and scipy), which needs no file or message conversion either, so it may not
import io. pipeline (the per-message step the node and `bag` share) is the one place where core and io meet below the
CLI; it shares a layer with simulation, and neither imports the other.
The static checks read every module's source with ``ast``, imports inside functions included, so a lazy upward
import counts too. The dynamic check imports every module below ros/ in a fresh interpreter where rclpy cannot be
imported (marked slow: it starts a process).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

import triplet_normal_ros

ROOT = triplet_normal_ros.__name__
PACKAGE_DIR = Path(triplet_normal_ros.__file__).parent
#: Rank of each top-level part; the root package itself (``__version__`` only) ranks with errors.
LAYERS = {
    "": 0, "errors": 0, "core": 1, "io": 1, "simulation": 2, "pipeline": 2, "training": 3, "evaluation": 4, "cli": 5,
    "ros": 6,
}  # fmt: skip
#: (importer, imported) pairs that are refused even where the ranks would allow the import.
APART = {("core", "io"), ("io", "core"), ("simulation", "io"), ("simulation", "pipeline"), ("pipeline", "simulation")}
#: Third-party imports a part must not make, each with the reason.
FORBIDDEN = {
    "io": {"torch": "io converts messages and files, it needs no torch"},
    "simulation": {"torch": "simulated sensors are numpy and scipy, they need no torch"},
}
ROS_ONLY = "rclpy"
ROS_FREE = ("core", "io", "simulation", "pipeline", "training", "evaluation")


def module_files() -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its own name, for its ``__init__``)."""
    modules = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


MODULES = module_files()


def imports_of(module: str, source: str, is_package: bool, known: set[str]) -> set[str]:
    """Absolute names ``source`` imports anywhere, functions too; ``from x import y`` gives x.y if that is a module."""
    package = module if is_package else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            found.update(f"{origin}.{a.name}" if f"{origin}.{a.name}" in known else origin for a in node.names)
    return found


def part(module: str) -> str:
    """The top-level part a module of ours belongs to ('' for the root package)."""
    return module.split(".")[1] if "." in module else ""


def graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """module -> every name it imports; ``sources`` maps module -> (source, is_package)."""
    known = set(sources)
    return {m: imports_of(m, src, is_pkg, known) for m, (src, is_pkg) in sources.items()}


def violations(edges: dict[str, set[str]]) -> list[str]:
    """Every import that runs upward, crosses a pair in APART, or pulls in what a part must not import."""
    found = []
    for src, targets in sorted(edges.items()):
        for dst in sorted(targets):
            if dst == ROOT or dst.startswith(ROOT + "."):
                a, b = part(src), part(dst)
                if LAYERS[b] > LAYERS[a] or (a, b) in APART:
                    found.append(f"{src} imports {dst} ({a or ROOT} may not import {b})")
            else:
                top = dst.split(".")[0]
                why = FORBIDDEN.get(part(src), {}).get(top)
                if why:
                    found.append(f"{src} imports {dst}: {why}")
                if top == ROS_ONLY and part(src) != "ros":
                    found.append(f"{src} imports {dst}: only ros/ may import {ROS_ONLY}")
    return found


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles among the modules in ``edges``: strongly connected components of two or more, self-loops."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan; the package has a few dozen modules, recursion depth is no concern
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(edges[v] & edges.keys()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            component.append(v)
            if len(component) > 1 or v in edges[v]:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def package_graph() -> dict[str, set[str]]:
    return graph({m: (p.read_text(), p.name == "__init__.py") for m, p in MODULES.items()})


def test_every_module_belongs_to_a_known_layer_and_every_layer_has_modules() -> None:
    parts = {part(m) for m in MODULES}
    assert parts <= LAYERS.keys(), sorted(parts - LAYERS.keys())
    assert parts == LAYERS.keys()  # a renamed or emptied part would make the checks below pass vacuously


def test_imports_run_downward_only() -> None:
    assert violations(package_graph()) == []


def test_there_is_no_import_cycle() -> None:
    assert cycles(package_graph()) == []


def test_the_checks_catch_what_they_are_for() -> None:
    """Planted faults, so the two tests above can fail for the right reason: relative imports resolve, upward and
    sideways imports, forbidden libraries and cycles are reported; pipeline may import io but not simulation."""
    sources = {
        ROOT: ("", True),
        f"{ROOT}.core": ("", True),
        f"{ROOT}.core.a": ("from . import b\ndef f():\n    from ..ros.node import Node\n", False),
        f"{ROOT}.core.b": ("from .a import thing\nimport triplet_normal_ros.io.c\n", False),
        f"{ROOT}.io": ("", True),
        f"{ROOT}.io.c": ("import torch\nfrom rclpy.node import Node\nfrom .. import __version__\n", False),
        f"{ROOT}.ros": ("", True),
        f"{ROOT}.ros.node": ("import rclpy\nfrom ..core import a\n", False),
        f"{ROOT}.simulation": ("", True),
        f"{ROOT}.simulation.d": ("import torch\nfrom ..io import c\n", False),
        f"{ROOT}.pipeline": ("", True),
        f"{ROOT}.pipeline.e": ("from ..io import c\nfrom ..simulation import d\n", False),
    }
    edges = graph(sources)
    assert edges[f"{ROOT}.core.a"] == {f"{ROOT}.core.b", f"{ROOT}.ros.node"}
    assert edges[f"{ROOT}.io.c"] == {"torch", "rclpy.node", ROOT}
    assert edges[f"{ROOT}.ros.node"] == {"rclpy", f"{ROOT}.core.a"}
    assert violations(edges) == [
        f"{ROOT}.core.a imports {ROOT}.ros.node (core may not import ros)",
        f"{ROOT}.core.b imports {ROOT}.io.c (core may not import io)",
        f"{ROOT}.io.c imports rclpy.node: only ros/ may import rclpy",
        f"{ROOT}.io.c imports torch: io converts messages and files, it needs no torch",
        f"{ROOT}.pipeline.e imports {ROOT}.simulation.d (pipeline may not import simulation)",
        f"{ROOT}.simulation.d imports torch: simulated sensors are numpy and scipy, they need no torch",
        f"{ROOT}.simulation.d imports {ROOT}.io.c (simulation may not import io)",
    ]
    assert cycles(edges) == [[f"{ROOT}.core.a", f"{ROOT}.core.b", f"{ROOT}.ros.node"]]


#: Runs in a fresh interpreter: rclpy made unimportable, then every module below ros/ imported.
_IMPORT_WITHOUT_RCLPY = """
import importlib, importlib.abc, json, pkgutil, sys

class NoRclpy(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "rclpy" or name.startswith("rclpy."):
            raise ImportError(f"rclpy is blocked in this test ({name})")
        return None

sys.meta_path.insert(0, NoRclpy())
imported = ["triplet_normal_ros.errors"]
importlib.import_module(imported[0])
for sub in sys.argv[1:]:
    pkg = importlib.import_module(f"triplet_normal_ros.{sub}")
    imported.append(pkg.__name__)
    for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        importlib.import_module(info.name)
        imported.append(info.name)
try:
    importlib.import_module("triplet_normal_ros.ros.node")
    control = "imported"
except ImportError as error:
    control = str(error)
print(json.dumps({"imported": imported, "rclpy_loaded": "rclpy" in sys.modules, "ros_node": control}))
"""


@pytest.mark.slow  # a fresh interpreter importing torch and everything else: seconds; the ast checks above are fast
def test_everything_below_ros_imports_without_rclpy(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-c", _IMPORT_WITHOUT_RCLPY, *ROS_FREE],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    expected = {m for m in MODULES if part(m) in (*ROS_FREE, "errors")}
    assert set(result["imported"]) == expected  # pkgutil found every module the source walk found
    assert not result["rclpy_loaded"]
    assert "rclpy is blocked" in result["ros_node"]  # the control: the block works, so the imports above prove it


# Inside core: config/ is pure Python, numba lives in `*_numba` modules alone, and imports sit at the top.

#: The most modules core/ keeps at its top level (its `__init__` included); everything else lives in a subpackage.
MAX_CORE_TOP_LEVEL = 10
#: The most imports core/ may make inside functions, each with a comment on its line saying why.
MAX_DEFERRED_IMPORTS = 2
COMPILER = "numba"


def imported_roots(source: str) -> set[str]:
    """The top-level names of every library ``source`` imports anywhere (``numba`` for ``from numba import njit``)."""
    roots = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def deferred_imports(source: str) -> list[tuple[int, str]]:
    """(line number, line) of every import inside a function of ``source``."""
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            for inner in ast.walk(node):
                if isinstance(inner, ast.Import | ast.ImportFrom):
                    found.append((inner.lineno, lines[inner.lineno - 1]))
    return found


def compiler_importers(sources: dict[str, str]) -> list[str]:
    """The modules of ``sources`` (dotted name -> source) that import numba without being a `*_numba` module."""
    return sorted(m for m, src in sources.items() if COMPILER in imported_roots(src) and not m.endswith("_numba"))


def _core_sources() -> dict[str, str]:
    return {m: p.read_text() for m, p in MODULES.items() if part(m) == "core"}


def test_core_keeps_few_modules_at_its_top_level() -> None:
    top = sorted(p.name for p in (PACKAGE_DIR / "core").glob("*.py"))
    assert len(top) <= MAX_CORE_TOP_LEVEL, top


def test_only_numba_modules_import_numba() -> None:
    sources = {m: p.read_text() for m, p in MODULES.items()}
    assert compiler_importers(sources) == []
    assert any(m.endswith("_numba") for m in sources)  # the rule is not vacuous


def test_core_imports_at_the_top_of_its_modules() -> None:
    """Imports inside functions hide what a module needs; the few that start-up needs say why on their line."""
    found = [
        f"{m}:{line}: {text.strip()}" for m, src in _core_sources().items() for line, text in deferred_imports(src)
    ]
    assert len(found) <= MAX_DEFERRED_IMPORTS, found
    assert all("#" in text for text in found), found


def test_config_imports_neither_torch_nor_numba_at_its_top() -> None:
    """Statically: no module of core/config imports numba anywhere, nor torch when it is imported (only inside a
    function, when a device name must be checked against the machine)."""
    config = {m: src for m, src in _core_sources().items() if m.startswith(f"{ROOT}.core.config")}
    assert config
    for module, source in config.items():
        assert COMPILER not in imported_roots(source), module
        assert "torch" not in imported_roots(module_level(source)), module


def module_level(source: str) -> str:
    """``source`` without its function bodies and its ``if TYPE_CHECKING:`` blocks: what importing it runs."""
    keep = [n for n in ast.parse(source).body if not (isinstance(n, ast.FunctionDef) or _is_type_checking(n))]
    return ast.unparse(ast.Module(body=keep, type_ignores=[]))


def _is_type_checking(node: ast.stmt) -> bool:
    return isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"


def test_the_core_checks_catch_what_they_are_for() -> None:
    sources = {
        f"{ROOT}.core.pca.eigen_numba": "from numba import njit\n",
        f"{ROOT}.core.pca.eigen": "import numba\n",
        f"{ROOT}.core.search.pools": "def f():\n    from numba import njit\n",
    }
    assert compiler_importers(sources) == [f"{ROOT}.core.pca.eigen", f"{ROOT}.core.search.pools"]
    assert deferred_imports("import os\ndef f():\n    import torch  # why\n") == [(3, "    import torch  # why")]
    lazy = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import torch\ndef f():\n    import torch\n"
    assert "torch" not in imported_roots(module_level(lazy))
    assert "torch" in imported_roots(module_level("import torch\n"))


#: Runs in a fresh interpreter: imports the named modules, then says which heavy libraries they loaded.
_LOADED = """
import importlib, json, sys
for name in sys.argv[1:]:
    importlib.import_module(name)
print(json.dumps({lib: lib in sys.modules for lib in ("torch", "numba")}))
"""


def _loaded(*modules: str) -> dict[str, bool]:
    done = subprocess.run([sys.executable, "-c", _LOADED, *modules], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_importing_config_loads_neither_torch_nor_numba() -> None:
    config = [m for m in MODULES if m.startswith(f"{ROOT}.core.config")]
    assert config and _loaded(*config) == {"torch": False, "numba": False}


def test_importing_ros_params_loads_no_compiler() -> None:
    """The node's parameter rules (and the CLI's) read config/ and the message settings, not the estimator's kernels."""
    assert _loaded(f"{ROOT}.ros.params")["numba"] is False
