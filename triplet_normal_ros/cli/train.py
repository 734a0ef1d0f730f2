"""`triplet-normal train`: a recipe preset plus overrides -> training.trainer.train."""

import argparse
import dataclasses
import math
from pathlib import Path

from ..core.config import defaults
from ..errors import TrainingError, UsageError
from . import args as checks

DESCRIPTION = """Train the encoder (phase a, triplet loss) and the regressor (phase b) from the generated shapes,
resumable with --resume. See docs/TRAINING.md."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..training.losses import LOSSES
    from ..training.recipes import RECIPES

    parser.add_argument(
        "--recipe", choices=sorted(RECIPES), default="scales", help="preset (default: scales, the shipped one's)"
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="checkpoint to write (default: run-dir/model.safetensors)"
    )
    parser.add_argument("--run-dir", type=Path, default=Path("out/train"), help="state, history and curves")
    parser.add_argument("--resume", action="store_true", help="continue from run-dir/state.pt")
    parser.add_argument("--device", default=defaults.DEVICE)
    parser.add_argument("--encoder-from", type=Path, help="skip phase (a): reuse this checkpoint's encoder")
    parser.add_argument("--no-triplet", action="store_true", help="ablation: train encoder+regressor directly")
    parser.add_argument("--shapes", nargs="+", help="train on these shapes only (smoke runs)")
    parser.add_argument("--val-shapes", nargs="+", help="validate on these shapes only")
    for name in (
        "k",
        "patches_per_shape",
        "encoder_epochs",
        "regressor_epochs",
        "regressor_patches_per_shape",
        "finetune_epochs",
        "finetune_patches_per_shape",
        "batch_size",
        "n_points",
        "exponent",
        "val_patches_per_cloud",
        "seed",
        "range_frames",
        "fold_frames",
    ):
        parser.add_argument("--" + name.replace("_", "-"), type=int)
    parser.add_argument(
        "--loss", choices=LOSSES, help="normal loss: the paper's cos^n, the squared angle, or it relative to PCA's"
    )
    parser.add_argument(
        "--relative-floor-deg", type=_positive_float, help="floor (> 0) on PCA's angle in the relative loss"
    )
    parser.add_argument(
        "--residual", action=argparse.BooleanOptionalAction, help="regress a correction to the PCA normal"
    )
    parser.add_argument(
        "--finetune-freeze-bn", action=argparse.BooleanOptionalAction, help="phase (c) keeps BatchNorm statistics"
    )
    parser.add_argument("--lr", type=_positive_float)
    parser.add_argument("--finetune-lr", type=_positive_float)
    parser.add_argument("--encoder-widths", type=int, nargs="+", dest="encoder")
    parser.add_argument("--regressor-widths", type=int, nargs="+", dest="regressor")
    parser.add_argument(
        "--scales",
        type=int,
        nargs="+",
        metavar="M",
        help="scale head: plane fits over the nearest M points (e.g. 8 16 32 64 128) besides the whole pool",
    )
    parser.add_argument(
        "--inlier-seeds",
        type=int,
        nargs="+",
        metavar="S",
        help="scale head: also inlier plane fits grown from the nearest S points (e.g. 16 32)",
    )


def _positive_float(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def recipe_from_args(args: argparse.Namespace):
    """The preset with every given option applied, checked."""
    from ..training.recipes import RECIPES, Recipe, check_counts

    overrides = {
        f.name: getattr(args, f.name) for f in dataclasses.fields(Recipe) if getattr(args, f.name, None) is not None
    }
    if args.no_triplet:
        overrides["triplet"] = False
    recipe = dataclasses.replace(RECIPES[args.recipe], **overrides)
    if args.relative_floor_deg is not None and recipe.loss != "relative":
        raise UsageError(f"--relative-floor-deg only applies to --loss relative (this run uses {recipe.loss!r})")
    try:
        check_counts(recipe)
    except TrainingError as error:  # a bad option value: a usage error (status 2), like argparse's own
        raise UsageError(str(error)) from None
    _check_fits(recipe)  # after the counts: it needs a valid k
    return recipe


def _check_fits(recipe) -> None:
    """The scale head's counts: valid, and within the pool (POOL_FACTOR × k) that they choose their points from."""
    from ..core.config.conventions import POOL_FACTOR
    from ..core.learned.scales import check_scales

    pool = POOL_FACTOR * recipe.k
    for flag, counts in (("--scales", recipe.scales), ("--inlier-seeds", recipe.inlier_seeds)):
        try:
            check_scales(counts)
        except ValueError as error:
            raise UsageError(f"{flag}: {error}") from None
        if counts and max(counts) > pool:
            raise UsageError(f"{flag}: {max(counts)} is more than the {pool}-point pool (4 × k = 4 × {recipe.k})")
    if recipe.inlier_seeds and not recipe.scales:
        raise UsageError("--inlier-seeds needs --scales (they are candidates of the scale head)")


def run(args: argparse.Namespace) -> int:
    from ..core.learned.checkpoint import default_checkpoint_path
    from ..training.trainer import train

    checks.device(args.device)
    recipe = recipe_from_args(args)
    out = args.out or args.run_dir / "model.safetensors"
    summary = train(recipe, out, args.run_dir, args.device, args.resume, args.encoder_from)
    final = summary["final_val_normal_loss"]  # None when no phase (b) or (c) epoch ran, e.g. an encoder-only run
    result = "no normal-loss epoch ran" if final is None else f"final validation normal loss {final:.4f}"
    print(f"wrote {out} in {summary['wall_seconds']:.0f} s on {summary['device']}; {result}")
    if out.resolve() == default_checkpoint_path():
        print("this replaced the shipped default checkpoint")
    return 0
