"""The user docs against docs/RESULTS.md and against the code: no figure without its measurement, no name without
its module, parameter, subcommand or default.

A *figure* is a measured number, recognised by how it is written: a number (or a range of two, ``3.3-4.4``) followed
by a unit of time (s, ms, µs, min, seconds, minutes), a percentage (%), a ratio (× with or without a space, or x
written straight after the number: ``6.5x``; ``640x480`` is a size, ``3 × 3`` a product), an angle (°, degrees, rad²)
or a rate (points/s, pts/s, patches/s, GFLOP/s); and any bare number with three or more decimals (``0.0136``: an MSAE).
Sizes (MB, kB), counts and parameter values (radius 0.05, k 64) are not figures. A doc's figure is held when
docs/RESULTS.md writes the same number with the same unit (spaces, thousands separators and the ×/x spelling aside),
or, for a bare figure, the same number anywhere; the few constants of the code that read like figures are listed in
ALLOWED, each checked against its source. Log formats in the docs write their figures as capital letters.

Figures are held by docs/RESULTS.md alone, today's tables; docs/HISTORY.md (studies and superseded figures) holds
none, so a figure that survives only in history fails here. RESULTS stays within RESULTS_MAX_LINES, and README's
accuracy table quotes the `eval` blocks themselves.
"""

from __future__ import annotations

import ast
import functools
import inspect
import json
import re
from collections.abc import Callable
from pathlib import Path

import pytest

import triplet_normal_ros
from triplet_normal_ros.cli.main import COMMANDS
from triplet_normal_ros.evaluation.report import read_section
from triplet_normal_ros.ros.params import SPEC_BY_NAME, SPECS

REPO = Path(__file__).resolve().parents[1]
PACKAGE_DIR = Path(triplet_normal_ros.__file__).parent
RESULTS = REPO / "docs" / "RESULTS.md"
RESULTS_MAX_LINES = 640
DOCS = ("README.md", "docs/NODE.md", "docs/CLI.md", "docs/MODEL.md", "docs/DESIGN.md", "docs/CHOOSING.md")
LAUNCH = REPO / "launch" / "triplet_normal.launch.py"
#: The package's folders (core, io, ros, ...): a path or dotted name starting with one is resolved inside the package.
LAYERS = tuple(sorted(p.parent.name for p in PACKAGE_DIR.glob("*/__init__.py")))
#: File names the docs mention that are not this repository's: image_pipeline's calibrator, a camera driver's launch.
EXTERNAL = {"calibrator.py", "camera.launch.py"}
#: A dotted word ending in one of these is a file name (``model.safetensors``, ``cloud.xyz``), not a module attribute.
FILE_SUFFIXES = {
    "py", "md", "yaml", "xml", "json", "png", "safetensors", "pt", "sh", "bash", "txt", "launch",
    "xyz", "normals", "pidx", "npy", "npz", "ply", "pcd", "mcap", "db3",
}  # fmt: skip

# --- figures ---------------------------------------------------------------------------------------------------------

_NUMBER = r"\d+(?:,\d{3})*(?:\.\d+)?"
_FIGURE = re.compile(
    rf"(?<![\w.\-/])(?P<number>{_NUMBER}(?:\s?[-–]\s?{_NUMBER})?)"
    r"(?:(?P<x>x)(?![\w²/])"
    r"|\s?(?P<unit>points/s|pts/s|patches/s|GFLOP/s|µs|ms|min|minutes|seconds|degrees|s|%|°|rad²)(?![\w²/])"
    r"|\s?(?P<times>×)(?!\s?[\d`]))"
)
_BARE = re.compile(r"(?<![\w.\-/])(\d+\.\d{3,})(?![\w.])")
_ANY_NUMBER = re.compile(rf"(?<![\w.])({_NUMBER})(?![\d])")
_UNIT_NAMES = {"x": "×", "pts/s": "points/s", "minutes": "min", "seconds": "s", "degrees": "°"}


