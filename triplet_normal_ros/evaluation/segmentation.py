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

A spinning LiDAR's scan is organized too (beams × azimuth columns), but no distance test serves it: on the ground,
neighbouring beams land up to metres apart at range (rings 1 m apart at 10 m, 4 m at 20 m), while a box face seen
along the ring has its points centimetres apart. `scan_segments` therefore joins 4-neighbours of the scan (the last
column beside the first: the scan closes on itself) by the coplanarity that a range-image segmentation uses in place of
distance: normals within `max_angle_deg`, and each point within `max_offset` of the other's tangent plane. Points on
one plane join however far apart the beams put them; a box top and the ground beyond it, or a face and a parallel one
behind it, do not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: PCL-style smoothness test of 4-neighbour pixels: distance (m) and angle (degrees).
MAX_DISTANCE, MAX_ANGLE_DEG = 0.05, 10.0
#: The scan test: normals within this angle (degrees) and each point within this distance (m) of the other's tangent
#: plane. 0.15 m is 7 × the spread of two neighbours' difference under the scans' 1.5 cm range noise, and under the
#: height of the smallest box (0.6 m).
SCAN_MAX_ANGLE_DEG, SCAN_MAX_OFFSET = 10.0, 0.15
#: A reference segment counts as recovered when one segment overlaps it with at least this IoU.
MIN_IOU = 0.8
#: Reference segments smaller than this many pixels are not counted in the recovered share (speckle at silhouettes).
MIN_SEGMENT = 200
#: The same for a scan's segments, in points: a 1 m crate face 10 m from a 32-beam scanner holds about 130 of them.
SCAN_MIN_SEGMENT = 50


def region_segments(
    points: np.ndarray,
    normals: np.ndarray,
    max_distance: float = MAX_DISTANCE,
    max_angle_deg: float = MAX_ANGLE_DEG,
) -> np.ndarray:
    """Segment labels (H, W), int64 from 0; -1 where the point or its normal is missing.

    points, normals: (H, W, 3) organized arrays; NaN marks a missing point or normal.
    """
    pairs = _smooth_pairs(points, normals, max_angle_deg, wrap=False)
    pairs.join &= np.linalg.norm(pairs.step(), axis=1) < max_distance
    return pairs.segments()


def scan_segments(
    points: np.ndarray,
    normals: np.ndarray,
    max_offset: float = SCAN_MAX_OFFSET,
    max_angle_deg: float = SCAN_MAX_ANGLE_DEG,
) -> np.ndarray:
    """Segment labels (beams, columns) of a spinning scan, as `region_segments` gives for a frame, but with the
    coplanarity test and the columns closed into a ring (the module's docstring says why)."""
    pairs = _smooth_pairs(points, normals, max_angle_deg, wrap=True)
    step = pairs.step()
    for ends in (pairs.first, pairs.second):
        pairs.join &= np.abs(np.einsum("ij,ij->i", pairs.unit[ends], step)) <= max_offset
    return pairs.segments()


@dataclass
class _Pairs:
    """The 4-neighbour pairs of an organized cloud that pass the smoothness test so far, and what the tests read."""

    shape: tuple[int, int]
    flat: np.ndarray
    unit: np.ndarray
    usable: np.ndarray
    first: np.ndarray
    second: np.ndarray
    join: np.ndarray

    def step(self) -> np.ndarray:
        """Each pair's second point less its first."""
        return self.flat[self.second] - self.flat[self.first]

    def segments(self) -> np.ndarray:
        """The connected components of the joined pairs as (H, W) labels, -1 where a pixel is not usable."""
        size = self.shape[0] * self.shape[1]
        row, col = self.first[self.join], self.second[self.join]
        graph = coo_matrix((np.ones(len(row), dtype=np.int8), (row, col)), shape=(size, size))
        _, labels = connected_components(graph, directed=False)
        labels = labels.astype(np.int64)
        labels[~self.usable] = -1
        return _renumbered(labels.reshape(self.shape))


def _smooth_pairs(points: np.ndarray, normals: np.ndarray, max_angle_deg: float, wrap: bool) -> _Pairs:
    """Every 4-neighbour pair, joined where both pixels have a point and a normal and the normals lie within
    `max_angle_deg` (sign-invariant, as PCL compares |n_i · n_j|)."""
    if points.shape != normals.shape or points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"points and normals must both be (H, W, 3), got {points.shape} and {normals.shape}")
    flat = points.reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero or NaN normal becomes NaN: not usable
        unit = normals.reshape(-1, 3) / np.linalg.norm(normals.reshape(-1, 3), axis=1, keepdims=True)
    usable = np.isfinite(flat).all(axis=1) & np.isfinite(unit).all(axis=1)
    first, second = _grid_pairs(points.shape[:2], wrap)
    join = usable[first] & usable[second]
    join &= np.abs(np.einsum("ij,ij->i", unit[first], unit[second])) >= np.cos(np.radians(max_angle_deg))
    return _Pairs(points.shape[:2], flat, unit, usable, first, second, join)


def _grid_pairs(shape: tuple[int, int], wrap: bool) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of every 4-neighbour pair (right and down), with each row's last pixel beside its first when
    `wrap`."""
    height, width = shape
    index = np.arange(height * width).reshape(height, width)
    right = np.roll(index, -1, axis=1) if wrap else index[:, 1:]
    left = index if wrap else index[:, :-1]
    first = np.concatenate([left.ravel(), index[:-1].ravel()])
    second = np.concatenate([right.ravel(), index[1:].ravel()])
    return first, second


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
