"""Rewrite docs/RESULTS.md's `training` block from the shipped checkpoints (`evaluation/training_card.py`).

Run from the repository root after copying a new checkpoint into triplet_normal_ros/checkpoints/:
  .venv/bin/python docs/tools/training_table.py --out docs/RESULTS.md

test/test_docs.py fails while the block and the shipped files differ.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from triplet_normal_ros.evaluation.report import update_section
from triplet_normal_ros.evaluation.training_card import markdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="results file to write the `training` block into")
    args = parser.parse_args()
    text = markdown()
    print(text)
    if args.out:
        print(f"wrote {update_section(args.out, 'training', text)}")


if __name__ == "__main__":
    main()
