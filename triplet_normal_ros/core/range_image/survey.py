"""Hybrid's window survey of an organized range image: the plane normal of each window, and whether its parts sit off
that plane (the cue its gate reads).

The survey's normal models noise along the sensor's rays (`ray_noise_normal`), the cue measures where a window's
parts sit off its own such plane (`structure`), first on the windows over the whole ball and then on the survey's,
fitted to the slope (`survey_on_slope`); `opens` is the gate over the cue. A compiled image
(`image_numba.CompiledImage`) takes the compiled twin (`survey_numba.survey`, the same values to roundoff). The path
that runs it is `paths/range_image.py`; the gate over pools is `pca.frames.quadric_gain`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from ..config.conventions import MIN_NEIGHBOURS
from . import survey_numba
from .image import MomentImage, WindowPCA, box_sums, ray_noise_normal

#: Hybrid's window survey reads a window's parts only when it spans at least this many pixels on both axes (3: a
#: LiDAR's 3-beam windows keep the survey, which measured 0.86 × pool PCA's MSAE on eval's scans; 5 sent them to pools
#: and measured 1.01 ×).
PART_SPAN = 3


def opens(cue: Structure, gate: float, bend: float) -> torch.Tensor:
    """Where a window's parts sit off its plane both significantly (z) and substantially (bend): the window gate."""
    return (cue.z > window_z(gate)) & (cue.bend > bend)


def window_z(gate: float) -> float:
    """The window gate's z threshold for hybrid's `gate`: a part's centroid more than sqrt(gate) standard errors off the
    survey's plane (3.16 at the default 10), beside the bend it must also exceed.

    On a plane the parts' largest z is about 1-3 whatever the noise, so the bend decides where the network answers
    and the z only keeps noise-sized departures out; a higher z leaves folds that bend a window by more than the bend
    but by few standard errors to the survey (docs/HISTORY.md, "The window gate, re-tuned with the lattice")."""
    return gate**0.5


def survey_and_cue(image: MomentImage, fit: WindowPCA) -> tuple[torch.Tensor, Structure]:
    """The survey's normal (`ray_noise_normal`) and the parts' cue along it (`structure`) of `fit`, the image's
    latest windows: compiled where the windows were (`survey_numba.survey`, the same values to roundoff:
    test_fused.py), else in torch."""
    if not image.compiled:
        survey = ray_noise_normal(fit)
        return survey, structure(image, fit, survey)
    normal, z, bend = survey_numba.survey(image.table.numpy(), image.offset.numpy(), image.fit)
    return torch.from_numpy(normal), Structure(torch.from_numpy(z), torch.from_numpy(bend))


def survey_normal(image: MomentImage, fit: WindowPCA) -> torch.Tensor:
    """`survey_and_cue`'s normal alone, for windows whose parts nothing reads."""
    if not image.compiled:
        return ray_noise_normal(fit)
    normal, _, _ = survey_numba.survey(image.table.numpy(), image.offset.numpy(), image.fit, parts=False)
    return torch.from_numpy(normal)


def survey_on_slope(
    image: MomentImage, fit: WindowPCA, survey: torch.Tensor, cue: Structure
) -> tuple[torch.Tensor, Structure]:
    """The survey's normal from windows fitted to the slope of its first plane (`image.on_slope`), where they fit one,
    and the parts' cue (`structure`) of those same windows; where none fits, `survey` (the normal of `fit`, the
    windows the fitted ones start from) and `cue` (the gate's first cue, of whichever windows the caller read).

    A window sized from the range reaches past the ball on a surface seen at a grazing angle, across a fold where the
    range is continuous; the window fitted to the slope of the first survey's plane covers the ball on that surface.
    The first plane is the ray-noise plane, not PCA's: on a far, noisy surface PCA's axis tips toward the ray and
    would read as a slope that is not there. The gate reads both windows' cues: the first window's parts see a fold
    beside the ball, the fitted window's parts see one the survey's own answer straddles, which the first window,
    sized for a frontal surface, can average away. Measured on fold and room frames eval never scores:
    docs/HISTORY.md, "Folds" and "The gate reads the fitted windows too".
    """
    first = torch.where(fit.valid.unsqueeze(-1), survey, 0.0)
    sloped = image.pca_on_slope(first)
    normal, sloped_cue = _sloped_survey(image, sloped)
    fitted = sloped.valid
    return torch.where(fitted.unsqueeze(-1), normal, survey), Structure(
        torch.where(fitted, sloped_cue.z, cue.z), torch.where(fitted, sloped_cue.bend, cue.bend)
    )


