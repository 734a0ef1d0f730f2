"""Sign disambiguation toward a viewpoint: PCL's flipNormalTowardsViewpoint, vectorised."""

from collections.abc import Sequence

import numpy as np


def orient_towards_viewpoint(
    points: np.ndarray, normals: np.ndarray, viewpoint: Sequence[float] = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """Flip each normal so that (viewpoint - p) · n >= 0; NaN rows stay NaN.

    For depth cameras the viewpoint is the sensor origin of the cloud's frame, so normals face the camera.
    """
    points = np.asarray(points)
    normals = np.asarray(normals)
    if points.shape != normals.shape or points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points {points.shape} and normals {normals.shape} must both be (N, 3)")
    view = np.asarray(viewpoint, dtype=np.float64).reshape(1, 3)
    facing = np.einsum("ij,ij->i", view - points, normals)
    return np.where((facing < 0)[:, None], -normals, normals).astype(normals.dtype, copy=False)
