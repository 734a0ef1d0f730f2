"""Inference patches (`learned.patches.build_patches`), compiled: one loop per pool gathers its offsets, sums its
covariance, takes LAPACK's eigen-decomposition (as torch's eigh does), fixes the axes' signs by the third moments,
hashes the keys and keeps the k smallest. test/core/test_fused_pools.py compares it with the torch code pool by pool.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..bands import bands
from ..config.conventions import MIN_NEIGHBOURS

_MASK32 = 0xFFFFFFFF


def build_patches(
    cloud: np.ndarray, centres: np.ndarray, pool: np.ndarray, radius: float, k: int, ids: np.ndarray, seed: int,
    point_ids: np.ndarray | None, pca: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:  # fmt: skip
    """The `Patches` fields (and the whole pool's `local` offsets, for a scale head's fits) of the -1 padded `pool`
    (M, P) around `centres` (M, 3), `ids` (M,) the centres' cloud rows; `point_ids` names the cloud's points for the
    hash (a tile's), and `pca` = (eigenvalues, frames) of these pools saves computing them, as in `build_patches`."""
    m, p = pool.shape
    given_values, given_frames = (np.empty((0, 3)), np.empty((0, 3, 3))) if pca is None else pca
    names = np.empty(0, dtype=np.int64) if point_ids is None else np.ascontiguousarray(point_ids, dtype=np.int64)
    out = {
        "points": np.zeros((m, k, 3), dtype=np.float32),
        "rotation": np.empty((m, 3, 3)),
        "selected": np.zeros((m, k), dtype=np.int64),
        "valid": np.zeros(m, dtype=np.bool_),
        "eigvals": np.empty((m, 3)),
        "local": np.zeros((m, p, 3)),
    }
    bands(
        _patches, m, np.ascontiguousarray(cloud, dtype=np.float64), np.ascontiguousarray(centres, dtype=np.float64),
        np.ascontiguousarray(pool, dtype=np.int64), float(radius), np.ascontiguousarray(ids, dtype=np.int64), names,
        int(seed), np.ascontiguousarray(given_values, dtype=np.float64),
        np.ascontiguousarray(given_frames, dtype=np.float64), out["points"], out["rotation"], out["selected"],
        out["valid"], out["eigvals"], out["local"], pieces=4,
    )  # fmt: skip
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _hash_key(centre: int, neighbour: int, seed: int) -> float:
    """`patches.hashed_keys` for one (centre, neighbour) pair."""
    h = (centre * 0x27D4EB2F + neighbour * 0x165667B1 + seed) & _MASK32
    for _ in range(2):
        h = (((h >> 16) ^ h) * 0x45D9F3B) & _MASK32
    h = (h >> 16) ^ h
    return h / 4294967296.0


@njit(cache=True, nogil=True, error_model="numpy")
def _patches(
    cloud, centres, pool, radius, ids, names, seed, given_values, given_frames, points, rotation, selected, valid,
    eigvals, local, lo, hi,
):  # fmt: skip
    p = pool.shape[1]
    given = len(given_values) > 0
    vectors = np.empty((3, 3))
    k = points.shape[1]
    keys = np.empty(p)
    for b in range(lo, hi):
        count = 0
        mean = np.zeros(3)
        for j in range(p):
            idx = pool[b, j]
            if idx < 0:
                continue
            count += 1
            for a in range(3):
                x = (cloud[idx, a] - centres[b, a]) / radius
                local[b, j, a] = x
                mean[a] += x
        valid[b] = count >= MIN_NEIGHBOURS
        n = max(count, 1)
        for a in range(3):
            mean[a] /= n
        if given:  # columns of eigh's vectors: z is the smallest axis, x the middle one
            for a in range(3):
                eigvals[b, a] = given_values[b, a]
                vectors[a, 0], vectors[a, 1] = given_frames[b, 2, a], given_frames[b, 0, a]
        else:
            _eigen(local[b], pool[b], mean, n, valid[b], eigvals[b], vectors)
        _frame(local[b], pool[b], mean, vectors, rotation[b])
        _select(pool[b], ids[b], names, seed, keys, count, k, selected[b], local[b], rotation[b], valid[b], points[b])


@njit(cache=True, nogil=True, error_model="numpy")
def _eigen(local, pool, mean, n, valid, eigvals, vectors):
    """The pool's covariance and its eigen-decomposition (`frames.principal_frames`): ascending eigenvalues clamped
    at 0 into `eigvals`, eigenvectors as the columns of `vectors`; an invalid pool gets the identity's."""
    cov = np.empty((3, 3))
    second = np.zeros((3, 3))
    for j in range(len(pool)):
        if pool[j] < 0:
            continue
        for a in range(3):
            for c in range(3):
                second[a, c] += local[j, a] * local[j, c]
    for a in range(3):
        for c in range(3):
            cov[a, c] = second[a, c] / n - mean[a] * mean[c]
    if not valid:
        cov[:, :] = 0.0
        for a in range(3):
            cov[a, a] = 1.0
    values, found = np.linalg.eigh(cov)
    for a in range(3):
        eigvals[a] = max(values[a], 0.0)
        for c in range(3):
            vectors[a, c] = found[a, c]


@njit(cache=True, nogil=True, error_model="numpy")
def _frame(local, pool, mean, vectors, rotation):
    """Rows x, y, z of the patch frame: z the smallest axis, x the middle one, each signed along its positive skew
    (`frames.canonical_signs`), y = z × x."""
    skew_x, skew_z = 0.0, 0.0
    for j in range(len(pool)):
        if pool[j] < 0:
            continue
        along_x, along_z = 0.0, 0.0
        for a in range(3):
            centred = local[j, a] - mean[a]
            along_x += centred * vectors[a, 1]
            along_z += centred * vectors[a, 0]
        skew_x += along_x * along_x * along_x
        skew_z += along_z * along_z * along_z
    sign_x = -1.0 if skew_x < 0 else 1.0
    sign_z = -1.0 if skew_z < 0 else 1.0
    for a in range(3):
        rotation[0, a] = vectors[a, 1] * sign_x
        rotation[2, a] = vectors[a, 0] * sign_z
    x, z = rotation[0], rotation[2]
    rotation[1, 0] = z[1] * x[2] - z[2] * x[1]
    rotation[1, 1] = z[2] * x[0] - z[0] * x[2]
    rotation[1, 2] = z[0] * x[1] - z[1] * x[0]


@njit(cache=True, nogil=True, error_model="numpy")
def _select(pool, centre, names, seed, keys, count, k, selected, local, rotation, valid, points):
    """The k entries with the smallest hash keys (then repeats, for a pool of fewer), rotated into the frame
    (`patches.sample_columns`)."""
    named = len(names) > 0
    centre_name = names[centre] if named else centre
    for j in range(len(pool)):
        idx = pool[j]
        keys[j] = 2.0 if idx < 0 else _hash_key(centre_name, names[idx] if named else idx, seed)
    order = np.argsort(keys)
    for i in range(k):
        j = order[i % max(count, 1)]
        selected[i] = max(pool[j], 0)
        if not valid:
            continue
        for a in range(3):
            points[i, a] = local[j, 0] * rotation[a, 0] + local[j, 1] * rotation[a, 1] + local[j, 2] * rotation[a, 2]


def warm() -> None:
    """Compile (or load from the cache) the kernels on two tiny pools, with and without a given frame, so that no
    cloud waits for it: the node's start-up probe calls this whatever its method."""
    v, u = np.mgrid[0:4, 0:4].astype(np.float64)
    cloud = np.stack((u, v, np.ones_like(u) + 0.1 * u * v), axis=-1).reshape(-1, 3)
    pool = np.arange(16, dtype=np.int64).reshape(2, 8)
    out = build_patches(cloud, cloud[:2], pool, 3.0, 4, np.arange(2), 0, None)
    build_patches(cloud, cloud[:2], pool, 3.0, 4, np.arange(2), 0, np.arange(16), (out["eigvals"], out["rotation"]))
