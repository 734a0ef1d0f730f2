"""Draw docs/images/depth_frame.png: one simulated depth frame's exact normals, depth and edge mask, and a LiDAR scan.

Run from the repository root: .venv/bin/python docs/tools/plot_range_scans.py [--seed N] [--out PATH]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from triplet_normal_ros.simulation.depth_camera import depth_frame
from triplet_normal_ros.simulation.edges import EDGE_RADIUS
from triplet_normal_ros.simulation.lidar import lidar_scan

REPO = Path(__file__).resolve().parents[2]


def normal_rgb(normals: np.ndarray) -> np.ndarray:
    """RGB = (n + 1) / 2 in the sensor frame, white where there is no return."""
    return np.where(np.isfinite(normals), (normals + 1) / 2, 1.0).clip(0, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "images" / "depth_frame.png")
    args = parser.parse_args()
    frame, scan = depth_frame(args.seed), lidar_scan(args.seed)
    fig = plt.figure(figsize=(15, 7.2))
    grid = fig.add_gridspec(2, 3, height_ratios=[3.2, 1])
    panels = [fig.add_subplot(grid[0, i]) for i in range(3)]
    panels[0].imshow(normal_rgb(frame.normals))
    panels[0].set_title("exact normals, optical frame, RGB = (n + 1) / 2")
    depth = panels[1].imshow(frame.points[..., 2], cmap="viridis")
    fig.colorbar(depth, ax=panels[1], fraction=0.035, label="noisy depth z (m); white: NaN")
    panels[1].set_title(f"depth, valid {frame.valid.mean():.0%}")
    edges = np.where(frame.valid, 0.35, 1.0)[..., None] * np.ones(3)
    edges[frame.near_edge] = (0.85, 0.2, 0.1)
    panels[2].imshow(edges)
    panels[2].set_title(f"near an edge (< {EDGE_RADIUS * 100:.0f} cm of another face): {frame.near_edge.mean():.0%}")
    lidar = fig.add_subplot(grid[1, :])
    lidar.imshow(normal_rgb(scan.normals), aspect="auto", interpolation="nearest")
    lidar.set_title(f"LiDAR scan {scan.points.shape[0]} x {scan.points.shape[1]}: exact normals (sensor frame)")
    lidar.set_xlabel("column (azimuth 0.2° steps, clockwise from +x)")
    lidar.set_ylabel("beam")
    for ax in panels:
        ax.set_axis_off()
    fig.suptitle(f"simulated range frames, seed {args.seed}")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=72)
    print(args.out)


if __name__ == "__main__":
    main()
