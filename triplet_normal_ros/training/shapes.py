"""Procedural shape catalogue for training and validation: CAD solids and analytic smooth surfaces.

CAD solids are built with manifold3d CSG, so every triangle lies on a true face of the solid and its plane normal is
the exact ground truth (round parts are 256-gon facets: at most 0.7° from the ideal cylinder, and exact for the mesh).
Smooth shapes are analytic surfaces: a high-resolution mesh only sets the area weights for sampling; each sample is
then snapped onto the exact surface and its normal is the normalised gradient of the implicit function, so the
ground truth is the true surface normal, not a facet normal.

The validation catalogue uses other parameters and compositions than the training one, and no shape reproduces a
PCPNet shape (no unit cube, fandisk, bunny, armadillo): PCPNet stays evaluation-only.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import manifold3d
import numpy as np
import trimesh

SEGMENTS = 256  # facets per full circle of a CAD round part; 180°/256 = 0.7° worst deviation from the true cylinder
ICOSPHERE_SUBDIVISIONS = 6  # 81,920 triangles: area weights for the star-shaped smooth surfaces
TORUS_SECTIONS = (384, 192)

Manifold = manifold3d.Manifold


class Surface(Protocol):
    """An analytic smooth surface: a mesh for area weights, and exact points and normals."""

    def mesh(self) -> trimesh.Trimesh: ...

    def snap(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map points on (or near) the mesh onto the exact surface; return (points, unit outward normals)."""
        ...

    def implicit(self, points: np.ndarray) -> np.ndarray:
        """A signed function that is zero exactly on the surface (for tests)."""
        ...


@dataclass(frozen=True)
class ShapeSpec:
    """One catalogue entry. `params` is a sorted tuple of (key, value) so the spec is hashable and cache-keyable."""

    name: str
    kind: str  # 'cad' | 'smooth'
    builder: str
    params: tuple[tuple[str, Any], ...]

    @property
    def param_dict(self) -> dict[str, Any]:
        return dict(self.params)

    def mesh(self) -> trimesh.Trimesh:
        """The watertight triangle mesh (cached per spec)."""
        return _mesh(self)

    def surface(self) -> Surface | None:
        """The analytic surface of a smooth shape; None for CAD shapes, whose mesh is exact."""
        return _surface(self) if self.kind == "smooth" else None


def _spec(name: str, kind: str, builder: str, **params: Any) -> ShapeSpec:
    return ShapeSpec(name, kind, builder, tuple(sorted(params.items())))


# ----------------------------------------------------------------------------------------------------- CAD solids


def _box(size: tuple[float, float, float]) -> Manifold:
    return Manifold.cube(size, True)


def _hull(points: Iterable[Iterable[float]]) -> Manifold:
    return Manifold.hull_points(np.asarray(points, dtype=np.float64))


def cad_box(size: tuple[float, float, float]) -> Manifold:
    return _box(size)


def cad_wedge(length: float, width: float, height: float) -> Manifold:
    """A ramp: right-triangle cross-section extruded along z."""
    section = manifold3d.CrossSection([np.array([[0.0, 0.0], [width, 0.0], [0.0, height]])])
    return Manifold.extrude(section, length)


def cad_pyramid(base: tuple[float, float], height: float, apex_offset: tuple[float, float] = (0.0, 0.0)) -> Manifold:
    bx, by = base[0] / 2, base[1] / 2
    return _hull([(-bx, -by, 0), (bx, -by, 0), (bx, by, 0), (-bx, by, 0), (*apex_offset, height)])


def cad_hull(points: tuple[tuple[float, float, float], ...]) -> Manifold:
    """Convex hull of a few points: irregular tetrahedra, octahedra."""
    return _hull(points)


def cad_prism(sides: int, radius: float, height: float) -> Manifold:
    angles = 2 * np.pi * np.arange(sides) / sides
    polygon = np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)
    return Manifold.extrude(manifold3d.CrossSection([polygon]), height)


def cad_frustum(radius_low: float, radius_high: float, height: float) -> Manifold:
    """Cylinder when the radii match, cone frustum otherwise."""
    return Manifold.cylinder(height, radius_low, radius_high, SEGMENTS, True)


