"""`triplet-normal bags IN_DIR OUT_DIR --topic T`: `bag` on every rosbag2 under IN_DIR, in parallel on Ray."""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import UsageError
from . import args as checks
from . import bag

#: What marks a rosbag2: a directory holding metadata.yaml, or a bare storage file.
METADATA, BARE_SUFFIXES = "metadata.yaml", (".mcap", ".db3")

DESCRIPTION = """Find every rosbag2 under IN_DIR at any depth (a directory with metadata.yaml, or a bare .mcap or
.db3 file) and write each to OUT_DIR under the same relative path (a bare file's without its suffix), exactly as
`triplet-normal bag` writes it, on Ray: a local Ray started in this process with --workers N (default: one per GPU,
else one per two cores), or a running cluster with --address. Each worker builds the estimator once, then takes bags.
A bag that fails is reported in one line and stops no other; the exit status is 1 if any failed. An interrupted run
continues with --resume. See docs/CLI.md."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN_DIR", type=Path, help="directory searched for rosbag2 recordings")
    p.add_argument("output", metavar="OUT_DIR", type=Path, help="where the outputs go, mirroring IN_DIR's layout")
    p.add_argument(
        "--resume", action="store_true", help="continue an interrupted run: finished outputs stay, unfinished continue"
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=int, metavar="N", help="local Ray workers (default: one per GPU, else one per two cores)"
    )
    where.add_argument("--address", metavar="ADDR", help="join a running Ray cluster: its head's HOST:PORT, or auto")
    bag.add_options(p)


@dataclass(frozen=True)
class BagJob:
    """One recording: where it is, where its output goes, and how many clouds it holds on --topic."""

    source: Path
    target: Path
    clouds: int


def find_bags(root: Path) -> list[Path]:
    """Every rosbag2 under `root`, sorted: bag directories (not searched further) and bare storage files."""
    found, todo = [], [root]
    while todo:
        folder = todo.pop()
        if (folder / METADATA).is_file():
            found.append(folder)
            continue
        for entry in sorted(folder.iterdir()):
            if entry.is_dir():
                todo.append(entry)
            elif entry.suffix in BARE_SUFFIXES:
                found.append(entry)
    return sorted(found)


def target_for(root: Path, out: Path, source: Path) -> Path:
    """OUT_DIR/<source's path under IN_DIR>, a bare file's without its suffix (the output is a bag directory)."""
    relative = source.relative_to(root)
    return out / (relative.with_suffix("") if source.is_file() else relative)


def run(args: argparse.Namespace) -> int:
    from . import cluster

    checks.apply_params_file(args)
    bag.check_options(args)
    cluster.check_workers(args.workers, args.address)
    _check_dirs(args.input, args.output)
    jobs, finished = _plan(args)
    options = {k: v for k, v in vars(args).items() if k not in ("handler", "argv", "input", "output")}
    began = time.perf_counter()
    try:
        outcome = _run_on_ray(args, options, jobs, cluster)
    except KeyboardInterrupt:
        print("triplet-normal: error: interrupted; finished bags are kept: rerun with --resume", file=sys.stderr)
        return 130
    for job, reason in outcome.failures:
        print(f"triplet-normal: error: {job.source}: {reason}", file=sys.stderr)
    print(
        f"{args.input}: {len(outcome.done)} of {len(jobs)} bags ({outcome.clouds} clouds) written, {finished} already "
        f"finished, {len(outcome.failures)} failed; {outcome.workers} workers on {outcome.where}; "
        f"{time.perf_counter() - began:.1f} s -> {args.output}"
    )
    return 1 if outcome.failures else 0


def _check_dirs(source: Path, target: Path) -> None:
    if not source.is_dir():
        raise UsageError(f"IN_DIR {source} is not a directory")
    bag.check_paths(source, target, ("IN_DIR", "OUT_DIR"))


def _plan(args: argparse.Namespace) -> tuple[list[BagJob], int]:
    """The bags still to write, and how many are already finished (--resume); refuses outputs left by another run."""
    from ..io.bag_output import partial_path

    sources = find_bags(args.input)
    if not sources:
        raise UsageError(f"no rosbag2 under {args.input} (a directory with {METADATA}, or a .mcap or .db3 file)")
    jobs, finished, existing, claimed = [], 0, [], {}
    for source in sources:
        target = target_for(args.input, args.output, source)
        if target in claimed:
            raise UsageError(f"{claimed[target]} and {source} would both be written to {target}; rename one")
        claimed[target] = source
        if target.exists() and args.resume:
            finished += 1
            continue
        if target.exists() or partial_path(target).exists():
            existing.append(target)
        jobs.append(BagJob(source, target, _clouds(source, args.topic)))
    if existing and not args.resume:
        first = existing[0]
        raise UsageError(f"{len(existing)} outputs under {args.output} already exist (first: {first}); pass --resume")
    return jobs, finished


def _clouds(source: Path, topic: str) -> int:
    """Clouds on `topic` in `source`, for the progress bar; 0 for a bag that cannot be read (its worker says why)."""
    from ..io.bags import InputBag

    try:
        with InputBag(source) as reader:
            return reader.count(topic)
    except Exception:  # any unreadable bag: its own conversion reports the reason in one line
        return 0


@dataclass
class _Outcome:
    """What a run did: its workers and where they ran, the bags written and their clouds, the bags that failed."""

    workers: int = 0
    where: str = ""
    clouds: int = 0
    done: list[BagJob] = field(default_factory=list)
    failures: list[tuple[BagJob, str]] = field(default_factory=list)


def _run_on_ray(args: argparse.Namespace, options: dict, jobs: list[BagJob], cluster) -> _Outcome:
    """Every job on a worker, one progress bar over bags and clouds."""
    from tqdm import tqdm

    outcome = _Outcome()
    with cluster.ray_session(args.address, args.workers or cluster.default_workers(args.device)):
        local = args.address is None
        outcome.workers, gpus_each = cluster.worker_count(args.workers, args.device, local)
        outcome.where = "this machine" if local else f"the cluster at {args.address}"
        pool = cluster.Pool.start(options, outcome.workers, gpus_each, local)
        total = sum(job.clouds for job in jobs)
        with tqdm(total=total or None, unit="cloud", desc="bags", disable=None, file=sys.stderr) as bar:

            def done(job: BagJob, result: tuple[int, str]) -> None:
                outcome.done.append(job)
                outcome.clouds += result[0]
                bar.write(result[1], file=sys.stdout)  # the bag's own summary line, skipped clouds included
                bar.update(job.clouds)
                bar.set_postfix_str(f"{len(outcome.done) + len(outcome.failures)}/{len(jobs)} bags")

            def failed(job: BagJob, reason: str) -> None:
                outcome.failures.append((job, reason))
                bar.set_postfix_str(f"{len(outcome.done) + len(outcome.failures)}/{len(jobs)} bags")

            pool.run(jobs, lambda actor, job: actor.bag.remote(str(job.source), str(job.target)), done, failed)
    return outcome
