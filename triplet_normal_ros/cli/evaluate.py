"""`triplet-normal eval`: accuracy of the learned estimator against PCA (evaluation.evaluate does the work)."""

import argparse
import sys
from pathlib import Path

from ..core.config import defaults
from ..core.config.conventions import RADIUS_FRACTION
from ..errors import UsageError
from . import args as checks

#: eval's data sets, in the order they run: validation shapes, simulated range images, segmentation, registration,
#: every checkpoint on the validation shapes, PCPNet.
SETS = ("val", "depth", "fold", "lidar", "segment", "icp", "matrix", "pcpnet")

DESCRIPTION = f"""MSAE (rad²) and RMSE (degrees) of the learned estimator, PCA at the same radius
({RADIUS_FRACTION:.0%} of the bbox diagonal) and PCA at its best radius per cloud (an oracle over 1-10%), on eight
sets: the validation shapes (val), simulated depth frames of rooms (depth), close-range fold frames (fold), 32-beam
LiDAR scans (lidar), a planar segmentation of fold frames by region growing (segment), point-to-plane ICP on pairs of
fold frames and of LiDAR scans (icp), every shipped checkpoint with learned and hybrid against PCA on the validation
shapes, regime by regime (matrix), and the PCPNet shapes with 0 / 0.12 / 0.6 / 1.2% noise (pcpnet). The range sets
(depth, fold, lidar) also score hybrid, PCA over windows and pools, and with the default checkpoint the lite and
range checkpoints too. PCPNet does not ship with this package: without --sets, pcpnet is skipped, in one line, when
--pcpnet-dir lacks its shapes. Prints the tables; with --out, also writes them into that markdown file and pictures
into images/ beside it; a file git tracks (docs/RESULTS.md) only with --update-tracked. See docs/CLI.md."""

#: Where the PCPNet shapes are looked for unless --pcpnet-dir says otherwise: beside the working directory.
DEFAULT_PCPNET_DIR = Path("../shared/data/pcpnet")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--checkpoint", metavar="C", default="default", help="checkpoint to evaluate (default: the shipped 'default')"
    )
    p.add_argument(
        "--device", default=defaults.DEVICE, metavar="D", help=f"auto, cpu, cuda or cuda:N (default {defaults.DEVICE})"
    )
    p.add_argument("--points-per-cloud", type=int, default=5000, metavar="N", help="query points per cloud (5000)")
    p.add_argument(
        "--pcpnet-dir",
        type=Path,
        default=DEFAULT_PCPNET_DIR,
        metavar="DIR",
        help=f"PCPNet shapes (default: {DEFAULT_PCPNET_DIR}, relative to the working directory)",
    )
    checks.add_results_options(p)
    p.add_argument("--quick", action="store_true", help="a small subset, for tests (not for reporting)")
    p.add_argument(
        "--sets",
        metavar="S[,S...]",
        help=f"which data sets to evaluate, comma-separated, from {', '.join(SETS)} (default: all, pcpnet only where "
        "--pcpnet-dir holds its shapes); a set named here whose data is missing is an error; with --out only their "
        "blocks are rewritten",
    )


def _sets(value: str) -> tuple[str, ...]:
    chosen = tuple(dict.fromkeys(s.strip() for s in value.split(",") if s.strip()))
    unknown = [s for s in chosen if s not in SETS]
    if unknown or not chosen:
        raise UsageError(f"--sets must name some of {', '.join(SETS)}, got {value!r}")
    return chosen


def run(args: argparse.Namespace) -> int:
    from ..evaluation import evaluate

    checks.at_least("points-per-cloud", args.points_per_cloud, 10)
    checks.device(args.device)
    checks.results_file(args.out, args.update_tracked)
    sets = _sets(args.sets) if args.sets is not None else _default_sets(args.pcpnet_dir, args.quick)
    evaluate.run(
        checkpoint=args.checkpoint,
        device=args.device,
        points_per_cloud=args.points_per_cloud,
        pcpnet_dir=args.pcpnet_dir,
        out=args.out,
        quick=args.quick,
        command=checks.command_line(args.argv),
        sets=sets,
    )
    return 0


def _default_sets(pcpnet_dir: Path, quick: bool) -> tuple[str, ...]:
    """Every set, less pcpnet when `pcpnet_dir` lacks its shapes (they do not ship), which one stderr line says."""
    from ..evaluation.evaluate import pcpnet_missing

    missing = pcpnet_missing(pcpnet_dir, quick)
    if not missing:
        return SETS
    print(
        f"triplet-normal eval: skipping pcpnet: {pcpnet_dir} lacks {', '.join(missing)} (PCPNet does not ship; "
        "pass --pcpnet-dir DIR)",
        file=sys.stderr,
    )
    return tuple(s for s in SETS if s != "pcpnet")
