"""Rewrite docs/NODE.md's "Which path runs when" table (block `paths`) from `core.plan.plan_table()`.

Run from the repository root: .venv/bin/python docs/tools/path_table.py [--out docs/NODE.md]

test/test_docs.py fails while the block and `plan_table()` differ.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from triplet_normal_ros.core.config.plan import plan_table
from triplet_normal_ros.evaluation.report import update_section

NODE_MD = Path(__file__).resolve().parents[1] / "NODE.md"
BLOCK = "paths"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=NODE_MD, help="the markdown file whose `paths` block to rewrite")
    args = parser.parse_args()
    print(f"wrote {update_section(args.out, BLOCK, plan_table())}")


if __name__ == "__main__":
    main()
