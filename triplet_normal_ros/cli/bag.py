"""`triplet-normal bag IN OUT --topic T`: normals for every PointCloud2 of a rosbag2, into a new rosbag2."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.config import defaults
from ..core.config.conventions import METHODS, NEIGHBOUR_SEARCHES, PCA_DEFAULT_K
from ..errors import CloudFormatError, EstimationCancelled, EstimatorError, UsageError
from . import args as checks

if TYPE_CHECKING:
    from ..core.estimator import NormalEstimator
    from ..pipeline.message_settings import MessageSettings

#: io.bag_output.SEGMENT_SECONDS (a test checks), written here so that `--help` does not import rosbags.
SEGMENT_SECONDS = 30.0

DESCRIPTION = """Read a rosbag2 (sqlite3 or MCAP; a bag directory or a bare .mcap/.db3 file) without ROS, estimate
normals for every sensor_msgs/PointCloud2 on --topic exactly as the node does (same defaults, normals oriented towards
--viewpoint), and write a new bag OUT: each cloud plus normal_x/y/z and curvature on --output-topic, with the input's
receive timestamps and header stamps, and every input topic copied through unless --no-copy. --start, --end and
--limit take a part of IN. OUT is written through OUT.partial and appears only when complete; an interrupted run
continues with --resume. See docs/CLI.md."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", type=Path, help="input rosbag2: a bag directory, or a .mcap or .db3 file")
    p.add_argument("output", metavar="OUT", type=Path, help="output bag directory (must not exist, see --overwrite)")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--overwrite", action="store_true", help="replace an existing OUT and an unfinished OUT.partial")
    again.add_argument("--resume", action="store_true", help="continue the unfinished run in OUT.partial")
    add_options(p)


def add_options(p: argparse.ArgumentParser) -> None:
    """Every option of one bag's conversion (topics, part, estimator, orientation): `bag` and `bags` share them."""
    p.add_argument("--topic", required=True, help="the sensor_msgs/PointCloud2 topic to estimate normals on")
    p.add_argument("--output-topic", metavar="TOPIC", help="topic of the clouds with normals (default: TOPIC/normals)")
    p.add_argument("--storage", choices=("sqlite3", "mcap"), help="output storage (default: the input's)")
    p.add_argument("--no-copy", action="store_true", help="write only the output topic, not the input's topics")
    p.add_argument("--start", type=float, metavar="S", help="read from S seconds after IN's first message (default 0)")
    p.add_argument("--end", type=float, metavar="S", help="read up to (not at) S seconds after IN's first message")
    p.add_argument("--limit", type=int, metavar="N", help="stop after the N-th cloud on --topic (OUT ends there)")
    p.add_argument(
        "--segment-seconds",
        type=float,
        default=SEGMENT_SECONDS,
        metavar="S",
        help=f"close a crash-safe segment of OUT.partial at least every S seconds (default {SEGMENT_SECONDS:g})",
    )
    p.add_argument("--method", choices=METHODS, default=defaults.METHOD, help=f"default {defaults.METHOD}, as the node")
    p.add_argument(
        "--radius", type=float, default=defaults.RADIUS, metavar="R", help=f"in m (default {defaults.RADIUS})"
    )
    p.add_argument(
        "--k",
        type=int,
        metavar="K",
        help=f"learned/hybrid: points per patch (default: the checkpoint's); pca: cap (default {PCA_DEFAULT_K})",
    )
    p.add_argument(
        "--checkpoint",
        metavar="C",
        help=f"safetensors path or shipped name ({checks.SHIPPED_HELP})",
    )
    p.add_argument(
        "--device", default=defaults.DEVICE, metavar="D", help=f"auto, cpu, cuda or cuda:N (default {defaults.DEVICE})"
    )
    checks.add_network_options(p)
    p.add_argument(
        "--neighbours",
        choices=NEIGHBOUR_SEARCHES,
        default=defaults.NEIGHBOURS,
        help=f"neighbour search (default {defaults.NEIGHBOURS}, as the node)",
    )
    p.add_argument(
        "--viewpoint",
        type=float,
        nargs=3,
        default=defaults.VIEWPOINT,
        metavar=("X", "Y", "Z"),
        help="flip normals to face this point of the cloud's frame (default 0 0 0: the sensor)",
    )
    p.add_argument("--no-orient", action="store_true", help="leave normal signs as estimated")
    checks.add_sensor_options(p)
    checks.add_params_file(p)


