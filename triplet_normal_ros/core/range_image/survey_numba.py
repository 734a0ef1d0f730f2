"""Hybrid's window survey and cue (`range_image.survey`), compiled: the ray-noise normal and the parts' z and bend per
pixel in one loop, from the moment tables `image_numba.CompiledImage` built.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..bands import bands
from ..config.conventions import MIN_NEIGHBOURS
from . import image_numba
from .image_numba import _box, ray_noise_normal

#: The first-moment table `survey` passes where it reads no parts: of the same type, so the same compiled kernel.
_NO_TABLE = np.zeros((1, 1, 4))


def survey(
    table: np.ndarray, offset: np.ndarray, fit: dict[str, np.ndarray], parts: bool = True
) -> tuple[np.ndarray, ...]:
    """Hybrid's window survey compiled: each window's ray-noise plane normal (`survey.ray_noise_normal`) and the
    z score and bend of its parts along that normal (`survey.structure`; zero unless `parts`), from `window_pca`'s
    table and fit."""
    n = len(fit["count"])
    normal, z, bend = np.empty((n, 3)), np.zeros(n), np.zeros(n)
    first = np.ascontiguousarray(table[..., :4]) if parts else _NO_TABLE
    bands(
        _survey, n, first, offset, fit["normal"], fit["eigvals"], fit["count"], fit["mean"], fit["cov"], fit["box"],
        fit["reach"], bool(parts), normal, z, bend, pieces=4,
    )  # fmt: skip
    return normal, z, bend


@njit(cache=True, nogil=True, error_model="numpy")
def _survey(first, offset, pca, eigvals, count, mean, cov, box, reach, parts, normal, z, bend, lo, hi):
    for i in range(lo, hi):
        mx, my, mz = mean[i, 0], mean[i, 1], mean[i, 2]
        nx, ny, nz = ray_noise_normal(cov[i], mx, my, mz, eigvals[i, 2], pca[i, 0], pca[i, 1], pca[i, 2])
        normal[i, 0], normal[i, 1], normal[i, 2] = nx, ny, nz
        if not parts:
            continue
        z[i], bend[i] = _parts(first, offset, box[0, i], box[1, i], box[2, i], box[3, i], count[i], reach[i],
                               mx - offset[0], my - offset[1], mz - offset[2], nx, ny, nz, cov[i])  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy")
def _parts(first, offset, top, bottom, left, right, count, reach, cx, cy, cz, nx, ny, nz, cov):
    """(z, bend) of one window's five parts (`survey.structure`): the largest height of a part's centroid off the
    plane through the window's centroid with normal n, over its noise standard error and over the reach."""
    across = cov[1] * nx * ny + cov[2] * nx * nz + cov[4] * ny * nz
    noise = max(cov[0] * nx * nx + cov[3] * ny * ny + cov[5] * nz * nz + 2 * across, 0.0)
    mid_row, mid_col = (top + bottom) // 2, (left + right) // 2
    quarter_row, quarter_col = (bottom - top + 2) // 4, (right - left + 2) // 4
    parts = (
        (top, mid_row, left, right),
        (mid_row + 1, bottom, left, right),
        (top, bottom, left, mid_col),
        (top, bottom, mid_col + 1, right),
        (mid_row - quarter_row + 1, mid_row + quarter_row, mid_col - quarter_col + 1, mid_col + quarter_col),
    )
    z, bend = 0.0, 0.0
    for t, b, lf, rt in parts:
        t, b = min(max(t, top), bottom), min(max(b, top), bottom)
        lf, rt = min(max(lf, left), right), min(max(rt, left), right)
        n = _box(first, t, b, lf, rt, 0)
        inverse = 1.0 / max(n, 1.0)
        height = abs(
            (_box(first, t, b, lf, rt, 1) * inverse - cx) * nx
            + (_box(first, t, b, lf, rt, 2) * inverse - cy) * ny
            + (_box(first, t, b, lf, rt, 3) * inverse - cz) * nz
        )
        spread = math.sqrt(noise * max(inverse - 1.0 / max(count, 1.0), 0.0))
        if n >= MIN_NEIGHBOURS and n < count:
            z = max(z, height / max(spread, 1e-12))
            bend = max(bend, height / reach)
    return z, bend


def warm() -> None:
    """Compile (or load from the cache) the windows' kernels and the survey's, so that no cloud waits for them."""
    fit = image_numba.warm().fit
    survey(fit["table"], fit["offset"], fit)
    survey(fit["table"], fit["offset"], fit, parts=False)
