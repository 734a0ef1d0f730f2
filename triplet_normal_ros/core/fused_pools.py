"""The pool path's per-pool work on a CPU, compiled: one loop per pool instead of a few dozen torch passes.

* **Pool PCA** (`kernels.pool_normals`, `pca`'s pools): the covariance of the offsets from the query point, the
  closed-form eigen-decomposition of `fused._eigen` (`eigen.smallest_eigenvector`'s), and LAPACK's eigh where the two
  smallest eigenvalues nearly coincide (`eigen.EIGEN_GAP`), as the torch code does. Over the KD-tree's pools
  (`tree_normals`) the search and the sums are one loop per point, and the pools are never stored.
* **Inference patches** (`patches.build_patches`). A patch's k points are drawn by the hash of (centre, neighbour,
  seed), never by a generator, and the frame is the pool's own PCA frame, so each patch depends on its pool alone:
  one loop gathers the pool's offsets, sums its covariance, takes LAPACK's eigen-decomposition (as torch's eigh
  does), fixes the axes' signs by the third moments, hashes the keys and keeps the k smallest.

The torch code stays the reference (its docstrings say why each step is what it is); test/core/test_fused_pools.py
compares the two pool by pool. The pools run in bands on `fused._bands`'s threads, for the reasons `fused.py` gives.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .conventions import MIN_NEIGHBOURS
from .fused import _bands, add_moments
from .fused import _eigen as _closed_form
from .kdtree import KDTree, _nearest_one, scratch_for

_MASK32 = 0xFFFFFFFF


def build(
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
    _bands(
        _patches, m, np.ascontiguousarray(cloud, dtype=np.float64), np.ascontiguousarray(centres, dtype=np.float64),
        np.ascontiguousarray(pool, dtype=np.int64), float(radius), np.ascontiguousarray(ids, dtype=np.int64), names,
        int(seed), np.ascontiguousarray(given_values, dtype=np.float64),
        np.ascontiguousarray(given_frames, dtype=np.float64), out["points"], out["rotation"], out["selected"],
        out["valid"], out["eigvals"], out["local"], pieces=4,
    )  # fmt: skip
    return out


def pool_normals(
    cloud: np.ndarray, pool: np.ndarray, rows: np.ndarray, gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`kernels.pool_normals` of the -1 padded `pool` (M, P) around the cloud points `rows` (M,): unit normals
    (M, 3), ascending eigenvalues (M, 3) and validity (M,); eigh where the two smallest eigenvalues lie within `gap`
    of the trace."""
    m = len(pool)
    normal, eigvals, valid = np.empty((m, 3)), np.empty((m, 3)), np.zeros(m, dtype=np.bool_)
    _bands(
        _pool_pca, m, np.ascontiguousarray(cloud, dtype=np.float64), np.ascontiguousarray(pool, dtype=np.int64),
        np.ascontiguousarray(rows, dtype=np.int64), float(gap), normal, eigvals, valid, pieces=4,
    )  # fmt: skip
    return normal, eigvals, valid


