"""Sets of simulated range frames: `depth_frames` and `lidar_scans`, each frame from its own seed, cached on disk.

Robots see range images, not area-uniform surface samples: density falls with distance, noise grows with depth and
acts along the ray, grazing surfaces drop out and the frame is full of NaN. The sensor modules (`depth_camera`,
`lidar`) ray cast simple CAD scenes analytically (`raycast`), so every pixel has the exact normal of the face it hit
and the id of that face, and `edges` marks the returns near another face. Generation is pure numpy + scipy and
seeded; a frame takes seconds, so the sets here cache each one as .npz next to the training data (see
docs/RANGE_SCANS.md). Training, evaluation and the benchmarks all draw their frames from here.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zlib
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from .cache import default_cache_dir, writable_cache
from .depth_camera import depth_frame
from .edges import EDGE_RADIUS
from .fold_scenes import KINDS as FOLD_KINDS
from .fold_scenes import fold_frame
from .lidar import RANGE_SIGMA, lidar_scan
from .range_frame import RangeFrame
from .seeds import derive_seed


def _source_digest() -> str:
    """SHA-256 of this package's modules: a frame is a function of them and of its key's parameters alone (numpy and
    scipy aside), so any edit to a scene, a sensor model or the edge mask changes every key and no stale frame is
    read."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        source = path.read_bytes()
        digest.update(f"{path.name}\n{len(source)}\n".encode() + source)
    return digest.hexdigest()


#: Part of every cache key: the frames' source, so the key follows the code without a hand-kept version number.
SOURCE_DIGEST = _source_digest()
#: Frame seeds of each use, so no frame is both trained and scored on: eval 0 (frames 0-2; fold frames 0-5), the
#: hybrid gate and survey studies 100 (docs/tools/gate_study.py, docs/tools/fold_study.py), training 200, training
#: validation 300.
TRAIN_SEED, VAL_SEED = 200, 300
#: What a cached frame stores besides its name and kind.
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


def _cached_frames(
    kind: str,
    count: int,
    seed: int,
    params: dict,
    shape: tuple[int, int],
    make: Callable[[int], RangeFrame],
    cache_dir: str | Path | None,
) -> list[RangeFrame]:
    """`count` frames, frame i from its own seed; each read from / written to the cache under a parameter key."""
    if count < 0:
        raise ValueError(f"count must be non-negative, got {count}")
    root = writable_cache(Path(cache_dir) if cache_dir is not None else default_cache_dir())
    frames = []
    for i in range(count):
        frame_seed = frame_seed_of(kind, seed, i)
        blob = json.dumps([kind, params, frame_seed, EDGE_RADIUS, SOURCE_DIGEST], sort_keys=True)
        path = root / f"{kind}-{hashlib.sha256(blob.encode()).hexdigest()[:16]}.npz" if root else None
        frame = _load_frame(path, shape) if path and path.exists() else None
        if frame is None:
            frame = make(frame_seed)
            if path:
                _save_frame(path, frame)
        frames.append(frame)
    return frames


def frame_seed_of(kind: str, seed: int, index: int) -> int:
    """The seed of frame `index` of a set of `kind` drawn from `seed`: each frame's own, so that a pair or a study can
    rebuild one frame of a set without the rest."""
    return derive_seed(seed, kind, index)


def fold_kind_and_seed(index: int, seed: int = 0) -> tuple[str, int]:
    """The scene kind and the frame seed of `fold_frames(n, seed)[index]`."""
    kind = FOLD_KINDS[index % len(FOLD_KINDS)]
    return kind, frame_seed_of(f"fold-{kind}", derive_seed(seed, index), 0)


def lidar_scan_seed(index: int, seed: int = 0) -> int:
    """The frame seed of `lidar_scans(n, seed)[index]`."""
    return frame_seed_of("lidar", seed, index)


def depth_frames(
    count: int, seed: int = 0, width: int = 640, height: int = 480, cache_dir: str | Path | None = None
) -> list[RangeFrame]:
    """`count` depth frames of different scenes, cached ($TRIPLET_NORMAL_CACHE, else ~/.cache/...)."""
    params = {"width": width, "height": height}
    make = partial(depth_frame, width=width, height=height)
    return _cached_frames("depth", count, seed, params, (height, width), make, cache_dir)


def fold_frames(
    count: int, seed: int = 0, width: int = 640, height: int = 480, cache_dir: str | Path | None = None
) -> list[RangeFrame]:
    """`count` close-range fold frames (`fold_scenes`), frame i of kind FOLD_KINDS[i mod 6], cached like the rest."""
    frames = []
    for i in range(count):
        kind = FOLD_KINDS[i % len(FOLD_KINDS)]
        params = {"width": width, "height": height, "scene": kind}
        make = partial(fold_frame, kind=kind, width=width, height=height)
        frames += _cached_frames(f"fold-{kind}", 1, derive_seed(seed, i), params, (height, width), make, cache_dir)
    return frames


def lidar_scans(
    count: int,
    seed: int = 0,
    beams: int = 32,
    azimuth_step_deg: float = 0.2,
    range_sigma: float = RANGE_SIGMA,
    cache_dir: str | Path | None = None,
) -> list[RangeFrame]:
    """`count` LiDAR scans of different yards, cached like `depth_frames`."""
    params = {"beams": beams, "azimuth_step_deg": azimuth_step_deg, "range_sigma": range_sigma}
    shape = (beams, round(360.0 / azimuth_step_deg))
    make = partial(lidar_scan, beams=beams, azimuth_step_deg=azimuth_step_deg, range_sigma=range_sigma)
    return _cached_frames("lidar", count, seed, params, shape, make, cache_dir)
