"""Rewrite the headline tables of README.md (`readme-accuracy`, `readme-speed`) and docs/CHOOSING.md (`choosing`)
from docs/RESULTS.md's blocks (`evaluation/headlines.py`).

Run from the repository root after `eval`, `bench` or `docs/tools/real_frame_speed.py` rewrote RESULTS:
  .venv/bin/python docs/tools/headline_tables.py

test/test_docs.py fails while a headline table and the blocks it is composed from differ.
"""

from __future__ import annotations

from pathlib import Path

from triplet_normal_ros.evaluation.headlines import choosing_table, readme_accuracy, readme_speed
from triplet_normal_ros.evaluation.report import update_section

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    results = REPO / "docs" / "RESULTS.md"
    for doc, block, table in (
        (REPO / "README.md", "readme-accuracy", readme_accuracy(results)),
        (REPO / "README.md", "readme-speed", readme_speed(results)),
        (REPO / "docs" / "CHOOSING.md", "choosing", choosing_table(results)),
    ):
        print(f"wrote {block} in {update_section(doc, block, table)}")


if __name__ == "__main__":
    main()
