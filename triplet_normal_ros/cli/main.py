"""`triplet-normal estimate | bag | bags | eval | train | ablate | bench`: the offline command line.

This module holds the parser and the error policy; each subcommand lives in its own module with `add_arguments`
and `run`. Heavy modules (torch, training data, matplotlib) are imported inside the handlers, so `--help` is instant
and `estimate` works without the training extras. Every expected failure prints one line
`triplet-normal: error: ...` on stderr: exit 2 for bad arguments, 1 for a bad file, checkpoint or device.
"""

import argparse
import sys
from collections.abc import Sequence

from ..errors import TripletNormalError, UsageError
from . import ablate, bag, bags, bench, estimate, evaluate, train

PROG = "triplet-normal"
#: (name, module, help); train and ablate add their options only when they are the command (they import torch).
COMMANDS = (
    ("estimate", estimate, "normals for one cloud file"),
    ("bag", bag, "normals for every PointCloud2 of a rosbag2, into a new rosbag2"),
    ("bags", bags, "bag on every rosbag2 under a directory, in parallel on Ray (this machine or a cluster)"),
    ("eval", evaluate, "accuracy tables vs PCA (and, with --out, into a results file)"),
    ("train", train, "train the encoder and regressor"),
    ("ablate", ablate, "the paper's ablations on the validation set"),
    ("bench", bench, "points/s per stage on a synthetic 100k-point cloud"),
)
_HEAVY = ("train", "ablate")


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
        return int(args.handler(args) or 0)
    except UsageError as error:
        return fail(str(error), 2)
    except KeyboardInterrupt:
        return fail("interrupted", 130)
    except (TripletNormalError, OSError, MemoryError) as error:
        return fail(one_line(error), 1)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The full parser; the options of a heavy command are only built when it is `command`."""
    parser = _Parser(prog=PROG, description="Learned (triplet) and PCA point-cloud normals, offline.")
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


def fail(message: str, status: int) -> int:
    """Print the one-line error and return `status`."""
    print(f"{PROG}: error: {one_line(message)}", file=sys.stderr)
    return status


def one_line(error: object) -> str:
    """Any message, folded onto one line."""
    return " ".join(str(error).split()) or type(error).__name__


def _command(argv: Sequence[str]) -> str | None:
    return next((a for a in argv if not a.startswith("-")), None)
