"""Point-to-plane ICP, the registration that reads a target cloud's normals (Chen & Medioni 1992; Open3D's
`TransformationEstimationPointToPlane`, PCL's `IterativeClosestPointWithNormals`), for `eval --sets icp`.

Each iteration pairs every source point with its nearest target point within `max_distance` that has a normal, and
takes the Gauss-Newton step of the small-angle linearisation of Σ (n · (R p + t - q))². Normals enter only through
the target's planes, so an estimator's error moves the registration where its planes tip: at edges, and on every
plane when they scatter.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..simulation.second_view import rotation_about

#: Iterations of one registration, and the step (rad and m) below which it has converged.
ITERATIONS = 40
CONVERGED = 1e-7
#: Fewer pairs than this cannot fix six degrees of freedom with any margin: the registration stops where it is.
MIN_PAIRS = 12
#: Singular values of the normal equations below this share of the largest count as a free motion (no step along it).
FREE = 1e-9


class TargetPlanes:
    """A target cloud's points with a finite normal, and the KD-tree over them that pairs source points with them."""

    def __init__(self, points: np.ndarray, normals: np.ndarray) -> None:
        keep = np.isfinite(points).all(axis=1) & np.isfinite(normals).all(axis=1)
        self.points = np.asarray(points[keep], dtype=np.float64)
        self.normals = np.asarray(normals[keep], dtype=np.float64)
        self.tree = cKDTree(self.points) if len(self.points) else None


def point_to_plane_icp(
    source: np.ndarray, target: TargetPlanes, start: np.ndarray, max_distance: float, iterations: int = ITERATIONS
) -> np.ndarray:
    """The 4 × 4 rigid motion that maps the (N, 3) `source` onto `target`'s planes, refined from `start`."""
    motion = np.array(start, dtype=np.float64)
    source = np.asarray(source, dtype=np.float64)
    if target.tree is None:
        return motion
    for _ in range(iterations):
        moved = source @ motion[:3, :3].T + motion[:3, 3]
        distance, nearest = target.tree.query(moved, distance_upper_bound=max_distance)
        paired = np.isfinite(distance)
        if np.count_nonzero(paired) < MIN_PAIRS:
            break
        step = _gauss_newton_step(moved[paired], target.points[nearest[paired]], target.normals[nearest[paired]])
        motion = _increment(step) @ motion
        if np.abs(step).max() < CONVERGED:
            break
    return motion


def _gauss_newton_step(p: np.ndarray, q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(rotation vector, translation) minimising Σ (n · (p + ω × p + t - q))². Where the pairs leave a motion free
    (every plane parallel to a slide, as on stairs or a corridor with exact normals), the step has no part along it:
    the least-squares solution of least norm, singular values below FREE of the largest taken as zero."""
    jacobian = np.hstack([np.cross(p, n), n])
    residual = np.einsum("ij,ij->i", p - q, n)
    return np.linalg.lstsq(jacobian.T @ jacobian, -jacobian.T @ residual, rcond=FREE)[0]


def _increment(step: np.ndarray) -> np.ndarray:
    """The 4 × 4 motion of a (rotation vector, translation) step."""
    angle = float(np.linalg.norm(step[:3]))
    out = np.eye(4)
    if angle > 0:
        out[:3, :3] = rotation_about(step[:3] / angle, angle)
    out[:3, 3] = step[3:]
    return out


def motion_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in m) of a 4 × 4 estimate against the true motion."""
    turn = estimate[:3, :3] @ truth[:3, :3].T
    cos = np.clip((np.trace(turn) - 1) / 2, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))


def perturbed_starts(truth: np.ndarray, count: int, degrees: float, metres: float, seed: int) -> list[np.ndarray]:
    """`count` starts around the true motion: each off by a rotation of up to `degrees` about a random axis and a
    translation of up to `metres` in a random direction (uniform in both), as an odometry prior would be."""
    rng = np.random.default_rng(seed)
    starts = []
    for _ in range(count):
        axis, direction = (v / np.linalg.norm(v) for v in rng.standard_normal((2, 3)))
        error = np.eye(4)
        error[:3, :3] = rotation_about(axis, np.radians(rng.uniform(0, degrees)))
        error[:3, 3] = direction * rng.uniform(0, metres)
        starts.append(error @ truth)
    return starts
