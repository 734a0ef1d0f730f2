"""The paper's two training losses, the triplet loss (Eq. 4) and the weighted cos^n normal loss (Eq. 5-6), and our
squared-angle losses, absolute and relative to PCA (docs/MODEL.md)."""

import math

import torch

#: φ in `relative_angle_loss` (degrees): patches where PCA errs by much less than φ all get a weight near 1.
RELATIVE_FLOOR_DEG = 5.0
LOSSES = ("cos", "angle", "relative")


def triplet_loss(anchor: torch.Tensor, positive: torch.Tensor, negative: torch.Tensor, margin: float = 0.0):
    """mean(max(||f(P) - f(S)||_2 - ||f(P) - f(T)||_2 + m, 0)); the paper uses m = 0."""
    d_pos = torch.linalg.vector_norm(anchor - positive, dim=-1)
    d_neg = torch.linalg.vector_norm(anchor - negative, dim=-1)
    return torch.relu(d_pos - d_neg + margin).mean()


def normal_loss(
    predicted: torch.Tensor,
    centre_normal: torch.Tensor,
    patch_normals: torch.Tensor,
    exponent: int = 8,
    support_deg: float = 15.0,
    valid: torch.Tensor | None = None,
) -> torch.Tensor:
    """Weighted mean over the patch of 1 - (n' · n_j)^exponent, weights exp(-(1 - n_i · n_j) / (1 - cos σ_s)).

    An even exponent makes it invariant to the sign of the prediction. A high exponent punishes only clearly wrong
    directions, so a prediction on an edge commits to one face instead of averaging both (the paper's sharpness).
    predicted (B, 3), centre_normal (B, 3), patch_normals (B, k, 3); `valid` (B, k) masks padded duplicates if wanted.
    """
    cos = torch.einsum("bkj,bj->bk", patch_normals, predicted)
    agreement = torch.einsum("bkj,bj->bk", patch_normals, centre_normal)
    weight = torch.exp(-(1.0 - agreement) / (1.0 - math.cos(math.radians(support_deg))))
    if valid is not None:
        weight = weight * valid.to(weight.dtype)
    per_patch = (weight * (1.0 - cos.pow(exponent))).sum(dim=1) / weight.sum(dim=1).clamp_min(1e-12)
    return per_patch.mean()


def squared_angles(predicted: torch.Tensor, centre_normal: torch.Tensor) -> torch.Tensor:
    """Per-row squared sign-invariant angle (rad²); atan2 keeps the gradient finite at 0 and 90°."""
    dot = (predicted * centre_normal).sum(dim=-1).abs()
    cross = torch.linalg.vector_norm(torch.linalg.cross(predicted, centre_normal, dim=-1), dim=-1)
    return torch.atan2(cross, dot).pow(2)


def angle_loss(predicted: torch.Tensor, centre_normal: torch.Tensor) -> torch.Tensor:
    """Mean squared sign-invariant angle (rad²) to the centre normal: the MSAE that evaluation reports, as a loss.

    Unlike cos^8 it does not reward committing to one face when the patch cannot tell which face the centre is on:
    its minimiser hedges between them in proportion to their odds.
    """
    return squared_angles(predicted, centre_normal).mean()


def relative_angle_loss(
    predicted: torch.Tensor, centre_normal: torch.Tensor, floor_deg: float = RELATIVE_FLOOR_DEG
) -> torch.Tensor:
    """Squared angle weighted by φ² / (θ_PCA² + φ²), φ = `floor_deg`: divided by PCA's own squared angle, softened.

    PCA's normal is +z in the patch frame. The plain squared angle spends the regressor on edges, where errors are
    tens of degrees, and leaves one or two degrees of random correction on smooth patches, where PCA is already close
    to optimal; the targets are ratios to PCA, so each patch is weighted by how much PCA leaves to gain there. The
    weight depends on the ground truth and PCA, not on the prediction, so the minimiser still hedges between faces
    like `angle_loss` where both faces are equally far from PCA, and leans towards the nearer face otherwise. φ = 0
    would divide by zero on exact planes, so it must be positive.
    """
    if not floor_deg > 0:
        raise ValueError(f"the relative loss needs a floor > 0 degrees, got {floor_deg!r}")
    pca = centre_normal.new_tensor((0.0, 0.0, 1.0)).expand_as(centre_normal)
    floor = math.radians(floor_deg) ** 2
    weight = floor / (squared_angles(pca, centre_normal) + floor)
    return (weight * squared_angles(predicted, centre_normal)).mean()


def patch_loss(
    kind: str,
    predicted: torch.Tensor,
    centre_normal: torch.Tensor,
    patch_normals: torch.Tensor,
    exponent: int = 8,
    support_deg: float = 15.0,
    floor_deg: float = RELATIVE_FLOOR_DEG,
) -> torch.Tensor:
    """The recipe's normal loss by name: 'cos' (the paper's Eq. 5-6), 'angle' (`angle_loss`) or 'relative'
    (`relative_angle_loss`)."""
    if kind == "angle":
        return angle_loss(predicted, centre_normal)
    if kind == "relative":
        return relative_angle_loss(predicted, centre_normal, floor_deg)
    if kind == "cos":
        return normal_loss(predicted, centre_normal, patch_normals, exponent, support_deg)
    raise ValueError(f"unknown normal loss {kind!r}: expected one of {LOSSES}")
