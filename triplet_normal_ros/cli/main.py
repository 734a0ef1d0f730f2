"""`triplet-normal estimate | bag | bags | eval | train | ablate | bench | warm`: the offline command line.

This module holds the parser and the error policy; each subcommand lives in its own module with `add_arguments`
and `run`. Heavy modules (torch, training data, matplotlib) are imported inside the handlers, so `--help` is instant
and `estimate` works without the training extras. Every expected failure prints one line
`triplet-normal: error: ...` on stderr: exit 2 for bad arguments, 1 for a bad file, checkpoint or device, or a
missing optional module. A command imports the optional modules its options need (`needed_modules`) before any work,
so a missing one is that line, naming the module and the pip command that installs it, rather than a traceback
after minutes of work.
"""

import argparse
import importlib
import re
import sys
from collections.abc import Sequence

from ..errors import TripletNormalError, UsageError
from . import ablate, bag, bags, bench, estimate, evaluate, train, warm

PROG = "triplet-normal"
#: (name, module, help); train and ablate add their options only when they are the command (they import torch).
COMMANDS = (
    ("estimate", estimate, "normals for one cloud file"),
    ("bag", bag, "normals for every PointCloud2 of a rosbag2, into a new rosbag2"),
    ("bags", bags, "bag on every rosbag2 under a directory, in parallel on Ray (this machine or a cluster)"),
    ("eval", evaluate, "accuracy tables vs PCA (and, with --out, into a results file)"),
    ("train", train, "train the encoder and regressor"),
    ("ablate", ablate, "the paper's ablations on the validation set"),
    ("bench", bench, "points/s per stage of pca, learned and hybrid on a simulated depth frame and a torus"),
    ("warm", warm, "compile the CPU kernels into numba's cache now (colcon build does), not at the first start"),
)
_HEAVY = ("train", "ablate")
#: Optional modules, by the PyPI distribution that installs them (`pip install <it>`): a step that works on a native
#: ROS 2 install too, where rosdep has no key for ray and pypcd4 and this package itself is not on PyPI. setup.py's
#: extras_require groups them for an install from a checkout.
DISTRIBUTIONS = {
    "ray": "ray",
    "rosbags": "rosbags",
    "pypcd4": "pypcd4",
    "yaml": "pyyaml",
    "trimesh": "trimesh",
    "manifold3d": "manifold3d",
    "rtree": "rtree",
    "matplotlib": "matplotlib",
}
#: Modules that come with ROS 2 rather than from pip: `bag` and `bags` use its message packages.
ROS_MODULES = ("builtin_interfaces", "std_msgs", "sensor_msgs")
_BAG_MODULES = ("rosbags", *ROS_MODULES)


class _Parser(argparse.ArgumentParser):
    """argparse prints usage plus a message; we print one line, the project's rule for user errors."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.exit(fail(message, 2))


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (also used directly by the tests)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser(command=_command(argv)).parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already printed by _Parser.error
        return done.code if isinstance(done.code, int) else 2
    args.argv = argv  # eval and bench record the exact command in their results
    try:
        import_needed(args)
        return int(args.handler(args) or 0)
    except ModuleNotFoundError as error:
        missing = missing_module(error, args.command)
        if missing is None:  # not an optional module: a bug, with its traceback
            raise
        return fail(missing, 1)
    except UsageError as error:
        return fail(str(error), 2)
    except KeyboardInterrupt:
        return fail("interrupted", 130)
    except (TripletNormalError, OSError, MemoryError) as error:
        return fail(one_line(error), 1)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The full parser; the options of a heavy command are only built when it is `command`."""
    parser = _Parser(prog=PROG, description="Learned (triplet), PCA and hybrid point-cloud normals, offline.")
    names = ",".join(name for name, _, _ in COMMANDS)
    commands = parser.add_subparsers(dest="command", required=True, metavar=f"{{{names}}}")
    for name, module, help_text in COMMANDS:
        full = name not in _HEAVY or name == command
        p = commands.add_parser(
            name,
            help=help_text if full else f"{help_text} (see `{name} --help`)",
            description=getattr(module, "DESCRIPTION", None),
            add_help=full,
        )
        if full:
            module.add_arguments(p)
        p.set_defaults(handler=module.run)
    return parser


def needed_modules(args: argparse.Namespace) -> list[str]:
    """The optional modules the command will import with these options (`DISTRIBUTIONS`, `ROS_MODULES`)."""
    cluster = ["ray"] if getattr(args, "workers", None) is not None or getattr(args, "address", None) else []
    params = ["yaml"] if getattr(args, "params_file", None) else []
    if args.command == "estimate":
        pcd = ["pypcd4"] if str(args.out or "").lower().endswith(".pcd") else []
        return [*params, *pcd, *cluster]
    if args.command == "bag":
        return [*params, *_BAG_MODULES]
    if args.command == "bags":
        return [*params, "ray", *_BAG_MODULES]
    if args.command in ("eval", "ablate"):
        return ["trimesh", "manifold3d", *(["matplotlib"] if args.command == "eval" and args.out else [])]
    if args.command == "train":
        return ["trimesh", "manifold3d", "matplotlib"]
    return []


def import_needed(args: argparse.Namespace) -> None:
    """Import each module `needed_modules` names: a missing one raises ModuleNotFoundError before any work."""
    for name in needed_modules(args):
        importlib.import_module(name)


def missing_module(error: ImportError, command: str) -> str | None:
    """The one line for an optional module that cannot be imported, naming how to install it; None for others."""
    name = error.name or next(iter(re.findall(r"No module named '([^']+)'", str(error))), "")
    top = name.partition(".")[0]
    if top in DISTRIBUTIONS:
        return f"{command} needs the Python module '{top}', which is not installed: pip install {DISTRIBUTIONS[top]}"
    if top in ROS_MODULES:
        return f"{command} needs the ROS 2 message package '{top}', which is not installed: source a ROS 2 setup.bash"
    return None


def fail(message: str, status: int) -> int:
    """Print the one-line error and return `status`."""
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return status


def one_line(error: object) -> str:
    """Any message, folded onto one line."""
    return " ".join(str(error).split()) or type(error).__name__


def _command(argv: Sequence[str]) -> str | None:
    return next((a for a in argv if not a.startswith("-")), None)


if __name__ == "__main__":  # `python -m triplet_normal_ros.cli.main`: what setup.py runs against the installed copy
    sys.exit(main())