def _sloped_survey(image: MomentImage, fit: WindowPCA) -> tuple[torch.Tensor, Structure]:
    """`ray_noise_normal` and `structure` of the windows `pca_on_slope` fitted: compiled where they were (the same
    values to roundoff: test_fused.py), else in torch."""
    if not image.compiled:
        normal = ray_noise_normal(fit)
        return normal, structure(image, fit, normal)
    normal, z, bend = survey_numba.survey(image.table.numpy(), image.offset.numpy(), image.slope_fit)
    return torch.from_numpy(normal), Structure(torch.from_numpy(z), torch.from_numpy(bend))


class Structure(NamedTuple):
    """How far each window departs from its own PCA plane, measured by the centroids of its parts (`structure`)."""

    #: Largest |height| of a part's centroid above the window's plane over the part's noise standard error: is the
    #: departure significant? About 1-3 on any plane, whatever its noise; large across a fold or an edge.
    z: torch.Tensor
    #: That largest height in units of the window's reach (the radius): is the departure large?
    bend: torch.Tensor


def structure(image: MomentImage, fit: WindowPCA, normal: torch.Tensor | None = None) -> Structure:
    """The O(1) cue of hybrid's gate: where a quadric would beat the plane, parts of the window sit off it.

    Each window is cut into five parts (its upper, lower, left and right halves, and its central quarter). On a
    plane every part's centroid lies on the window's PCA plane up to noise; across a fold or an edge the halves
    on either side and the centre sit above or below it by a fraction of the radius. The heights come from the
    first-moment sums of the parts, so the cue costs five box lookups per pixel, not a neighbourhood. Heights run
    along `normal` (default: PCA's), the noise is the window's variance along it; pass the survey's normal, or a
    noise-dominated window measures its heights along whichever in-plane axis PCA mistook for the normal."""
    top, bottom, left, right = fit.box
    mid_row, mid_col = (
        torch.div(top + bottom, 2, rounding_mode="floor"),
        torch.div(left + right, 2, rounding_mode="floor"),
    )
    quarter_row = torch.div(bottom - top + 2, 4, rounding_mode="floor")
    quarter_col = torch.div(right - left + 2, 4, rounding_mode="floor")
    parts = (
        (top, mid_row, left, right),
        (mid_row + 1, bottom, left, right),
        (top, bottom, left, mid_col),
        (top, bottom, mid_col + 1, right),
        (mid_row - quarter_row + 1, mid_row + quarter_row, mid_col - quarter_col + 1, mid_col + quarter_col),
    )
    first = image.first
    normal = fit.normal if normal is None else normal
    a00, a01, a02, a11, a12, a22 = fit.cov.unbind(dim=-1)
    nx, ny, nz = normal.unbind(dim=-1)
    noise = (
        a00 * nx * nx + a11 * ny * ny + a22 * nz * nz + 2 * (a01 * nx * ny + a02 * nx * nz + a12 * ny * nz)
    ).clamp_min(0)
    z = torch.zeros_like(fit.count)
    bend = torch.zeros_like(fit.count)
    centroid = fit.mean - image.offset
    for part in parts:
        lows, highs = (top, top, left, left), (bottom, bottom, right, right)
        part = tuple(b.clamp(lo, hi) for b, lo, hi in zip(part, lows, highs, strict=True))
        sums = box_sums(first, *part)
        n = sums[:, 0]
        height = ((sums[:, 1:] / n.clamp_min(1).unsqueeze(-1) - centroid) * normal).sum(dim=-1).abs()
        spread = torch.sqrt(noise * (1 / n.clamp_min(1) - 1 / fit.count.clamp_min(1)).clamp_min(0))
        ok = (n >= MIN_NEIGHBOURS) & (n < fit.count)
        z = torch.where(ok, torch.maximum(z, height / spread.clamp_min(1e-12)), z)
        bend = torch.where(ok, torch.maximum(bend, height / fit.reach), bend)
    return Structure(z, bend)
