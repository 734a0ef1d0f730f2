"""The network on a lattice of hybrid's gated pixels; a pixel between takes its neighbours' mean where they agree.

Where hybrid's gate opens on an organized range image (a fold, an edge, a small object), it opens on connected bands
of pixels, and along a band neighbouring pixels get nearly the same network answer. So the network runs on the gated
pixels of a lattice (every STRIDE-th row and column), and each gated pixel between looks at the gated lattice pixels
that bracket it (up to four, at most STRIDE - 1 pixels away on each axis). Where at least two of them answered and
every answer lies within AGREE_DEGREES of their sign-aligned mean, the pixel takes that mean; where they disagree (it
sits across a fold from some of them), or fewer than two answered (a band one pixel wide), the network answers it on
its own pool. The mean of agreeing answers also averages the network's own noise: on frames eval never scores this is
as accurate as the network on every gated pixel, at 40 % of its passes at 10° and a fifth fewer at 25° (docs/HISTORY.md,
"The network on a lattice").

The lattice's own pixels are answered the same way one level up: those off the coarser lattice (every COARSE_STRIDE-th
row and column) take the mean of their gated coarse neighbours where those agree within the tighter
COARSE_AGREE_DEGREES, else the network. A real depth camera's noise opens the gate on wide patches of a surface, where
this cuts a quarter to two fifths of the passes; at folds the coarse neighbours disagree and the finer rule stands
(docs/HISTORY.md, "The gate reads the fitted windows too").

A pixel that takes its neighbours' mean never opens its own pool, so where that pool would have given no answer (it
lies on one scan line) the pixel has the neighbours' network answer instead of the survey's; both are planes its
window determines. A pixel's answer depends on the image alone, not on which pixels were asked for: a sparse query
gets the answers the whole frame gets, at up to 21 network passes per gated pixel asked for (its four lattice
neighbours, each of theirs at the coarser level, and each one's own where those disagree).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

#: The lattice's spacing in pixels: the network runs on 1/STRIDE² of a whole frame's gated pixels, and on those whose
#: lattice neighbours disagree.
STRIDE = 2
#: Lattice answers agree when each lies within this angle of their mean. Chosen on fold and room frames of seeds eval
#: never scores (docs/RESULTS.md): from 5° to 25° hybrid's MSAE moved by about 1 %, and 25° runs the network on a fifth
#: fewer pixels than 10°, which buys back most of what the window gate's lower z (`survey.window_z`) adds.
AGREE_DEGREES = 25.0
#: The coarser lattice's spacing in pixels (a multiple of STRIDE; STRIDE or less turns the coarser level off) ...
COARSE_STRIDE = 4
#: ... and its agreement angle: tighter than AGREE_DEGREES because its neighbours lie twice as far apart. Chosen on
#: fold and room frames of seeds eval never scores and the real Kinect frames (docs/RESULTS.md).
COARSE_AGREE_DEGREES = 7.5


def levels() -> tuple[tuple[int, float], ...]:
    """The lattice levels, finest first, as (stride, agreement angle), read at the call: none at STRIDE 1 (the
    network on every gated pixel), the coarser level only where COARSE_STRIDE exceeds STRIDE. A coarser stride must
    be a multiple of STRIDE, so that the coarse lattice's pixels lie on the finer one."""
    if STRIDE <= 1:
        return ()
    if COARSE_STRIDE > STRIDE:
        if COARSE_STRIDE % STRIDE:
            raise ValueError(f"the coarser lattice's stride {COARSE_STRIDE} is not a multiple of {STRIDE}")
        return ((STRIDE, AGREE_DEGREES), (COARSE_STRIDE, COARSE_AGREE_DEGREES))
    return ((STRIDE, AGREE_DEGREES),)


class LatticePlan(NamedTuple):
    """Which pixels the network answers first, and each asked-for gated pixel's lattice neighbours among them."""

    run: np.ndarray  # (R,) sorted unique pixel indices: the gated lattice pixels some asked-for pixel needs
    candidates: np.ndarray  # (M, 4) positions in `run` of each asked-for pixel's gated lattice neighbours, -1 padded


def plan_lattice(
    gated: np.ndarray, shape: tuple[int, int], pixels: np.ndarray, stride: int | None = None
) -> LatticePlan:
    """The lattice plan for the gated `pixels` (flat indices) of an H × W image whose gate is `gated` (H·W bool),
    at `stride` (default STRIDE, read at the call: 1 sends every gated pixel to the network).

    A pixel's candidates are the gated pixels among the lattice points that bracket it: the lattice rows at or
    around its row times the lattice columns at or around its column. A lattice pixel's only candidate is itself."""
    height, width = shape
    stride = STRIDE if stride is None else stride
    row, col = np.divmod(pixels.astype(np.int64), width)
    rows, cols = _bracket(row, stride, height), _bracket(col, stride, width)
    candidates = (rows[:, :, None] * width + cols[:, None, :]).reshape(len(pixels), 4)
    usable = ((rows[:, :, None] >= 0) & (cols[:, None, :] >= 0)).reshape(len(pixels), 4)
    usable &= gated[np.where(usable, candidates, 0)]
    run = np.unique(candidates[usable])
    return LatticePlan(run, np.where(usable, np.searchsorted(run, np.where(usable, candidates, 0)), -1))


def _bracket(index: np.ndarray, stride: int, size: int) -> np.ndarray:
    """(M, 2) the lattice lines at or around each index: (index, -1) on a lattice line, else the one before and the
    one after (-1 past the image's edge)."""
    below = index - index % stride
    above = below + stride
    on = index % stride == 0
    return np.stack((below, np.where(on | (above >= size), -1, above)), axis=1)


def agreed(answers: torch.Tensor, candidates: torch.Tensor, degrees: float | None = None) -> torch.Tensor:
    """(M, 3) the sign-aligned mean of each pixel's candidate answers (rows of `answers`, NaN where the network gave
    none) where at least two answered and each lies within `degrees` (default AGREE_DEGREES) of it; NaN elsewhere.
    One neighbour's answer alone is not taken: it carries that pixel's network noise undiluted, and its own answer
    costs the same. `candidates` (M, 4) rows of `answers`, -1 padded."""
    if len(answers) == 0:  # no asked-for pixel has a gated lattice neighbour
        return torch.full((len(candidates), 3), torch.nan, dtype=torch.float64)
    normal = answers[candidates.clamp_min(0)].to(torch.float64)  # (M, 4, 3)
    usable = (candidates >= 0) & torch.isfinite(normal).all(dim=-1)
    normal = torch.where(usable.unsqueeze(-1), normal, 0.0)
    first = normal[torch.arange(len(normal)), usable.to(torch.int8).argmax(dim=1)]
    sign = torch.where((normal * first.unsqueeze(1)).sum(dim=-1) < 0, -1.0, 1.0)
    mean = torch.nn.functional.normalize((normal * sign.unsqueeze(-1)).sum(dim=1), dim=-1)
    within = math.cos(math.radians(AGREE_DEGREES if degrees is None else degrees))
    close = (normal * mean.unsqueeze(1)).sum(dim=-1).abs() >= within
    agree = (close | ~usable).all(dim=1) & (usable.sum(dim=1) >= 2)
    return torch.where(agree.unsqueeze(-1), mean, torch.nan)
