"""The closed-form eigen-decomposition of symmetric 3×3 matrices: a neighbourhood's normal without batched eigh.

Window PCA (`range_image/image.py`) answers a few hundred thousand pixels at once and pool PCA (`paths/pools.py`) tens
of thousands of pools per chunk; torch's batched eigh is most of either's cost, the closed form a few dozen elementwise
passes.
"""

from __future__ import annotations

import math

import torch

#: Below this length (the matrix scaled to unit trace) the largest cross product of two rows of A - λ0 I says no
#: plane: the smallest eigenvalue is repeated, and the eigenvector answer is NaN rather than an arbitrary axis.
DEGENERATE_CROSS = 1e-10
#: Pool PCA and the compiled scale fits hand a matrix to eigh when its two smallest eigenvalues lie closer than this
#: fraction of the trace: there the closed form's normal drifts from eigh's (1e-12 at 1e-3 on a depth frame, growing as
#: the gap closes), and at 0 (a line, coincident points, an isotropic blob) only eigh's choice of axis matches
#: `pools.pool_pca`'s.
EIGEN_GAP = 1e-3


def smallest_eigenvector(cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Ascending eigenvalues (N, 3) and the unit eigenvector of the smallest (N, 3) of symmetric 3×3 matrices given as
    their upper triangles (N, 6) = (a00, a01, a02, a11, a12, a22), in closed form.

    The eigenvalues are the trigonometric roots of the characteristic cubic (Smith 1961), the eigenvector the largest
    cross product of two rows of A - λ0 I (the rows span the plane it is normal to). Matrices are scaled by their
    trace first, so the formulas see numbers near 1 at any range or radius.
    """
    scale = (cov[:, 0].abs() + cov[:, 3].abs() + cov[:, 5].abs()).clamp_min(torch.finfo(cov.dtype).tiny)
    a00, a01, a02, a11, a12, a22 = (cov / scale.unsqueeze(-1)).unbind(dim=-1)
    q = (a00 + a11 + a22) / 3
    off = a01 * a01 + a02 * a02 + a12 * a12
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = torch.sqrt(((b00 * b00 + b11 * b11 + b22 * b22 + 2 * off) / 6).clamp_min(0))
    safe_p = p.clamp_min(1e-30)
    det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)) / safe_p.pow(
        3
    )
    phi = torch.acos((det / 2).clamp(-1.0, 1.0)) / 3
    largest = q + 2 * p * torch.cos(phi)
    smallest = q + 2 * p * torch.cos(phi + 2 * math.pi / 3)
    middle = 3 * q - largest - smallest
    eigvals = torch.stack((smallest, middle, largest), dim=-1).clamp_min(0) * scale.unsqueeze(-1)
    rows = torch.stack(
        (
            torch.stack((a00 - smallest, a01, a02), dim=-1),
            torch.stack((a01, a11 - smallest, a12), dim=-1),
            torch.stack((a02, a12, a22 - smallest), dim=-1),
        ),
        dim=1,
    )
    crosses = torch.stack(
        (
            torch.linalg.cross(rows[:, 0], rows[:, 1], dim=-1),
            torch.linalg.cross(rows[:, 0], rows[:, 2], dim=-1),
            torch.linalg.cross(rows[:, 1], rows[:, 2], dim=-1),
        ),
        dim=1,
    )
    norms = crosses.norm(dim=-1)
    pick = norms.argmax(dim=1)
    vector = crosses[torch.arange(len(pick), device=cov.device), pick]
    length = norms.gather(1, pick.unsqueeze(1))
    # No two rows of A - λ0 I span a plane when λ0 is repeated (a line, a point, an isotropic blob): no normal.
    determined = length > DEGENERATE_CROSS
    return eigvals, torch.where(determined, vector / length.clamp_min(torch.finfo(cov.dtype).tiny), torch.nan)