def run(args: argparse.Namespace) -> int:
    """Open IN, check the topic, then estimate, write and merge; Ctrl-C keeps the finished work for --resume."""
    from ..io.bag_output import partial_path
    from ..io.bags import InputBag

    checks.apply_params_file(args)
    check_options(args)
    check_paths(args.input, args.output)
    try:
        with InputBag(args.input) as bag:
            _, summary = _convert(args, bag)
    except (KeyboardInterrupt, EstimationCancelled):  # main's one line, plus where the work is and how to go on
        kept = partial_path(args.output)
        where = f"finished work is kept in {kept}: rerun with --resume" if kept.exists() else "nothing was kept"
        print(f"triplet-normal: error: interrupted; {where}", file=sys.stderr)
        return 130
    print(summary)
    return 0


def checkpoints_in_force(args: argparse.Namespace) -> str:
    """The checkpoints the estimate loads where this runs, in words (`plan.checkpoints_in_words`): --checkpoint, or
    without it the node's, the shipped ones for the device ('range on range images and lite otherwise' on a CPU)."""
    from ..core.config.device import device_type
    from ..core.config.plan import checkpoints_in_words
    from ..core.config.settings import Settings

    chosen = Settings(method=args.method, checkpoint=args.checkpoint or "")
    return checkpoints_in_words(chosen, device_type(args.device))


def convert(args: argparse.Namespace, estimator=None) -> tuple[int, str]:
    """One bag, args.input -> args.output, with `estimator` (built from the options when None): (clouds, summary)."""
    from ..io.bags import InputBag

    with InputBag(args.input) as bag:
        return _convert(args, bag, estimator)


def check_options(args: argparse.Namespace) -> None:
    """The options of one bag's conversion (`bag` and `bags`), before any bag is opened; the estimator's by their
    settings' rules, as the node checks its parameters."""
    checks.check_settings(args)
    checks.viewpoint(args.viewpoint)
    _non_negative("segment-seconds", args.segment_seconds)
    _check_part(args)


def message_settings(args: argparse.Namespace) -> MessageSettings:
    """What every cloud is answered with: the node's per-cloud step (`answer_message`) under the options."""
    from ..pipeline.message_settings import MessageSettings

    return MessageSettings(
        checks.estimator_settings(args, args.radius), not args.no_orient, tuple(args.viewpoint), not args.keep_zeros
    )


def check_paths(source_path: Path, target_path: Path, names: tuple[str, str] = ("IN", "OUT")) -> None:
    """The output must neither be the input, lie inside it, nor contain it (`bags` checks its folders the same way)."""
    source, target = source_path.resolve(), target_path.resolve()
    if source == target or source in target.parents or target in source.parents:
        raise UsageError(f"{names[1]} {target_path} must lie outside {names[0]} {source_path} and not contain it")


def _non_negative(name: str, value: float | None) -> None:
    """`value` must be a finite number >= 0 when given."""
    if value is not None and not (np.isfinite(value) and value >= 0):
        raise UsageError(f"--{name} must be a finite number >= 0, got {value}")


def _check_part(args: argparse.Namespace) -> None:
    """--start, --end and --limit describe a part of IN that can hold a message (IN's length is checked later)."""
    _non_negative("start", args.start)
    _non_negative("end", args.end)
    if args.end is not None and args.end <= (args.start or 0):
        raise UsageError(f"--end must be greater than --start ({args.start or 0:g} s), got {args.end:g}")
    checks.at_least("limit", args.limit, 1)


