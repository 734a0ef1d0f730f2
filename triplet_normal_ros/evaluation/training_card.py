"""The shipped checkpoints' training, as each file records it: the `training` block of docs/RESULTS.md.

Every figure comes from the checkpoint itself (its metadata and its tensors), so the block cannot drift from what
ships: test_docs compares the block with `markdown()`, and `docs/tools/training_table.py` rewrites it after a new
checkpoint is copied in. Curves and the runs that were not shipped stay in docs/TRAINING.md.
"""

from __future__ import annotations

from typing import Any

from ..core.learned.checkpoint import (
    SHIPPED,
    checkpoint_sha256,
    load_checkpoint,
    read_metadata,
    shipped_checkpoint_path,
)
from .bench import network_mflop

COMMAND = ".venv/bin/python docs/tools/training_table.py --out docs/RESULTS.md"
HEADER = (
    "| checkpoint | sha256 | k | encoder; regressor | parameters | MFLOP per patch | phase (b) loss | training data "
    "| epochs (a; b) | validation loss | wall time |\n"
    "| --- | --- | ---: | --- | ---: | ---: | --- | --- | --- | ---: | ---: |"
)


def markdown(names: tuple[str, ...] = SHIPPED) -> str:
    """The block: the table, one row per shipped checkpoint, then the command each was trained by."""
    rows = [row(name) for name in names]
    commands = [f"- `{name}`: `{command(name)}`" for name in names]
    return (
        f"Command: `{COMMAND}` (read from the shipped files; test_docs fails while this block and the files differ)\n\n"
        "What each shipped checkpoint records of its training. *Validation loss*: the best on the run's validation "
        "patches, in the run's own loss (the relative and the angle loss do not compare across rows); *wall time*: "
        "the last run that wrote the file, on the device it records (a resumed run counts from its resume).\n\n"
        + HEADER
        + "\n"
        + "\n".join(rows)
        + "\n\nThe commands, as each file records them:\n\n"
        + "\n".join(commands)
        + "\n"
    )


def command(name: str) -> str:
    """The command line the checkpoint's last training run recorded."""
    return read_metadata(shipped_checkpoint_path(name))["training"]["command"]


def row(name: str) -> str:
    """One checkpoint's row of the table."""
    path = shipped_checkpoint_path(name)
    meta = read_metadata(path)
    training, recipe = meta["training"], meta["training"]["recipe"]
    architecture = meta["architecture"]
    widths = f"{'-'.join(map(str, architecture['encoder']))}; {'-'.join(map(str, architecture['regressor']))}"
    model, _ = load_checkpoint(path)
    parameters = sum(p.numel() for p in model.parameters())
    _, mflop = network_mflop(name)
    epochs = f"{recipe['encoder_epochs'] if recipe.get('triplet') else 0}; {recipe['regressor_epochs']}"
    cells = (
        f"`{name}`",
        f"{checkpoint_sha256(path)[:12]}…",
        str(meta["k"]),
        widths,
        f"{parameters:,}",
        f"{mflop:.2f}",
        loss(recipe),
        data(recipe),
        epochs,
        f"{training['final_val_normal_loss']:.5f}",
        f"{training['wall_seconds'] / 60:.1f} min ({training.get('device', 'device not recorded')})",
    )
    return "| " + " | ".join(cells) + " |"


def loss(recipe: dict[str, Any]) -> str:
    """The regressor's loss (`training.losses`), with the scale head's candidates where it has one."""
    names = {
        "relative": f"relative squared angle (floor {recipe.get('relative_floor_deg', 0):g}°)",
        "angle": "squared angle",
        "cos": f"the paper's weighted 1 - cos^{recipe.get('exponent', 8)}",
    }
    name = names.get(recipe["loss"], recipe["loss"])
    if recipe.get("scales"):
        name += f", scale head over fits of {', '.join(map(str, recipe['scales']))} points"
    return name


def data(recipe: dict[str, Any]) -> str:
    """The training clouds: the CAD and smooth shapes at every noise level, plus simulated range frames if any."""
    text = f"the shapes' {recipe['n_points'] // 1000}k-point clouds"
    frames = recipe.get("range_frames") or 0
    if frames:
        text += f", {frames} depth frames and {frames} LiDAR scans"
    folds = recipe.get("fold_frames") or 0
    if folds:
        text += f", {folds} close-range fold frames"
    return text + f"; {recipe['regressor_patches_per_shape']} patches per cloud"
