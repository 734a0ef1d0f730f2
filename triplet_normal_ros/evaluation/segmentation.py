"""Planar segmentation of an organized frame by region growing, and how well one segmentation recovers another.

This is what a robot builds on normals most often: surfaces split at their edges (tabletop extraction, box faces for
grasping, floor removal). The region growing is PCL's `RegionGrowing` smoothness test on the pixel grid: 4-neighbour
pixels join when they lie within `max_distance` of each other and their normals within `max_angle_deg`
(sign-invariant, as PCL compares |n_i · n_j|). PCL's curvature test is left out, so a segment is exactly a connected
component of the graph of joined pairs, whatever order the growing visits them in. A pixel without a normal joins
nothing.

Two segmentations are compared by the adjusted Rand index (1: the same partition; about 0: chance) and by the share
of reference segments that some segment recovers with an intersection over union of at least `min_iou`. The
reference is the segmentation of the exact normals with the same test, so a method is scored on what its normals do to
the segments, not on the test's thresholds.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: PCL-style smoothness test of 4-neighbour pixels: distance (m) and angle (degrees).
MAX_DISTANCE, MAX_ANGLE_DEG = 0.05, 10.0
#: A reference segment counts as recovered when one segment overlaps it with at least this IoU.
MIN_IOU = 0.8
#: Reference segments smaller than this many pixels are not counted in the recovered share (speckle at silhouettes).
MIN_SEGMENT = 200


def region_segments(
    points: np.ndarray,
    normals: np.ndarray,
    max_distance: float = MAX_DISTANCE,
    max_angle_deg: float = MAX_ANGLE_DEG,
) -> np.ndarray:
    """Segment labels (H, W), int64 from 0; -1 where the point or its normal is missing.

    points, normals: (H, W, 3) organized arrays; NaN marks a missing point or normal.
    """
    if points.shape != normals.shape or points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"points and normals must both be (H, W, 3), got {points.shape} and {normals.shape}")
    height, width = points.shape[:2]
    unit = normals / np.linalg.norm(normals, axis=2, keepdims=True)
    usable = np.isfinite(points).all(axis=2) & np.isfinite(unit).all(axis=2)
    index = np.arange(height * width).reshape(height, width)
    cos_limit = np.cos(np.radians(max_angle_deg))
    rows, cols = [], []
    for a, b in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))), ((slice(0, -1),), (slice(1, None),))):
        join = usable[a] & usable[b]
        join &= np.linalg.norm(points[a] - points[b], axis=-1) < max_distance
        join &= np.abs(np.einsum("...i,...i->...", unit[a], unit[b])) >= cos_limit
        rows.append(index[a][join])
        cols.append(index[b][join])
    row, col = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(row), dtype=np.int8), (row, col)), shape=(height * width,) * 2)
    _, labels = connected_components(graph, directed=False)
    labels = labels.reshape(height, width).astype(np.int64)
    labels[~usable] = -1
    return _renumbered(labels)


def _renumbered(labels: np.ndarray) -> np.ndarray:
    """Labels 0..n-1 in order of first appearance, -1 kept: the same partition always reads the same."""
    out = np.full(labels.shape, -1, dtype=np.int64)
    seen = labels >= 0
    _, first, inverse = np.unique(labels[seen], return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    out[seen] = order[inverse]
    return out


def adjusted_rand_index(reference: np.ndarray, labels: np.ndarray) -> float:
    """Hubert and Arabie's adjusted Rand index over the pixels the reference labels (>= 0).

    A pixel the other segmentation leaves out (-1) counts as a segment of its own: refusing a pixel must not help.
    """
    ref = np.asarray(reference).reshape(-1)
    other = np.asarray(labels).reshape(-1)
    keep = ref >= 0
    ref, other = ref[keep], other[keep].copy()
    alone = other < 0
    other[alone] = other.max(initial=-1) + 1 + np.arange(int(alone.sum()))
    n = len(ref)
    if n < 2:
        return 1.0
    _, ref_ids = np.unique(ref, return_inverse=True)
    _, other_ids = np.unique(other, return_inverse=True)
    table = coo_matrix((np.ones(n), (ref_ids, other_ids))).tocsr()
    table.sum_duplicates()
    pairs = _pairs(table.data).sum()
    row_pairs = _pairs(np.asarray(table.sum(axis=1)).ravel()).sum()
    col_pairs = _pairs(np.asarray(table.sum(axis=0)).ravel()).sum()
    expected = row_pairs * col_pairs / _pairs(np.array([n]))[0]
    best = (row_pairs + col_pairs) / 2
    if best == expected:  # both partitions trivial (one segment, or all singletons): identical or not comparable
        return 1.0 if pairs == best else 0.0
    return float((pairs - expected) / (best - expected))


def _pairs(counts: np.ndarray) -> np.ndarray:
    counts = np.asarray(counts, dtype=np.float64)
    return counts * (counts - 1) / 2


def recovered_segments(
    reference: np.ndarray, labels: np.ndarray, min_iou: float = MIN_IOU, min_size: int = MIN_SEGMENT
) -> tuple[int, int]:
    """(how many of the reference's segments of at least `min_size` pixels one segment of `labels` overlaps with
    IoU >= `min_iou`, how many such reference segments there are)."""
    ref = np.asarray(reference).reshape(-1)
    other = np.asarray(labels).reshape(-1)
    ids, sizes = np.unique(ref[ref >= 0], return_counts=True)
    big = ids[sizes >= min_size]
    other_sizes = np.bincount(other[other >= 0], minlength=1)
    recovered = 0
    for segment in big:
        mine = ref == segment
        overlap = np.bincount(other[mine & (other >= 0)], minlength=len(other_sizes))
        best = int(overlap.argmax())
        union = mine.sum() + other_sizes[best] - overlap[best]
        recovered += bool(overlap[best] > 0 and overlap[best] / union >= min_iou)
    return recovered, len(big)