def _window(args: argparse.Namespace, bag) -> tuple[int | None, int | None]:
    """--start and --end in ns after IN's first message; a window that begins after IN's last message is refused."""
    start, end = (None if s is None else round(s * 1e9) for s in (args.start, args.end))
    if (start is not None or end is not None) and (start or 0) >= bag.duration:
        raise UsageError(
            f"the window starts at {args.start or 0:g} s, not before the end of {args.input} (its messages span "
            f"{bag.duration / 1e9:.3f} s)"
        )
    return start, end


def _part(args: argparse.Namespace) -> str:
    """The summary's words for the part of IN that was read, or '' for all of it."""
    words = []
    if args.start is not None or args.end is not None:
        end = "its end" if args.end is None else f"{args.end:g} s"
        words.append(f"from {args.start or 0:g} s to {end}")
    if args.limit is not None:
        words.append(f"at most {args.limit} clouds")
    return f" ({', '.join(words)})" if words else ""


def _convert(args: argparse.Namespace, bag, estimator=None) -> tuple[int, str]:
    """Every message of IN in time order -> OUT.partial, then OUT; returns (clouds, the summary line)."""
    from ..io.bag_output import ResumableBagWriter
    from ..io.bags import CLOUD_TYPE

    began = time.perf_counter()
    cloud_spec = bag.cloud_spec(args.topic)
    output_topic = args.output_topic or f"{args.topic.rstrip('/')}/normals"
    copied = [] if args.no_copy else bag.specs()
    if output_topic in {spec.topic for spec in copied}:
        raise UsageError(f"--output-topic {output_topic} is a topic of {args.input}; choose another")
    start, end = _window(args, bag)
    storage = args.storage or bag.storage
    topics = [*copied, cloud_spec.renamed(output_topic)]
    with ResumableBagWriter(
        args.output, storage, topics, _job(args, bag, output_topic, storage),
        overwrite=args.overwrite, resume=args.resume, segment_seconds=args.segment_seconds,
    ) as writer:  # fmt: skip
        estimator = estimator or checks.make_estimator(args, args.radius)
        answering = _Answering(estimator, message_settings(args), (output_topic, CLOUD_TYPE))
        _note_undescribed(copied)  # only now: a run refused before any work says so in one line
        stream = bag.messages(None if copied else {args.topic}, start, end)
        total = _clouds_expected(args, bag)
        clouds, skipped = _estimate_all(args, stream, writer, answering, total)
        _merge(writer)
    resumed = f", resumed at input message {writer.resumed_at}" if writer.resumed_at else ""
    return clouds, (
        f"{args.input}{_part(args)}: {clouds} clouds on {args.topic} ({skipped} skipped){resumed}, {len(copied)} "
        f"topics copied; {estimator.method}{checks.served_words(answering.served)}, radius {estimator.radius:g} m, "
        f"{estimator.device}; "
        f"{time.perf_counter() - began:.1f} s -> {args.output} ({storage}, {output_topic})"
    )


def _note_undescribed(copied: list) -> None:
    """One line per copied topic whose type the bag does not define: OUT holds its messages but cannot decode them."""
    for spec in copied:
        if not spec.described:
            print(
                f"triplet-normal: note: topic {spec.topic} ({spec.msgtype}): no message definition in the bag; "
                "copied as raw messages",
                file=sys.stderr,
            )


def _clouds_expected(args: argparse.Namespace, bag) -> int | None:
    """The progress bar's total: every cloud of IN, or --limit of them; unknown for a time window."""
    everything = None if args.start is not None or args.end is not None else bag.count(args.topic)
    if args.limit is None:
        return everything
    return args.limit if everything is None else min(args.limit, everything)


@dataclass(frozen=True)
class _Answering:
    """How each cloud of IN is answered: the estimator, the run's settings snapshot, and the output's (topic, type)."""

    estimator: NormalEstimator
    settings: MessageSettings
    output_key: tuple[str, str]
    #: The checkpoints that answered a cloud, in the order they first did (for the summary line).
    served: list[str] = field(default_factory=list)

    def __call__(self, message, stop: threading.Event) -> memoryview:
        """The output message for one input cloud: the node's answer (`answer_message`), as a bag stores it."""
        from ..io.bags import as_message, decode_cloud, encode_message
        from ..pipeline.messages import answer_message

        answer = answer_message(as_message(decode_cloud(message)), self.estimator, self.settings, stop)
        plan = self.estimator.last_run.plan
        if plan is not None and plan.checkpoint and plan.checkpoint not in self.served:
            self.served.append(plan.checkpoint)
        return encode_message(answer.message)


