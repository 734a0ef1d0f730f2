"""Close-range scenes full of folds, seen by the Kinect-like depth camera: where two faces meet with no range jump.

The rooms of `depth_camera` put their objects 1-3.5 m away, where a frame's error is mostly far-range noise. A robot
arm's camera, a mobile base docking or a scanner walking a shelf sees things from 0.5-3 m, where most of what is hard
is a fold: a box standing on the floor, a stair's nosing, a room's corner, a table's edge, a shelf board against its
side, a cylinder on the ground. A window of pixels seen at a grazing angle reaches across such a fold although the
range is continuous there, so these frames are where a survey that bleeds shows it.

Six kinds, in this order (frame i of a set is kind i mod 6): boxes, stairs, corner, table, shelf, cylinders. Each
scene draws its sizes and poses from its own seed; `range_scans.fold_frames` caches the frames like the others.
"""

from __future__ import annotations

import numpy as np

from .depth_camera import DEPTH_RANGE, _camera_pose, camera_rays, kinect_sigma
from .placement import place, standing_box
from .range_frame import RangeFrame, simulate
from .raycast import Box, Cylinder, Plane, Primitive, Scene
from .seeds import derive_seed

KINDS = ("boxes", "stairs", "corner", "table", "shelf", "cylinders")


def _floor() -> Plane:
    return Plane((0, 0, 0), (0, 0, 1))


def _boxes(rng: np.random.Generator) -> list[Primitive]:
    """Two to four boxes standing 0.6-2 m ahead: box-floor folds and box edges, some seen at grazing angles."""
    prims: list[Primitive] = [_floor()]
    footprints: list = []
    for _ in range(rng.integers(2, 5)):
        half = rng.uniform((0.08, 0.08, 0.06), (0.25, 0.25, 0.3))

        def spot() -> tuple[float, float]:
            x = rng.uniform(0.6, 2.0)
            return x, rng.uniform(-0.45, 0.45) * x

        if (xy := place(footprints, spot, float(np.hypot(*half[:2])), True)) is not None:
            prims.append(standing_box(rng, *xy, 0.0, half))
    return prims


def _stairs(rng: np.random.Generator) -> list[Primitive]:
    """A flight of 3-6 steps rising away from the camera: treads and risers fold at every nosing and foot."""
    start, tread, riser = rng.uniform(0.7, 1.4), rng.uniform(0.25, 0.32), rng.uniform(0.15, 0.19)
    width, yaw = rng.uniform(0.8, 1.4), rng.uniform(-0.35, 0.35)
    c, s = np.cos(yaw), np.sin(yaw)
    prims: list[Primitive] = [_floor()]
    for step in range(int(rng.integers(3, 7))):
        along = start + (step + 0.5) * tread
        height = (step + 1) * riser
        centre = (float(c * along), float(s * along), float(height / 2))
        prims.append(Box(centre, (float(tread / 2), float(width / 2), float(height / 2)), float(yaw)))
    return prims


def _corner(rng: np.random.Generator) -> list[Primitive]:
    """A room corner 1.2-2.5 m ahead: floor and two walls fold at three edges that meet, with a box in the corner."""
    distance, turn = rng.uniform(1.2, 2.5), rng.uniform(-0.4, 0.4)
    corner = np.array([distance * np.cos(turn), distance * np.sin(turn), 0.0])
    bearing = turn + np.pi  # the walls open towards the camera
    prims: list[Primitive] = [_floor()]
    for side in (-1, 1):
        angle = bearing + side * np.pi / 4
        normal = (float(np.sin(angle) * side), float(-np.cos(angle) * side), 0.0)  # into the room
        prims.append(Plane(tuple(map(float, corner)), normal))
    half = rng.uniform((0.1, 0.1, 0.1), (0.2, 0.2, 0.3))
    inset = corner + 0.8 * (np.hypot(*half[:2]) + 0.05) * np.array([np.cos(bearing), np.sin(bearing), 0.0])
    prims.append(Box((float(inset[0]), float(inset[1]), float(half[2])), tuple(map(float, half)), float(turn)))
    return prims


