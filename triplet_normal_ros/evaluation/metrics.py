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
#: The seed of the fixed query subset every validation-shape table scores (`query_indices`).
QUERY_SEED = 0


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


def ratio_interval(
    pairs: list[tuple[np.ndarray, np.ndarray]], draws: int = 1000, level: float = 0.95, seed: int = 0
) -> tuple[float, float]:
    """Paired bootstrap interval of Σ mean(a) / Σ mean(b) over clouds, e.g. ours' MSAE over PCA's.

    `pairs` holds each cloud's per-point squared angles for both methods at the same query points. Points are
    resampled within each cloud, the same draw for both methods, so the interval reflects which query points were
    drawn, not the choice of shapes or noise. Why: a ratio of 1.005 means nothing without its sampling error.
    """
    rng = np.random.default_rng(seed)
    num, den = np.zeros(draws), np.zeros(draws)
    for a, b in pairs:
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if a.shape != b.shape or a.ndim != 1 or len(a) == 0:
            raise ValueError(f"each pair needs two equal, non-empty 1-D arrays, got {a.shape} and {b.shape}")
        rows = rng.integers(0, len(a), size=(draws, len(a)))
        num += a[rows].mean(axis=1)
        den += b[rows].mean(axis=1)
    lo, hi = np.quantile(num / den, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def query_indices(n: int, count: int) -> np.ndarray:
    """The fixed query subset: numpy.random.default_rng(QUERY_SEED).choice(n, count, replace=False), sorted."""
    return np.sort(np.random.default_rng(QUERY_SEED).choice(n, min(n, count), replace=False))
