"""A scale head's plane fits (`scales.scale_fits`) on a CPU, compiled: one loop per patch instead of a few dozen
batched torch passes over every patch's whole pool.

Per patch: the nearest `max(scales, seeds)` pool points, sorted once, give every nearest-m fit as a running sum of their
moments; the whole pool is one more sum; each inlier fit refits its band INLIER_STEPS times. Every fit is the
closed-form eigen-decomposition of `eigen_numba.smallest_eigenvector`, with LAPACK's eigh where the two smallest
eigenvalues nearly coincide (`eigen.EIGEN_GAP`), in float64 from the float32 offsets the torch code fits.

The torch code stays the reference and runs on a GPU; it fits in float32 with LAPACK's eigh, so the two agree to
float32 roundoff, except where a point sits on an inlier band's edge or two pool points are equally near at a
scale's boundary: there each picks its own side (test/core/test_fused_scales.py counts those patches). Where a fit's
two smallest eigenvalues coincide (collinear or coincident points) any axis across them is an answer, and the two
solvers may pick different ones.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..bands import bands
from ..config.conventions import MIN_NEIGHBOURS
from ..pca.eigen import EIGEN_GAP
from ..pca.eigen_numba import add_moments, moments_pca
from .scales import CUES_PER_SCALE, INLIER_BAND, INLIER_SLACK, INLIER_STEPS


def scale_fits(
    local: np.ndarray, mask: np.ndarray, rotation: np.ndarray, scales: tuple[int, ...], seeds: tuple[int, ...],
    pool_size: int,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """`scales.scale_fits`' candidate normals (B, fits, 3) and cues (B, fits × CUES_PER_SCALE), float32, of the pool
    offsets `local` (B, P, 3) in radii with `mask` (B, P) and the patch frames `rotation` (B, 3, 3)."""
    b = len(mask)
    count = len(scales) + 1 + len(seeds)
    normals = np.empty((b, count, 3), dtype=np.float32)
    cues = np.empty((b, count * CUES_PER_SCALE), dtype=np.float32)
    bands(
        _patch_fits, b, np.ascontiguousarray(local, dtype=np.float64), np.ascontiguousarray(mask, dtype=np.bool_),
        np.ascontiguousarray(rotation.astype(np.float32), dtype=np.float64), np.array(scales, dtype=np.int64),
        np.array(seeds, dtype=np.int64), float(pool_size), normals, cues, pieces=4,
    )  # fmt: skip
    return normals, cues


def warm() -> None:
    """Compile (or load from the cache) the kernel on two tiny pools, so that no cloud waits for it."""
    grid = np.mgrid[0:4, 0:4].reshape(2, -1).T / 4.0
    local = np.concatenate((grid, 0.05 * grid[:, :1] * grid[:, 1:]), axis=1)
    scale_fits(
        np.stack((local, local[::-1])), np.ones((2, 16), dtype=np.bool_), np.stack((np.eye(3),) * 2), (4, 8), (4,), 16
    )


@njit(cache=True, nogil=True, error_model="numpy")
def _patch_fits(local, mask, rotation, scales, seeds, pool_size, normals, cues, lo, hi):
    p = mask.shape[1]
    widest = min(max(scales.max() if len(scales) else 0, seeds.max() if len(seeds) else 0), p)
    dist2, order = np.empty(p), np.empty(p, dtype=np.int64)
    points = np.zeros((p, 3))
    sums, grown_sums = np.empty(10), np.empty(10)
    cov, eigvals, world = np.empty((3, 3)), np.empty(3), np.empty(3)
    for b in range(lo, hi):
        valid, frame = mask[b], rotation[b]
        for j in range(p):
            if valid[j]:  # the float32 offsets the torch code fits
                for a in range(3):
                    points[j, a] = np.float32(local[b, j, a])
            x, y, z = points[j, 0], points[j, 1], points[j, 2]
            dist2[j] = x * x + y * y + z * z if valid[j] else np.inf
        _nearest_first(dist2, widest, order)
        slot = 0
        sums[:] = 0.0
        reach2 = 0.0
        taken = 0
        for m in scales:  # the nearest m: running sums over the sorted points
            while taken < min(m, widest):
                j = order[taken]
                if valid[j]:
                    add_moments(sums, points[j, 0], points[j, 1], points[j, 2])
                    reach2 = dist2[j]
                taken += 1
            _finish(sums, reach2, float(m), cov, eigvals, world, frame, normals[b, slot], cues[b], slot)
            slot += 1
        reach2 = _band_sums(points, valid, dist2, 0.0, 0.0, 0.0, 0.0, np.inf, sums)  # the whole pool
        count = sums[0]
        _finish(sums, reach2, pool_size, cov, eigvals, world, frame, normals[b, slot], cues[b], slot)
        slot += 1
        for s in seeds:  # the inlier fits, grown from the nearest s
            sums[:] = 0.0
            reach2 = 0.0
            for t in range(min(s, p)):
                j = order[t]
                if valid[j]:
                    add_moments(sums, points[j, 0], points[j, 1], points[j, 2])
                    reach2 = dist2[j]
            for _ in range(INLIER_STEPS):
                reach2 = _grow(points, valid, dist2, sums, grown_sums, reach2, cov, eigvals, world)
            _finish(sums, reach2, max(count, 1.0), cov, eigvals, world, frame, normals[b, slot], cues[b], slot)
            slot += 1


@njit(cache=True, nogil=True, error_model="numpy")
def _nearest_first(dist2, widest, order):
    """The `widest` smallest of `dist2` into order[:widest], nearest first, equal distances by position (a stable
    sort's first `widest`, from a partition and a sort of those alone)."""
    kth = np.partition(dist2.copy(), widest - 1)[widest - 1]
    n = 0
    for j in range(len(dist2)):
        if dist2[j] < kth:
            order[n] = j
            n += 1
    for j in range(len(dist2)):
        if n < widest and dist2[j] == kth:
            order[n] = j
            n += 1
    chosen = order[:n].copy()
    order[:n] = chosen[np.argsort(dist2[chosen], kind="mergesort")]


@njit(cache=True, nogil=True, error_model="numpy")
def _plane(sums, cov, eigvals, world):
    """`scales._plane` from the moment sums: eigenvalues, normal and whether it holds a plane's three points; a fit
    of fewer takes the identity's decomposition, as the torch code's eigh of the identity gives it."""
    if moments_pca(sums, EIGEN_GAP, cov, eigvals, world):
        return True
    eigvals[:] = 1.0
    world[0], world[1], world[2] = 1.0, 0.0, 0.0
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _grow(points, valid, dist2, sums, grown_sums, reach2, cov, eigvals, world):
    """One refit of `scales._inliers`: the pool points within the band of the plane whose points' moment sums are
    `sums` replace them where they are three; returns the kept points' largest squared distance from the query."""
    _plane(sums, cov, eigvals, world)
    level = (sums[1] * world[0] + sums[2] * world[1] + sums[3] * world[2]) / max(sums[0], 1.0)
    band = INLIER_BAND * np.sqrt(eigvals[0]) + INLIER_SLACK
    grown_reach2 = _band_sums(points, valid, dist2, world[0], world[1], world[2], level, band, grown_sums)
    if grown_sums[0] < MIN_NEIGHBOURS:
        return reach2
    sums[:] = grown_sums
    return grown_reach2


@njit(cache=True, nogil=True, error_model="numpy")
def _band_sums(points, valid, dist2, nx, ny, nz, level, band, out):
    """The ten moment sums (into `out`) and the largest squared distance of the valid points less than `band` off
    the plane n · x = level; in scalars, which the compiler keeps in registers, where sums into an array would go
    through memory at every point."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = 0.0
    reach2 = 0.0
    for j in range(len(valid)):
        x, y, z = points[j, 0], points[j, 1], points[j, 2]
        if valid[j] and abs(x * nx + y * ny + z * nz - level) < band:
            s0 += 1.0
            s1 += x
            s2 += y
            s3 += z
            s4 += x * x
            s5 += x * y
            s6 += x * z
            s7 += y * y
            s8 += y * z
            s9 += z * z
            reach2 = max(reach2, dist2[j])
    out[0], out[1], out[2], out[3], out[4] = s0, s1, s2, s3, s4
    out[5], out[6], out[7], out[8], out[9] = s5, s6, s7, s8, s9
    return reach2


@njit(cache=True, nogil=True, error_model="numpy")
def _finish(sums, reach2, full, cov, eigvals, world, frame, normal, cues, slot):
    """`scales._fit`'s normal in the patch frame (z >= 0) and its cues, into `normal` and the fit's slot of `cues`."""
    ok = _plane(sums, cov, eigvals, world)
    for a in range(3):
        normal[a] = (
            frame[a, 0] * world[0] + frame[a, 1] * world[1] + frame[a, 2] * world[2] if ok else (1.0 if a == 2 else 0.0)
        )
    if normal[2] < 0:
        normal[0], normal[1], normal[2] = -normal[0], -normal[1], -normal[2]
    at = slot * CUES_PER_SCALE
    cues[at], cues[at + 1], cues[at + 2] = normal[0], normal[1], normal[2]
    if not ok:
        cues[at + 3 : at + CUES_PER_SCALE] = 0.0
        return
    n = max(sums[0], 1.0)
    offset = 0.0
    for a in range(3):  # the signed normal back in world axes, against the fit's mean
        offset -= sums[1 + a] / n * (frame[0, a] * normal[0] + frame[1, a] * normal[1] + frame[2, a] * normal[2])
    cues[at + 3] = eigvals[0] / max(eigvals[0] + eigvals[1] + eigvals[2], 1e-30)
    cues[at + 4] = (eigvals[2] - eigvals[1]) / max(eigvals[2], 1e-30)
    cues[at + 5] = offset
    cues[at + 6] = np.sqrt(reach2)
    cues[at + 7] = min(sums[0] / full, 1.0)
