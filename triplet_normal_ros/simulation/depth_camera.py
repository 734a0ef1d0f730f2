"""A Kinect-v1-like depth camera: its intrinsics, range and depth noise, the rooms it looks into, and its frames.

A frame is organized 640 x 480 in the optical frame (x right, y down, z forward, the camera at the origin), with
depth noise along each ray that grows with the square of depth, as a structured-light sensor's does.
"""

from __future__ import annotations

import numpy as np

from .placement import place, stacked_boxes, standing_box
from .range_frame import RangeFrame, simulate
from .raycast import Cylinder, Plane, Primitive, Scene
from .seeds import derive_seed

#: Kinect v1 depth camera (640 x 480): focal lengths and principal point in pixels.
KINECT_FX, KINECT_FY, KINECT_CX, KINECT_CY = 525.0, 525.0, 319.5, 239.5
DEPTH_RANGE = (0.4, 5.0)  # m, depth z outside this is NaN (Kinect's working range)


def kinect_sigma(z: np.ndarray | float) -> np.ndarray:
    """Axial (along the ray) depth noise std in m of a Kinect v1 at depth z m: 0.0012 + 0.0019 (z - 0.4)^2.

    Khoshelham & Elberink (2012) show the axial error grows with the square of depth (disparity is measured, depth
    is its inverse), from a few mm at 0.5 m to about 4 cm at 5 m; these coefficients are Nguyen, Izadi & Lovell's
    (2012) fit, which gives 1.9 mm at 1 m and 4.1 cm at 5 m.
    """
    z = np.asarray(z, dtype=np.float64)
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def camera_rays(width: int = 640, height: int = 480) -> np.ndarray:
    """(H*W, 3) optical-frame rays with z = 1, so a hit's ray parameter is its depth z.

    Other sizes keep the Kinect's field of view: the focal lengths scale with the image, the principal point stays
    in the middle.
    """
    fx, fy = KINECT_FX * width / 640, KINECT_FY * height / 480
    cx, cy = KINECT_CX * (width - 1) / 639, KINECT_CY * (height - 1) / 479
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3)


def _camera_pose(height: float, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Optical axes (x right, y down, z forward) in the world for a camera at `height` looking +x, `pitch` down."""
    c, s = np.cos(pitch), np.sin(pitch)
    z_axis, x_axis = np.array([c, 0.0, -s]), np.array([0.0, -1.0, 0.0])
    return np.array([0.0, 0.0, height]), np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])


def depth_scene(seed: int) -> Scene:
    """A floor, a back wall, a few boxes, a stacked pair and one or two cylinders seen by a tilted depth camera.

    The camera stands 0.8-1.5 m above the floor looking 25-45 degrees down; objects stand 1-3.5 m ahead inside the
    horizontal field of view, so most of the frame is within the Kinect's range.
    """
    rng = np.random.default_rng(derive_seed(seed, "depth", "scene"))
    origin, rotation = _camera_pose(rng.uniform(0.8, 1.5), np.radians(rng.uniform(25, 45)))
    wall, yaw = rng.uniform(3.3, 4.0), np.radians(rng.uniform(-15, 15))
    prims: list[Primitive] = [
        Plane((0, 0, 0), (0, 0, 1)),
        Plane((wall, 0, 0), (-float(np.cos(yaw)), -float(np.sin(yaw)), 0)),
    ]
    footprints: list = []

    def spot() -> tuple[float, float]:
        x = rng.uniform(1.0, wall - 0.6)
        return x, rng.uniform(-0.5, 0.5) * x  # within +-27 degrees; the camera sees +-31

    lower = np.array([rng.uniform(0.2, 0.35), rng.uniform(0.2, 0.35), rng.uniform(0.12, 0.25)])
    if (xy := place(footprints, spot, float(np.hypot(*lower[:2])), True)) is not None:
        prims += stacked_boxes(rng, *xy, lower)
    for _ in range(rng.integers(1, 3)):
        radius, height = rng.uniform(0.06, 0.2), rng.uniform(0.3, 0.9)
        if (xy := place(footprints, spot, radius, True)) is not None:
            prims.append(Cylinder((*xy, 0.0), radius, height))
    for _ in range(rng.integers(2, 5)):  # boxes last: they fill what room the stack and the cylinders left
        half = np.array([rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.35)])
        if (xy := place(footprints, spot, float(np.hypot(*half[:2])), True)) is not None:
            prims.append(standing_box(rng, *xy, 0.0, half))
    return Scene(tuple(prims), origin, rotation)


def depth_frame(seed: int, width: int = 640, height: int = 480) -> RangeFrame:
    """One Kinect-like frame of `depth_scene(seed)`: depth noise N(0, kinect_sigma(z)) along each ray."""
    rng = np.random.default_rng(derive_seed(seed, "depth", "noise"))
    rays = camera_rays(width, height)
    return simulate(f"depth_{seed}", "depth", depth_scene(seed), rays, kinect_sigma, DEPTH_RANGE, rng, (height, width))