def _constant(module: str, name: str) -> float:
    """A module-level literal of the package (``NAME = 5.0``, or one of ``A, B = 1, 2``), read without importing."""
    tree = ast.parse((PACKAGE_DIR / module).read_text())
    for stmt in tree.body:
        if not isinstance(stmt, ast.Assign) or len(stmt.targets) != 1:
            continue
        target, value = stmt.targets[0], stmt.value
        pairs = zip(target.elts, value.elts, strict=True) if isinstance(target, ast.Tuple) else [(target, value)]
        for t, v in pairs:
            if isinstance(t, ast.Name) and t.id == name:
                return float(ast.literal_eval(v))
    raise LookupError(f"{module} has no constant {name}")


def _loss_support_deg() -> float:
    from triplet_normal_ros.training.losses import normal_loss

    return float(inspect.signature(normal_loss).parameters["support_deg"].default)


#: Constants of the code that the docs write like figures: (number, unit) -> why, and the values in the code, each of
#: which must equal the number.
ALLOWED: dict[tuple[str, str], tuple[str, Callable[[], set[float]]]] = {
    ("5", "s"): (
        "the statistics window (`stats_period`'s default) and the node's log throttle",
        lambda: {SPEC_BY_NAME["stats_period"].default, _constant("ros/serving.py", "THROTTLE_S")},
    ),
    ("0.1", "s"): (
        "how often the idle worker loop looks for a stop",
        lambda: {_constant("ros/serving.py", "SERVE_POLL_S")},
    ),
    ("1.5", "s"): ("the shutdown watchdog's wait", lambda: {_constant("ros/serving.py", "JOIN_TIMEOUT_S")}),
    ("0.3", "s"): (
        "how long a stop during the start waits for the main thread's next check",
        lambda: {_constant("ros/stopper.py", "START_GRACE_S")},
    ),
    ("20", "s"): (
        "how long `--address` waits for a connection",
        lambda: {_constant("cli/cluster.py", "CONNECT_TIMEOUT_S")},
    ),
    ("0.1", "%"): (
        "the inlier fits' slack, of the radius",
        lambda: {100 * _constant("core/learned/scales.py", "INLIER_SLACK")},
    ),
    ("15", "°"): ("the support angle of the paper's normal loss", lambda: {_loss_support_deg()}),
    ("0.25", "s"): (
        "the start-up probe's small image, above which its own points stand for the forecast",
        lambda: {_constant("core/throughput.py", "POINTS_DOMINATE_S")},
    ),
    ("10", "×"): (
        "how much slower than the slowest cloud is stuck",
        lambda: {_constant("ros/health.py", "STUCK_FACTOR")},
    ),
    ("25", "°"): ("the lattice's agreement angle", lambda: {_constant("core/range_image/lattice.py", "AGREE_DEGREES")}),
    ("7.5", "°"): (
        "the coarser lattice level's agreement angle",
        lambda: {_constant("core/range_image/lattice.py", "COARSE_AGREE_DEGREES")},
    ),
    ("20", "°"): (
        "the triplets' positive / negative angle",
        lambda: {_constant("training/triplets.py", "THRESHOLD_DEG")},
    ),
    ("5", "°"): ("the relative loss's floor φ", lambda: {_constant("training/losses.py", "RELATIVE_FLOOR_DEG")}),
    ("2", "×"): ("FLOPs per multiply-add, as bench counts them", lambda: {_flops_per_multiply_add()}),
    ("3", "×"): (
        "how much better a one-sided window must fit",
        lambda: {_constant("core/range_image/sides.py", "SHARPER")},
    ),
    ("30", "°"): ("the fold snap's reach", lambda: {_constant("core/range_image/sides.py", "SNAP_DEGREES")}),
}


def _flops_per_multiply_add() -> float:
    """`bench.network_mflop` of the default checkpoint over its multiply-adds counted by the tests' own arithmetic."""
    from helpers import multiply_adds

    from triplet_normal_ros.core.learned.checkpoint import read_metadata, resolve_checkpoint
    from triplet_normal_ros.evaluation.bench import network_mflop

    meta = read_metadata(resolve_checkpoint("default"))
    return round(network_mflop("default")[1] * 1e6 / multiply_adds(meta["architecture"], meta["k"]), 6)


