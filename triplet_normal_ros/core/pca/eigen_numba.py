"""The 3 × 3 eigen solver of `pca.eigen` for one matrix at a time, and the moment sums it reads, for the compiled
kernels: the same closed form, in the same order, so the compiled and torch paths agree to roundoff.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..config.conventions import MIN_NEIGHBOURS
from .eigen import DEGENERATE_CROSS

_TINY = np.finfo(np.float64).tiny


@njit(cache=True, nogil=True, error_model="numpy")
def add_moments(sums, x, y, z):
    """Add one point to `sums`, the ten moment channels (count, x, y, z, xx, xy, xz, yy, yz, zz)."""
    sums[0] += 1.0
    sums[1] += x
    sums[2] += y
    sums[3] += z
    sums[4] += x * x
    sums[5] += x * y
    sums[6] += x * z
    sums[7] += y * y
    sums[8] += y * z
    sums[9] += z * z


@njit(cache=True, nogil=True, error_model="numpy")
def smallest_eigenvector(a00, a01, a02, a11, a12, a22, eigvals, normal):
    """`eigen.smallest_eigenvector` for one matrix: ascending eigenvalues and the smallest one's unit eigenvector
    (NaN where no two rows of A - λ0 I span a plane) into `eigvals` and `normal`."""
    scale = max(abs(a00) + abs(a11) + abs(a22), _TINY)
    a00, a01, a02, a11, a12, a22 = a00 / scale, a01 / scale, a02 / scale, a11 / scale, a12 / scale, a22 / scale
    q = (a00 + a11 + a22) / 3
    off = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt(max((b00 * b00 + b11 * b11 + b22 * b22 + 2 * off) / 6, 0.0))
    safe_p = max(p, 1e-30)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)) / (
        safe_p * safe_p * safe_p
    )
    phi = math.acos(min(max(det / 2, -1.0), 1.0)) / 3
    largest = q + 2 * p * math.cos(phi)
    smallest = q + 2 * p * math.cos(phi + 2 * math.pi / 3)
    middle = 3 * q - largest - smallest
    eigvals[0] = max(smallest, 0.0) * scale
    eigvals[1] = max(middle, 0.0) * scale
    eigvals[2] = max(largest, 0.0) * scale
    r0 = (a00 - smallest, a01, a02)
    r1 = (a01, a11 - smallest, a12)
    r2 = (a02, a12, a22 - smallest)
    best, bx, by, bz = -1.0, 0.0, 0.0, 0.0
    for u, v in ((r0, r1), (r0, r2), (r1, r2)):
        x = u[1] * v[2] - u[2] * v[1]
        y = u[2] * v[0] - u[0] * v[2]
        z = u[0] * v[1] - u[1] * v[0]
        length = math.sqrt(x * x + y * y + z * z)
        if length > best:
            best, bx, by, bz = length, x, y, z
    if best > DEGENERATE_CROSS:
        normal[0], normal[1], normal[2] = bx / best, by / best, bz / best
    else:
        normal[0] = normal[1] = normal[2] = np.nan


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def moments_pca(sums, gap, cov, eigvals, normal):
    """The pool's eigenvalues (ascending) and normal from its ten moment sums (offsets from the query point): the
    closed form, eigh where the two smallest eigenvalues lie within `gap` of the trace; returns whether the pool
    holds MIN_NEIGHBOURS points."""
    valid = sums[0] >= MIN_NEIGHBOURS
    n = max(sums[0], 1.0)
    mx, my, mz = sums[1] / n, sums[2] / n, sums[3] / n
    a00, a01, a02 = sums[4] / n - mx * mx, sums[5] / n - mx * my, sums[6] / n - mx * mz
    a11, a12, a22 = sums[7] / n - my * my, sums[8] / n - my * mz, sums[9] / n - mz * mz
    smallest_eigenvector(a00, a01, a02, a11, a12, a22, eigvals, normal)
    if valid and eigvals[1] - eigvals[0] <= gap * (eigvals[0] + eigvals[1] + eigvals[2]):
        cov[0, 0], cov[0, 1], cov[0, 2] = a00, a01, a02
        cov[1, 0], cov[1, 1], cov[1, 2] = a01, a11, a12
        cov[2, 0], cov[2, 1], cov[2, 2] = a02, a12, a22
        values, vectors = np.linalg.eigh(cov)
        for a in range(3):
            eigvals[a] = max(values[a], 0.0)
            normal[a] = vectors[a, 0]
    return valid


@njit(cache=True, nogil=True, error_model="numpy")
def write_answer(x, y, z, eigvals, answered, normals, curvature, i):
    """Row i of a compiled path's output: the unit normal (x, y, z) and PCL's curvature λ0 / (λ0 + λ1 + λ2) from
    the ascending `eigvals` (`frames.surface_variation`), NaN unless `answered`: what `paths.call.finish` makes of a
    torch path's answers, one row at a time."""
    if not answered:
        normals[i, 0] = normals[i, 1] = normals[i, 2] = curvature[i] = np.nan
        return
    length = max(math.sqrt(x * x + y * y + z * z), 1e-12)
    normals[i, 0], normals[i, 1], normals[i, 2] = x / length, y / length, z / length
    total = eigvals[0] + eigvals[1] + eigvals[2]
    curvature[i] = eigvals[0] / max(total, _TINY) if total > 0 else 0.0
