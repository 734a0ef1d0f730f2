"""Helpers shared by tests in several folders, importable as ``helpers`` (test/conftest.py puts test/ on sys.path).

Only test code uses these, so they live here rather than in the package. Training-related helpers come first; add
other layers' helpers in their own section. The node's estimator (`node_estimator`) needs no rclpy: `ros/params.py`
is plain data. The references the answers are checked against (plain PCA, exact normals of simulated frames) use
numpy, scipy and the simulation only.
"""

import itertools
import tracemalloc
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.model import regressor_dims
from triplet_normal_ros.core.learned.scales import candidate_count
from triplet_normal_ros.io.cloud_files import write_normals
from triplet_normal_ros.ros.params import SPECS, NodeSettings, apply
from triplet_normal_ros.simulation.range_frame import RangeFrame
from triplet_normal_ros.simulation.range_scans import depth_frames
from triplet_normal_ros.training.dataset import LabelledCloud, build_dataset

# --- training data -------------------------------------------------------------------------------------------------

#: A CAD shape of the validation catalogue: never trained on, so accuracy on it measures generalisation.
HELDOUT_SHAPE = "v_notch_block"


def multiply_adds(architecture: dict, k: int) -> int:
    """A checkpoint's multiply-adds per patch, from its stored architecture: each of the k points through the
    encoder's Linear layers, then one latent and the scale head's cues through the regressor."""
    encoder = [3, *architecture["encoder"]]
    candidates = candidate_count(architecture.get("scales", []), architecture.get("inlier_seeds", []))
    head = regressor_dims(encoder[-1], architecture["regressor"], candidates)
    return k * sum(a * b for a, b in itertools.pairwise(encoder)) + sum(a * b for a, b in itertools.pairwise(head))


def heldout_cad_cloud(n_points: int = 20_000, noise: float = 0.01, seed: int = 123) -> LabelledCloud:
    """`HELDOUT_SHAPE` with `n_points` points at `noise` × its bbox diagonal, exactly as the validation set draws it
    for dataset seed `seed`: the accuracy regression tests measure the shipped checkpoint on it."""
    clouds = build_dataset("val", n_points, seed, shapes=[HELDOUT_SHAPE], noise_levels=[noise], progress=False)
    return clouds[0]


# --- point-cloud files ---------------------------------------------------------------------------------------------


def write_points(path: str | Path, points: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Write points (and optional normals) as .xyz text (`%.6f`) or, via `write_normals`, as .npy/.ply/.pcd."""
    path = Path(path)
    if path.suffix.lower() == ".xyz":
        np.savetxt(path, np.asarray(points, dtype=np.float64), fmt="%.6f")
        return
    write_normals(path, points, np.full(np.shape(points), np.nan) if normals is None else normals)


# --- the node's estimator ------------------------------------------------------------------------------------------


def node_settings(params: Mapping[str, Any]) -> NodeSettings:
    """The settings a node started with parameter file `params` runs with: every declared default, then `params`."""
    return apply(NodeSettings(), {**{spec.name: spec.default for spec in SPECS}, **params})


def node_estimator(params: Mapping[str, Any]) -> NormalEstimator:
    """An estimator built the way the node builds its own from `params` (same method, device, neighbours, ...)."""
    return NormalEstimator(**node_settings(params).estimator_args())


# --- independent references ----------------------------------------------------------------------------------------


def ball_pca(
    points: np.ndarray,
    query: np.ndarray,
    radius: float | np.ndarray,
    k: int | None = None,
    viewpoint: Sequence[float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Plain PCA, written here without the package: for each point `points[query]`, every finite point within `radius`
    (a scalar, or one per query), or with `k` only the nearest `k` of them; their covariance, and its smallest
    eigenvector (numpy's eigh) facing `viewpoint`; curvature l0 / (l0 + l1 + l2). Fewer than three points, or a
    non-finite query, give NaN. No window, grid, gate or network: the textbook answer the node's paths approximate."""
    points = np.asarray(points, dtype=np.float64)
    finite = np.isfinite(points).all(axis=1)
    inside = points[finite]
    tree, centres = cKDTree(inside), np.nan_to_num(points[query])
    radii = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(query),))
    if k is None:
        members = tree.query_ball_point(centres, radii)
    else:
        found = np.stack([tree.query(c, k=k, distance_upper_bound=r)[1] for c, r in zip(centres, radii, strict=True)])
        members = [row[row < len(inside)] for row in found]
    covariances = np.full((len(query), 3, 3), np.nan)
    for row, (ids, ok) in enumerate(zip(members, finite[query], strict=True)):
        if ok and len(ids) >= 3:
            local = inside[ids] - inside[ids].mean(axis=0)
            covariances[row] = local.T @ local / len(ids)
    answered = np.isfinite(covariances).all(axis=(1, 2))
    normals, curvature = np.full((len(query), 3), np.nan), np.full(len(query), np.nan)
    values, vectors = np.linalg.eigh(covariances[answered])
    normals[answered] = vectors[:, :, 0]
    curvature[answered] = values[:, 0] / np.maximum(values.sum(axis=1), np.finfo(float).tiny)
    away = np.einsum("ij,ij->i", normals, np.asarray(viewpoint) - points[query]) < 0
    normals[away] *= -1
    return normals, curvature


#: Simulated depth frames (simulation.range_scans) the tests score answers on: drawn from a seed that none of eval (0),
#: the gate study (100), training (200) or its validation (300) uses, so no test scores a frame a figure came from.
FRAME_SEED = 500


def held_out_depth_frame(index: int = 0) -> RangeFrame:
    """Frame `index` of the FRAME_SEED depth frames: 640x480 Kinect-like, noisy points and exact normals (cached)."""
    return depth_frames(index + 1, seed=FRAME_SEED)[index]


def angles_deg(a: np.ndarray, b: np.ndarray, signed: bool = False) -> np.ndarray:
    """Angles between corresponding rows of unit vectors, in degrees; up to sign unless `signed`."""
    cosine = np.einsum("ij,ij->i", a, b)
    return np.degrees(np.arccos(np.clip(cosine if signed else np.abs(cosine), -1.0, 1.0)))


#: How far below zero the cosine between a normal and its ray to the viewpoint may fall for the normal still to count
#: as facing the viewpoint. The package decides the flip in float64; a message carries the points and normals in
#: float32, whose rounding (6e-8 relative per component) moves that cosine by about 2e-7 at most, so a normal nearly
#: edge-on to its ray may read as facing away by that much. A normal that faces away by more than 0.0006 degrees fails.
FACING_TOLERANCE = 1e-5


def faces_viewpoint(
    points: np.ndarray, normals: np.ndarray, viewpoint: Sequence[float] = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """Per row, whether the normal faces the viewpoint: cos(viewpoint - p, n) >= -FACING_TOLERANCE, in float64.
    A point at the viewpoint itself faces it either way."""
    rays = np.asarray(viewpoint, dtype=np.float64).reshape(1, 3) - np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    dot = np.einsum("ij,ij->i", rays, normals)
    scale = np.linalg.norm(rays, axis=1) * np.linalg.norm(normals, axis=1)
    return dot >= -FACING_TOLERANCE * scale


#: What parsing a small file or message that claims a huge size may allocate at most: far below what the claim needs.
ALLOCATION_BOUND = 1 << 20


def peak_allocation(call: Callable[[], object]) -> tuple[object, int]:
    """What ``call`` returns and the peak of the memory it held allocated at once (tracemalloc: Python objects and
    numpy arrays alike). It runs once untraced first, so that imports done on first use do not count."""
    call()
    tracemalloc.start()
    try:
        got = call()
        return got, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
