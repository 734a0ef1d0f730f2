"""A worker forked from a process that has already estimated (so the band threads and torch's thread pool exist)
gets the same normals as its parent. A fork copies only the forking thread, so without the at-fork reset the child
would queue bands on threads that are not there and wait for ever; the join's timeout turns such a hang into a
failure of this test rather than of the suite."""

from __future__ import annotations

import multiprocessing
from multiprocessing.connection import Connection

import numpy as np
import pytest
import torch
from helpers import node_estimator

from triplet_normal_ros.simulation.depth_camera import depth_frame

#: How long the child gets to answer one 640x480 frame: seconds on a quiet machine, room for a loaded one.
CHILD_S = 60.0


def _normals() -> np.ndarray:
    """The node's CPU default on a simulated depth frame, organized, so it runs the banded compiled kernels."""
    frame = depth_frame(1)
    normals, _ = node_estimator({"device": "cpu"}).estimate(frame.points.reshape(-1, 3), shape=frame.points.shape[:2])
    return normals


def _child(pipe: Connection) -> None:
    pipe.send(_normals())
    pipe.close()


@pytest.fixture
def two_threads():
    """At least two torch threads, so the bands run on the pool (one thread runs them inline)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(max(2, threads))
    yield
    torch.set_num_threads(threads)


def test_a_forked_worker_gets_its_parents_normals(two_threads) -> None:
    parent = _normals()
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_child, args=(send,))
    child.start()
    send.close()
    try:
        assert receive.poll(CHILD_S), f"the forked child gave no answer within {CHILD_S:.0f} s"
        answer = receive.recv()
    finally:
        child.kill()
        child.join(CHILD_S)
    np.testing.assert_array_equal(answer, parent)
    assert np.isfinite(parent).all(axis=1).mean() > 0.5
