"""`triplet-normal estimate | eval | train | ablate | bench`: the offline command line.

Argument parsing lives here; heavy modules (torch, training data, matplotlib) are imported inside the handlers,
so `--help` is instant and `estimate` works without the training extras. Every expected failure prints one line
`triplet-normal: error: ...` on stderr: exit 2 for bad arguments, 1 for a bad file, checkpoint or device.
"""

import argparse
import importlib
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

PROG = "triplet-normal"
DEFAULT_RADIUS_REL = 0.05
#: Inputs with more query points than this get a tqdm bar (on a terminal), fed by the estimator's progress callback.
PROGRESS_MIN_POINTS = 20_000


class UsageError(Exception):
    """Arguments that parse but make no sense together; exit status 2 like argparse's own errors."""


class _Parser(argparse.ArgumentParser):
    """argparse prints usage plus a message; we print one line, the project's rule for user errors."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.exit(_fail(message, 2))


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (also used directly by the tests)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser(with_train=_command(argv) in ("train", "ablate")).parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already printed by _Parser.error
        return done.code if isinstance(done.code, int) else 2
    args.argv = argv  # eval and bench record the exact command in docs/RESULTS.md
    try:
        return int(args.handler(args) or 0)
    except UsageError as error:
        return _fail(str(error), 2)
    except KeyboardInterrupt:
        return _fail("interrupted", 130)
    except _expected_errors() as error:
        return _fail(_one_line(error), 1)


def build_parser(with_train: bool = False) -> argparse.ArgumentParser:
    """The full parser; train's options come from train.py and are only imported when `train` is the command."""
    parser = _Parser(prog=PROG, description="Learned (triplet) and PCA point-cloud normals, offline.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="{estimate,eval,train,ablate,bench}")
    _add_estimate(commands)
    _add_eval(commands)
    _add_train(commands, with_train)
    _add_ablate(commands, with_train)
    _add_bench(commands)
    return parser


def _add_estimate(commands) -> None:
    p = commands.add_parser("estimate", help="normals for one cloud file", description=_ESTIMATE_HELP)
    p.add_argument("input", metavar="IN", type=Path, help="point cloud: .xyz, .npy, .ply or .pcd")
    p.add_argument("--out", metavar="OUT", help="output: .normals, .npy, .ply or .pcd; '-' = .normals on stdout")
    p.add_argument("--indices", metavar="FILE", type=Path, help="PCPNet .pidx: estimate only at these 0-based indices")
    radius = p.add_mutually_exclusive_group()
    radius.add_argument("--radius", type=float, metavar="R", help="ball radius in the cloud's units")
    radius.add_argument(
        "--radius-rel",
        type=float,
        metavar="F",
        help=f"radius as a fraction of the bbox diagonal (default {DEFAULT_RADIUS_REL})",
    )
    p.add_argument(
        "--k", type=int, metavar="K", help="patch size (learned) / max neighbours (pca); default: checkpoint's k"
    )
    p.add_argument("--checkpoint", metavar="C", help="safetensors checkpoint (default: the one shipped in the package)")
    p.add_argument("--method", choices=("learned", "pca"), default="learned", help="default: learned")
    p.add_argument("--device", default="auto", metavar="D", help="auto, cpu, cuda or cuda:N (default auto)")
    p.add_argument("--viewpoint", type=float, nargs=3, metavar=("X", "Y", "Z"), help="flip normals to face this point")
    p.add_argument("--batch-size", type=int, metavar="B", help="patches per network call (default: the estimator's)")
    p.set_defaults(handler=run_estimate)


def _add_eval(commands) -> None:
    p = commands.add_parser("eval", help="accuracy tables vs PCA; writes docs/RESULTS.md", description=_EVAL_HELP)
    p.add_argument("--checkpoint", metavar="C", help="checkpoint to evaluate (default: the shipped one)")
    p.add_argument("--device", default="auto", metavar="D", help="auto, cpu, cuda or cuda:N (default auto)")
    p.add_argument("--points-per-cloud", type=int, default=5000, metavar="N", help="query points per cloud (5000)")
    p.add_argument("--pcpnet-dir", type=Path, metavar="DIR", help="PCPNet shapes (default: ../shared/data/pcpnet)")
    p.add_argument("--out", type=Path, default=Path("docs/RESULTS.md"), metavar="MD", help="(default docs/RESULTS.md)")
    p.add_argument("--quick", action="store_true", help="a small subset, for tests (not for reporting)")
    p.set_defaults(handler=_run_module("evaluate"))


def _add_train(commands, with_train: bool) -> None:
    _add_training_command(commands, "train", "train", "train the encoder and regressor", with_train)


def _add_ablate(commands, with_train: bool) -> None:
    _add_training_command(commands, "ablate", "ablation", "the paper's ablations on the validation set", with_train)


def _add_training_command(commands, name: str, module: str, help_text: str, with_train: bool) -> None:
    """Training commands import torch and the shape generators only when they are the command being run."""
    p = commands.add_parser(name, help=f"{help_text} (see `{name} --help`)", add_help=with_train)
    if with_train:
        try:
            handler = importlib.import_module(f"triplet_normal_ros.{module}")
        except ImportError as error:
            sys.exit(_fail(f"{name} needs the training extras (pip install '.[train]'): {error}", 1))
        handler.add_arguments(p)
        p.set_defaults(handler=handler.run)


def _add_bench(commands) -> None:
    p = commands.add_parser("bench", help="points/s per stage on a synthetic 100k-point cloud")
    p.add_argument("--points", type=int, default=100_000, metavar="N", help="cloud size (default 100000)")
    p.add_argument("--device", metavar="D", help="only this device (default: cpu, plus cuda when available)")
    p.add_argument("--method", choices=("learned", "pca"), help="only this method (default: both)")
    p.add_argument("--learned-cpu-queries", type=int, default=5000, metavar="M", help="learned on CPU times M queries")
    p.add_argument("--checkpoint", metavar="C", help="checkpoint (default: the shipped one)")
    p.add_argument("--out", type=Path, default=Path("docs/RESULTS.md"), metavar="MD", help="(default docs/RESULTS.md)")
    p.set_defaults(handler=_run_module("bench"))


def _run_module(name: str):
    def handler(args: argparse.Namespace) -> int:
        module = __import__(f"{__package__}.{name}", fromlist=["run"])
        return module.run(args)

    return handler


# ---------------------------------------------------------------- estimate


def run_estimate(args: argparse.Namespace) -> int:
    """Read IN, estimate at all points or at --indices, orient if asked, write OUT, print one summary line."""
    from .cloud_files import bbox_diagonal, read_cloud, read_indices, write_normals

    _check_estimate_args(args)
    out = _output_path(args)
    cloud = read_cloud(args.input)
    query = read_indices(args.indices, len(cloud.points)) if args.indices else np.arange(len(cloud.points))
    radius = args.radius or (args.radius_rel or DEFAULT_RADIUS_REL) * bbox_diagonal(cloud.points)
    if not radius > 0:
        raise UsageError(f"{args.input}: the cloud has zero extent, so --radius-rel gives radius 0; pass --radius")
    estimator = _make_estimator(args, radius)
    start = time.perf_counter()
    normals, curvature = estimate_with_progress(estimator, cloud.points, query)
    seconds = time.perf_counter() - start
    if args.viewpoint is not None:
        from .orientation import orient_towards_viewpoint

        normals = orient_towards_viewpoint(cloud.points[query], normals, args.viewpoint)
    organized = (cloud.height, cloud.width) if args.indices is None else None
    write_normals(out, cloud.points[query], normals, curvature, organized=organized)
    valid = int(np.isfinite(normals).all(axis=1).sum())
    summary = (
        f"{args.input}: {len(cloud.points)} points, {len(query)} estimated, {valid} valid, {seconds:.2f} s "
        f"({args.method}, radius {radius:.6g}, {estimator.device}) -> {out}"
    )
    print(summary, file=sys.stderr if out == "-" else sys.stdout)
    return 0


def estimate_with_progress(estimator, points: np.ndarray, query: np.ndarray, timings: dict | None = None):
    """`estimator.estimate` with a tqdm bar fed by its progress callback (shown on a terminal only)."""
    if len(query) <= PROGRESS_MIN_POINTS:
        return estimator.estimate(points, query, timings=timings)
    from tqdm import tqdm

    with tqdm(total=len(query), unit="pt", desc=estimator.method, disable=None, file=sys.stderr) as bar:
        return estimator.estimate(points, query, timings=timings, progress=bar.update)


def _check_estimate_args(args: argparse.Namespace) -> None:
    from .torch_device import validate_device_name

    for name in ("radius", "radius_rel"):
        value = getattr(args, name)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise UsageError(f"--{name.replace('_', '-')} must be a finite number > 0, got {value}")
    if args.k is not None and args.k < 3:
        raise UsageError(f"--k must be >= 3, got {args.k}")
    if args.batch_size is not None and args.batch_size < 1:
        raise UsageError(f"--batch-size must be >= 1, got {args.batch_size}")
    if args.viewpoint is not None and not np.isfinite(args.viewpoint).all():
        raise UsageError(f"--viewpoint must be three finite numbers, got {args.viewpoint}")
    reason = validate_device_name(args.device)
    if reason:
        raise UsageError(reason)


def _output_path(args: argparse.Namespace) -> str:
    """--out as given, or IN with suffix .normals beside it, never overwriting (PCPNet keeps ground truth there)."""
    from .cloud_files import NORMALS_SUFFIXES

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


def _make_estimator(args: argparse.Namespace, radius: float):
    from .estimator import NormalEstimator

    options = {"k": args.k, "checkpoint": args.checkpoint, "device": args.device}
    if args.batch_size is not None:
        options["batch_size"] = args.batch_size
    return NormalEstimator(method=args.method, radius=radius, **options)


# ---------------------------------------------------------------- errors


def _expected_errors() -> tuple[type[BaseException], ...]:
    """Errors that mean bad input, not a bug; imported lazily so the parser stays light."""
    errors: list[type[BaseException]] = [OSError, MemoryError]
    for module, name in (
        ("cloud_files", "CloudFileError"),
        ("checkpoint", "CheckpointError"),
        ("estimator", "EstimatorError"),
        ("train", "TrainingError"),
    ):
        mod = sys.modules.get(f"{__package__}.{module}")
        if mod is not None:
            errors.append(getattr(mod, name))
    return tuple(errors)


def _fail(message: str, status: int) -> int:
    print(f"{PROG}: error: {_one_line(message)}", file=sys.stderr)
    return status


def _one_line(error: object) -> str:
    return " ".join(str(error).split()) or type(error).__name__


def _command(argv: Sequence[str]) -> str | None:
    return next((a for a in argv if not a.startswith("-")), None)


_ESTIMATE_HELP = """Estimate unoriented unit normals (and PCA curvature) for one point cloud.
Without --out the normals go to IN with suffix .normals (never overwriting an existing file).
Rows for points with fewer than 3 neighbours within the radius are NaN. See docs/CLI.md."""

_EVAL_HELP = """MSAE (rad²) and RMSE (degrees) of the learned estimator, PCA at the same radius (5% of the bbox
diagonal) and PCA at its best radius per cloud (an oracle over 1-10%), on the validation set and on the PCPNet
shapes with 0 / 0.12 / 0.6 / 1.2% noise. Writes the tables and a heat map into --out. See docs/CLI.md."""
