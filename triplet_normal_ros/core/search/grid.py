"""Ball neighbourhoods of an organized cloud through its pixel grid, in torch, on the estimator's device.

A depth camera or a spinning LiDAR publishes a range image: the neighbours of a pixel in 3D are (mostly) its neighbours
in the image. Depth-image pipelines (PCL's integral-image normals, depth_image_proc) use that instead of a KD-tree. Here
each query looks at a window of the image around its pixel, sized from the metric radius and the point's range, sampled
on a regular sub-grid of at most ``side × side`` pixels, and keeps the samples that fall inside the metric ball. The
result has the same form as `NeighbourIndex.ball` (indices into the cloud, -1 padded), so both methods use it unchanged.

What it gives is a *uniform sample of the whole ball* (every pixel when the ball spans fewer than ``side`` pixels per
axis), not the nearest ``max_nn`` points: on a dense depth frame a nearest-512 pool covers only the inner 40 % of a 5 cm
ball, while training patches (uniform samples of CAD shapes) see the whole ball. docs/DESIGN.md shows the comparison.

The window size assumes the cloud is in the sensor's frame (sensor at the origin), as drivers publish organized
clouds; `range_image.check.inspect_grid` says whether it is, and measures the pitch.
"""

from __future__ import annotations

import math

import torch

#: The angular pitch of a range image's rows and columns (radians per pixel), one value per row and per column.
RangePitch = tuple[torch.Tensor, torch.Tensor]
#: Half-side of the coarse probe lattice that measures the ball's extent per axis before the full lattice is laid.
_PROBE_HALF = 3


class GridIndex:
    """Neighbour search through the (height, width) pixel grid of one organized cloud, on `points`' device."""

    def __init__(self, points: torch.Tensor, height: int, width: int, pitch: RangePitch) -> None:
        if points.ndim != 2 or points.shape != (height * width, 3):
            raise ValueError(f"points {tuple(points.shape)} do not form a {height}x{width} organized cloud")
        self.height, self.width = height, width
        self.points = points.to(torch.float32)  # sensor data is float32; the ball test needs no more
        self.finite = torch.isfinite(points).all(dim=1)
        self.range = torch.where(self.finite, points.norm(dim=1), torch.inf)
        self.pitch = pitch  # per row (between rows r, r+1), per column

    def ball(self, rows: torch.Tensor, radius: float, samples: int) -> torch.Tensor:
        """Indices (M, side²) of about `samples` points spread uniformly over each query's ball, -1 padded.

        The lattice has side² >= samples × 4/π slots (a disc fills π/4 of its square), so a ball seen face-on holds
        about `samples` of them.

        Two passes: a coarse probe, spaced for a surface facing the sensor (the widest the ball can appear), measures
        how far the ball really reaches along each image axis; the full lattice then spans just that, so a floor seen
        at a grazing angle, a few pixels tall, is still sampled on several rows instead of one line. The query point
        itself is always a sample.
        """
        half = _odd_side(math.ceil(samples * 4 / math.pi)) // 2
        # The ball's half-angle as seen from the sensor: a neighbour may be up to `radius` nearer than the query.
        reach = radius / (self.range[rows] - radius).clamp_min(radius)
        lines = (rows // self.width, rows % self.width)
        span = torch.stack([torch.ceil(reach / p[i]) for p, i in zip(self.pitch, lines, strict=True)], dim=1)
        span = span.clamp(1, 1 << 20)  # pixels from the query to the ball's edge, per axis, at most
        # A coarse probe measures how far the ball really reaches along each axis before the full lattice is laid.
        probe = min(half, _PROBE_HALF)
        probe_step = torch.ceil(span / probe)
        coarse = _spiral_offsets(probe, rows.device)
        hit = self._sample(rows, coarse, probe_step, radius) >= 0
        reached = (coarse.abs().unsqueeze(0) * probe_step.unsqueeze(1)).where(hit.unsqueeze(-1), 0).amax(dim=1)
        span = torch.minimum(span, reached + probe_step - 1).clamp_min(1)
        return self._sample(rows, _spiral_offsets(half, rows.device), torch.ceil(span / half), radius)

    def _sample(self, rows: torch.Tensor, offsets: torch.Tensor, steps: torch.Tensor, radius: float) -> torch.Tensor:
        """Cloud indices of the lattice `offsets` × per-query `steps` (row, column) around each query, inside the
        ball, else -1. Strict `<`, like the KD-tree's ball; NaN points compare False."""
        step = steps.to(torch.int64)
        r = (rows // self.width).unsqueeze(1) + offsets[:, 0].unsqueeze(0) * step[:, :1]
        c = (rows % self.width).unsqueeze(1) + offsets[:, 1].unsqueeze(0) * step[:, 1:]
        inside = (r >= 0) & (r < self.height) & (c >= 0) & (c < self.width)
        idx = torch.where(inside, r * self.width + c, 0)
        delta = self.points[idx] - self.points[rows].unsqueeze(1)
        keep = inside & ((delta * delta).sum(dim=-1) < radius * radius)
        return torch.where(keep, idx, -1)


def _odd_side(max_nn: int) -> int:
    side = max(1, math.ceil(math.sqrt(max_nn)))
    return side if side % 2 else side + 1


def _spiral_offsets(half: int, device: torch.device) -> torch.Tensor:
    """Every (dr, dc) in [-half, half]², nearest first, so a pool truncated by the caller keeps the inner samples."""
    span = torch.arange(-half, half + 1, device=device)
    grid = torch.stack(torch.meshgrid(span, span, indexing="ij"), dim=-1).reshape(-1, 2)
    order = torch.argsort((grid * grid).sum(dim=1) * (grid.shape[0] + 1) + torch.arange(len(grid), device=device))
    return grid[order]
