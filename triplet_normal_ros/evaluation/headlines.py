"""The headline tables of README.md and docs/CHOOSING.md, composed from docs/RESULTS.md's generated blocks.

A reader meets the figures first in README (accuracy, speed) and in CHOOSING (checkpoint × method: error, time,
memory in one table), so those tables are copies; composing them here from the blocks that `eval`, `bench` and
`docs/tools/real_frame_speed.py` write keeps every copy today's. `docs/tools/headline_tables.py` writes them, and
test_docs fails while a copy and the blocks differ.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ..core.learned.checkpoint import read_metadata, resolve_checkpoint
from ..io.samples import FRAMES
from .range_eval import PCA_WINDOW
from .report import read_section

#: The range-image sets of eval, with README's names (the real frames, in real_frame_speed's order: `FRAMES`).
SETS = {"depth": "depth frames of rooms", "fold": "close-range fold frames", "lidar": "32-beam LiDAR scans"}
#: eval's row labels for the `default` checkpoint, whose rows carry no checkpoint name.
EVAL_DEFAULT = {"learned": "learned", "hybrid": "hybrid (F > 10, bend > 0.03)"}
EVAL_PCA_WINDOW, EVAL_PCA_POOL = PCA_WINDOW, "PCA, k = 512 (the learned pool)"
#: The real-frame row of what a node user gets with no parameter set (a range image on a CPU gets `range`); the
#: speed tool writes it and the tables read it.
NODE_DEFAULT = "hybrid, range (the node's default on a CPU)"


@dataclass(frozen=True)
class Choice:
    """One row of CHOOSING's table: a method with a checkpoint, and where the defaults pick it."""

    method: str
    checkpoint: str
    default_where: str

    def eval_label(self) -> str:
        if self.method == "pca":
            return EVAL_PCA_WINDOW
        return EVAL_DEFAULT[self.method] if self.checkpoint == "default" else f"{self.method}, {self.checkpoint}"

    def speed_label(self) -> str:
        """real_frame_speed's label; the learned rows are not timed there (every pixel through the network)."""
        if self.method == "pca":
            return "pca (window)"
        if self.method == "learned":
            return ""
        return {"range": NODE_DEFAULT, "default": "hybrid, default checkpoint"}.get(
            self.checkpoint, f"hybrid, {self.checkpoint}"
        )

    def memory_label(self) -> str:
        """bench's memory-table label, where bench measures this row."""
        if self.method == "pca":
            return "pca (windows)"
        suffix = " (the node's CPU default)" if (self.method, self.checkpoint) == ("hybrid", "range") else ""
        return f"{self.method}, {self.checkpoint}{suffix}"


CHOICES = (
    Choice("pca", "", "never (`pca` is the safe floor)"),
    Choice("hybrid", "range", "the node on a CPU, range images"),
    Choice("hybrid", "lite", "the node on a CPU, other clouds"),
    Choice("hybrid", "default", "the node on a GPU"),
    Choice("learned", "range", "`estimate` on a CPU, range images (an organized `.pcd`)"),
    Choice("learned", "lite", "`estimate` on a CPU, clouds that are not range images"),
    Choice("learned", "default", "`estimate` on a GPU"),
)


def table_rows(results: Path, block: str, first_header: str) -> dict[str, list[str]]:
    """The rows of the table in `block` whose header starts with `first_header`, keyed by their first cell (bold
    marks removed), or by the first and third cells joined by ' / ' where the first repeats (per-frame tables)."""
    body = read_section(results, block)
    if body is None:
        raise KeyError(f"{results} has no block {block}")
    lines = body.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header} |"))
    rows = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [re.sub(r"\*\*(.*?)\*\*", r"\1", c.strip()) for c in line.strip().strip("|").split("|")]
        rows[cells[0] if cells[0] not in FRAMES else f"{cells[0]} / {cells[2]}"] = cells
    return rows


def accuracy(results: Path, kind: str, label: str) -> str:
    """MSAE of eval's `label` row on the range-image set `kind`."""
    return table_rows(results, f"eval-{kind}", "method")[label][2]


def seconds(results: Path, label: str) -> list[str]:
    """real_frame_speed's seconds per frame for `label`, one per shipped frame."""
    rows = table_rows(results, "real-frame-speed", "frame")
    return [rows[f"{frame} / {label}"][3] for frame in FRAMES]


def peak_mb(results: Path, label: str) -> str:
    rows = table_rows(results, "bench", "method | idle MB")
    return rows[label][2] if label in rows else ""


def choosing_table(results: Path) -> str:
    """CHOOSING's `choosing` block: every method and checkpoint on a CPU, error, time and memory; the node's default
    in bold."""
    lines = [
        "| method | checkpoint (k) | depth frames | fold frames | LiDAR scans | s per real frame | peak MB | "
        "the default where |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for choice in CHOICES:
        errors = [accuracy(results, kind, choice.eval_label()) for kind in SETS]
        times = " / ".join(seconds(results, choice.speed_label())) if choice.speed_label() else ""
        cells = [*errors, times, peak_mb(results, choice.memory_label())]
        if (choice.method, choice.checkpoint) == ("hybrid", "range"):
            cells = [f"**{c}**" if c else c for c in cells]
        k = read_metadata(resolve_checkpoint(choice.checkpoint))["k"] if choice.checkpoint else None
        checkpoint = f"`{choice.checkpoint}` ({k})" if k else "none"
        method = "`pca` (windows)" if choice.method == "pca" else f"`{choice.method}`"
        lines.append(f"| {method} | {checkpoint} | " + " | ".join(cells) + f" | {choice.default_where} |")
    lines.append(f"| Open3D KNN-30, for reference | | | | | {' / '.join(seconds(results, 'Open3D KNN30'))} | | |")
    return "\n".join(lines)


def readme_accuracy(results: Path) -> str:
    """README's `readme-accuracy` block: the range-image sets, PCA against the networks, the CPU default in bold."""
    columns = (EVAL_PCA_WINDOW, EVAL_PCA_POOL, "learned", EVAL_DEFAULT["hybrid"], "hybrid, range")
    lines = [
        "| data (simulated, 3-6 frames) | `pca` (windows) | PCA over the learned pool | `learned`, `default` | "
        "`hybrid`, `default` (GPU default) | `hybrid`, `range` (CPU default) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for kind, name in SETS.items():
        cells = [accuracy(results, kind, label) for label in columns]
        cells[-1] = f"**{cells[-1]}**"
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def readme_speed(results: Path) -> str:
    """README's `readme-speed` block: seconds per real frame, Open3D beside, the CPU default in bold."""
    rows = (
        ("Open3D KNN-30, for reference", "Open3D KNN30"),
        ("`pca` (windows)", "pca (window)"),
        ("**`hybrid`, `range` (the node's CPU default)**", NODE_DEFAULT),
        ("`hybrid`, `lite`", "hybrid, lite"),
        ("`hybrid`, `default` (a GPU's choice, here on the CPU)", "hybrid, default checkpoint"),
    )
    lines = [f"| method, checkpoint | {FRAMES[0]} (s) | {FRAMES[1]} (s) |", "| --- | ---: | ---: |"]
    for name, label in rows:
        times = seconds(results, label)
        if label == NODE_DEFAULT:
            times = [f"**{t}**" for t in times]
        lines.append(f"| {name} | " + " | ".join(times) + " |")
    return "\n".join(lines)