def cad_groove_box(size: tuple[float, float, float], groove: tuple[float, float]) -> Manifold:
    """A block with a rectangular groove (width, depth) cut along x across its top face."""
    sx, _, sz = size
    width, depth = groove
    cutter = _box((sx + 1.0, width, 2 * depth)).translate((0.0, 0.0, sz / 2))
    return _box(size) - cutter


def cad_stepped_block(steps: int, run: float, rise: float, depth: float) -> Manifold:
    """A staircase: `steps` boxes of growing height side by side (convex and concave edges)."""
    blocks = [_box((run, depth, rise * (i + 1))).translate((run * i, 0.0, rise * (i + 1) / 2)) for i in range(steps)]
    return Manifold.batch_boolean(blocks, manifold3d.OpType.Add)


def cad_l_bracket(leg: float, thickness: float, width: float, height: float) -> Manifold:
    base = _box((leg, width, thickness)).translate((leg / 2, 0.0, thickness / 2))
    wall = _box((thickness, width, height)).translate((thickness / 2, 0.0, height / 2))
    return base + wall


def cad_box_hole(size: tuple[float, float, float], radius: float, axis: str) -> Manifold:
    """A block minus a through cylinder along `axis` (concave round surface meeting flat faces)."""
    drill = Manifold.cylinder(2 * max(size) + 1.0, radius, -1.0, SEGMENTS, True)
    drill = {"x": drill.rotate((0.0, 90.0, 0.0)), "y": drill.rotate((90.0, 0.0, 0.0)), "z": drill}[axis]
    return _box(size) - drill


def cad_cross(arms: tuple[float, float, float], thickness: float) -> Manifold:
    """Three orthogonal bars of different lengths: a 3-D plus sign with many concave corners."""
    ax, ay, az = arms
    bars = [_box((ax, thickness, thickness)), _box((thickness, ay, thickness)), _box((thickness, thickness, az))]
    return Manifold.batch_boolean(bars, manifold3d.OpType.Add)


def cad_v_notch(size: tuple[float, float, float], notch: float, step: tuple[float, float]) -> Manifold:
    """A block with a 90° V-groove along x on top and a rectangular step cut off one end."""
    sx, sy, sz = size
    vee = _box((sx + 1.0, notch, notch)).rotate((45.0, 0.0, 0.0)).translate((0.0, 0.0, sz / 2))
    step_cut = _box((step[0] * 2, sy + 1.0, step[1] * 2)).translate((sx / 2, 0.0, sz / 2))
    return _box(size) - vee - step_cut


def cad_boss_plate(plate: tuple[float, float, float], boss_radius: float, boss_height: float) -> Manifold:
    """A plate with a cylindrical boss on top (convex round rim, concave circular seam)."""
    boss = Manifold.cylinder(boss_height, boss_radius, -1.0, SEGMENTS, False).translate((0.0, 0.0, plate[2] / 2))
    return _box(plate) + boss


def cad_slotted_frame(size: tuple[float, float, float], window: tuple[float, float], slot: float) -> Manifold:
    """A thick frame: block minus a through window along z, minus a slot along y through one side."""
    sx, sy, sz = size
    opening = _box((window[0], window[1], sz + 1.0))
    cut = _box((slot, sy + 1.0, sz / 2)).translate((sx / 4, 0.0, sz / 4))
    return _box(size) - opening - cut


# ------------------------------------------------------------------------------------------------ smooth surfaces


