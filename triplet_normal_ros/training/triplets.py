"""Triplet mining as in the paper: for an anchor centre p_i, the positive centre s_i has a ground-truth normal within
20° of n_i, the negative t_i one beyond it, both as close to p_i as possible: first inside the ball of radius r, then
in a widening neighbourhood, so negatives sit just across the nearest sharp feature.

The widening search is done exactly: anchors that find no candidate in the ball are matched against the whole cloud
by brute force (a few hundred anchors × 100k points is a fraction of a second), which is the limit of a search
radius grown in infinitely small steps.
"""

import math

import numpy as np

from ..core.search.neighbours import NeighbourIndex

THRESHOLD_DEG = 20.0
#: Anchors per brute-force block: bounds the (block, N) distance matrix to ~100 MB at N = 100k.
_BLOCK = 128


def mine_triplets(
    index: NeighbourIndex,
    normals: np.ndarray,
    anchors: np.ndarray,
    radius: float,
    pool: int = 512,
    threshold_deg: float = THRESHOLD_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """Positive and negative centre indices (A,) for anchor indices (A,); -1 where the cloud has none at all.

    The search is deterministic (the nearest qualifying point), so it draws no random numbers.
    """
    cos_th = math.cos(math.radians(threshold_deg))
    positive = np.full(len(anchors), -1, dtype=np.int64)
    negative = np.full(len(anchors), -1, dtype=np.int64)
    candidates, _ = index.ball(index.points[anchors], radius, min(pool, len(index.points)))
    _take_nearest(candidates, anchors, normals, cos_th, positive, negative, np.arange(len(anchors)))
    todo = np.flatnonzero((positive < 0) | (negative < 0))
    for lo in range(0, len(todo), _BLOCK):
        rows = todo[lo : lo + _BLOCK]
        _brute_force(index, normals, anchors[rows], cos_th, positive, negative, rows)
    return positive, negative


def _take_nearest(candidates, anchor_idx, normals, cos_th, positive, negative, rows) -> None:
    """Fill still-missing positives/negatives of `rows` from distance-sorted candidates (-1 padded)."""
    usable = (candidates >= 0) & (candidates != anchor_idx[:, None])
    cos = np.einsum("apj,aj->ap", normals[np.maximum(candidates, 0)], normals[anchor_idx])
    for target, ok in ((positive, usable & (cos >= cos_th)), (negative, usable & (cos < cos_th))):
        first = ok.argmax(axis=1)
        found = ok[np.arange(len(rows)), first] & (target[rows] < 0)
        target[rows[found]] = candidates[found, first[found]]


def _brute_force(index: NeighbourIndex, normals, anchor_idx, cos_th, positive, negative, rows) -> None:
    """Nearest qualifying point in the whole cloud for each anchor of the block (float32 BLAS for speed)."""
    finite = np.flatnonzero(index.finite)
    pts = index.points[finite].astype(np.float32)
    nrm = normals[finite].astype(np.float32)
    a = index.points[anchor_idx].astype(np.float32)
    dist = (pts * pts).sum(axis=1)[None, :] - 2.0 * (a @ pts.T)  # |a|^2 is constant per row: irrelevant to argmin
    dist[finite[None, :] == anchor_idx[:, None]] = np.inf
    same = (normals[anchor_idx].astype(np.float32) @ nrm.T) >= cos_th
    for target, ok in ((positive, same), (negative, ~same)):
        masked = np.where(ok, dist, np.inf)
        best = masked.argmin(axis=1)
        found = np.isfinite(masked[np.arange(len(rows)), best]) & (target[rows] < 0)
        target[rows[found]] = finite[best[found]]