def figures(text: str) -> list[tuple[str, str]]:
    """Every figure of `text` as (number, unit), normalised: no thousands separators or spaces, one dash, one name per
    unit (× for x, s for seconds, ...). A bare figure has the unit ''."""
    found = []
    for match in _FIGURE.finditer(text):
        number = re.sub(r"\s", "", match["number"]).replace(",", "").replace("–", "-")
        unit = match["unit"] or match["x"] or match["times"]
        found.append((number, _UNIT_NAMES.get(unit, unit)))
    found += [(m[1], "") for m in _BARE.finditer(text)]
    return found


def numbers(text: str) -> set[str]:
    """Every number written in `text`, thousands separators dropped."""
    return {m[1].replace(",", "") for m in _ANY_NUMBER.finditer(text)}


def unheld_figures(doc: str, results: str) -> list[str]:
    """The figures of `doc` that `results` does not hold and ALLOWED does not list, each with its line."""
    held, held_numbers = set(figures(results)), numbers(results)
    missing = []
    for lineno, line in enumerate(doc.splitlines(), 1):
        for number, unit in figures(line):
            ok = number in held_numbers if unit == "" else (number, unit) in held or (number, unit) in ALLOWED
            if not ok:
                missing.append(f"line {lineno}: {number}{unit}: {line.strip()[:100]}")
    return missing


# --- names -----------------------------------------------------------------------------------------------------------

_PY_PATH = re.compile(r"(?<![\w./-])([\w./-]*\w\.py)(?!\w)")
_SLASHED_ATTRIBUTE = re.compile(rf"(?<![\w./-])((?:{'|'.join(LAYERS)})/\w+)\.(\w+)")
_DOTTED = re.compile(r"(?<![\w./-])([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)+)(?!\w)")
_COMMAND = re.compile(r"triplet-normal\s+([a-z][a-z-]*)")


def package_modules() -> set[str]:
    """Every module file of the package, as a path below the package (``core/tiles.py``), ``__init__.py`` aside."""
    return {p.relative_to(PACKAGE_DIR).as_posix() for p in PACKAGE_DIR.rglob("*.py") if p.name != "__init__.py"}


@functools.cache
def _known_py_names() -> set[str]:
    places = [PACKAGE_DIR, REPO / "test", REPO / "docs" / "tools", REPO / "launch"]
    return {p.name for place in places for p in place.rglob("*.py")} | {"setup.py"} | EXTERNAL


@functools.cache
def _module_stems() -> dict[str, list[Path]]:
    stems: dict[str, list[Path]] = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        if path.name != "__init__.py":
            stems.setdefault(path.stem, []).append(path)
    return stems


