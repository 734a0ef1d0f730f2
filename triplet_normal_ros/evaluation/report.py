"""docs/RESULTS.md as named blocks, so eval, bench, training and ablation tools each rewrite only their own part."""

import os
import re
import shlex
import sys
import time
from pathlib import Path

HEADER = "# Results\n\nEach block below is written by the tool named in it; rerun the tool to refresh it.\n"


def update_section(path: str | Path, name: str, markdown: str) -> Path:
    """Replace the text between `<!-- BEGIN name -->` and `<!-- END name -->` (append the block if missing).

    Written atomically (temp file + rename) so a crash never leaves a half-written results file.
    """
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise ValueError(f"block name must be letters, digits, '.', '_' or '-', got {name!r}")
    path = Path(path)
    text = path.read_text() if path.exists() else HEADER
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    block = f"{begin}\n{markdown.strip()}\n{end}"
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.DOTALL)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def read_section(path: str | Path, name: str) -> str | None:
    """The markdown inside block `name`, or None when the file or block is absent."""
    path = Path(path)
    if not path.exists():
        return None
    match = re.search(
        rf"<!-- BEGIN {re.escape(name)} -->\n(.*?)\n<!-- END {re.escape(name)} -->", path.read_text(), re.DOTALL
    )
    return match.group(1) if match else None


def tool_command(script: str) -> str:
    """The command line a docs tool was run with, as its block's `Command:` line quotes it.

    Tools run from the repository root with the venv's interpreter (their docstrings say so), so the quoted command is
    the one a reader reruns to refresh the block, whatever interpreter path this process was given.
    """
    return shlex.join([".venv/bin/python", script, *sys.argv[1:]])


def tool_header(command: str, load: float, *more: str) -> str:
    """A docs tool's block's first line: the command, today's date and the load it started under, then `more`.

    The load is part of every measurement's record because these 2-core machines are shared: a figure taken at a load
    of 9 does not compare with one taken quiet.
    """
    parts = [f"Command: `{command}`", time.strftime("%Y-%m-%d"), f"load average at start {load:.1f} (2 cores)", *more]
    return " · ".join(parts)


def tool_block(header: str, about: str, columns: str, rows: list[str]) -> str:
    """A docs tool's block: its header line (`tool_header`), what a row is, and the table (`columns`: the header line
    and the rule line)."""
    return f"{header}\n\n{about}\n\n{columns}\n" + "\n".join(rows) + "\n"
