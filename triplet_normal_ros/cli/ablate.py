"""`triplet-normal ablate`: the paper's ablations and ours (evaluation.ablation does the work)."""

import argparse
from pathlib import Path

from ..core.config import defaults
from . import args as checks

DESCRIPTION = """Train every ablation variant at a stated, reduced budget and score it on the validation set.
Prints the table; with --out, also writes it into that markdown file, a file git tracks (docs/RESULTS.md) only with
--update-tracked. See docs/RESULTS.md."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--encoder-from",
        metavar="C",
        default="default",
        help="frozen triplet encoder for the exponent rows: a checkpoint path or shipped name (default: default)",
    )
    parser.add_argument("--patches-per-shape", type=int, default=200)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--per-cloud", type=int, default=1000, help="validation query points per cloud")
    parser.add_argument("--run-dir", type=Path, default=Path("out/ablation"))
    parser.add_argument("--device", default=defaults.DEVICE)
    checks.add_results_options(parser)


def run(args: argparse.Namespace) -> int:
    from ..core.learned.checkpoint import resolve_checkpoint
    from ..evaluation.ablation import Budget, run

    checks.at_least("patches-per-shape", args.patches_per_shape, 1)
    checks.at_least("epochs", args.epochs, 1)
    checks.at_least("per-cloud", args.per_cloud, 1)
    checks.device(args.device)
    checks.results_file(args.out, args.update_tracked)
    budget = Budget(resolve_checkpoint(args.encoder_from), args.patches_per_shape, args.epochs, args.per_cloud)
    run(budget, args.run_dir, args.device, args.out, checks.command_line(args.argv))
    return 0
