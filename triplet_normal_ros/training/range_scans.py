"""Simulated range sensors: organized depth-camera frames and spinning-LiDAR scans of simple CAD scenes.

Robots see range images, not area-uniform surface samples: density falls with distance, noise grows with depth and
acts along the ray, grazing surfaces drop out and the frame is full of NaN. These frames are ray cast analytically
against planes, yawed boxes and vertical cylinders, so every pixel has the exact normal of the face it hit and the id
of that face. Points are in the sensor frame (the sensor is the origin, like a real driver's cloud); a depth frame is
in the optical frame (x right, y down, z forward), a LiDAR scan in the sensor body frame (x forward, y left, z up).
Normals face the sensor. Generation is pure numpy + scipy and seeded; `depth_frames` / `lidar_scans` cache the frames
as .npz next to the training data (see docs/RANGE_SCANS.md).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .dataset import _seed, _writable_cache, default_cache_dir

CODE_VERSION = 1  # bump when a scene, the sensor models or the edge mask change: stale cache entries are then ignored
EDGE_RADIUS = 0.05  # m, the metric evaluation radius; "near an edge" = within this of another face
#: Frame seeds of each use, so no frame is both trained and scored on: eval 0 (frames 0-2), the hybrid gate study
#: 100 (docs/tools/gate_study.py), training 200, training validation 300.
TRAIN_SEED, VAL_SEED = 200, 300
#: Kinect v1 depth camera (640 x 480): focal lengths and principal point in pixels.
KINECT_FX, KINECT_FY, KINECT_CX, KINECT_CY = 525.0, 525.0, 319.5, 239.5
DEPTH_RANGE = (0.4, 5.0)  # m, depth z outside this is NaN (Kinect's working range)
LIDAR_RANGE = (0.5, 100.0)  # m, range outside this is NaN
LIDAR_HEIGHT = 1.8  # m above the ground
LIDAR_ELEVATION = (10.0, -30.0)  # degrees, top and bottom beam (HDL-32E / VLP-32 like, evenly spaced)
GRAZING = (75.0, 88.0)  # degrees of incidence: dropout probability rises linearly from 0 to 1 between these
SPECKLE = 0.002  # fraction of otherwise valid returns lost at random (specular spots, interference)
FACES = {"plane": 1, "box": 6, "cylinder": 3}


def kinect_sigma(z: np.ndarray | float) -> np.ndarray:
    """Axial (along the ray) depth noise std in m of a Kinect v1 at depth z m: 0.0012 + 0.0019 (z - 0.4)^2.

    Khoshelham & Elberink (2012) show the axial error grows with the square of depth (disparity is measured, depth
    is its inverse), from a few mm at 0.5 m to about 4 cm at 5 m; these coefficients are Nguyen, Izadi & Lovell's
    (2012) fit, which gives 1.9 mm at 1 m and 4.1 cm at 5 m.
    """
    z = np.asarray(z, dtype=np.float64)
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


# --------------------------------------------------------------------------------------------------- primitives


def _times(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """v @ m for (N, 3) rows: einsum, because a threaded BLAS call on a skinny matrix can be 50x slower."""
    return np.einsum("ij,jk->ik", v, m)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (N, 3) rows with (N, 3) rows or one (3,) vector."""
    return np.einsum("ij,ij->i", a, np.broadcast_to(b, a.shape))


