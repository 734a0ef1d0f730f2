"""Analytic ray casting against planes, yawed boxes and vertical cylinders: exact hits, normals and face ids.

A simulated sensor needs the exact normal of every return and the face it came from (for the edge mask), which a
mesh ray caster would only approximate; these three solids cover floors, walls, crates and pillars, and each has a
closed-form ray intersection and signed distance. Scenes are in a z-up world frame; `cast` takes rays in the
sensor's frame and answers there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Faces per primitive kind; a scene numbers its faces 0.. in primitive order.
FACES = {"plane": 1, "box": 6, "cylinder": 3}


def _times(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """v @ m for (N, 3) rows: einsum, because a threaded BLAS call on a skinny matrix can be 50x slower."""
    return np.einsum("ij,jk->ik", v, m)


def row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
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
            t = float((np.asarray(self.point) - origin) @ n) / row_dot(dirs, n)
        t = np.where(t > 0, t, np.inf)
        return t, np.broadcast_to(n, dirs.shape), np.zeros(len(dirs), dtype=np.int32)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (positive on the normal's side)."""
        return row_dot(points - np.asarray(self.point), np.asarray(self.normal))


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
    facing = row_dot(normals, dirs) > 0
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
    along = row_dot(dirs, w)
    gap = float(w @ w) - along**2 / row_dot(dirs, dirs)  # squared distance from the centre to the ray's line
    return np.flatnonzero((gap <= radius**2 * (1 + 1e-9)) & ((along > 0) | (float(w @ w) <= radius**2)))