@functools.cache
def _top_level_names(path: Path) -> set[str]:
    names = set()
    for stmt in ast.parse(path.read_text()).body:
        if isinstance(stmt, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(stmt.name)
        elif isinstance(stmt, ast.Assign | ast.AnnAssign):
            targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
            for target in targets:
                names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
        elif isinstance(stmt, ast.Import | ast.ImportFrom):
            names.update((a.asname or a.name).split(".")[0] for a in stmt.names)
    return names


@functools.cache
def _class_members() -> dict[str, set[str]]:
    """Every class of the package by name, with the names its body defines (methods, properties, attributes)."""
    members: dict[str, set[str]] = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                found = members.setdefault(node.name, set())
                for stmt in node.body:
                    if isinstance(stmt, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                        found.add(stmt.name)
                    elif isinstance(stmt, ast.Assign | ast.AnnAssign):
                        targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
                        found.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
    return members


def _resolves(base: Path, parts: list[str]) -> bool:
    """Whether `parts` name a module below `base` (a package folder), optionally followed by attributes of it."""
    for i, part in enumerate(parts):
        if (base / part).is_dir():
            base = base / part
            continue
        module = base / f"{part}.py"
        if not module.is_file():
            return False
        return i + 1 == len(parts) or parts[i + 1] in _top_level_names(module)
    return True


def dotted_exists(name: str) -> bool | None:
    """Whether a dotted name of ours (``core.plan.make_plan``, ``frames.COLLINEAR_RATIO``, ``Mailbox.put``) exists;
    None when the name is not ours to check (``est.radius``, ``torch.cuda``, a file name)."""
    parts = name.split(".")
    if parts[-1] in FILE_SUFFIXES:
        return None
    if parts[0] == triplet_normal_ros.__name__:
        return len(parts) == 1 or _resolves(PACKAGE_DIR, parts[1:])
    if parts[0] in LAYERS:
        return _resolves(PACKAGE_DIR, parts)
    classes = _class_members()
    if parts[0] in classes:
        return parts[1] in classes[parts[0]]
    modules = _module_stems().get(parts[0])
    if not modules:
        return None
    return any(parts[1] in _top_level_names(module) for module in modules)


def py_path_exists(path: str) -> bool:
    """Whether a ``.py`` path the docs name exists: below the package when it starts with one of its folders, else in
    the repository; a bare file name anywhere in the package, test/, docs/tools/ or launch/."""
    if "/" not in path:
        return path in _known_py_names()
    if path.split("/")[0] in LAYERS:
        return (PACKAGE_DIR / path).is_file()
    return (REPO / path).is_file()


def unknown_names(text: str) -> list[str]:
    """Modules, module attributes and subcommands that `text` names and the package does not have."""
    unknown = [f"no file {p}" for p in _PY_PATH.findall(text) if not py_path_exists(p)]
    dotted = [m[1] for m in _DOTTED.finditer(text)]
    dotted += [f"{m[1].replace('/', '.')}.{m[2]}" for m in _SLASHED_ATTRIBUTE.finditer(text) if m[2] != "py"]
    unknown += [f"no module or attribute {d}" for d in dotted if dotted_exists(d) is False]
    commands = {name for name, _, _ in COMMANDS}
    unknown += [f"no subcommand {c}" for c in _COMMAND.findall(text) if c not in commands]
    return unknown


_SECTION = re.compile(r"\b([A-Z_]+\.md)\)?,?\s*\(?\"([^\"\n]+)\"")


def unknown_sections(text: str) -> list[str]:
    """Sections cited as `FILE.md, "Heading"` (or `FILE.md ("Heading")`) that FILE.md has no heading starting with."""
    unknown = []
    for file, section in _SECTION.findall(text):
        path = next((p for p in (REPO / "docs" / file, REPO / file) if p.is_file()), None)
        lines = path.read_text().splitlines() if path else []
        headings = [line.lstrip("#").strip() for line in lines if line.startswith("#")]
        if not any(h.startswith(section) for h in headings):
            unknown.append(f'{file}, "{section}"')
    return unknown


# --- tables ----------------------------------------------------------------------------------------------------------


def tables(text: str, header: tuple[str, ...]) -> list[list[list[str]]]:
    """The markdown tables of `text` whose header row starts with `header`: rows of cells, header and rule dropped."""
    found, rows, inside = [], [], False
    for line in [*text.splitlines(), ""]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells is None:
            if inside:
                found.append(rows)
            rows, inside = [], False
        elif not inside and tuple(cells[: len(header)]) == header:
            inside = True
        elif inside and not set(cells[0]) <= set("-: "):
            rows.append(cells)
    return found


def _code(cell: str) -> list[str]:
    return re.findall(r"`([^`]*)`", cell)


def _literal(cell: str) -> object:
    text = cell.strip().strip("`")
    if text == '""':
        return ""
    if text in ("true", "false"):
        return text == "true"
    try:
        return json.loads(text)
    except ValueError:
        return text


PARAM_HEADER = ("name", "type", "default")
TYPE_NAMES = {str: "string", int: "int", float: "double", bool: "bool", list: "double[3]"}


def parameter_table_problems(text: str) -> list[str]:
    """Parameter tables must list exactly ros.params.SPECS, with each parameter's type and default."""
    problems = []
    for rows in tables(text, PARAM_HEADER):
        names = []
        for name_cell, type_cell, default_cell, *_ in rows:
            name = (_code(name_cell) or [name_cell])[0]
            names.append(name)
            spec = SPEC_BY_NAME.get(name)
            if spec is None:
                problems.append(f"{name}: not a node parameter")
                continue
            if type_cell != TYPE_NAMES[spec.kind]:
                problems.append(f"{name}: type {type_cell}, the node declares {TYPE_NAMES[spec.kind]}")
            if _literal(default_cell) != spec.default:
                problems.append(f"{name}: default {default_cell}, the node's is {spec.default!r}")
        missing = [s.name for s in SPECS if s.name not in names]
        if missing:
            problems.append(f"not in the table: {', '.join(missing)}")
    return problems


def launch_arguments() -> dict[str, object]:
    """The launch file's arguments: name -> default (a string, or None when the default is an expression)."""
    found = {}
    for node in ast.walk(ast.parse(LAUNCH.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument":
            default = next((k.value for k in node.keywords if k.arg == "default_value"), None)
            found[ast.literal_eval(node.args[0])] = default.value if isinstance(default, ast.Constant) else None
    return found


def design_modules(text: str) -> list[str]:
    """The modules DESIGN.md's table names, in order; a bare name in a row continues the folder before it
    (``cli/estimate.py``, ``bag.py`` is cli/bag.py)."""
    modules = []
    for rows in tables(text, ("module", "concern")):
        for row in rows:
            folder = ""
            for name in _code(row[0]):
                if "/" in name:
                    folder = name.rpartition("/")[0] + "/"
                    modules.append(name)
                else:
                    modules.append(folder + name)
    return modules


# --- the docs --------------------------------------------------------------------------------------------------------


def _read(doc: str) -> str:
    return (REPO / doc).read_text()


@pytest.mark.parametrize("doc", DOCS)
def test_every_figure_is_in_results(doc: str) -> None:
    missing = unheld_figures(_read(doc), RESULTS.read_text())
    assert not missing, f"{doc} quotes figures docs/RESULTS.md does not hold (quote it, or link there):\n" + "\n".join(
        missing
    )


@pytest.mark.parametrize("doc", DOCS)
def test_every_module_and_subcommand_named_exists(doc: str) -> None:
    unknown = unknown_names(_read(doc))
    assert not unknown, f"{doc}:\n" + "\n".join(unknown)


@pytest.mark.parametrize("doc", DOCS)
def test_every_section_cited_exists(doc: str) -> None:
    assert unknown_sections(_read(doc)) == []


@pytest.mark.parametrize("doc", DOCS)
def test_parameter_tables_match_the_node(doc: str) -> None:
    assert parameter_table_problems(_read(doc)) == []


def generated_blocks(text: str, prefix: str = "") -> str:
    """The bodies of `text`'s BEGIN/END blocks whose names start with `prefix`, joined."""
    found = re.findall(r"<!-- BEGIN (\S+) -->\n(.*?)<!-- END \1 -->", text, re.DOTALL)
    return "\n".join(body for name, body in found if name.startswith(prefix))


def test_results_holds_todays_tables_within_its_length() -> None:
    lines = RESULTS.read_text().count("\n")
    assert lines <= RESULTS_MAX_LINES, f"docs/RESULTS.md has {lines} lines: move studies to docs/HISTORY.md"


def block_writer(body: str) -> Path | None:
    """The source that writes a block, from its `Command:` line: a docs tool, or the `triplet-normal` subcommand's."""
    command = re.search(r"Command: `([^`]*)`", body)
    if command is None:
        return None
    tool = re.search(r"docs/tools/\w+\.py", command.group(1))
    if tool:
        return REPO / tool.group(0)
    sub = re.search(r"triplet-normal (\w+)", command.group(1))
    modules = {name: module for name, module, _ in COMMANDS}
    if sub is None or sub.group(1) not in modules:
        return None
    return Path(inspect.getsourcefile(modules[sub.group(1)]))


def writes_block(source: str, name: str) -> bool:
    """Whether `source` passes block `name` to `update_section`, as a literal, as a constant it defines, or as the
    f-string family it belongs to (`eval-{kind}`); a module that only reads blocks does not count."""
    family = re.escape(name.split("-")[0])
    quoted = rf"""(["']{re.escape(name)}["']|f["']{family}-\{{)"""
    if re.search(rf"update_section\([^)]*?{quoted}", source, re.DOTALL):
        return True
    constant = re.search(rf"^(\w+) = {quoted}", source, re.MULTILINE)
    return bool(constant and re.search(rf"update_section\([^)]*\b{constant.group(1)}\b", source))


def run_module_sources(path: Path) -> str:
    """A subcommand's module and the evaluation modules that write its blocks (those calling `update_section`)."""
    writers = [p for p in sorted((PACKAGE_DIR / "evaluation").glob("*.py")) if "update_section(" in p.read_text()]
    return path.read_text() + "".join(p.read_text() for p in writers if p.name != "report.py")


def test_every_results_table_is_in_a_block_its_command_writes() -> None:
    """A table outside the BEGIN/END blocks is written by hand; a block whose command does not write it is stale."""
    text = RESULTS.read_text()
    outside = re.sub(r"<!-- BEGIN (\S+) -->\n.*?<!-- END \1 -->", "", text, flags=re.DOTALL)
    assert [line for line in outside.splitlines() if line.startswith("| ---")] == [], "a table outside the blocks"
    for name, body in re.findall(r"<!-- BEGIN (\S+) -->\n(.*?)<!-- END \1 -->", text, re.DOTALL):
        writer = block_writer(body)
        assert writer is not None and writer.exists(), f"block {name} names no command of this repository"
        source = writer.read_text() if "docs/tools" in str(writer) else run_module_sources(writer)
        assert writes_block(source, name), f"block {name}: {writer.name} does not write it"


@pytest.mark.parametrize(
    ("doc", "block", "compose"),
    [
        ("README.md", "readme-accuracy", "readme_accuracy"),
        ("README.md", "readme-speed", "readme_speed"),
        ("docs/CHOOSING.md", "choosing", "choosing_table"),
    ],
)
def test_headline_tables_are_the_results_blocks(doc: str, block: str, compose: str) -> None:
    from triplet_normal_ros.evaluation import headlines

    expected = getattr(headlines, compose)(RESULTS)
    assert read_section(REPO / doc, block) == expected, f"rerun docs/tools/headline_tables.py ({doc}, {block})"


def test_training_block_is_what_the_shipped_checkpoints_record() -> None:
    from triplet_normal_ros.evaluation.training_card import markdown

    assert read_section(RESULTS, "training") == markdown().strip(), "rerun docs/tools/training_table.py --out"


def test_readme_accuracy_figures_are_the_eval_blocks() -> None:
    """Every MSAE README's accuracy section quotes is in an `eval-*` block, not only in prose that quotes one."""
    readme = _read("README.md")
    section = readme[readme.index("\n## Accuracy") :]
    section = section[: section.index("\n## ", 1)]
    quoted = {number for number, unit in figures(section) if unit == ""}
    assert quoted, "README's accuracy section quotes no MSAE"
    assert sorted(quoted - numbers(generated_blocks(RESULTS.read_text(), "eval-"))) == []


def test_readme_is_a_quickstart_linking_every_doc() -> None:
    lines = _read("README.md").splitlines()
    assert len(lines) <= 180, f"README.md has {len(lines)} lines: move details into docs/"
    first = "\n".join(lines[:80])
    for command in ("make demo", "make test", "ros2 run triplet_normal_ros node"):
        assert command in first, f"README's first 80 lines lack `{command}`"
    unlinked = [p.name for p in sorted((REPO / "docs").glob("*.md")) if f"(docs/{p.name})" not in "\n".join(lines)]
    assert unlinked == [], f"README links no {unlinked}"


def test_node_doc_has_the_parameter_table() -> None:
    assert tables(_read("docs/NODE.md"), PARAM_HEADER), "docs/NODE.md lost its parameter table"


def test_allowed_constants_match_the_code() -> None:
    for (number, unit), (_why, values) in ALLOWED.items():
        assert values() == {float(number)}, f"{number}{unit} is no longer the code's value: {values()}"


def test_cli_table_lists_every_subcommand() -> None:
    (rows,) = tables(_read("docs/CLI.md"), ("command", "does"))
    listed = [_code(row[0])[0].split()[0] for row in rows]
    assert listed == [name for name, _, _ in COMMANDS]


def test_launch_table_matches_the_launch_file() -> None:
    (rows,) = tables(_read("docs/NODE.md"), ("argument", "default", "effect"))
    declared = launch_arguments()
    assert [_code(row[0])[0] for row in rows] == list(declared)
    for row in rows:
        default = declared[_code(row[0])[0]]
        if default is not None:
            assert _literal(row[1]) == default, row


def test_design_lists_exactly_the_packages_modules() -> None:
    listed = design_modules(_read("docs/DESIGN.md"))
    assert len(listed) == len(set(listed)), "a module listed twice"
    actual = package_modules()
    assert sorted(set(listed) - actual) == [], "DESIGN.md lists modules the package does not have"
    assert sorted(actual - set(listed)) == [], "DESIGN.md's table misses these modules"


def test_design_api_calls_match_the_signatures() -> None:
    """DESIGN.md's quoted calls of NormalEstimator, estimate and estimate_cloud name every parameter with its
    default."""
    from triplet_normal_ros.core.cloud import estimate_cloud
    from triplet_normal_ros.core.estimator import NormalEstimator

    functions = {
        "NormalEstimator": NormalEstimator,
        "estimate": NormalEstimator.estimate,
        "estimate_cloud": estimate_cloud,
    }
    text = _read("docs/DESIGN.md")
    snippets = re.findall(r"```python\n(.*?)```", text, re.DOTALL) + re.findall(r"`([^`\n]+\(.*?\))`", text)
    checked = set()
    for snippet in snippets:
        try:
            tree = ast.parse(snippet)
        except SyntaxError:
            continue
        for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)):
            function = functions.get(call.func.id)
            if function is None:
                continue
            params = {n: p for n, p in inspect.signature(function).parameters.items() if n != "self"}
            with_defaults = {n for n, p in params.items() if p.default is not inspect.Parameter.empty}
            quoted = {k.arg: k.value for k in call.keywords}
            assert set(quoted) >= with_defaults, f"{call.func.id}: DESIGN.md omits {with_defaults - set(quoted)}"
            assert set(quoted) <= set(params), f"{call.func.id}: no parameter {set(quoted) - set(params)}"
            for name, node in quoted.items():
                assert ast.literal_eval(node) == params[name].default, f"{call.func.id}({name}=...)"
            checked.add(call.func.id)
    assert checked == set(functions)


def test_node_path_table_is_the_plans() -> None:
    from triplet_normal_ros.core.config.plan import plan_table

    block = read_section(REPO / "docs" / "NODE.md", "paths")
    assert block is not None and block.strip() == plan_table().strip(), "run docs/tools/path_table.py"


def test_node_quotes_the_start_up_line_in_its_current_format() -> None:
    from triplet_normal_ros.core.config.plan import Plan
    from triplet_normal_ros.core.kernels import CacheCount
    from triplet_normal_ros.core.throughput import Throughput

    plan = Plan("hybrid", "window", "kdtree", "range")
    line = Throughput(2400.0, 0.07, plan, warm_up_s=0.5, cache=CacheCount(23, 0))
    text = line.describe("cpu")
    text = re.sub(r"about [\d,]+ points/s", "about N points/s", text)
    text = re.sub(r"~[\d.]+ s", "~T s", text)
    text = re.sub(r"\d+% of probe", "P% of probe", text)
    text = re.sub(r"warm-up [\d.]+ s, \d+ kernels loaded from the cache, \d+ compiled", "warm-up W s, L kernels loaded "
                  "from the cache, C compiled", text)  # fmt: skip
    assert text in _read("docs/NODE.md")


# --- the checkers on bad examples ------------------------------------------------------------------------------------


def test_figures_are_numbers_with_units() -> None:
    text = (
        "took 17 s, then 3596 ms at 75,529 points/s; 0.40 × PCA, 6.5x fewer, 3.3-4.4 s, 17.63° and 0.0136; "
        "not 640x480, 3 × 3, sqrt(3 × `gate`), radius 0.05, OS-1-128 scan or 9.8 MB"
    )
    assert figures(text) == [
        ("17", "s"), ("3596", "ms"), ("75529", "points/s"), ("0.40", "×"), ("6.5", "×"), ("3.3-4.4", "s"),
        ("17.63", "°"), ("0.0136", ""),
    ]  # fmt: skip


def test_a_figure_results_does_not_hold_is_reported() -> None:
    results = "hybrid 0.395 × PCA, 3.3-4.4 s per frame; MSAE 0.0136 in a table"
    doc = "0.395× PCA in 3.3–4.4 s (0.0136); then 0.40 × and 17 s, 0.0140; every 5 s"
    assert [m.split(":")[1].strip() for m in unheld_figures(doc, results)] == ["0.40×", "17s", "0.0140"]


def test_unknown_modules_attributes_and_subcommands_are_reported() -> None:
    good = "`core/pca/frames.py`, `frames.COLLINEAR_RATIO`, `cli/main.COMMANDS`, triplet_normal_ros.core.config, "
    good += "`bag.py`, "
    good += "`NormalEstimator.estimate`"
    assert unknown_names(good + " triplet-normal bags, est.radius, model.safetensors, cloud.xyz") == []
    bad = "`core/nowhere.py`, `frames.NO_SUCH`, `cli/main.NOTHING`, triplet_normal_ros.core.nowhere, "
    bad += "triplet-normal frob, `NormalEstimator.no_such`"
    assert unknown_names(bad) == [
        "no file core/nowhere.py",
        "no module or attribute frames.NO_SUCH",
        "no module or attribute triplet_normal_ros.core.nowhere",
        "no module or attribute NormalEstimator.no_such",
        "no module or attribute cli.main.NOTHING",
        "no subcommand frob",
    ]


def test_a_missing_section_is_reported() -> None:
    text = 'docs/RESULTS.md, "Targets"; RESULTS.md ("Throughput"); docs/NODE.md, "No such heading"'
    assert unknown_sections(text) == ['NODE.md, "No such heading"']


def test_a_wrong_parameter_table_is_reported() -> None:
    rows = [f"| `{s.name}` | {TYPE_NAMES[s.kind]} | `{json.dumps(s.default)}` | | |" for s in SPECS]
    table = ["| name | type | default | range | description |", "| --- | --- | --- | --- | --- |"]
    assert parameter_table_problems("\n".join(table + rows)) == []
    rows[0] = "| `method` | string | `learned` | | |"
    rows[1] = "| `no_such` | int | 3 | | |"
    assert parameter_table_problems("\n".join(table + rows)) == [
        f"method: default `learned`, the node's is {SPECS[0].default!r}",
        "no_such: not a node parameter",
        f"not in the table: {SPECS[1].name}",
    ]


def test_design_rows_group_modules_of_one_folder() -> None:
    table = "| module | concern |\n| --- | --- |\n| `errors.py` | x |\n| `cli/estimate.py`, `bag.py` | y |\n"
    assert design_modules(table) == ["errors.py", "cli/estimate.py", "cli/bag.py"]
