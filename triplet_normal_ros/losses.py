"""The paper's two training losses: the triplet loss (Eq. 4) and the weighted cos^n normal loss (Eq. 5-6)."""

import math

import torch


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
