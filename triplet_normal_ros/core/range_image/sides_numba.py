"""Sharp folds (`range_image.sides`), compiled: each gated pixel's eight one-sided windows, their planes and scores,
and the snap, in one loop per pixel over the moment table `image_numba.CompiledImage` built.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..bands import bands
from ..pca.eigen_numba import smallest_eigenvector
from . import image_numba
from .image_numba import _SIDES, _box_moments, _half_widths, _largest_clear, _ray_noise, _valid_fit
from .survey import PART_SPAN


def snap_to_sides(
    fit: dict[str, np.ndarray],
    pitch: tuple[np.ndarray, np.ndarray],
    points: np.ndarray,
    pixels: np.ndarray,
    answers: np.ndarray,
    sharper: float,
    cos_snap: float,
) -> np.ndarray:
    """`sides.snap_to_sides` on `window_pca`'s `fit` (its table, walls, ranges, reach and window cap), the image's
    per-row and per-column `pitch`, the cloud's (H·W, 3) `points`, at the flat `pixels`: float32 (M, 3)."""
    out = np.ascontiguousarray(answers, dtype=np.float64).copy()
    bands(
        _snap, len(pixels), np.ascontiguousarray(pixels, dtype=np.int64), fit["table"], fit["counts"], fit["offset"],
        fit["ranges"], fit["reach_grid"], np.ascontiguousarray(pitch[0], dtype=np.float64),
        np.ascontiguousarray(pitch[1], dtype=np.float64), fit["col_walls"], fit["row_walls"], fit["eigvals"],
        np.ascontiguousarray(points, dtype=np.float64), float(fit["cap"]), float(sharper), float(cos_snap),
        int(PART_SPAN), out, pieces=4,
    )  # fmt: skip
    return out.astype(np.float32)


@njit(cache=True, nogil=True, error_model="numpy")
def _snap(
    pixels, table, counts, offset, ranges, reach, pitch_row, pitch_col, col_walls, row_walls, whole, points, cap,
    sharper, cos_snap, part_span, out, lo, hi,
):  # fmt: skip
    height, width = ranges.shape
    eigvals, axis = np.empty(3), np.empty(3)
    for i in range(lo, hi):
        ax, ay, az = out[i, 0], out[i, 1], out[i, 2]
        if not (np.isfinite(ax) and np.isfinite(ay) and np.isfinite(az)):
            continue
        p = pixels[i]
        r, c = p // width, p % width
        px, py, pz = points[p, 0] - offset[0], points[p, 1] - offset[1], points[p, 2] - offset[2]
        half_row, half_col = _half_widths(ranges, reach, pitch_row, pitch_col, r, c, cap)
        nearest, bx, by, bz = cos_snap, ax, ay, az
        for s in range(len(_SIDES)):
            top, bottom, left, right, _ = _largest_clear(
                r, c, half_row, half_col, _SIDES[s, 0], _SIDES[s, 1], _SIDES[s, 2], _SIDES[s, 3],
                col_walls, row_walls, height, width,
            )  # fmt: skip
            if bottom - top < part_span - 1 or right - left < part_span - 1:
                continue
            k, mx, my, mz, c0, c1, c2, c3, c4, c5 = _box_moments(table, top, bottom, left, right)
            smallest_eigenvector(c0, c1, c2, c3, c4, c5, eigvals, axis)
            if not _valid_fit(counts, r, c, top, bottom, left, right, k, eigvals, axis):
                continue
            ray_x, ray_y, ray_z = mx + offset[0], my + offset[1], mz + offset[2]
            nx, ny, nz = _ray_noise(c0, c1, c2, c3, c4, c5, ray_x, ray_y, ray_z, eigvals[2], axis[0], axis[1], axis[2])
            offside = (px - mx) * nx + (py - my) * ny + (pz - mz) * nz
            if not sharper * (eigvals[0] + offside * offside) < whole[p, 0]:
                continue
            dot = nx * ax + ny * ay + nz * az
            if abs(dot) > nearest:
                sign = 1.0 if dot > 0 else -1.0
                nearest, bx, by, bz = abs(dot), sign * nx, sign * ny, sign * nz
        out[i, 0], out[i, 1], out[i, 2] = bx, by, bz


def warm() -> None:
    """Compile (or load from the cache) the snap's kernel on `image_numba.warm`'s image, so that no cloud waits for it
    (the thresholds do not change what compiles)."""
    image = image_numba.warm()
    pixels = np.arange(image.height * image.width, dtype=np.int64)
    answers = np.nan_to_num(image.fit["normal"]).astype(np.float32)
    pitch = (image.pitch_row.numpy(), image.pitch_col.numpy())
    snap_to_sides(image.fit, pitch, image.points.numpy().reshape(-1, 3), pixels, answers, 3.0, 0.5)
