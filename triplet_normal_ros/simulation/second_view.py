"""A second frame of a simulated scene, seen from a sensor moved by a known motion: the frame pairs that registration
is scored on (`evaluation/icp_eval.py`).

The motion is what a robot makes between two frames: a depth camera carried at walking pace (5 cm and 2° at a
random axis), a LiDAR on a vehicle at 3 m/s and 10 Hz (30 cm level, 2° of yaw). The second frame draws its own noise and
dropouts, so no point of it lies exactly on a point of the first, as in a real pair.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .fold_scenes import fold_frame, fold_scene
from .lidar import lidar_scan, lidar_scene
from .range_frame import RangeFrame
from .range_scans import fold_kind_and_seed, lidar_scan_seed
from .raycast import Scene
from .seeds import derive_seed

#: (translation in m, rotation in degrees) of the sensor between the two frames of a pair.
DEPTH_MOTION = (0.05, 2.0)
LIDAR_MOTION = (0.30, 2.0)


@dataclass(frozen=True)
class ViewPair:
    """Two frames of one scene and the rigid motion (4 × 4) that maps the second frame's points into the first's
    sensor frame."""

    first: RangeFrame
    second: RangeFrame
    second_to_first: np.ndarray


def fold_pair(index: int, seed: int = 0, width: int = 640, height: int = 480) -> ViewPair:
    """The fold frame `range_scans.fold_frames(n, seed)[index]` and a second frame of its scene after DEPTH_MOTION."""
    kind, scene_seed = fold_kind_and_seed(index, seed)
    rng = np.random.default_rng(derive_seed(scene_seed, "second view"))
    moved, motion = _moved(fold_scene(scene_seed, kind), DEPTH_MOTION, rng)
    first = fold_frame(scene_seed, kind, width, height)
    return ViewPair(first, fold_frame(scene_seed, kind, width, height, moved=moved), motion)


def lidar_pair(index: int, seed: int = 0, beams: int = 32, azimuth_step_deg: float = 0.2) -> ViewPair:
    """The LiDAR scan `range_scans.lidar_scans(n, seed)[index]` and a second scan of its yard after LIDAR_MOTION: a
    level step and a yaw about the vertical, as a vehicle drives and turns (the LiDAR's frame is level)."""
    scan_seed = lidar_scan_seed(index, seed)
    rng = np.random.default_rng(derive_seed(scan_seed, "second view"))
    moved, motion = _moved(lidar_scene(scan_seed), LIDAR_MOTION, rng, axis=np.array([0.0, 0.0, 1.0]), level=True)
    first = lidar_scan(scan_seed, beams, azimuth_step_deg)
    return ViewPair(first, lidar_scan(scan_seed, beams, azimuth_step_deg, moved=moved), motion)


def _moved(
    scene: Scene,
    motion: tuple[float, float],
    rng: np.random.Generator,
    axis: np.ndarray | None = None,
    level: bool = False,
) -> tuple[Scene, np.ndarray]:
    """The scene with its sensor moved by `motion` (translation along a random direction, horizontal with `level`,
    as a vehicle drives; rotation about `axis` or a random one; both in the sensor's frame), and the 4 × 4 map from the
    moved sensor's frame into the first's."""
    step, degrees = motion
    direction = rng.standard_normal(3)
    if level:
        direction[2] = 0.0
    direction = _unit(direction)
    axis = _unit(rng.standard_normal(3)) if axis is None else axis
    turn = rotation_about(axis, np.radians(degrees) * rng.choice([-1.0, 1.0]))
    second_to_first = np.eye(4)
    second_to_first[:3, :3], second_to_first[:3, 3] = turn, step * direction
    # sensor -> world is p ↦ R p + o; the moved sensor's R' = R · turn and o' = o + R · t
    moved = replace(scene, origin=scene.origin + scene.rotation @ (step * direction), rotation=scene.rotation @ turn)
    return moved, second_to_first


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """The 3 × 3 rotation by `angle` radians about the unit `axis` (Rodrigues)."""
    x, y, z = axis
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)
