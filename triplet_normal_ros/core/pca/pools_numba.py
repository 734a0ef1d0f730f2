"""Pool PCA (`pools.pool_normals`, `pca`'s pools) on a CPU, compiled: one loop per pool instead of a few dozen torch
passes.

The covariance of the offsets from the query point, the closed-form eigen-decomposition of
`eigen_numba.smallest_eigenvector` (`eigen.smallest_eigenvector`'s), and LAPACK's eigh where the two smallest
eigenvalues nearly coincide (`eigen.EIGEN_GAP`), as the torch code does. Over the KD-tree's pools (`tree_normals`)
the search and the sums are one loop per point, and the pools are never stored. The torch code stays the reference
(its docstrings say why each step is what it is); test/core/test_fused_pools.py compares the two pool by pool. The
pools run in bands on `bands.bands`'s threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..bands import bands
from ..search.kdtree_numba import KDTree, _nearest_one, scratch_for
from .eigen_numba import add_moments, moments_pca, write_answer
from .frames import COLLINEAR_RATIO

_MASK32 = 0xFFFFFFFF


def pool_normals(
    cloud: np.ndarray, pool: np.ndarray, rows: np.ndarray, gap: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pools.pool_normals` of the -1 padded `pool` (M, P) around the cloud points `rows` (M,): unit normals
    (M, 3), ascending eigenvalues (M, 3) and validity (M,); eigh where the two smallest eigenvalues lie within `gap`
    of the trace."""
    m = len(pool)
    normal, eigvals, valid = np.empty((m, 3)), np.empty((m, 3)), np.zeros(m, dtype=np.bool_)
    bands(
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
        valid[b] = moments_pca(sums, gap, cov, eigvals[b], normal[b])


def tree_normals(
    tree: KDTree, centres: np.ndarray, rows: np.ndarray | None, radius: float, k: int, gap: float, width: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pool_normals` of the nearest `k` points inside the ball around each centre, searched and summed in one loop
    per point (`KDTree.nearest`'s search; `rows` as there): the pools are never stored, and their points are summed
    while the search has them in cache. With the `width` of an organized cloud whose rows of `width` pixels the
    tree's ids are, a pool within one image row or one image column is not valid (`search.pools.ScanLines.single`:
    one scan line, collinear whatever its noise says)."""
    m = len(centres)
    normal, eigvals, valid = np.full((m, 3), np.nan), np.full((m, 3), np.nan), np.zeros(m, dtype=np.bool_)
    if tree.size and m and k > 0:
        coordinates, at, which, starts = tree.in_leaf_order(centres, rows)
        bands(
            _tree_pca, m, tree.columns, tree.ids, tree.span, tree.box, tree.depth, tree.leaf_size, coordinates,
            at, which, starts, float(radius) ** 2, int(k), float(gap), int(width), normal, eigvals, valid, pieces=4,
        )  # fmt: skip
    return normal, eigvals, valid


@njit(cache=True, nogil=True, error_model="numpy")
def _tree_pca(
    cols, ids, span, box, depth, leaf_size, centres, at, which, starts, r2, k, gap, width, normal, eigvals, valid,
    lo, hi,
):  # fmt: skip
    """`_pool_pca` of each query's nearest k (`kdtree._nearest_one`), its moments summed from the tree's own points
    while the search has them in cache, for the queries at[lo:hi] into the rows which[lo:hi]; with a `width`, not
    valid where the pool lies on one scan line (`single`)."""
    scratch = scratch_for(k, leaf_size)
    cov = np.empty((3, 3))
    sums = np.empty(10)
    for j in range(lo, hi):
        c, q = at[j], which[j]
        x, y, z = centres[c, 0], centres[c, 1], centres[c, 2]
        count = _nearest_one(cols, ids, span, box, depth, starts[j], x, y, z, r2, k, scratch)
        if count == 0:
            continue
        sums[:] = 0.0
        for a in range(count):
            t = scratch.best_pos[a]
            add_moments(sums, cols[0, t] - x, cols[1, t] - y, cols[2, t] - z)
        valid[q] = moments_pca(sums, gap, cov, eigvals[q], normal[q])
        if width > 0 and valid[q]:
            valid[q] = not single(ids, scratch.best_pos, count, width)


def answers(normal: np.ndarray, eigvals: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`paths.call.finish` of `pca`'s answers (`tree_normals`' or a range image's `pool_normals`'): float32 unit
    normals (M, 3) and curvature (M,), NaN where not valid or where the pool spans no plane (`frames.spans_plane`).
    One compiled loop: as torch passes over a chunk of 65k answers the same steps took about three times as long."""
    m = len(valid)
    normals, curvature = np.empty((m, 3), dtype=np.float32), np.empty(m, dtype=np.float32)
    _answers(normal, eigvals, valid, normals, curvature)
    return normals, curvature


@njit(cache=True, nogil=True, error_model="numpy")
def _answers(normal, eigvals, valid, normals, curvature):
    for i in range(len(valid)):
        spans = eigvals[i, 1] > COLLINEAR_RATIO * eigvals[i, 2]
        write_answer(normal[i, 0], normal[i, 1], normal[i, 2], eigvals[i], valid[i] and spans, normals, curvature, i)


@njit(cache=True, nogil=True, inline="always")
def single(ids, places, count, width):
    """`search.pools.ScanLines.single` of one pool, its compiled twin: whether the pool ids[places[:count]] lies
    within one image row or one image column of an image `width` pixels wide. The torch one also counts a short
    pool's padding as the centre's pixel, which changes nothing here: a pool of fewer than k points holds every point
    of the ball, its centre among them. Most pools leave both lines within their first few points, so the loop stops
    there."""
    row0, col0 = divmod(ids[places[0]], width)
    same_row = same_col = True
    for a in range(1, count):
        row, col = divmod(ids[places[a]], width)
        same_row = same_row and row == row0
        same_col = same_col and col == col0
        if not (same_row or same_col):
            return False
    return True


def warm() -> None:
    """Compile (or load from the cache) the kernels on a few tiny pools, so that no
    cloud waits for it: the node's start-up probe calls this whatever its method."""
    v, u = np.mgrid[0:4, 0:4].astype(np.float64)
    cloud = np.stack((u, v, np.ones_like(u) + 0.1 * u * v), axis=-1).reshape(-1, 3)
    pool = np.arange(16, dtype=np.int64).reshape(2, 8)
    pool_normals(cloud, pool, np.arange(2), 1e-3)
    answers(*tree_normals(KDTree(cloud), cloud[:2], np.arange(2), 3.0, 8, 1e-3, width=4))
