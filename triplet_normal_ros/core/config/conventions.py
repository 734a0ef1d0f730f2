"""The contract between training and inference, defined once.

A checkpoint records these values in its metadata (``conventions``) and loading refuses one trained under others,
so changing a value here can never silently mismatch a shipped model.
"""

import numpy as np

from ..rows import finite_rows

#: The methods `NormalEstimator` offers: the network everywhere (weighed against the ball's plane), PCA, or PCA with
#: the network where it is not flat.
METHODS = ("learned", "pca", "hybrid")
#: The learned method draws its k points from the nearest POOL_FACTOR * k points inside the ball; its PCA frame comes
#: from that whole pool (its curvature, over pools, from the whole ball: `learned.trust`).
POOL_FACTOR = 4
#: Training radius, and the offline tools' default: this fraction of the cloud's bounding-box diagonal.
RADIUS_FRACTION = 0.05
#: The metric radii of the simulated range sets, in training and evaluation alike: 5 cm on depth frames, as robots
#: use; on 32-beam LiDAR scans the rings are ~1.3° apart, so a ball must span several of them: 25 cm.
DEPTH_RADIUS, LIDAR_RADIUS = 0.05, 0.25
#: ... and beyond 8 m the LiDAR ball grows with range, to 0.03 × the range (`NormalEstimator.range_scale`): windows
#: then span about three beams of a 32-beam scanner at any range, and more of denser ones (docs/RESULTS.md, "LiDAR
#: neighbourhoods").
LIDAR_RANGE_SCALE = 0.03
#: Fewer neighbours than this inside the ball gives a NaN row (PCL's convention: a plane needs three points).
MIN_NEIGHBOURS = 3
#: Hybrid's gate, on its two surveys. Over pools (any cloud that is not an organized range image) the network answers
#: where a quadric explains the neighbourhood better than the PCA plane by more than HYBRID_GATE, an F statistic
#: (about 1 on a flat surface at any noise level), ...
HYBRID_GATE = 10.0
#: ... and departs from the plane by more than HYBRID_BEND, an RMS height in units of the radius (a systematic
#: millimetre of waviness in a 5 cm ball is significant but harmless). On an organized range image the survey is the
#: integral-image window (core/range_image/survey.py) and the gate reads the window's parts instead: the network
#: answers where a part's centroid sits off the survey's plane by more than sqrt(gate) standard errors
#: (`survey.window_z`, a z threshold) and by more than bend radii (`survey.opens`). The pool values were chosen with
#: docs/tools/gate_study.py, the window's with docs/tools/window_gate_study.py and lattice_study.py, on seeds eval does
#: not score.
HYBRID_BEND = 0.03
#: Neighbour searches: 'kdtree' (CPU), 'grid' (organized clouds only; falls back to the KD-tree), 'voxel' (sorted cell
#: lists on the device, any cloud), 'window' (organized range images: integral-image windows, O(1) per pixel, for
#: pca and for hybrid's survey; falls back like 'grid'), 'auto' (the window for whole-ball pca and hybrid's survey on
#: an organized range image; otherwise on CUDA the grid for organized clouds, else voxel; the KD-tree on a CPU).
NEIGHBOUR_SEARCHES = ("auto", "kdtree", "grid", "voxel", "window")
#: PCA's neighbour cap when no k is given: large enough to be the whole ball for typical depth-camera radii.
PCA_DEFAULT_K = 500


def checkpoint_conventions() -> dict[str, float | int]:
    """What a checkpoint records, and what loading compares against."""
    return {"pool_factor": POOL_FACTOR, "radius_fraction": RADIUS_FRACTION}


def bbox_diagonal(points: np.ndarray) -> float:
    """Length of the axis-aligned bounding-box diagonal of the finite points (0 for fewer than two)."""
    points = np.asarray(points)
    finite = points[finite_rows(points)]
    if len(finite) < 2:
        return 0.0
    return float(np.linalg.norm(finite.max(axis=0) - finite.min(axis=0)))
