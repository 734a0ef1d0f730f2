"""Draw docs/images/training_shapes.png: every training and validation shape, coloured by its exact normal.

Run from the repository root: .venv/bin/python docs/tools/plot_catalogue.py docs/images/training_shapes.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from triplet_normal_ros.training.dataset import sample_shape
from triplet_normal_ros.training.shapes import catalogue

COLUMNS = 6
#: The camera of every panel; points facing away from it are culled, since see-through clouds are unreadable.
ELEVATION_DEG, AZIMUTH_DEG = 25.0, -55.0


def plot_catalogue(path: Path, n_points: int = 4000, seed: int = 0) -> Path:
    """A 3-D scatter grid of every training and validation shape, coloured RGB = (n + 1) / 2."""
    specs = [(split, spec) for split in ("train", "val") for spec in catalogue(split)]
    rows = -(-len(specs) // COLUMNS)
    fig = plt.figure(figsize=(2.6 * COLUMNS, 2.6 * rows))
    elev, azim = np.radians(ELEVATION_DEG), np.radians(AZIMUTH_DEG)
    towards_camera = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    for i, (split, spec) in enumerate(specs):
        points, normals = sample_shape(spec, n_points, seed)
        front = normals @ towards_camera > 0
        ax = fig.add_subplot(rows, COLUMNS, i + 1, projection="3d")
        ax.view_init(ELEVATION_DEG, AZIMUTH_DEG)
        ax.scatter(*points[front].T, c=(normals[front] + 1) / 2, s=2.0, linewidths=0, depthshade=False)
        ax.set_title(f"{spec.name}\n{split} · {spec.kind}", fontsize=8)
        ax.set_box_aspect(np.ptp(points, axis=0))
        ax.set_axis_off()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the PNG to write (docs/images/training_shapes.png)")
    parser.add_argument("--points", type=int, default=4000, help="points per shape (default: 4000)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"wrote {plot_catalogue(args.out, args.points, args.seed)}")


if __name__ == "__main__":
    main()
