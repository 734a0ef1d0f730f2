"""One simulated organized frame, and the sensor effects every range sensor shares: noise along the ray, dropouts.

A depth camera and a spinning LiDAR differ in their rays, noise and range limits, but both return the nearest hit
along each ray, lose returns on grazing surfaces and at random, and publish an organized frame with NaN holes; that
common step lives here, and each sensor module supplies its rays, scene and noise model.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .edges import near_edges
from .raycast import Scene, cast, row_dot

GRAZING = (75.0, 88.0)  # degrees of incidence: dropout probability rises linearly from 0 to 1 between these
SPECKLE = 0.002  # fraction of otherwise valid returns lost at random (specular spots, interference)


@dataclass
class RangeFrame:
    """One organized frame in its sensor frame (viewpoint = origin).

    points (H, W, 3) float32 noisy, NaN in all three coordinates where there is no return; normals (H, W, 3) float32
    exact, unit, facing the sensor, NaN where there is no return; face (H, W) int32 id of the hit face, -1 where
    there is no return; near_edge (H, W) bool, the return lies within EDGE_RADIUS of another face (measured on the
    clean points); kind "depth" or "lidar".
    """

    name: str
    kind: str
    points: np.ndarray
    normals: np.ndarray
    face: np.ndarray
    near_edge: np.ndarray
    viewpoint: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(H, W) bool: pixels with a return."""
        return self.face >= 0


def incidence_deg(dirs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Angle in degrees between each ray and its surface normal (0: head-on, 90: grazing)."""
    cos = np.abs(row_dot(dirs, normals)) / np.sqrt(row_dot(dirs, dirs))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def dropout_probability(incidence: np.ndarray) -> np.ndarray:
    """Chance that a return is lost: 0 below GRAZING[0] degrees, rising linearly to 1 at GRAZING[1] (too little
    light comes back from grazing surfaces), plus SPECKLE everywhere."""
    ramp = np.clip((np.asarray(incidence) - GRAZING[0]) / (GRAZING[1] - GRAZING[0]), 0.0, 1.0)
    return SPECKLE + (1 - SPECKLE) * ramp


def simulate(
    name: str,
    kind: str,
    scene: Scene,
    rays: np.ndarray,
    sigma: Callable[[np.ndarray], np.ndarray],
    span: tuple[float, float],
    rng: np.random.Generator,
    shape: tuple[int, int],
) -> RangeFrame:
    """Cast, add noise N(0, sigma(t)) along each ray, drop returns; NaN where nothing comes back.

    t is both the ray parameter and what the sensor's range limits `span` apply to (depth z for the camera's z = 1
    rays, range for the LiDAR's unit rays). The edge mask is measured on the clean in-range hits, so it does not
    depend on which returns happened to drop out.
    """
    hits = cast(scene, rays)
    inside = np.isfinite(hits.t) & (hits.t >= span[0]) & (hits.t <= span[1])
    t = np.where(inside, hits.t, 0.0)
    t_noisy = t + rng.standard_normal(len(rays)) * sigma(t)
    lost = rng.random(len(rays)) < dropout_probability(incidence_deg(rays, hits.normals))
    keep = inside & ~lost & (t_noisy > 0)
    edge = near_edges(rays * t[:, None], np.where(inside, hits.face, -1)) & keep
    points = np.where(keep[:, None], rays * t_noisy[:, None], np.nan).astype(np.float32)
    normals = np.where(keep[:, None], hits.normals, np.nan).astype(np.float32)
    face = np.where(keep, hits.face, -1).astype(np.int32)
    h, w = shape
    organized = (points.reshape(h, w, 3), normals.reshape(h, w, 3), face.reshape(h, w), edge.reshape(h, w))
    return RangeFrame(name, kind, *organized, np.zeros(3, dtype=np.float32))
