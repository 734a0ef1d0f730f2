"""Which path this cloud takes: the settings' plan (`config.plan.make_plan`) checked against the cloud itself.

The plan rule is pure (config/); whether an organized cloud's grid is a range image is a measurement of the data
(`range_image.check.inspect_grid`), so the two meet here, once per estimate.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from .config.plan import Plan, checkpoint_for, is_organized, make_plan
from .config.settings import Settings
from .range_image.check import inspect_grid
from .search.grid import RangePitch


def plan_cloud(
    settings: Settings, device: torch.device, cloud: torch.Tensor, shape: tuple[int, int] | None
) -> tuple[Plan, RangePitch | None]:
    """The plan for `cloud` (N, 3) on `device`, and the range image's pitch when the plan reads the grid. An organized
    cloud's grid is inspected (`check.inspect_grid`): its scan lines always, its pitch when the plan would read
    the grid or would choose another checkpoint for a range image (`checkpoint_for`), so that only a grid trusted
    as a range image gets the range image's network. A grid that is not a range image gets the pool path, and the
    plan's `note` says why."""
    organized = is_organized(shape, len(cloud))
    hopeful = make_plan(settings, device.type, organized, range_image=organized)
    if not organized:
        return hopeful, None
    other_network = hopeful.checkpoint != checkpoint_for(settings, device.type)
    check = inspect_grid(cloud, shape, pitch=hopeful.uses_range_image or other_network)
    if check.reason:
        note = f"the {shape[1]}x{shape[0]} organized cloud is not a range image: {check.reason}; pools instead"
        plan = make_plan(settings, device.type, organized, range_image=False)
        return replace(plan, scan_lines=check.scan_lines, note=note), None
    return hopeful, check.pitch if hopeful.uses_range_image else None
