"""Sign-invariant angular error metrics for unoriented normals.

MSAE (the paper's metric, after Lu et al.'s DFP) is the mean squared angle in rad²; RMSE is PCPNet's metric,
sqrt(mean(angle²)) in degrees. Both treat n and -n as the same normal, because neither PCA nor the network
orients its output.

A prediction that is NaN (the estimator found < 3 neighbours) counts as the worst sign-invariant error, 90°,
instead of being dropped: dropping would reward a method for refusing hard points. `invalid_count` reports how
many there were so tables can show it.
"""

import numpy as np

WORST_ANGLE = np.pi / 2


def angles_rad(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-point angle arccos(clip(|n·g|, 0, 1)) in radians after normalising both; NaN predictions give 90°."""
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(gt, dtype=np.float64).reshape(-1, 3)
    if pred.shape != gt.shape:
        raise ValueError(f"pred and gt must have the same shape, got {pred.shape} and {gt.shape}")
    pred = pred / np.linalg.norm(pred, axis=1, keepdims=True)
    gt = gt / np.linalg.norm(gt, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", pred, gt))
    angle = np.arccos(np.clip(cos, 0.0, 1.0))
    return np.where(np.isfinite(angle), angle, WORST_ANGLE)


def angles_deg(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """`angles_rad` in degrees (the heat maps' colour scale)."""
    return np.degrees(angles_rad(pred, gt))


def msae(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean squared angular error in rad² (the paper's MSAE); NaN predictions count as 90°."""
    return float(np.mean(angles_rad(pred, gt) ** 2))


def rmse_deg(pred: np.ndarray, gt: np.ndarray) -> float:
    """Root mean squared angle in degrees (PCPNet's RMSE); NaN predictions count as 90°."""
    return float(np.degrees(np.sqrt(msae(pred, gt))))


def invalid_count(pred: np.ndarray) -> int:
    """How many predicted rows are not finite (scored as 90° by the metrics above)."""
    return int((~np.isfinite(np.asarray(pred).reshape(-1, 3)).all(axis=1)).sum())
