"""`triplet-normal estimate IN [--out OUT]`: normals for one cloud file."""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..core.config import defaults
from ..core.config.conventions import METHODS, NEIGHBOUR_SEARCHES, PCA_DEFAULT_K
from ..errors import UsageError
from . import args as checks

#: Inputs with more query points than this get a tqdm bar (on a terminal), fed by the estimator's progress callback.
PROGRESS_MIN_POINTS = 20_000
#: With --workers or --address, each tile answers for at most this many points (its halo adds the balls around them).
TILE_POINTS = 250_000

DESCRIPTION = """Estimate unit normals (and PCA curvature) for one point cloud. Normal signs are arbitrary unless
--viewpoint is given, which flips each normal to face that point (PCL's flipNormalTowardsViewpoint).
Without --out the normals go to IN with suffix .normals (never overwriting an existing file).
Rows are NaN for points with fewer than 3 neighbours within the radius, whose neighbours determine no plane, or at
exactly (0, 0, 0) (a LiDAR's no-returns; --keep-zeros to keep them). One summary line names the method, the
checkpoint that served, the radius, device and search. See docs/CLI.md."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", type=Path, help="point cloud: .xyz, .npy, .ply or .pcd")
    p.add_argument("--out", metavar="OUT", help="output: .normals, .npy, .ply or .pcd; '-' = .normals on stdout")
    p.add_argument("--indices", metavar="FILE", type=Path, help="PCPNet .pidx: estimate only at these 0-based indices")
    radius = p.add_mutually_exclusive_group()
    radius.add_argument("--radius", type=float, metavar="R", help="ball radius in the cloud's units")
    radius.add_argument(
        "--radius-rel",
        type=float,
        metavar="F",
        help=f"radius as a fraction of the bbox diagonal (default {defaults.ESTIMATE_RADIUS_FRACTION})",
    )
    p.add_argument(
        "--k",
        type=int,
        metavar="K",
        help=(
            f"learned and hybrid: points per patch (default: the checkpoint's); pca: neighbour cap "
            f"(default {PCA_DEFAULT_K})"
        ),
    )
    p.add_argument("--checkpoint", metavar="C", help=f"safetensors path or shipped name ({checks.SHIPPED_HELP})")
    p.add_argument(
        "--method",
        choices=METHODS,
        default=defaults.ESTIMATE_METHOD,
        help=f"learned, pca, or hybrid (PCA, with the network where the surface is not flat); default "
        f"{defaults.ESTIMATE_METHOD}",
    )
    p.add_argument(
        "--device", default=defaults.DEVICE, metavar="D", help=f"auto, cpu, cuda or cuda:N (default {defaults.DEVICE})"
    )
    p.add_argument(
        "--viewpoint", type=float, nargs=3, metavar=("X", "Y", "Z"), help="orient: flip normals to face this point"
    )
    checks.add_network_options(p)
    checks.add_sensor_options(p)
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=int, metavar="N", help="cut the cloud into tiles and estimate them on N local Ray workers"
    )
    where.add_argument(
        "--address", metavar="ADDR", help="... or on a running Ray cluster (its head's HOST:PORT, or auto)"
    )
    p.add_argument(
        "--tile-points",
        type=int,
        metavar="P",
        help=f"with --workers/--address: points each tile answers for (default {TILE_POINTS}); bounds worker memory",
    )
    p.add_argument(
        "--neighbours",
        choices=NEIGHBOUR_SEARCHES,
        default=defaults.NEIGHBOURS,
        help="kdtree, grid (organized clouds: the pixel grid), voxel (the KD-tree's neighbours from cell lists on the "
        "device), window (organized clouds: pca and hybrid's survey from integral images), or auto (default: window "
        "for hybrid and whole-ball pca on organized clouds; else on a GPU grid for organized clouds, else voxel; on a "
        "CPU kdtree)",
    )
    checks.add_params_file(p)


def run(args: argparse.Namespace) -> int:
    """Read IN, estimate at all points or at --indices, orient if asked, write OUT, print one summary line."""
    from ..core.cloud import without_no_returns
    from ..core.config.conventions import bbox_diagonal
    from ..io.cloud_files import read_cloud, read_indices, write_normals

    checks.apply_params_file(args)
    _check(args)
    out = _output_path(args)
    cloud = read_cloud(args.input)
    query = read_indices(args.indices, len(cloud.points)) if args.indices else np.arange(len(cloud.points))
    points = cloud.points if args.keep_zeros else without_no_returns(cloud.points)
    radius = args.radius or (args.radius_rel or defaults.ESTIMATE_RADIUS_FRACTION) * bbox_diagonal(points)
    if not radius > 0:
        raise UsageError(f"{args.input}: the cloud has zero extent, so --radius-rel gives radius 0; pass --radius")
    estimator = checks.make_estimator(args, radius)
    start = time.perf_counter()
    tiled = args.workers is not None or args.address is not None
    if not tiled:
        normals, curvature = estimate_with_progress(estimator, points, query, shape=(cloud.height, cloud.width))
    else:
        normals, curvature = _tiled(args, estimator, points, query, cloud.height)
    seconds = time.perf_counter() - start
    method, search = (estimator.method, "tiles on Ray") if tiled else (_method(estimator), estimator.last_run.search)
    method += _checkpoint(estimator, tiled)
    if args.viewpoint is not None:
        from ..core.orientation import orient_towards_viewpoint

        normals = orient_towards_viewpoint(cloud.points[query], normals, args.viewpoint)
    organized = (cloud.height, cloud.width) if args.indices is None else None
    write_normals(out, cloud.points[query], normals, curvature, organized=organized)
    valid = int(np.isfinite(normals).all(axis=1).sum())
    summary = (
        f"{args.input}: {len(cloud.points)} points, {len(query)} estimated, {valid} valid, {seconds:.2f} s "
        f"({method}, radius {radius:.6g}, {estimator.device}, {search}) -> {out}"
    )
    print(summary, file=sys.stderr if out == "-" else sys.stdout)
    return 0


def _tiled(args: argparse.Namespace, estimator, points: np.ndarray, query: np.ndarray, height: int):
    """The cloud cut into tiles with halos (core/tiles.py), each estimated on a Ray worker, joined in query order."""
    from tqdm import tqdm

    from ..core.tiles import plan_tiles
    from . import cluster

    if height > 1:
        raise UsageError(f"{args.input} is organized ({height} rows): one sensor frame; estimate it without --workers")
    wanted = np.zeros(len(points), bool)
    wanted[query] = True

    def halo_of(interior: np.ndarray) -> float:
        return float(estimator.search_radii(np.linalg.norm(points[interior], axis=1).max(initial=0.0)))

    tiles = [t for t in plan_tiles(points, args.tile_points or TILE_POINTS, halo_of) if wanted[t.interior].any()]
    normals = np.full((len(points), 3), np.nan, np.float32)
    curvature = np.full(len(points), np.nan, np.float32)
    options = {k: v for k, v in vars(args).items() if k not in ("handler", "argv", "input", "out", "indices")}
    options["radius"] = estimator.radius  # --radius-rel's, resolved here
    bar = tqdm(total=len(tiles), unit="tile", disable=None, file=sys.stderr)
    with cluster.ray_session(args.address, args.workers or cluster.default_workers(args.device)), bar:
        workers, gpus_each = cluster.worker_count(args.workers, args.device, args.address is None)
        pool = cluster.Pool.start(options, workers, gpus_each, args.address is None)
        failures: list[str] = []

        def submit(actor, tile):
            inside = tile.interior[wanted[tile.interior]]
            return actor.tile.remote(points[tile.members], np.searchsorted(tile.members, inside), tile.members)

        def done(tile, result) -> None:
            inside = tile.interior[wanted[tile.interior]]
            normals[inside], curvature[inside] = result
            bar.update(1)

        pool.run(tiles, submit, done, lambda tile, reason: failures.append(reason))
    if failures:
        raise cluster.ClusterError(f"{len(failures)} of {len(tiles)} tiles failed: {failures[0]}")
    return normals[query], curvature[query]


def _checkpoint(estimator, tiled: bool) -> str:
    """The summary's words for the checkpoint that served: the one the plan ran; on tiles, each worker's choice."""
    if tiled:
        from ..core.config.plan import checkpoints_in_words

        words = checkpoints_in_words(estimator.settings, estimator.device.type)
        return f", checkpoint {words}" if words else ""
    plan = estimator.last_run.plan
    return checks.served_words([plan.checkpoint] if plan is not None and plan.checkpoint else [])


def _method(estimator) -> str:
    if estimator.method != "hybrid":
        return estimator.method
    return f"hybrid, network passes for {estimator.last_run.network_fraction:.0%} of the points"


def estimate_with_progress(
    estimator, points: np.ndarray, query: np.ndarray, timings: dict | None = None, shape: tuple[int, int] | None = None
):
    """`estimator.estimate` with a tqdm bar fed by its progress callback (shown on a terminal only)."""
    if len(query) <= PROGRESS_MIN_POINTS:
        return estimator.estimate(points, query, timings=timings, shape=shape)
    from tqdm import tqdm

    with tqdm(total=len(query), unit="pt", desc=estimator.method, disable=None, file=sys.stderr) as bar:
        return estimator.estimate(points, query, timings=timings, progress=bar.update, shape=shape)


def _check(args: argparse.Namespace) -> None:
    """The options, before the cloud is read; the estimator's by their settings' rules (as the node's parameters)."""
    checks.check_settings(args)
    checks.positive("radius-rel", args.radius_rel)
    checks.viewpoint(args.viewpoint)
    checks.at_least("tile-points", args.tile_points, 1)
    if args.tile_points is not None and args.workers is None and args.address is None:
        raise UsageError("--tile-points cuts the cloud for --workers or --address; give one of them")
    if args.workers is not None or args.address is not None:
        from . import cluster

        cluster.check_workers(args.workers, args.address)


def _output_path(args: argparse.Namespace) -> str:
    """--out as given, or IN with suffix .normals beside it, never overwriting (PCPNet keeps ground truth there)."""
    from ..io.cloud_files import NORMALS_SUFFIXES

    if args.out == "-":
        return "-"
    if args.out is not None:
        out = Path(args.out)
        if out.suffix.lower() not in NORMALS_SUFFIXES:
            raise UsageError(f"--out {out}: unknown output suffix {out.suffix!r} (use {', '.join(NORMALS_SUFFIXES)})")
        if not out.parent.is_dir():
            raise UsageError(f"--out {out}: directory {out.parent} does not exist")
        return str(out)
    out = args.input.with_suffix(".normals")
    if out.exists():
        raise UsageError(f"{out} already exists; pass --out {out} to overwrite it, or another --out")
    return str(out)
