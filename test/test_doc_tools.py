"""The docs tools that write docs/RESULTS.md's hand-run blocks: each one's `--out` writes its own block, with the
command that reruns it, and leaves the rest of the file alone (test_docs checks that each block names such a tool)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from triplet_normal_ros.evaluation.report import read_section, update_section

pytestmark = pytest.mark.slow  # subprocesses that import torch and write bags

REPO = Path(__file__).resolve().parents[1]


def run_tool(script: str, *args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(REPO / "docs" / "tools" / script), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )


def test_bag_overhead_writes_its_block_beside_the_others(tmp_path: Path) -> None:
    results = tmp_path / "RESULTS.md"
    update_section(results, "bench", "kept")
    done = run_tool("bag_overhead.py", "--frames", "2", "--storage", "mcap", "sqlite3", "--out", results)
    assert done.returncode == 0, done.stderr[-2000:]
    block = read_section(results, "bag-overhead")
    assert block.startswith("Command: `.venv/bin/python docs/tools/bag_overhead.py --frames 2"), block
    rows = [line.split(" | ")[0] for line in block.splitlines() if line.startswith("| ") and "---" not in line]
    assert rows == ["| storage", "| mcap", "| sqlite3"]
    assert read_section(results, "bench") == "kept"


def test_gpu_check_table_writes_a_failed_row_and_fails(tmp_path: Path) -> None:
    rows = [
        {"what": "probe", "device": "cuda", "seconds": None, "result": "H100", "ok": True},
        {"what": "compare", "device": "cuda", "seconds": 1.5, "result": "a | b", "ok": False},
    ]
    jsonl = tmp_path / "results.jsonl"
    jsonl.write_text("".join(json.dumps(row) + "\n" for row in rows))
    results = tmp_path / "RESULTS.md"
    done = run_tool("gpu_check.py", "table", "--results", jsonl, "--out", results)
    assert done.returncode == 1, "a failed row must fail the table"
    block = read_section(results, "gpu-check")
    assert block.startswith("Command: `.venv/bin/python docs/tools/gpu_check.py table"), block
    assert "| compare | cuda | 1.5 | a / b | **FAILED** |" in block
    assert block.endswith("gpu_check: 1 of 2 ok, 1 FAILED")


def test_window_stages_times_every_stage_of_the_compiled_window_path() -> None:
    """The study calls the window path's stages as `window_normals` runs them, so a kernel whose signature changes
    breaks it here rather than on the next person who runs it."""
    done = run_tool("window_stages.py", "--frames", "1", "--repeats", "1")
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [
        [cell.strip() for cell in line.strip("|").split("|")]
        for line in done.stdout.splitlines()
        if line.startswith("| eval depth 0 | ")
    ]
    timed = [row for row in rows if len(row) == 7]  # frame, threads, whole and the four stages
    assert timed and len(rows) == len(timed) + 1, done.stdout  # then the frame's census
    assert all(float(cell) > 0 for row in timed for cell in row[2:]), timed
