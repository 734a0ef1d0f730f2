"""Sharp folds on a range image: where hybrid's gate opened, the network's answer snapped to the plane of the one-sided
window on the pixel's own face.

A window that straddles a fold holds both faces, and so does the network's patch: both answers turn gradually across
the fold, and region growing (a 10° test between neighbours) lets one face leak into the other. A half or quarter of
the window (`image.ONE_SIDED`, each shrunk until no wall crosses it, as the windows are) that lies on one face fits
that face's plane far better than the whole window fits any. So at each gated pixel every part at least PART_SPAN
pixels across on both axes (a LiDAR's 2-beam part is a plane only across its beams) is scored by its residual
variance (its smallest eigenvalue) plus the squared distance of the pixel's own point from the part's plane (a part
on the other face fits that face well but misses the pixel). Among the parts that fit SHARPER times better than the
whole window, the one whose ray-noise plane lies nearest the network's answer, and within SNAP_DEGREES of it,
replaces the answer. The network decides which face the pixel is on; the part gives that face's plane. On a curved
face the parts fit little better than the whole window, and the answer stands.

On fold frames of seeds eval never scores this took the node's segmentation ARI from 0.15 to 0.98 with less error
overall and near edges (docs/HISTORY.md, "Sharp folds"). It runs on the gated pixels only; a compiled image takes the
compiled twin (`sides_numba.snap_to_sides`, the same answers to roundoff: test_fused.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from . import sides_numba
from .image import MomentImage, WindowPCA, box_pca, ray_noise_normal
from .survey import PART_SPAN

#: A part replaces the answer only where the whole window's smallest eigenvalue exceeds this many times the part's
#: score. Chosen on fold frames of seeds eval never scores (`docs/tools/sharp_folds_study.py`): 2 and 3 gave the same
#: segments and error, 4 a segmentation ARI of 0.95 against 0.98, 8 of 0.81.
SHARPER = 3.0
#: ... and only where the part's plane lies within this angle of the answer: 15° left the ARI at 0.81, 45° let parts
#: of the other face in (7 % more error than 30°).
SNAP_DEGREES = 30.0
_COS_SNAP = math.cos(math.radians(SNAP_DEGREES))


def snap_to_sides(
    image: MomentImage, fit: WindowPCA, cloud: torch.Tensor, pixels: np.ndarray, answers: np.ndarray
) -> np.ndarray:
    """(M, 3) float32: `answers` at the flat `pixels` (row · width + col) of `image`, after `image.pca` or
    `pca_capped` gave `fit` (its latest windows), each replaced by the plane of its best one-sided part where one
    qualifies (module docstring), its sign kept; rows with no answer (NaN) stay NaN."""
    if len(pixels) == 0:
        return answers
    if image.compiled:
        pitch = (image.pitch_row.numpy(), image.pitch_col.numpy())
        points = image.points.numpy().reshape(-1, 3)
        return sides_numba.snap_to_sides(image.fit, pitch, points, pixels, answers, SHARPER, _COS_SNAP)
    index = torch.from_numpy(pixels).to(image.device)
    row, col = index // image.width, index % image.width
    answer = torch.from_numpy(answers).to(image.device, torch.float64)
    whole = fit.eigvals[index, 0]
    point = cloud[index].to(torch.float64)
    counts = image.counts
    reach = fit.reach if isinstance(fit.reach, float) else fit.reach[index]
    best = answer.clone()
    nearest = torch.full((len(pixels),), _COS_SNAP, dtype=torch.float64, device=image.device)
    for box in image.one_sided_boxes(pixels).unbind(0):
        top, bottom, left, right = box.unbind(0)
        part = box_pca(image.table, counts, image.offset, (top, bottom, left, right), row, col, reach)
        normal = ray_noise_normal(part)
        offside = ((point - part.mean) * normal).sum(dim=-1).square()
        wide = (bottom - top >= PART_SPAN - 1) & (right - left >= PART_SPAN - 1)
        fits = part.valid & wide & (SHARPER * (part.eigvals[:, 0] + offside) < whole)
        dot = (normal * answer).sum(dim=-1)
        closer = fits & (dot.abs() > nearest)
        nearest = torch.where(closer, dot.abs(), nearest)
        best = torch.where(closer.unsqueeze(-1), normal * torch.sign(dot).unsqueeze(-1), best)
    return best.to(torch.float32).cpu().numpy()
