"""The range checkpoint: shipped beside default and lite, selectable by name, trained by the `range` recipe, as small
as docs/MODEL.md says, and what an empty checkpoint means on a CPU's range images. Its cost is checked by arithmetic
on the stored architecture, never by timing; its accuracy on depth frames is test_node_default_accuracy.py's job.
"""

import dataclasses

import numpy as np
from helpers import multiply_adds

from triplet_normal_ros.core.config.conventions import POOL_FACTOR, checkpoint_conventions
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import (
    SHIPPED,
    read_metadata,
    resolve_checkpoint,
    shipped_checkpoint_path,
)
from triplet_normal_ros.training.recipes import RECIPES, Recipe

#: What docs/MODEL.md and docs/RESULTS.md state for the range network.
RANGE_K, RANGE_ENCODER, RANGE_REGRESSOR = 32, [32, 64, 128], [64, 32]


def test_range_is_shipped_and_resolves_by_name():
    assert "range" in SHIPPED
    path = resolve_checkpoint("range")
    assert path == shipped_checkpoint_path("range") and path.is_file()
    assert path not in (resolve_checkpoint("default"), resolve_checkpoint("lite"))


def test_range_metadata_records_the_range_recipe_and_conventions():
    meta = read_metadata(resolve_checkpoint("range"))
    recorded = {**dataclasses.asdict(Recipe()), **meta["training"]["recipe"]}
    assert recorded == dataclasses.asdict(RECIPES["range"])
    assert recorded["range_frames"] > 0  # depth frames and LiDAR scans were among its training clouds
    assert "--recipe range" in meta["training"]["command"]
    assert meta["conventions"] == checkpoint_conventions()
    assert meta["k"] == RANGE_K
    expected = {"encoder": RANGE_ENCODER, "regressor": RANGE_REGRESSOR, "residual": True}
    head = {"scales": RECIPES["range"].scales, "inlier_seeds": RECIPES["range"].inlier_seeds}
    assert meta["architecture"] == {**expected, **head}


def test_range_is_at_least_eight_times_cheaper_than_lite_per_patch():
    ranged, lite = read_metadata(resolve_checkpoint("range")), read_metadata(resolve_checkpoint("lite"))
    range_macs = multiply_adds(ranged["architecture"], ranged["k"])
    assert range_macs == 344_896  # the figure docs/MODEL.md quotes (0.69 MFLOP)
    assert 8 * range_macs <= multiply_adds(lite["architecture"], lite["k"])
    assert POOL_FACTOR * ranged["k"] == 128  # its pool, half of lite's: the searches and patches it saves


def test_range_estimator_finds_a_tilted_planes_normal_in_a_range_image():
    """End to end through the default estimator on a CPU, which picks the range checkpoint for the image: a noiseless
    tilted plane seen by a pinhole camera, every pixel away from the image border within a few degrees."""
    v, u = np.mgrid[0:60, 0:80].astype(np.float64)
    rays = np.stack(((u - 40) / 80, (v - 30) / 80, np.ones_like(u)), axis=-1).reshape(-1, 3)
    plane = np.array([0.3, 0.1, 1.0])
    points = rays / (rays @ plane)[:, None]
    estimator = NormalEstimator("learned", radius=0.05, device="cpu")
    normals, _ = estimator.estimate(points, shape=(60, 80))
    assert estimator.last_run.plan.checkpoint == "range"
    inside = ((v > 10) & (v < 50) & (u > 10) & (u < 70)).reshape(-1)
    truth = plane / np.linalg.norm(plane)
    degrees = np.degrees(np.arccos(np.clip(np.abs(normals[inside] @ truth), 0, 1)))
    assert degrees.max() < 3.0
    assert degrees.mean() < 1.5
