"""The console entry points ``node`` and ``managed_node``: they take SIGINT and SIGTERM before anything else.

Importing a node (rclpy, torch, numba) takes 1-3 s, during which Python's own SIGINT handler would end a Ctrl-C'd
process with a KeyboardInterrupt traceback and a code of 130 instead of a clean exit 0. So this module imports the
standard library, `stopper` and the pure-Python defaults only; each entry point installs the stopper, then imports
its node's module (a lazy import, for that reason alone) and runs its ``main``.
"""

from __future__ import annotations

import importlib
from typing import NoReturn

from ..core.config.defaults import NODE_NAME
from .stopper import STOPPER

#: Each console script's node module.
NODES = {"node": f"{__package__}.node", "managed_node": f"{__package__}.managed_node"}


def node() -> NoReturn:
    """``node``: the plain node (ros/node.py)."""
    _start("node")


def managed_node() -> NoReturn:
    """``managed_node``: the lifecycle node (ros/managed_node.py)."""
    _start("managed_node")


def _start(script: str) -> NoReturn:
    STOPPER.install(NODE_NAME)
    importlib.import_module(NODES[script]).main()
