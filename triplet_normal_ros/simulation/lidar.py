"""A 32-beam spinning LiDAR (HDL-32E / VLP-32 like): its beams, range and noise, the yards it scans, and its scans.

A scan is organized (beams, 360 deg / azimuth step) in the sensor body frame (x forward, y left, z up, the sensor at
the origin), row 0 the highest beam, with range noise of constant spread along each ray, as time-of-flight gives.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .placement import place, stacked_boxes, standing_box
from .range_frame import RangeFrame, simulate
from .raycast import Cylinder, Plane, Primitive, Scene
from .seeds import derive_seed

LIDAR_RANGE = (0.5, 100.0)  # m, range outside this is NaN
RANGE_SIGMA = 0.015  # m, the scans' range noise (std) unless asked for another
LIDAR_HEIGHT = 1.8  # m above the ground
LIDAR_ELEVATION = (10.0, -30.0)  # degrees, top and bottom beam (HDL-32E / VLP-32 like, evenly spaced)


def lidar_elevations(beams: int = 32) -> np.ndarray:
    """Beam elevation angles in degrees, row 0 the highest (an organized scan reads top to bottom like an image)."""
    return np.linspace(*LIDAR_ELEVATION, beams)


def lidar_rays(beams: int = 32, azimuth_step_deg: float = 0.2) -> np.ndarray:
    """(beams * columns, 3) unit rays; column j looks at azimuth -j * step (clockwise from +x, as the head spins)."""
    columns = round(360.0 / azimuth_step_deg)
    elevation = np.radians(lidar_elevations(beams))[:, None]
    azimuth = -np.radians(np.arange(columns) * azimuth_step_deg)[None, :]
    ce = np.cos(elevation)
    rays = np.stack(np.broadcast_arrays(ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)), axis=-1)
    return rays.reshape(-1, 3)


def lidar_scene(seed: int) -> Scene:
    """A yard around a LiDAR 1.8 m up: ground, 15-30 crates (some stacked) and 5-12 pillars within 3-30 m."""
    rng = np.random.default_rng(derive_seed(seed, "lidar", "scene"))
    prims: list[Primitive] = [Plane((0, 0, 0), (0, 0, 1))]
    footprints: list = [(0.0, 0.0, 2.0)]  # keep the robot's own spot free

    def spot() -> tuple[float, float]:
        r, phi = np.sqrt(rng.uniform(3**2, 30**2)), rng.uniform(0, 2 * np.pi)  # uniform over the annulus
        return r * np.cos(phi), r * np.sin(phi)

    for _ in range(rng.integers(15, 31)):
        half = rng.uniform(0.3, 0.8, 3)
        if (xy := place(footprints, spot, float(np.hypot(*half[:2])))) is None:
            continue
        prims += stacked_boxes(rng, *xy, half) if rng.random() < 0.3 else [standing_box(rng, *xy, 0.0, half)]
    for _ in range(rng.integers(5, 13)):
        radius = rng.uniform(0.15, 0.4)
        if (xy := place(footprints, spot, radius)) is not None:
            prims.append(Cylinder((*xy, 0.0), radius, rng.uniform(3.0, 6.0)))
    return Scene(tuple(prims), np.array([0.0, 0.0, LIDAR_HEIGHT]), np.eye(3))


def lidar_scan(
    seed: int,
    beams: int = 32,
    azimuth_step_deg: float = 0.2,
    range_sigma: float = RANGE_SIGMA,
    *,
    moved: Scene | None = None,
) -> RangeFrame:
    """One spinning-LiDAR scan of `lidar_scene(seed)`, (beams, 360 / step); range noise N(0, range_sigma) m; with
    `moved` (that yard seen by a moved sensor: `second_view`), the second scan of a pair, which draws noise of its
    own."""
    view = ("second view",) if moved is not None else ()
    rng = np.random.default_rng(derive_seed(seed, "lidar", *view, "noise"))
    rays = lidar_rays(beams, azimuth_step_deg)
    shape = (beams, len(rays) // beams)
    sigma = partial(np.full_like, fill_value=range_sigma)  # the same for every range
    scene = lidar_scene(seed) if moved is None else moved
    name = f"lidar_{seed}" + ("_moved" if view else "")
    return simulate(name, "lidar", scene, rays, sigma, LIDAR_RANGE, rng, shape)