@functools.lru_cache(maxsize=1)
def _unit_icosphere() -> tuple[np.ndarray, np.ndarray]:
    sphere = trimesh.creation.icosphere(ICOSPHERE_SUBDIVISIONS)
    return np.asarray(sphere.vertices, dtype=np.float64), np.asarray(sphere.faces, dtype=np.int64)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class StarSurface:
    """A surface r(d)·d over unit directions d, with implicit F(x) = 0; star-shaped around the origin."""

    def radius(self, d: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def gradient(self, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def implicit(self, points: np.ndarray) -> np.ndarray:
        """Signed radial distance: |x| - r(x/|x|)."""
        norm = np.linalg.norm(points, axis=1)
        return norm - self.radius(points / norm[:, None])

    def mesh(self) -> trimesh.Trimesh:
        directions, faces = _unit_icosphere()
        return trimesh.Trimesh(self.radius(directions)[:, None] * directions, faces, process=False)

    def snap(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = _unit(points)
        on_surface = self.radius(d)[:, None] * d
        return on_surface, _unit(self.gradient(on_surface))


@dataclass(frozen=True)
class SuperEllipsoid(StarSurface):
    """(|x/a|^(2/e2) + |y/b|^(2/e2))^(e2/e1) + |z/c|^(2/e1) = 1; e ≤ 1 keeps it C², e = 1 is an ellipsoid."""

    axes: tuple[float, float, float]
    e1: float
    e2: float

    def _level(self, p: np.ndarray) -> np.ndarray:
        q = np.abs(p) / np.asarray(self.axes)
        return (q[:, 0] ** (2 / self.e2) + q[:, 1] ** (2 / self.e2)) ** (self.e2 / self.e1) + q[:, 2] ** (2 / self.e1)

    def radius(self, d: np.ndarray) -> np.ndarray:
        # The level function is homogeneous of degree 2/e1, so the ray t·d meets the surface at t = level(d)^(-e1/2).
        return self._level(d) ** (-self.e1 / 2)

    def gradient(self, p: np.ndarray) -> np.ndarray:
        axes = np.asarray(self.axes)
        q = np.abs(p) / axes
        s = np.maximum(q[:, 0] ** (2 / self.e2) + q[:, 1] ** (2 / self.e2), 1e-300)
        outer = s ** (self.e2 / self.e1 - 1)
        gx = outer * q[:, 0] ** (2 / self.e2 - 1)
        gy = outer * q[:, 1] ** (2 / self.e2 - 1)
        gz = q[:, 2] ** (2 / self.e1 - 1)
        return (2 / self.e1) * np.sign(p) * np.stack([gx, gy, gz], axis=1) / axes


@dataclass(frozen=True)
class Blob(StarSurface):
    """A sphere smoothly displaced by a few sinusoids of the direction: r(d) = R (1 + Σ a sin(ω·d + φ))."""

    base_radius: float
    freqs: tuple[tuple[float, float, float], ...]
    phases: tuple[float, ...]
    amps: tuple[float, ...]

    def radius(self, d: np.ndarray) -> np.ndarray:
        arg = d @ np.asarray(self.freqs).T + np.asarray(self.phases)
        return self.base_radius * (1 + np.sin(arg) @ np.asarray(self.amps))

    def gradient(self, p: np.ndarray) -> np.ndarray:
        # F(x) = |x| - r(x/|x|)  =>  ∇F = d - (I - d dᵀ) ∇r(d) / |x|
        norm = np.linalg.norm(p, axis=1, keepdims=True)
        d = p / norm
        freqs = np.asarray(self.freqs)
        grad_r = self.base_radius * (np.cos(d @ freqs.T + np.asarray(self.phases)) * np.asarray(self.amps)) @ freqs
        tangential = grad_r - np.sum(grad_r * d, axis=1, keepdims=True) * d
        return d - tangential / norm


@dataclass(frozen=True)
class Capsule(StarSurface):
    """Points at distance `radius` from the z segment [-half_length, half_length] (C¹ where cap meets side)."""

    radius_: float
    half_length: float

    def radius(self, d: np.ndarray) -> np.ndarray:
        rho = np.hypot(d[:, 0], d[:, 1])
        dc = np.abs(d[:, 2]) * self.half_length
        with np.errstate(divide="ignore", invalid="ignore"):  # the unused branch may be inf / NaN
            t_side = self.radius_ / rho
            t_cap = dc + np.sqrt(dc**2 - self.half_length**2 + self.radius_**2)
        on_side = np.abs(t_side * d[:, 2]) <= self.half_length
        return np.where(on_side & (rho > 0), t_side, t_cap)

    def gradient(self, p: np.ndarray) -> np.ndarray:
        axis_point = np.zeros_like(p)
        axis_point[:, 2] = np.clip(p[:, 2], -self.half_length, self.half_length)
        return p - axis_point


@dataclass(frozen=True)
class Torus:
    """Ring torus around z; the closest point on it is closed-form, so snapping is an exact projection."""

    major: float
    minor: float

    def mesh(self) -> trimesh.Trimesh:
        major_sections, minor_sections = TORUS_SECTIONS
        return trimesh.creation.torus(self.major, self.minor, major_sections, minor_sections)

    def _tube_offset(self, points: np.ndarray) -> np.ndarray:
        ring = points.copy()
        ring[:, 2] = 0.0
        ring = self.major * _unit(ring)
        return points - ring

    def implicit(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(self._tube_offset(points), axis=1) - self.minor

    def snap(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        offset = self._tube_offset(points)
        normals = _unit(offset)
        return points - offset + self.minor * normals, normals


def smooth_superellipsoid(axes: tuple[float, float, float], e1: float, e2: float) -> Surface:
    return SuperEllipsoid(tuple(axes), e1, e2)


def smooth_blob(radius: float, terms: int, amplitude: float, max_freq: float, seed: int) -> Surface:
    """Random but seeded displacement; amplitude·terms < 1 keeps r > 0, so the surface stays embedded."""
    rng = np.random.default_rng(seed)
    freqs = _unit(rng.normal(size=(terms, 3))) * rng.uniform(1.0, max_freq, size=(terms, 1))
    phases = rng.uniform(0, 2 * np.pi, size=terms)
    amps = amplitude * rng.uniform(0.5, 1.0, size=terms)
    as_tuple = tuple(tuple(float(v) for v in row) for row in freqs)
    return Blob(radius, as_tuple, tuple(float(v) for v in phases), tuple(float(v) for v in amps))


def smooth_capsule(radius: float, half_length: float) -> Surface:
    return Capsule(radius, half_length)


def smooth_torus(major: float, minor: float) -> Surface:
    return Torus(major, minor)


# ------------------------------------------------------------------------------------------------------ catalogue

CAD_BUILDERS: dict[str, Callable[..., Manifold]] = {
    "box": cad_box,
    "wedge": cad_wedge,
    "pyramid": cad_pyramid,
    "hull": cad_hull,
    "prism": cad_prism,
    "frustum": cad_frustum,
    "groove_box": cad_groove_box,
    "stepped_block": cad_stepped_block,
    "l_bracket": cad_l_bracket,
    "box_hole": cad_box_hole,
    "cross": cad_cross,
    "v_notch": cad_v_notch,
    "boss_plate": cad_boss_plate,
    "slotted_frame": cad_slotted_frame,
}

SMOOTH_BUILDERS: dict[str, Callable[..., Surface]] = {
    "superellipsoid": smooth_superellipsoid,
    "blob": smooth_blob,
    "capsule": smooth_capsule,
    "torus": smooth_torus,
}

TRAIN_SHAPES: tuple[ShapeSpec, ...] = (
    _spec("box_3x2x1", "cad", "box", size=(3.0, 2.0, 1.0)),
    _spec("wedge", "cad", "wedge", length=2.0, width=1.6, height=0.9),
    _spec("pyramid", "cad", "pyramid", base=(2.0, 1.5), height=1.3, apex_offset=(0.2, 0.0)),
    _spec("tetrahedron", "cad", "hull", points=((0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (0.6, 1.7, 0.0), (0.8, 0.6, 1.5))),
    _spec("hex_prism", "cad", "prism", sides=6, radius=0.8, height=1.4),
    _spec("cylinder", "cad", "frustum", radius_low=0.6, radius_high=0.6, height=1.7),
    _spec("groove_box", "cad", "groove_box", size=(2.4, 1.6, 1.0), groove=(0.5, 0.4)),
    _spec("stepped_block", "cad", "stepped_block", steps=3, run=0.7, rise=0.45, depth=1.4),
    _spec("l_bracket", "cad", "l_bracket", leg=2.0, thickness=0.4, width=1.2, height=1.5),
    _spec("box_hole", "cad", "box_hole", size=(2.2, 1.8, 0.9), radius=0.45, axis="z"),
    _spec("cross", "cad", "cross", arms=(2.4, 1.8, 1.4), thickness=0.5),
    _spec("sphere", "smooth", "superellipsoid", axes=(1.0, 1.0, 1.0), e1=1.0, e2=1.0),
    _spec("ellipsoid_triaxial", "smooth", "superellipsoid", axes=(1.0, 0.7, 0.45), e1=1.0, e2=1.0),
    _spec("spheroid_prolate", "smooth", "superellipsoid", axes=(0.5, 0.5, 1.2), e1=1.0, e2=1.0),
    _spec("superellipsoid_rounded_box", "smooth", "superellipsoid", axes=(1.0, 0.9, 0.8), e1=0.5, e2=0.5),
    _spec("superellipsoid_rounded_cylinder", "smooth", "superellipsoid", axes=(0.8, 0.8, 1.0), e1=0.55, e2=1.0),
    _spec("superellipsoid_pillow", "smooth", "superellipsoid", axes=(1.0, 0.8, 0.5), e1=1.0, e2=0.6),
    _spec("torus", "smooth", "torus", major=1.0, minor=0.4),
    _spec("capsule", "smooth", "capsule", radius=0.45, half_length=0.7),
    _spec("blob_a", "smooth", "blob", radius=1.0, terms=4, amplitude=0.2, max_freq=2.5, seed=11),
    _spec("blob_b", "smooth", "blob", radius=1.0, terms=6, amplitude=0.13, max_freq=3.5, seed=22),
    _spec("blob_c", "smooth", "blob", radius=1.0, terms=8, amplitude=0.09, max_freq=5.0, seed=33),
)

VAL_SHAPES: tuple[ShapeSpec, ...] = (
    _spec("v_notch_block", "cad", "v_notch", size=(2.6, 1.5, 1.2), notch=0.5, step=(0.6, 0.4)),
    _spec(
        "octahedron_squashed",
        "cad",
        "hull",
        points=((1.0, 0, 0), (-1.0, 0, 0), (0, 0.8, 0), (0, -0.8, 0), (0, 0, 0.6), (0, 0, -0.6)),
    ),
    _spec("frustum", "cad", "frustum", radius_low=0.8, radius_high=0.35, height=1.3),
    _spec("boss_plate", "cad", "boss_plate", plate=(2.4, 1.8, 0.5), boss_radius=0.5, boss_height=0.6),
    _spec("slotted_frame", "cad", "slotted_frame", size=(2.2, 1.6, 0.8), window=(1.0, 0.7), slot=0.3),
    _spec("ellipsoid_flat", "smooth", "superellipsoid", axes=(1.0, 0.6, 0.3), e1=1.0, e2=1.0),
    _spec("superellipsoid_soft", "smooth", "superellipsoid", axes=(1.0, 0.8, 0.6), e1=0.75, e2=0.65),
    _spec("torus_thin", "smooth", "torus", major=1.0, minor=0.22),
    _spec("blob_d", "smooth", "blob", radius=1.0, terms=5, amplitude=0.15, max_freq=3.0, seed=44),
)

CATALOGUES: dict[str, tuple[ShapeSpec, ...]] = {"train": TRAIN_SHAPES, "val": VAL_SHAPES}


def catalogue(split: str) -> tuple[ShapeSpec, ...]:
    """The shapes of one split ('train' | 'val')."""
    if split not in CATALOGUES:
        raise ValueError(f"unknown split {split!r}; expected one of {sorted(CATALOGUES)}")
    return CATALOGUES[split]


@functools.lru_cache(maxsize=64)
def _surface(spec: ShapeSpec) -> Surface:
    return SMOOTH_BUILDERS[spec.builder](**spec.param_dict)


@functools.lru_cache(maxsize=64)
def _mesh(spec: ShapeSpec) -> trimesh.Trimesh:
    if spec.kind == "smooth":
        mesh = _surface(spec).mesh()
    else:
        solid = CAD_BUILDERS[spec.builder](**spec.param_dict)
        raw = solid.to_mesh64()
        mesh = trimesh.Trimesh(np.asarray(raw.vert_properties)[:, :3], np.asarray(raw.tri_verts), process=False)
    if not mesh.is_watertight:
        raise RuntimeError(f"shape {spec.name!r} did not build a watertight mesh")
    return mesh