def _estimate_all(args, stream, writer, answering: _Answering, total: int | None) -> tuple[int, int]:
    """Write each input message's outputs, in order, from the writer's resume point, up to the --limit-th cloud;
    returns (clouds, skipped)."""
    from tqdm import tqdm

    clouds = skipped = 0
    bar = tqdm(total=total or None, unit="cloud", desc="normals", disable=None, file=sys.stderr)
    with _ctrl_c() as stop, bar:
        for message in stream:
            if stop.is_set():
                raise KeyboardInterrupt
            is_cloud = message.topic == args.topic
            clouds += is_cloud
            if message.index >= writer.done:  # else it was written before the interruption
                outputs, failed = _outputs(args, message, answering, stop, bar.write)
                skipped += failed
                writer.write(message.index, outputs)
            bar.update(is_cloud)
            if is_cloud and clouds == args.limit:
                break
        if stop.is_set():  # Ctrl-C after the estimator's last cancel check: still an interruption, not a finished run
            raise KeyboardInterrupt
    return clouds, skipped


def _outputs(
    args: argparse.Namespace, message, answering: _Answering, stop: threading.Event, warn: Callable
) -> tuple[list, bool]:
    """What one input message puts in OUT (itself unless --no-copy; for a cloud, the cloud with normals), and whether
    it was a cloud that had to be skipped (`warn` gets the line saying why)."""
    outputs = [] if args.no_copy else [((message.topic, message.msgtype), message.timestamp, message.raw)]
    if message.topic != args.topic:
        return outputs, False
    try:
        outputs.append((answering.output_key, message.timestamp, answering(message, stop)))
    except (CloudFormatError, EstimatorError) as error:
        warn(f"triplet-normal: warning: skipped the cloud at {message.timestamp} ns: {error}", file=sys.stderr)
        return outputs, True
    return outputs, False


@contextmanager
def _ctrl_c() -> Iterator[threading.Event]:
    """The first Ctrl-C only sets the event: the loop stops before the next message and the estimator between chunks.

    A KeyboardInterrupt raised inside scipy's threaded KD-tree query leaves its worker threads running into the
    interpreter's teardown, which then segfaults. A second Ctrl-C interrupts at once.
    """
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def first(signum: int, frame: object) -> None:
        stop.set()
        signal.signal(signal.SIGINT, previous)

    previous = signal.signal(signal.SIGINT, first)
    try:
        yield stop
    finally:
        signal.signal(signal.SIGINT, previous)


def _merge(writer) -> None:
    from tqdm import tqdm

    with tqdm(unit="msg", desc="writing OUT", disable=None, file=sys.stderr) as bar:
        writer.finish(progress=bar.update, total=bar.reset)


def _job(args: argparse.Namespace, bag, output_topic: str, storage: str) -> dict:
    """What the output depends on; --resume refuses to continue a run started with anything else."""
    return {
        "input": str(args.input.resolve()),
        "input_messages": bag.count(),
        "topic": args.topic,
        "output_topic": output_topic,
        "copy": not args.no_copy,
        "storage": storage,
        "method": args.method,
        "radius": args.radius,
        "k": args.k,
        "checkpoint": checkpoints_in_force(args),
        "gate": args.gate,
        "bend": args.bend,
        "neighbours": args.neighbours,
        "viewpoint": None if args.no_orient else list(args.viewpoint),
        "keep_zeros": args.keep_zeros,
        "range_scale": args.range_scale,
        "start": args.start or 0.0,  # --start 0 reads what no --start reads
        "end": args.end,
        "limit": args.limit,
    }