@dataclass(frozen=True)
class Plane:
    """An infinite plane through `point` with unit `normal` (floor, walls). One face."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, world normal, local face) of each ray origin + t dirs; t = inf where missed."""
        n = np.asarray(self.normal, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = float((np.asarray(self.point) - origin) @ n) / _dot(dirs, n)
        t = np.where(t > 0, t, np.inf)
        return t, np.broadcast_to(n, dirs.shape), np.zeros(len(dirs), dtype=np.int32)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (positive on the normal's side)."""
        return _dot(points - np.asarray(self.point), np.asarray(self.normal))


@dataclass(frozen=True)
class Box:
    """A solid box: centre, half extents along its own axes, yawed by `yaw` radians about world z. Six faces."""

    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float = 0.0

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Slab method in the box frame: the entry face is the axis whose slab is entered last."""
        half, rows = np.asarray(self.half), np.arange(len(dirs))
        o, d = _yawed(origin - np.asarray(self.centre), -self.yaw), _yawed(dirs, -self.yaw)
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / d, (half - o) / d
        near, far = np.minimum(t1, t2), np.maximum(t1, t2)
        axis = np.where(near[:, 0] >= near[:, 1], 0, 1)
        axis = np.where(near[:, 2] > near[rows, axis], 2, axis)
        t_in, t_out = near[rows, axis], np.minimum(np.minimum(far[:, 0], far[:, 1]), far[:, 2])
        t = np.where((t_in <= t_out) & (t_in > 0), t_in, np.inf)
        sign = -np.sign(d[rows, axis])  # the entry face's outward normal opposes the ray
        local = np.zeros_like(d)
        local[rows, axis] = sign
        return t, _yawed(local, self.yaw), (2 * axis + (sign < 0)).astype(np.int32)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        q = np.abs(_yawed(points - np.asarray(self.centre), -self.yaw)) - np.asarray(self.half)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def _yawed(v: np.ndarray, yaw: float) -> np.ndarray:
    """Vectors (N, 3) or (3,) rotated by `yaw` radians about z (cheaper than a 3 x 3 product for the boxes)."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, v[..., 2]], axis=-1)


@dataclass(frozen=True)
class Cylinder:
    """A solid vertical cylinder standing on `base` (centre of its bottom cap). Faces: side, top cap, bottom cap."""

    base: tuple[float, float, float]
    radius: float
    height: float

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest of the side (quadratic in x, y) and the two caps (planes clipped to the disc)."""
        o = origin - np.asarray(self.base)
        side = self._side(o, dirs)
        top, bottom = self._cap(o, dirs, self.height), self._cap(o, dirs, 0.0)
        t = np.stack([side, top, bottom])
        face = t.argmin(axis=0).astype(np.int32)
        best = t.min(axis=0)
        hit = o + np.where(np.isfinite(best), best, 0.0)[:, None] * dirs
        normal = np.zeros_like(dirs)
        normal[:, :2] = hit[:, :2] / self.radius
        normal[face > 0] = 0.0
        normal[face == 1, 2], normal[face == 2, 2] = 1.0, -1.0
        return best, normal, face

    def _side(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[0] * d[:, 0] + o[1] * d[:, 1]
        disc = b**2 - a * (o[0] ** 2 + o[1] ** 2 - self.radius**2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-b - np.sqrt(np.maximum(disc, 0))) / a
        z = o[2] + t * d[:, 2]
        return np.where((disc >= 0) & (a > 0) & (t > 0) & (z >= 0) & (z <= self.height), t, np.inf)

    def _cap(self, o: np.ndarray, d: np.ndarray, z: float) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z - o[2]) / d[:, 2]
            x, y = o[0] + t * d[:, 0], o[1] + t * d[:, 1]
        return np.where((t > 0) & (x**2 + y**2 <= self.radius**2), t, np.inf)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = points - np.asarray(self.base)
        radial = np.hypot(p[:, 0], p[:, 1]) - self.radius
        axial = np.abs(p[:, 2] - self.height / 2) - self.height / 2
        q = np.stack([radial, axial], axis=1)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


Primitive = Plane | Box | Cylinder


@dataclass(frozen=True)
class Scene:
    """Primitives in a z-up world frame and the sensor's pose: its position and axes (columns of `rotation`)."""

    primitives: tuple[Primitive, ...]
    origin: np.ndarray
    rotation: np.ndarray

    def face_offsets(self) -> np.ndarray:
        """First global face id of each primitive (face ids are 0.. in primitive order, FACES per kind)."""
        counts = [FACES[type(p).__name__.lower()] for p in self.primitives]
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)

    def primitive_of(self, face: np.ndarray) -> np.ndarray:
        """Index of the primitive that owns each global face id (-1 stays -1)."""
        face = np.asarray(face)
        return np.where(face >= 0, np.searchsorted(self.face_offsets(), face, side="right") - 1, -1)


@dataclass
class Hits:
    """Nearest hit per ray in the sensor frame: ray parameter t (inf: miss), unit normal facing the sensor, face id."""

    t: np.ndarray
    normals: np.ndarray
    face: np.ndarray


def cast(scene: Scene, dirs: np.ndarray) -> Hits:
    """Ray cast sensor-frame directions `dirs` (N, 3) from the sensor; t scales `dirs`, so hit = t * dirs."""
    world = _times(dirs.astype(np.float64), scene.rotation.T)
    t = np.full(len(dirs), np.inf)
    normals, face = np.zeros_like(world), np.full(len(dirs), -1, dtype=np.int32)
    for primitive, offset in zip(scene.primitives, scene.face_offsets(), strict=True):
        rows = _may_hit(primitive, scene.origin, world)
        t_p, n_p, f_p = primitive.intersect(scene.origin, world[rows])
        closer = t_p < t[rows]
        rows = rows[closer]
        t[rows], normals[rows], face[rows] = t_p[closer], n_p[closer], f_p[closer] + offset
    normals = _times(normals, scene.rotation)  # back to the sensor frame
    facing = _dot(normals, dirs) > 0
    normals[facing] *= -1  # the camera is outside every solid, so this only ever turns plane normals round
    return Hits(t, normals, face)


def _may_hit(primitive: Primitive, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Indices of the rays that pass through the primitive's bounding sphere (all rays for a plane).

    A box or cylinder covers a few percent of a frame, so testing the sphere first makes casting ~5x faster.
    """
    if isinstance(primitive, Plane):
        return np.arange(len(dirs))
    if isinstance(primitive, Box):
        centre, radius = np.asarray(primitive.centre), float(np.linalg.norm(primitive.half))
    else:
        centre = np.asarray(primitive.base) + np.array([0.0, 0.0, primitive.height / 2])
        radius = float(np.hypot(primitive.radius, primitive.height / 2))
    w = centre - origin
    along = _dot(dirs, w)
    gap = float(w @ w) - along**2 / _dot(dirs, dirs)  # squared distance from the centre to the ray's line
    return np.flatnonzero((gap <= radius**2 * (1 + 1e-9)) & ((along > 0) | (float(w @ w) <= radius**2)))


# ------------------------------------------------------------------------------------------------------ scenes


def _place(footprints: list, sample: Callable[[], tuple[float, float]], size: float, in_sight: bool = False):
    """A free (x, y) for an object of footprint radius `size`, or None after 200 tries (the scene is full).

    With `in_sight`, the object's centre must also not hide behind another object's silhouette as seen from the
    sensor's foot (0, 0), nor hide another's centre: a depth camera sees only a wedge, and a scene whose objects are
    mostly occluded would test little.
    """
    for _ in range(200):
        x, y = sample()
        if all(np.hypot(x - fx, y - fy) > size + fr + 0.05 for fx, fy, fr in footprints) and (
            not in_sight or all(_apart(x, y, size, *other) for other in footprints)
        ):
            footprints.append((x, y, size))
            return float(x), float(y)
    return None


def _apart(x: float, y: float, size: float, fx: float, fy: float, fr: float) -> bool:
    """Whether two footprints' bearings differ by more than either one's angular half-width."""
    gap = abs(np.angle(complex(x, y) / complex(fx, fy)))
    return gap > max(np.arcsin(min(1.0, size / np.hypot(x, y))), np.arcsin(min(1.0, fr / np.hypot(fx, fy))))


def _box(rng: np.random.Generator, x: float, y: float, z0: float, half: np.ndarray) -> Box:
    """A box standing at height z0 with a random yaw (plain floats, so a scene prints readably)."""
    return Box((float(x), float(y), float(z0 + half[2])), tuple(map(float, half)), rng.uniform(0, np.pi))


def _stack(rng: np.random.Generator, x: float, y: float, lower: np.ndarray) -> list[Box]:
    """A box with a smaller one on top, yawed against it and kept inside its footprint."""
    upper = lower * np.array([rng.uniform(0.5, 0.8), rng.uniform(0.5, 0.8), rng.uniform(0.6, 1.0)])
    room = max(0.0, lower[:2].min() - np.hypot(*upper[:2]))
    dx, dy = rng.uniform(-room, room, 2) if room > 0 else (0.0, 0.0)
    base = _box(rng, x, y, 0.0, lower)
    return [base, _box(rng, x + dx, y + dy, 2 * lower[2], upper)]


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
    rng = np.random.default_rng(_seed(seed, "depth", "scene"))
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
    if (xy := _place(footprints, spot, float(np.hypot(*lower[:2])), True)) is not None:
        prims += _stack(rng, *xy, lower)
    for _ in range(rng.integers(1, 3)):
        radius, height = rng.uniform(0.06, 0.2), rng.uniform(0.3, 0.9)
        if (xy := _place(footprints, spot, radius, True)) is not None:
            prims.append(Cylinder((*xy, 0.0), radius, height))
    for _ in range(rng.integers(2, 5)):  # boxes last: they fill what room the stack and the cylinders left
        half = np.array([rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.35)])
        if (xy := _place(footprints, spot, float(np.hypot(*half[:2])), True)) is not None:
            prims.append(_box(rng, *xy, 0.0, half))
    return Scene(tuple(prims), origin, rotation)


def lidar_scene(seed: int) -> Scene:
    """A yard around a LiDAR 1.8 m up: ground, 15-30 crates (some stacked) and 5-12 pillars within 3-30 m."""
    rng = np.random.default_rng(_seed(seed, "lidar", "scene"))
    prims: list[Primitive] = [Plane((0, 0, 0), (0, 0, 1))]
    footprints: list = [(0.0, 0.0, 2.0)]  # keep the robot's own spot free

    def spot() -> tuple[float, float]:
        r, phi = np.sqrt(rng.uniform(3**2, 30**2)), rng.uniform(0, 2 * np.pi)  # uniform over the annulus
        return r * np.cos(phi), r * np.sin(phi)

    for _ in range(rng.integers(15, 31)):
        half = rng.uniform(0.3, 0.8, 3)
        if (xy := _place(footprints, spot, float(np.hypot(*half[:2])))) is None:
            continue
        prims += _stack(rng, *xy, half) if rng.random() < 0.3 else [_box(rng, *xy, 0.0, half)]
    for _ in range(rng.integers(5, 13)):
        radius = rng.uniform(0.15, 0.4)
        if (xy := _place(footprints, spot, radius)) is not None:
            prims.append(Cylinder((*xy, 0.0), radius, rng.uniform(3.0, 6.0)))
    return Scene(tuple(prims), np.array([0.0, 0.0, LIDAR_HEIGHT]), np.eye(3))


# ------------------------------------------------------------------------------------------------------ sensors


def camera_rays(width: int = 640, height: int = 480) -> np.ndarray:
    """(H*W, 3) optical-frame rays with z = 1, so a hit's ray parameter is its depth z.

    Other sizes keep the Kinect's field of view: the focal lengths scale with the image, the principal point stays
    in the middle.
    """
    fx, fy = KINECT_FX * width / 640, KINECT_FY * height / 480
    cx, cy = KINECT_CX * (width - 1) / 639, KINECT_CY * (height - 1) / 479
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1).reshape(-1, 3)


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


def incidence_deg(dirs: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Angle in degrees between each ray and its surface normal (0: head-on, 90: grazing)."""
    cos = np.abs(_dot(dirs, normals)) / np.sqrt(_dot(dirs, dirs))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def dropout_probability(incidence: np.ndarray) -> np.ndarray:
    """Chance that a return is lost: 0 below GRAZING[0] degrees, rising linearly to 1 at GRAZING[1] (too little
    light comes back from grazing surfaces), plus SPECKLE everywhere."""
    ramp = np.clip((np.asarray(incidence) - GRAZING[0]) / (GRAZING[1] - GRAZING[0]), 0.0, 1.0)
    return SPECKLE + (1 - SPECKLE) * ramp


# ------------------------------------------------------------------------------------------------------- frames


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


def near_edges(points: np.ndarray, face_ids: np.ndarray, radius: float = EDGE_RADIUS) -> np.ndarray:
    """Whether each point lies closer than `radius` (m) to a point of a different face; False for invalid points.

    Exact, and symmetric (both sides of an edge are marked). Works on (N, 3) / (N,) or organized (H, W, 3) / (H, W)
    inputs; the result has the shape of `face_ids`. Only points whose voxel neighbourhood holds two faces can
    qualify (`_mixed`); among those, one KD-tree per face answers "is a point of this face within `radius`?".
    """
    flat, faces = np.asarray(points, dtype=np.float64).reshape(-1, 3), np.asarray(face_ids).reshape(-1)
    index = np.flatnonzero(np.isfinite(flat).all(axis=1) & (faces >= 0))
    index = index[_mixed(flat[index], faces[index], radius)]
    pts, fcs = flat[index], faces[index]
    marked = np.zeros(len(index), dtype=bool)
    for face in np.unique(fcs):
        own = fcs == face
        lo, hi = pts[own].min(axis=0) - radius, pts[own].max(axis=0) + radius
        candidates = np.flatnonzero(~own & ~marked & ((pts >= lo) & (pts <= hi)).all(axis=1))
        marked[candidates[_within(pts[own], pts[candidates], radius)]] = True
    out = np.zeros(len(faces), dtype=bool)
    out[index[marked]] = True
    return out.reshape(np.shape(face_ids))


def _within(surface: np.ndarray, queries: np.ndarray, radius: float) -> np.ndarray:
    """Whether each query lies closer than `radius` to some surface point; exact, but mostly on a thinned surface.

    One surface point per (radius / 5)-voxel is a subset, so being within `radius` of it settles "yes"; and every
    surface point is within a voxel diagonal of its voxel's representative, so being beyond radius + diagonal settles
    "no". Only the thin band between asks the full tree: about 3x faster than asking it everything.
    """
    if len(queries) == 0:
        return np.zeros(0, dtype=bool)
    step = radius / 5
    _, first = np.unique(_voxel_codes(surface, step)[0], return_index=True)
    slack = step * np.sqrt(3)
    coarse, _ = cKDTree(surface[first]).query(queries, distance_upper_bound=radius + slack, workers=-1)
    near = coarse < radius
    unsure = np.flatnonzero(~near & np.isfinite(coarse))
    if unsure.size:
        fine, _ = cKDTree(surface).query(queries[unsure], distance_upper_bound=radius, workers=-1)
        near[unsure] = np.isfinite(fine)
    return near


def _voxel_codes(points: np.ndarray, size: float, pad: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One int64 per point naming its `size`-voxel, and the grid's dims; `pad` spare voxels lie on every side."""
    cell = np.floor(points / size).astype(np.int64)
    cell -= cell.min(axis=0) - pad
    dims = cell.max(axis=0) + 1 + pad
    return (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2], dims


def _mixed(points: np.ndarray, faces: np.ndarray, radius: float) -> np.ndarray:
    """Points whose 3 x 3 x 3 block of `radius`-sized voxels holds more than one face.

    Two points closer than `radius` lie in neighbouring voxels, so both ends of every edge pair pass: a cheap, exact
    prefilter that leaves the KD-trees only the few percent of a frame near its edges.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    code, dims = _voxel_codes(points, radius, pad=1)  # the padding keeps the neighbours' codes on the grid
    n_faces = int(faces.max()) + 1
    occupied = _distinct(code * n_faces + faces)  # (voxel, face) pairs
    steps = np.array([-1, 0, 1])
    offsets = ((steps[:, None, None] * dims[1] + steps[None, :, None]) * dims[2] + steps[None, None, :]).ravel()
    spread = (occupied // n_faces)[:, None] + offsets[None, :]
    seen = _distinct(spread * n_faces + (occupied % n_faces)[:, None]) // n_faces  # a voxel per face seen from it
    mixed = _distinct(seen[1:][seen[1:] == seen[:-1]])  # voxels listed twice see two faces
    slot = np.minimum(np.searchsorted(mixed, code), max(len(mixed) - 1, 0))
    return mixed[slot] == code if len(mixed) else np.zeros(len(code), dtype=bool)


def _distinct(values: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an int array; a plain sort, as np.unique's hashing is slow on these voxel codes."""
    values = np.sort(values, axis=None)
    return values[np.concatenate([[True], values[1:] != values[:-1]])] if len(values) else values


def _simulate(name: str, kind: str, scene: Scene, rays: np.ndarray, sigma, span, rng, shape) -> RangeFrame:
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


def depth_frame(seed: int, width: int = 640, height: int = 480) -> RangeFrame:
    """One Kinect-like frame of `depth_scene(seed)`: depth noise N(0, kinect_sigma(z)) along each ray."""
    rng = np.random.default_rng(_seed(seed, "depth", "noise"))
    rays = camera_rays(width, height)
    return _simulate(f"depth_{seed}", "depth", depth_scene(seed), rays, kinect_sigma, DEPTH_RANGE, rng, (height, width))


def lidar_scan(seed: int, beams: int = 32, azimuth_step_deg: float = 0.2, range_sigma: float = 0.015) -> RangeFrame:
    """One spinning-LiDAR scan of `lidar_scene(seed)`, (beams, 360 / step); range noise N(0, range_sigma) m."""
    rng = np.random.default_rng(_seed(seed, "lidar", "noise"))
    rays = lidar_rays(beams, azimuth_step_deg)
    shape = (beams, len(rays) // beams)
    sigma = partial(np.full_like, fill_value=range_sigma)  # the same for every range
    return _simulate(f"lidar_{seed}", "lidar", lidar_scene(seed), rays, sigma, LIDAR_RANGE, rng, shape)


# -------------------------------------------------------------------------------------------------------- cache

_ARRAYS = ("points", "normals", "face", "near_edge", "viewpoint")


def _save_frame(path: Path, frame: RangeFrame) -> None:
    """Write atomically (temp file + rename) so a killed run never leaves a half-written cache entry."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, name=frame.name, kind=frame.kind, **{key: getattr(frame, key) for key in _ARRAYS})
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _load_frame(path: Path, shape: tuple[int, int]) -> RangeFrame | None:
    """A cached frame, or None when missing, truncated or of the wrong shape (it is then regenerated)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            frame = RangeFrame(str(data["name"]), str(data["kind"]), *(data[key] for key in _ARRAYS))
    except (OSError, ValueError, KeyError, EOFError, zlib.error):
        return None
    if frame.points.shape != (*shape, 3) or frame.face.shape != shape or frame.points.dtype != np.float32:
        return None
    return frame


def _cached_frames(kind: str, count: int, seed: int, params: dict, shape, make, cache_dir) -> list[RangeFrame]:
    """`count` frames, frame i from its own seed; each read from / written to the cache under a parameter key."""
    if count < 0:
        raise ValueError(f"count must be non-negative, got {count}")
    root = _writable_cache(Path(cache_dir) if cache_dir is not None else default_cache_dir())
    frames = []
    for i in range(count):
        frame_seed = _seed(seed, kind, i)
        blob = json.dumps([kind, params, frame_seed, EDGE_RADIUS, CODE_VERSION], sort_keys=True)
        path = root / f"{kind}-{hashlib.sha256(blob.encode()).hexdigest()[:16]}.npz" if root else None
        frame = _load_frame(path, shape) if path and path.exists() else None
        if frame is None:
            frame = make(frame_seed)
            if path:
                _save_frame(path, frame)
        frames.append(frame)
    return frames


def depth_frames(
    count: int, seed: int = 0, width: int = 640, height: int = 480, cache_dir: str | Path | None = None
) -> list[RangeFrame]:
    """`count` depth frames of different scenes, cached ($TRIPLET_NORMAL_CACHE, else ~/.cache/...)."""
    params = {"width": width, "height": height}
    make = partial(depth_frame, width=width, height=height)
    return _cached_frames("depth", count, seed, params, (height, width), make, cache_dir)


def lidar_scans(
    count: int,
    seed: int = 0,
    beams: int = 32,
    azimuth_step_deg: float = 0.2,
    range_sigma: float = 0.015,
    cache_dir: str | Path | None = None,
) -> list[RangeFrame]:
    """`count` LiDAR scans of different yards, cached like `depth_frames`."""
    params = {"beams": beams, "azimuth_step_deg": azimuth_step_deg, "range_sigma": range_sigma}
    shape = (beams, round(360.0 / azimuth_step_deg))
    make = partial(lidar_scan, beams=beams, azimuth_step_deg=azimuth_step_deg, range_sigma=range_sigma)
    return _cached_frames("lidar", count, seed, params, shape, make, cache_dir)
