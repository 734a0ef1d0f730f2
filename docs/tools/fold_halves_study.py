"""Would one-sided windows sharpen the window survey at folds? A study on close-range fold frames eval never scores.

The window survey answers a pixel with the plane of its whole window. Beside a fold (a box standing on the floor, a
stair) the window holds both faces, so its plane turns gradually across the fold, the 10° test of region growing
passes pixel by pixel, and the box joins the floor. PCL's integral images and the survey already cut windows at depth
jumps (`range_image.image`, one-sided halves and quarters beside a wall); a fold has no jump. Here every pixel also
fits its four half windows and four quarter windows (the same summed-area tables: eight more box lookups and 3×3
solves). Each part is scored by its residual variance (smallest eigenvalue) plus the squared distance of the pixel's
own point from the part's plane: a part lying on the other face fits that face well but misses the pixel. Where the
whole window's smallest eigenvalue exceeds `ratio` × the best part's score, the pixel takes that part's plane
(Kuwahara's rule, for normals).

Rows: the survey's plane (what `hybrid` answers where its gate stays shut) and the node's `hybrid`, each as is and
with the one-sided rule in the pixels its gate leaves to the survey. MSAE (rad², sign-invariant, a missing normal
scored as 90°) over every valid pixel of 6 fold frames, overall and near edges; ARI and recovered segments of
`eval --sets segment`'s region growing on the first 3.

    .venv/bin/python docs/tools/fold_halves_study.py [--seed 100] [--checkpoint range] [--ratios 2,4,8]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image.check import inspect_grid
from triplet_normal_ros.core.range_image.image import MomentImage, box_pca, ray_noise_normal
from triplet_normal_ros.core.range_image.survey import PART_SPAN, opens, survey_and_cue, survey_on_slope
from triplet_normal_ros.evaluation.segmentation import (
    adjusted_rand_index,
    recovered_segments,
    region_segments,
)
from triplet_normal_ros.simulation.range_scans import fold_frames

RADIUS = 0.05


def one_sided(image: MomentImage) -> tuple[torch.Tensor, torch.Tensor]:
    """Per pixel, the ray-noise normal and score of its best half or quarter window (least smallest eigenvalue plus
    squared distance of the pixel from the part's plane, among the valid parts); call after `image.pca`."""
    pixels = np.arange(image.height * image.width)
    row, col = torch.from_numpy(pixels) // image.width, torch.from_numpy(pixels) % image.width
    reach = image._sizing[3]
    best_normal = torch.full((len(pixels), 3), torch.nan, dtype=torch.float64)
    best_residual = torch.full((len(pixels),), torch.inf, dtype=torch.float64)
    for box in image.one_sided_boxes(pixels).unbind(0):
        fit = box_pca(image.table, image.counts, image.offset, tuple(box.unbind(0)), row, col, reach)
        normal = ray_noise_normal(fit)
        # The pixel's own distance from the part's plane: a part that lies on another face fits that face well but
        # does not pass through the pixel.
        offside = ((image.points.reshape(-1, 3) + image.offset - fit.mean) * normal).sum(dim=-1) ** 2
        residual = torch.where(fit.valid, fit.eigvals[:, 0] + offside, torch.inf)
        better = residual < best_residual
        best_residual = torch.where(better, residual, best_residual)
        best_normal = torch.where(better.unsqueeze(-1), normal, best_normal)
    return best_normal, best_residual


def survey_state(points: np.ndarray, shape: tuple[int, int]):
    """The survey's normal, the whole window's residual, the pixels hybrid's gate leaves to the survey, and the
    one-sided candidates, all per pixel (torch path of `paths.range_image.window_hybrid`)."""
    cloud = torch.from_numpy(points.reshape(-1, 3).astype(np.float32))
    check = inspect_grid(cloud, shape)
    image = MomentImage(cloud, shape, check.pitch)
    fit = image.pca(RADIUS)
    first, cue = survey_and_cue(image, fit)
    survey, fitted = survey_on_slope(image, fit, first, cue)
    top, bottom, left, right = fit.box
    narrow = (bottom - top < PART_SPAN - 1) | (right - left < PART_SPAN - 1)
    valid = fit.valid & image.finite.reshape(-1)
    gate, bend = defaults.GATE, defaults.BEND
    gated = opens(cue, gate, bend) | opens(fitted, gate, bend)
    surveyed = valid & ~narrow & ~gated
    side_normal, side_residual = one_sided(image)
    return survey, fit.eigvals[:, 0], surveyed, side_normal, side_residual, valid & ~narrow & gated


def squared_angles(normals: np.ndarray, exact: np.ndarray) -> np.ndarray:
    cos = np.abs((normals * exact).sum(axis=1)) / (np.linalg.norm(normals, axis=1) * np.linalg.norm(exact, axis=1))
    angle = np.arccos(np.clip(np.nan_to_num(cos, nan=0.0), 0.0, 1.0))
    return angle**2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--checkpoint", default="")
    parser.add_argument("--ratios", default="2,4,8")
    parser.add_argument("--frames", type=int, default=6)
    args = parser.parse_args()
    ratios = [float(r) for r in args.ratios.split(",")]
    hybrid = NormalEstimator("hybrid", radius=RADIUS, checkpoint=args.checkpoint or None, device="cpu")
    rows: dict[str, dict[str, list]] = {}

    def add(name: str, frame, normals: np.ndarray, segment: bool) -> None:
        row = rows.setdefault(name, {"sq": [], "edge": [], "ari": [], "rec": [0, 0]})
        valid = frame.valid.reshape(-1)
        sq = squared_angles(normals, frame.normals.reshape(-1, 3))[valid]
        row["sq"].append(sq)
        row["edge"].append(sq[frame.near_edge.reshape(-1)[valid]])
        if segment:
            points = np.where(frame.valid[..., None], frame.points, np.nan)
            reference = region_segments(points, frame.normals)
            labels = region_segments(points, np.where(frame.valid[..., None], normals.reshape(points.shape), np.nan))
            row["ari"].append(adjusted_rand_index(reference, labels))
            found, count = recovered_segments(reference, labels)
            row["rec"][0] += found
            row["rec"][1] += count

    for index, frame in enumerate(fold_frames(args.frames, args.seed)):
        segment = index < 3
        points = np.where(frame.valid[..., None], frame.points, np.nan)
        start = time.perf_counter()
        survey, residual, surveyed, side, side_residual, valid_gated = survey_state(points, frame.points.shape[:2])
        print(f"frame {index}: survey and one-sided windows in {time.perf_counter() - start:.1f} s", flush=True)
        node, _ = hybrid.estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
        add("survey plane", frame, survey.numpy(), segment)
        add("hybrid (the node)", frame, node, segment)
        for ratio in ratios:
            take = (residual > ratio * side_residual) & torch.isfinite(side).all(dim=-1)
            add(
                f"survey plane, one-sided where ratio > {ratio:g}",
                frame,
                torch.where(take.unsqueeze(-1), side, survey).numpy(),
                segment,
            )
            mixed = np.where((take & surveyed).numpy()[:, None], side.numpy(), node)
            add(f"hybrid, one-sided where ratio > {ratio:g}", frame, mixed, segment)
            everywhere = np.where(take.numpy()[:, None], side.numpy(), node)
            add(f"hybrid, one-sided where ratio > {ratio:g}, gated pixels too", frame, everywhere, segment)
            gated = np.where((take & valid_gated).numpy()[:, None], side.numpy(), node)
            add(f"hybrid, one-sided where ratio > {ratio:g}, gated pixels only", frame, gated, segment)
    print("| normals | MSAE | near edges | ARI | recovered |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, row in rows.items():
        sq, edge = np.concatenate(row["sq"]), np.concatenate(row["edge"])
        found, count = row["rec"]
        print(f"| {name} | {sq.mean():.5f} | {edge.mean():.5f} | {np.mean(row['ari']):.3f} | {found} of {count} |")


if __name__ == "__main__":
    main()