@njit(cache=True, nogil=True, error_model="numpy")
def _pool_pca(cloud, pool, rows, gap, normal, eigvals, valid, lo, hi):
    cov = np.empty((3, 3))
    sums = np.empty(10)
    for b in range(lo, hi):
        centre = rows[b]
        sums[:] = 0.0
        for j in range(pool.shape[1]):
            idx = pool[b, j]
            if idx >= 0:
                x, y, z = (
                    cloud[idx, 0] - cloud[centre, 0],
                    cloud[idx, 1] - cloud[centre, 1],
                    cloud[idx, 2] - cloud[centre, 2],
                )
                add_moments(sums, x, y, z)
        valid[b] = _moments_pca(sums, gap, cov, eigvals[b], normal[b])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _moments_pca(sums, gap, cov, eigvals, normal):
    """The pool's eigenvalues (ascending) and normal from its ten moment sums (offsets from the query point): the
    closed form, eigh where the two smallest eigenvalues lie within `gap` of the trace; returns whether the pool
    holds MIN_NEIGHBOURS points."""
    valid = sums[0] >= MIN_NEIGHBOURS
    n = max(sums[0], 1.0)
    mx, my, mz = sums[1] / n, sums[2] / n, sums[3] / n
    a00, a01, a02 = sums[4] / n - mx * mx, sums[5] / n - mx * my, sums[6] / n - mx * mz
    a11, a12, a22 = sums[7] / n - my * my, sums[8] / n - my * mz, sums[9] / n - mz * mz
    _closed_form(a00, a01, a02, a11, a12, a22, eigvals, normal)
    if valid and eigvals[1] - eigvals[0] <= gap * (eigvals[0] + eigvals[1] + eigvals[2]):
        cov[0, 0], cov[0, 1], cov[0, 2] = a00, a01, a02
        cov[1, 0], cov[1, 1], cov[1, 2] = a01, a11, a12
        cov[2, 0], cov[2, 1], cov[2, 2] = a02, a12, a22
        values, vectors = np.linalg.eigh(cov)
        for a in range(3):
            eigvals[a] = max(values[a], 0.0)
            normal[a] = vectors[a, 0]
    return valid


def tree_normals(
    tree: KDTree, centres: np.ndarray, rows: np.ndarray | None, radius: float, k: int, gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pool_normals` of the nearest `k` points inside the ball around each centre, searched and summed in one loop
    per point (`KDTree.nearest`'s search; `rows` as there): the pools are never stored, and their points are summed
    while the search has them in cache."""
    m = len(centres)
    normal, eigvals, valid = np.full((m, 3), np.nan), np.full((m, 3), np.nan), np.zeros(m, dtype=np.bool_)
    if tree.size and m and k > 0:
        coordinates, at, which = tree.in_leaf_order(centres, rows)
        _bands(
            _tree_pca, m, tree.points, tree.ids, tree.span, tree.box, tree.depth, coordinates, at, which,
            float(radius) ** 2, int(k), float(gap), normal, eigvals, valid, pieces=4,
        )  # fmt: skip
    return normal, eigvals, valid


@njit(cache=True, nogil=True, error_model="numpy")
def _tree_pca(pts, ids, span, box, depth, centres, at, which, r2, k, gap, normal, eigvals, valid, lo, hi):
    """`_pool_pca` of each query's nearest k (`kdtree._nearest_one`), its moments summed from the tree's own points
    while the search has them in cache, for the queries at[lo:hi] into the rows which[lo:hi]."""
    scratch = scratch_for(k)
    cov = np.empty((3, 3))
    sums = np.empty(10)
    for j in range(lo, hi):
        c, q = at[j], which[j]
        x, y, z = centres[c, 0], centres[c, 1], centres[c, 2]
        count = _nearest_one(pts, ids, span, box, depth, x, y, z, r2, k, scratch)
        if count == 0:
            continue
        sums[:] = 0.0
        for a in range(count):
            t = scratch.best_pos[a]
            add_moments(sums, pts[t, 0] - x, pts[t, 1] - y, pts[t, 2] - z)
        valid[q] = _moments_pca(sums, gap, cov, eigvals[q], normal[q])


def warm() -> None:
    """Compile (or load from the cache) the kernels on a few tiny pools, with and without a given frame, so that no
    cloud waits for it: the node's start-up probe calls this whatever its method."""
    v, u = np.mgrid[0:4, 0:4].astype(np.float64)
    cloud = np.stack((u, v, np.ones_like(u) + 0.1 * u * v), axis=-1).reshape(-1, 3)
    pool = np.arange(16, dtype=np.int64).reshape(2, 8)
    pool_normals(cloud, pool, np.arange(2), 1e-3)
    tree_normals(KDTree(cloud), cloud[:2], np.arange(2), 3.0, 8, 1e-3)
    out = build(cloud, cloud[:2], pool, 3.0, 4, np.arange(2), 0, None)
    build(cloud, cloud[:2], pool, 3.0, 4, np.arange(2), 0, np.arange(16), (out["eigvals"], out["rotation"]))


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
