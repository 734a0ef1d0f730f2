"""`triplet-normal bench`: points/s per stage (evaluation.bench does the work)."""

import argparse

from ..core.config.conventions import METHODS
from . import args as checks

DESCRIPTION = """Points/s per stage of pca (k = 30 and k = 512), and learned and hybrid with every shipped checkpoint
(default, lite, range: hybrid with range is the CPU node's default on a depth frame), on a simulated 640x480 depth
frame and a noisy torus (--points), side by side in one run, with the neighbour searches, plain matmul GFLOP/s and
PointCloud2 conversion, and on a CPU each method's resident memory (idle, and over a whole frame, each in a fresh
process). When Open3D or OpenCV's
RgbdNormals imports, or PCL's headers are installed (none is a dependency; PCL's tool compiles on the first run), also
times and scores them on the same clouds as anchors. Prints the tables; with --out, also writes them into that
markdown file, a file git tracks (docs/RESULTS.md) only with --update-tracked. See docs/RESULTS.md."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--points", type=int, default=100_000, metavar="N", help="torus size (default 100000)")
    p.add_argument("--device", metavar="D", help="the device the package's methods run on (default: cpu)")
    p.add_argument("--method", choices=METHODS, help="only this method (default: all)")
    p.add_argument("--queries", type=int, default=5000, metavar="M", help="query points timed per cloud (5000)")
    p.add_argument(
        "--checkpoint", metavar="C", help="checkpoint of the network rows (default: the shipped 'default' and 'lite')"
    )
    checks.add_results_options(p)
    p.add_argument(
        "--no-anchors",
        action="store_true",
        help="do not time Open3D / OpenCV / PCL even when they are there (default: do)",
    )


def run(args: argparse.Namespace) -> int:
    from ..evaluation import anchors, bench

    checks.at_least("points", args.points, bench.WARMUP_QUERIES)
    checks.at_least("queries", args.queries, 1)
    checks.device(args.device)
    checks.results_file(args.out, args.update_tracked)
    bench.run(
        n_points=args.points,
        device=args.device,
        method=args.method,
        queries=args.queries,
        checkpoint=args.checkpoint,
        out=args.out,
        command=checks.command_line(args.argv),
        libraries=None if args.no_anchors else anchors.LIBRARIES,
    )
    return 0
