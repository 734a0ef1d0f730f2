"""Seeded training / validation clouds with exact normals, Gaussian noise variants and an on-disk cache.

Every cloud is normalised (translated so the bounding-box centre of the clean sample is the origin, scaled so its
bounding-box diagonal is 1), so noise levels and patch radii mean the same thing on every shape, as in PCPNet and the
paper. Noise moves points only: a noisy point keeps its clean point's normal (PCPNet's convention). The same seed
gives the same bytes; see docs/TRAINING_DATA.md.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import TrainingError
from ..simulation import seeds
from ..simulation.cache import default_cache_dir, writable_cache
from ..simulation.seeds import derive_seed
from . import shapes
from .shapes import ShapeSpec, catalogue

NOISE_LEVELS: tuple[float, ...] = (0.0, 0.0025, 0.005, 0.01, 0.015, 0.025)  # clean + the paper's five, × bbox diagonal


def _source_digest() -> str:
    """SHA-256 of the modules a clean sample is a function of (the shapes, the sampling here, the seed derivation):
    any edit to them changes every cache key, so no stale cloud is read and no version number is kept by hand."""
    digest = hashlib.sha256()
    for path in (Path(shapes.__file__), Path(__file__), Path(seeds.__file__)):
        source = path.resolve().read_bytes()
        digest.update(f"{path.name}\n{len(source)}\n".encode() + source)
    return digest.hexdigest()


#: Part of every cache key: the samples' source.
SOURCE_DIGEST = _source_digest()


@dataclass
class LabelledCloud:
    """One training / validation cloud labelled with its exact normals: float32 (n, 3) points and unit normals in the
    normalised frame, the shape name and kind, and the noise level (× the bounding-box diagonal)."""

    name: str
    kind: str
    noise: float
    points: np.ndarray
    normals: np.ndarray


def sample_surface(spec: ShapeSpec, n_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform float64 samples in the shape's own frame with exact unit normals (vectorised barycentric draw)."""
    mesh = spec.mesh()
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    ab, ac = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    cross = np.cross(ab, ac)
    area = np.linalg.norm(cross, axis=1)
    face = rng.choice(len(area), size=n_points, p=area / area.sum())
    u, v = rng.random(n_points), rng.random(n_points)
    flip = u + v > 1  # reflect the unit square's upper half back into the triangle: uniform over it
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    points = triangles[face, 0] + u[:, None] * ab[face] + v[:, None] * ac[face]
    surface = spec.surface()
    if surface is None:
        return points, cross[face] / area[face, None]
    return surface.snap(points)


def normalise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre the bounding box on the origin and scale its diagonal to 1; return (points, centre, diagonal)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, diagonal = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    return (points - centre) / diagonal, centre, diagonal


def sample_shape(spec: ShapeSpec, n_points: int = 100_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """`n_points` clean surface samples of `spec`, normalised (bbox centred, diagonal 1); float32 points, normals."""
    if n_points < 1:
        raise ValueError(f"n_points must be positive, got {n_points}")
    points, normals = sample_surface(spec, n_points, np.random.default_rng(seed))
    points, _, _ = normalise(points)
    return points.astype(np.float32), normals.astype(np.float32)


def add_noise(points: np.ndarray, sigma_rel: float, seed: int) -> np.ndarray:
    """Isotropic Gaussian noise with sigma = sigma_rel × the bounding-box diagonal of `points`; float32."""
    if sigma_rel < 0:
        raise ValueError(f"sigma_rel must be non-negative, got {sigma_rel}")
    points = np.asarray(points, dtype=np.float64)
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    noise = np.random.default_rng(seed).normal(scale=sigma_rel * diagonal, size=points.shape)
    return (points + noise).astype(np.float32)


def _cache_key(spec: ShapeSpec, n_points: int, seed: int) -> str:
    blob = json.dumps([spec.name, spec.kind, spec.builder, spec.params, n_points, seed, SOURCE_DIGEST], default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _load(path: Path, n_points: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A cached clean sample, or None when missing, truncated or of the wrong shape (it is then regenerated)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            points, normals = data["points"], data["normals"]
    except (OSError, ValueError, KeyError, EOFError, zlib.error):
        return None
    expected = (n_points, 3)
    if points.shape != expected or normals.shape != expected or points.dtype != np.float32:
        return None
    return points, normals


def _save(path: Path, points: np.ndarray, normals: np.ndarray) -> None:
    """Write atomically (temp file + rename) so a killed run never leaves a half-written cache entry."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, points=points, normals=normals)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def clean_sample(spec: ShapeSpec, n_points: int, seed: int, cache_dir: Path | None) -> tuple[np.ndarray, np.ndarray]:
    """The clean normalised sample of one shape for a dataset seed, read from / written to the cache."""
    path = cache_dir / f"{spec.name}-{_cache_key(spec, n_points, seed)}.npz" if cache_dir else None
    cached = _load(path, n_points) if path and path.exists() else None
    if cached is not None:
        return cached
    points, normals = sample_shape(spec, n_points, derive_seed(seed, spec.name, "sample"))
    if path:
        _save(path, points, normals)
    return points, normals


def _select(split: str, shapes: Iterable[str | ShapeSpec] | None) -> list[ShapeSpec]:
    specs = catalogue(split)
    if shapes is None:
        return list(specs)
    by_name = {spec.name: spec for spec in specs}
    chosen = [s if isinstance(s, ShapeSpec) else by_name.get(s) for s in shapes]
    unknown = [s for s, spec in zip(shapes, chosen, strict=True) if spec is None]
    if unknown:
        raise TrainingError(f"unknown {split} shapes {unknown}; known: {sorted(by_name)}")
    return chosen


def build_dataset(
    split: str = "train",
    n_points: int = 100_000,
    seed: int = 0,
    cache_dir: str | Path | None = None,
    shapes: Iterable[str | ShapeSpec] | None = None,
    noise_levels: Iterable[float] = NOISE_LEVELS,
    progress: bool = True,
) -> list[LabelledCloud]:
    """Every (shape, noise level) cloud of a split, shape-major: 22 × 6 = 132 for 'train'.

    Only the clean sample of each shape is cached (`.npz`, keyed by shape, params, n, seed and SOURCE_DIGEST); the
    noisy variants are redrawn from their own seed, which costs milliseconds and keeps the cache 6× smaller. The
    noisy clouds of a shape share one read-only normals array.
    """
    from tqdm import tqdm

    specs, levels = _select(split, shapes), tuple(float(s) for s in noise_levels)
    root = writable_cache(Path(cache_dir) if cache_dir is not None else default_cache_dir())
    clouds = []
    for spec in tqdm(specs, desc=f"{split} clouds", unit="shape", disable=not progress):
        points, normals = clean_sample(spec, n_points, seed, root)
        points.setflags(write=False)
        normals.setflags(write=False)
        for level in levels:
            noisy = add_noise(points, level, derive_seed(seed, spec.name, round(level * 1e6))) if level > 0 else points
            clouds.append(LabelledCloud(spec.name, spec.kind, level, noisy, normals))
    return clouds
