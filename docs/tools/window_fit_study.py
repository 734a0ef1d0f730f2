"""Which plane should `pca` answer from a range image's window? A study on frames eval never scores.

`pca` on an organized cloud fits each pixel's integral-image window (`range_image.image`). The window's smallest
covariance axis is PCA's normal, PCL's answer. A depth camera's and a LiDAR's noise runs along the rays, and once it
rivals the window's extent (a Kinect's centimetres at 4 m in a 5 cm ball) that axis tips toward the ray. The ray-noise
plane (`image.ray_noise_normal`: adj(C) · ray) is the plane whatever the noise along the rays, and PCA's normal on a
noise-free window. A ball search bounds the noise another way: a point displaced along its ray past the radius leaves
the ball.

Rows: the window's smallest axis, the window's ray-noise plane, the ray-noise plane of windows of at most about
256, 500 and 1000 pixels (`MomentImage.pca`'s `pixels`: the window's angular radius capped where the ball would hold
more), those windows fitted to the slope of the plane at their block's centre (`MomentImage.fitted_planes`), `pca`
on the organized cloud (the fitted windows, and where walls cut a window below a plane, PCA of the ball's points among
the pixels around it: `MomentImage.ball_pool`), and PCA over the ball (the
unorganized `pca`, the nearest 500 points in the ball), on simulated depth, fold and
LiDAR frames of seeds 100 and up, at eval's radii. MSAE (rad², sign-invariant, a missing normal scored as 90°) at 8000
valid pixels per frame, overall and near edges.

    .venv/bin/python docs/tools/window_fit_study.py [--seed 100]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.range_image.check import range_pitch
from triplet_normal_ros.core.range_image.image import MomentImage, ray_noise_normal
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.evaluation.range_eval import SETS, edge_mask
from triplet_normal_ros.simulation import range_scans

FRAMES = {"depth": 3, "fold": 6, "lidar": 3}
#: Window sizes in pixels at most (`MomentImage.pca`'s `pixels`): the default k's pool, and half and twice it.
CAPS = (256, 500, 1000)
QUERIES = 8000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=100, help="first frame seed (eval scores 0-5)")
    args = parser.parse_args()
    print("| frames | plane | MSAE | near edges |\n| --- | --- | ---: | ---: |")
    for kind, count in FRAMES.items():
        scores: dict[str, list[tuple[float, float]]] = {}
        for frame in _frames(kind, count, args.seed):
            for name, (msae, edge) in _score(kind, frame).items():
                scores.setdefault(name, []).append((msae, edge))
        for name, rows in scores.items():
            msae, edge = np.mean(rows, axis=0)
            print(f"| {kind} | {name} | {msae:.5f} | {edge:.5f} |")


def _frames(kind: str, count: int, seed: int) -> list:
    make = {"depth": range_scans.depth_frames, "fold": range_scans.fold_frames, "lidar": range_scans.lidar_scans}
    return make[kind](count, seed)


def _score(kind: str, frame) -> dict[str, tuple[float, float]]:
    """Each plane's MSAE at the frame's fixed-seed query pixels, overall and near edges."""
    spec = SETS[kind]
    shape = frame.points.shape[:2]
    points = frame.points.reshape(-1, 3).astype(np.float64)
    truth = frame.normals.reshape(-1, 3)
    query = np.sort(np.random.default_rng(0).choice(np.flatnonzero(frame.valid.reshape(-1)), QUERIES, replace=False))
    edge = edge_mask(frame, spec.radius)[query]
    cloud = torch.from_numpy(points)
    fit = MomentImage(cloud, shape, range_pitch(cloud, shape)).pca(spec.radius, spec.range_scale)
    answered = fit.valid.numpy()
    planes = {
        "window, smallest axis (PCA)": fit.normal.numpy(),
        "window, ray-noise plane": ray_noise_normal(fit).numpy(),
    }
    planes = {name: np.where(answered[:, None], normal, np.nan)[query] for name, normal in planes.items()}
    image = MomentImage(cloud, shape, range_pitch(cloud, shape))
    for pixels in CAPS:
        capped = image.pca(spec.radius, spec.range_scale, pixels)
        normal = np.where(capped.valid.numpy()[:, None], ray_noise_normal(capped).numpy(), np.nan)
        planes[f"window of at most about {pixels} pixels, ray-noise plane"] = normal[query]
    normal, _, valid = image.fitted_planes(spec.radius, spec.range_scale, CAPS[1])
    planes[f"window of at most about {CAPS[1]} pixels fitted to the slope"] = np.where(
        valid.numpy()[:, None], normal.numpy(), np.nan
    )[query]
    estimator = NormalEstimator("pca", radius=spec.radius, range_scale=spec.range_scale, device="cpu")
    planes["`pca` on the image: those fitted windows, the ball where walls cut one"] = estimator.estimate(
        points, query, shape=shape
    )[0]
    planes["ball PCA (unorganized)"] = estimator.estimate(points, query)[0]
    scores = {}
    for name, normal in planes.items():
        squared = np.nan_to_num(angles_rad(normal, truth[query]), nan=np.pi / 2) ** 2
        scores[name] = (float(squared.mean()), float(squared[edge].mean()) if edge.any() else float("nan"))
    return scores


if __name__ == "__main__":
    main()
