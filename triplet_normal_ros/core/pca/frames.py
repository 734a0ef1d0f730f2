"""Batched, masked PCA of neighbourhoods: normals, surface variation, and the proper rotation into the PCA frame."""

from typing import NamedTuple

import torch


def masked_covariance(points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean-centred covariance of the masked points of each row: (B, P, 3), (B, P) -> (B, 3, 3).

    Masked-out entries are zeroed first: padding may point at a NaN point, and NaN × 0 is still NaN.
    """
    points = torch.where(mask.unsqueeze(-1), points, 0.0)
    count = mask.sum(dim=1).clamp_min(1).to(points.dtype)
    mean = points.sum(dim=1) / count.unsqueeze(-1)
    # E[x x^T] - m m^T as one batched matmul: broadcasting (B, P, 3) elementwise ops cost 5x more on the CPU.
    # Coordinates are relative to the query point (|x| <= r), so float64 keeps the difference exact enough.
    second = points.transpose(1, 2) @ points / count.view(-1, 1, 1)
    return second - mean.unsqueeze(2) * mean.unsqueeze(1)


def principal_frames(cov: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Ascending eigenvalues (B, 3) and rotations R (B, 3, 3) whose rows are (x, y, z) in world coordinates.

    z is the last principal axis (smallest variance, the PCA normal), x the second, y = z × x, so det R = +1 and
    `R @ v` expresses a world vector in the patch frame. Invalid rows get the identity so eigh never sees NaN.
    """
    eye = torch.eye(3, dtype=cov.dtype, device=cov.device).expand_as(cov)
    cov = torch.where(valid.view(-1, 1, 1), cov, eye)
    eigvals, eigvecs = torch.linalg.eigh(cov)
    z_axis, x_axis = eigvecs[..., 0], eigvecs[..., 1]
    y_axis = torch.linalg.cross(z_axis, x_axis, dim=-1)
    return eigvals.clamp_min(0.0), torch.stack((x_axis, y_axis, z_axis), dim=1)


#: A neighbourhood whose middle eigenvalue is at most this fraction of its largest lies along a line (or its points
#: coincide): the plane through it may turn freely about that line, so its normal is unknown and the estimator
#: answers NaN, where PCL and Open3D publish an arbitrary axis. 1e-2 is a strip a tenth as wide as it is long: a cable,
#: a sliver beside an edge, one scan line of a LiDAR with its range noise. docs/RESULTS.md ("LiDAR neighbourhoods,
#: no-returns and degenerate neighbourhoods") measures what it removes.
COLLINEAR_RATIO = 1e-2


def spans_plane(eigvals: torch.Tensor) -> torch.Tensor:
    """(..., 3) ascending eigenvalues -> (...) bool: whether the neighbourhood spreads in two directions, so that a
    plane, and with it a normal, is determined (see COLLINEAR_RATIO)."""
    return eigvals[..., 1] > COLLINEAR_RATIO * eigvals[..., 2]


def surface_variation(eigvals: torch.Tensor) -> torch.Tensor:
    """PCL's curvature λ0 / (λ0 + λ1 + λ2); 0 for a degenerate (all coincident) neighbourhood."""
    total = eigvals.sum(dim=-1)
    return torch.where(total > 0, eigvals[..., 0] / total.clamp_min(torch.finfo(eigvals.dtype).tiny), 0.0)


def canonical_signs(frame: torch.Tensor, points: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Fix the sign ambiguity of the principal axes: x and z point along the positive skew (third moment) of the
    masked, mean-centred points, and y = z × x keeps det = +1.

    eigh returns each axis with an arbitrary sign, so without this the same surface can reach the network in four
    mirrored poses; a canonical pose makes the learned estimate rotation-equivariant and the learning problem smaller.
    A symmetric patch (zero skew) keeps +, which is harmless precisely because it looks the same either way.
    """
    points = torch.where(mask.unsqueeze(-1), points, 0.0)
    weight = mask.to(points.dtype).unsqueeze(-1)
    mean = (points * weight).sum(dim=1) / weight.sum(dim=1).clamp_min(1.0)
    centred = (points - mean.unsqueeze(1)) * weight
    x_axis, z_axis = frame[:, 0], frame[:, 2]
    sign_x = torch.where(torch.einsum("bpj,bj->bp", centred, x_axis).pow(3).sum(dim=1) < 0, -1.0, 1.0)
    sign_z = torch.where(torch.einsum("bpj,bj->bp", centred, z_axis).pow(3).sum(dim=1) < 0, -1.0, 1.0)
    x_axis = x_axis * sign_x.to(frame.dtype).unsqueeze(-1)
    z_axis = z_axis * sign_z.to(frame.dtype).unsqueeze(-1)
    return torch.stack((x_axis, torch.linalg.cross(z_axis, x_axis, dim=-1), z_axis), dim=1)


#: Residual variance floor, as a fraction of r² (local coordinates are in units of r): a noiseless plane has zero
#: residuals, and 0/0 must read as "no structure" rather than as an arbitrary ratio.
_RESIDUAL_FLOOR = 1e-8


class QuadricGain(NamedTuple):
    """How much a quadric z = f(x, y) gains over the PCA plane, per neighbourhood: the two halves of hybrid's gate."""

    #: ((SS_plane - SS_quadric) / 3) / (SS_quadric / (n - 6)): is the bend *significant*? About 1 on a flat surface
    #: whatever the noise level, large where the ball straddles an edge or a fold.
    f: torch.Tensor
    #: sqrt((SS_plane - SS_quadric) / n), in units of the radius: is the bend *large*? The RMS height by which the best
    #: quadric departs from the plane over the ball. Noise alone adds only about sigma * sqrt(3 / n).
    bend: torch.Tensor
    #: SS_quadric / (n - 6), in units of the radius squared: the variance of the heights the quadric leaves, the noise
    #: once the surface's own bend is taken out (where PCA's smallest eigenvalue counts the bend as noise).
    noise: torch.Tensor


def quadric_gain(local: torch.Tensor, mask: torch.Tensor, frame: torch.Tensor) -> QuadricGain:
    """Fit a quadric to the heights above each neighbourhood's PCA plane; its F statistic and bend (`QuadricGain`).

    PCA's surface variation cannot tell a noisy far-away floor from an edge (noise alone raises it); F can. But F is
    a significance test: with hundreds of points even a millimetre of systematic waviness (real Kinect depth has it)
    is significant, so F alone sent 74-96 % of a real frame to the network. The bend measures the effect itself, in
    units of the radius, so hybrid asks for both. `local` (B, P, 3) in units of the radius, `mask` (B, P), `frame`
    (B, 3, 3) as from `principal_frames`. Rows with fewer than 7 points get F = bend = 0 and their plane's residual as
    the noise.
    """
    # float32 is enough: coordinates are in units of the radius (|x| <= 1) and the ridge below keeps the solve sane.
    weight = mask.to(torch.float32)
    local = torch.where(mask.unsqueeze(-1), local, 0.0).to(torch.float32)
    count = weight.sum(dim=1)
    mean = local.sum(dim=1) / count.clamp_min(1).unsqueeze(-1)
    xyz = ((local - mean.unsqueeze(1)) @ frame.to(torch.float32).transpose(1, 2)) * weight.unsqueeze(-1)
    x, y, z = xyz.unbind(dim=-1)
    design = torch.stack((weight, x, y, x * x, x * y, y * y), dim=-1)
    gram = design.transpose(1, 2) @ design + torch.eye(6, device=local.device) * 1e-6
    rhs = design.transpose(1, 2) @ z.unsqueeze(-1)
    # The quadric's explained sum of squares is rhs' G^-1 rhs: no per-point residuals needed.
    explained = (rhs * torch.linalg.solve(gram, rhs)).sum(dim=(1, 2))
    ss_plane = z.pow(2).sum(dim=1)
    ss_quadric = (ss_plane - explained).clamp_min(0)
    gain = ss_plane - ss_quadric
    noise = (ss_quadric / (count - 6).clamp_min(1)).clamp_min(_RESIDUAL_FLOOR)
    enough = count >= 7
    f = torch.where(enough, gain / 3 / noise, 0.0)
    bend = torch.where(enough, (gain / count.clamp_min(1)).sqrt(), 0.0)
    residual = ss_plane / count.clamp_min(1)
    return QuadricGain(f, bend, torch.where(enough, noise, residual))