def _table(rng: np.random.Generator) -> list[Primitive]:
    """A table 1-2 m ahead, its top 0.45-0.75 m high on four legs, with a box on it: top-edge and leg-floor folds."""
    x, y, yaw = rng.uniform(1.0, 2.0), rng.uniform(-0.3, 0.3), rng.uniform(-0.5, 0.5)
    top_half = rng.uniform((0.3, 0.25, 0.012), (0.6, 0.45, 0.025))
    height, leg = rng.uniform(0.45, 0.75), rng.uniform(0.02, 0.035)
    c, s = np.cos(yaw), np.sin(yaw)
    prims: list[Primitive] = [_floor(), Box((x, y, float(height - top_half[2])), tuple(map(float, top_half)), yaw)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            lx, ly = sx * (top_half[0] - 2 * leg), sy * (top_half[1] - 2 * leg)
            centre = (float(x + c * lx - s * ly), float(y + s * lx + c * ly), float((height - 2 * top_half[2]) / 2))
            prims.append(Box(centre, (leg, leg, float((height - 2 * top_half[2]) / 2)), yaw))
    box = rng.uniform((0.06, 0.06, 0.05), (0.15, 0.12, 0.15))
    prims.append(standing_box(rng, x, y, float(height), box))
    return prims


def _shelf(rng: np.random.Generator) -> list[Primitive]:
    """A shelf unit 1-2 m ahead against a wall: sides, 3-4 boards and boxes on them, all meeting at right angles."""
    x, yaw = rng.uniform(1.0, 2.0), rng.uniform(-0.3, 0.3)
    depth, width, board = rng.uniform(0.25, 0.4), rng.uniform(0.7, 1.2), rng.uniform(0.012, 0.02)
    levels = int(rng.integers(3, 5))
    gap = rng.uniform(0.3, 0.4)
    tall = levels * gap
    c, s = np.cos(yaw), np.sin(yaw)

    def at(along: float, across: float, z: float) -> tuple[float, float, float]:
        return float(c * along - s * across), float(s * along + c * across), float(z)

    prims: list[Primitive] = [_floor(), Plane(at(x + depth / 2, 0, 0), (float(-c), float(-s), 0.0))]
    for side in (-1, 1):
        prims.append(Box(at(x, side * (width / 2 + board), tall / 2), (depth / 2, board, tall / 2), float(yaw)))
    for level in range(levels):
        z = level * gap + board
        prims.append(Box(at(x, 0, z), (depth / 2, width / 2, board), float(yaw)))
        if rng.random() < 0.7:
            half = rng.uniform((0.05, 0.05, 0.04), (min(0.12, depth / 2 - 0.02), 0.15, min(0.12, gap / 2 - 0.02)))
            across = rng.uniform(-width / 2 + half[1], width / 2 - half[1])
            prims.append(Box(at(x, across, z + board + half[2]), tuple(map(float, half)), float(yaw)))
    return prims


def _cylinders(rng: np.random.Generator) -> list[Primitive]:
    """Two to four cylinders and a box 0.6-2 m ahead: curved sides folding into the floor and into flat caps."""
    prims: list[Primitive] = [_floor()]
    footprints: list = []

    def spot() -> tuple[float, float]:
        x = rng.uniform(0.6, 2.0)
        return x, rng.uniform(-0.45, 0.45) * x

    for _ in range(rng.integers(2, 5)):
        radius, height = rng.uniform(0.04, 0.18), rng.uniform(0.1, 0.6)
        if (xy := place(footprints, spot, radius, True)) is not None:
            prims.append(Cylinder((*xy, 0.0), radius, height))
    half = rng.uniform((0.08, 0.08, 0.06), (0.2, 0.2, 0.2))
    if (xy := place(footprints, spot, float(np.hypot(*half[:2])), True)) is not None:
        prims.append(standing_box(rng, *xy, 0.0, half))
    return prims


_BUILDERS = {
    "boxes": _boxes,
    "stairs": _stairs,
    "corner": _corner,
    "table": _table,
    "shelf": _shelf,
    "cylinders": _cylinders,
}


#: Degrees the camera looks down, per kind: steeply at what stands on the floor, level at walls and shelves.
_PITCH = {
    "boxes": (20, 45),
    "stairs": (10, 30),
    "corner": (5, 25),
    "table": (20, 40),
    "shelf": (5, 20),
    "cylinders": (20, 45),
}


def fold_scene(seed: int, kind: str) -> Scene:
    """One scene of `kind`, with the camera 0.5-1.3 m above the floor, looking down by `_PITCH[kind]` degrees."""
    if kind not in _BUILDERS:
        raise ValueError(f"unknown fold scene kind {kind!r}; expected one of {', '.join(KINDS)}")
    rng = np.random.default_rng(derive_seed(seed, "fold", kind, "scene"))
    low, high = _PITCH[kind]
    origin, rotation = _camera_pose(rng.uniform(0.5, 1.3), np.radians(rng.uniform(low, high)))
    return Scene(tuple(_BUILDERS[kind](rng)), origin, rotation)


def fold_frame(seed: int, kind: str, width: int = 640, height: int = 480, *, moved: Scene | None = None) -> RangeFrame:
    """One Kinect-like frame of `fold_scene(seed, kind)`, with the depth camera's noise and dropouts; with `moved` (that
    scene seen by a moved camera: `second_view`), the second frame of a pair, which draws noise of its own."""
    view = ("second view",) if moved is not None else ()
    rng = np.random.default_rng(derive_seed(seed, "fold", kind, *view, "noise"))
    rays = camera_rays(width, height)
    scene = fold_scene(seed, kind) if moved is None else moved
    name = f"fold_{kind}_{seed}" + ("_moved" if view else "")
    return simulate(name, "depth", scene, rays, kinect_sigma, DEPTH_RANGE, rng, (height, width))
