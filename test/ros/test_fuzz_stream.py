"""A stream of fuzzed clouds into the colcon-installed node, from this process over DDS (issue #11 item 6).

The clouds come from the generator the in-process properties use (test/fuzz_clouds.py), driven by a seeded
``random.Random`` so the stream is the same on every run. Malformed ones are sent without waiting; every readable one
is requested and its answer checked field by field; after each malformed cloud a well-conditioned reference cloud is
requested and its normals compared with the estimator run here. At the end the node must still be running, must have
counted every malformed cloud as rejected (or, if the next cloud replaced it in the one-slot mailbox, as dropped),
must never have logged anything but a CloudFormatError for them, and must exit cleanly on SIGINT.
"""

from __future__ import annotations

import re
import signal
import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from fuzz_clouds import NORMALS, SeededChoices, expected_xyz, field_bits, fuzzed_cloud, node_refusal
from probe_client import ProbeClient
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.orientation import orient_towards_viewpoint
from triplet_normal_ros.io.pointcloud2 import make_cloud, read_field, read_xyz

pytestmark = pytest.mark.slow  # colcon build and a node process

IN, OUT = "/tn_fuzz/points", "/tn_fuzz/normals"
RADIUS, K = 0.03, 16
PARAMS = {"method": "pca", "radius": RADIUS, "k": K, "stats_period": 1.0}
STREAM = 150  # fuzzed clouds; about half are malformed
TOTALS = re.compile(r"total: (\d+) arrived, (\d+) clouds, (\d+) dropped, (\d+) rejected")


def _header(i: int) -> Header:
    """A stamp per cloud: answers are matched to requests by stamp."""
    return Header(stamp=Time(sec=1_000 + i, nanosec=0), frame_id=f"fuzz_{i}")


def _reference(i: int) -> PointCloud2:
    """An organized 8x12 patch of a tilted plane, 1 cm apart, with two holes: normals are exact and stable."""
    u, v = np.meshgrid(np.arange(12) * 0.01, np.arange(8) * 0.01)
    xyz = np.stack([u, v, 1.0 + 0.2 * u + 0.1 * v], axis=-1).reshape(-1, 3).astype(np.float32)
    xyz[[5, 40]] = np.nan
    columns = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": np.arange(96, dtype=np.uint16)}
    return make_cloud(_header(i), columns, 8, 12)


def _normals(msg: PointCloud2) -> np.ndarray:
    return np.stack([read_field(msg, name) for name in NORMALS[:3]], axis=1)


def _check_reference(sent: PointCloud2, out: PointCloud2 | None) -> None:
    assert out is not None, f"no answer to reference cloud {sent.header.frame_id}"
    points = read_xyz(sent)
    estimator = NormalEstimator("pca", radius=RADIUS, k=K, device="cpu")
    expected, curvature = estimator.estimate(points, shape=(sent.height, sent.width))
    expected = orient_towards_viewpoint(points, expected, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(_normals(out), expected, atol=1e-5)
    np.testing.assert_allclose(read_field(out, "curvature"), curvature, atol=1e-6)
    np.testing.assert_array_equal(read_field(out, "intensity"), np.arange(96))


def _check_fuzzed(sent: PointCloud2, out: PointCloud2 | None) -> None:
    """Every field byte for byte, the normal fields appended, NaN normals where xyz is not finite, unit elsewhere."""
    assert out is not None, f"no answer to readable cloud {sent.header.frame_id}"
    assert out.header == sent.header
    kept = [f for f in sent.fields if f.name not in NORMALS]
    assert [f.name for f in out.fields] == [f.name for f in kept] + list(NORMALS)
    if sent.height * sent.width == 0:
        assert out.height * out.width == 0 and len(out.data) == 0
        return
    assert (out.height, out.width) == (sent.height, sent.width)
    for i, f in enumerate(kept):
        assert field_bits(out, out.fields[i]) == field_bits(sent, f), f.name
    normals = _normals(out)
    holes = ~np.isfinite(expected_xyz(sent)).all(axis=1)
    assert np.isnan(normals[holes]).all()
    found = ~np.isnan(normals).any(axis=1)
    np.testing.assert_allclose(np.linalg.norm(normals[found], axis=1), 1.0, atol=1e-4)


def _totals(log: str) -> tuple[int, ...] | None:
    found = TOTALS.findall(log)
    return tuple(int(v) for v in found[-1]) if found else None


def test_a_stream_of_fuzzed_clouds_never_stops_the_node(start_node) -> None:
    node = start_node(PARAMS, {"input": IN, "output": OUT}, reliable_topics=(IN,))
    assert node.wait_for_log("ready:", 60), node.log
    sent = answered = malformed = 0
    reasons: set[str] = set()
    with ProbeClient(IN, OUT) as client:
        assert client.wait_for_node(30), "the node's topics and parameter services never matched"
        for seed in range(STREAM):
            cloud = fuzzed_cloud(SeededChoices(seed), _header(2 * seed))
            reason = node_refusal(cloud)
            sent += 1
            if reason is None:
                _check_fuzzed(cloud, client.request(cloud, timeout=30))
                answered += 1
                continue
            malformed += 1
            reasons.add(reason)
            client.send(cloud)
            client.spin_for(0.2)  # lets the worker take it before the next cloud can replace it in the mailbox
            reference = _reference(2 * seed + 1)
            _check_reference(reference, client.request(reference, timeout=30))
            sent += 1
            answered += 1
        assert malformed > 40 and answered - malformed > 40, (malformed, answered)
        assert len(reasons) >= 6, reasons  # the stream covers most of the documented refusals
    deadline = time.monotonic() + 30
    while (totals := _totals(node.log)) is None or totals[0] < sent:
        assert time.monotonic() < deadline, f"stats never showed {sent} arrivals:\n{node.log[-2000:]}"
        time.sleep(0.2)
    arrived, processed, dropped, rejected = totals
    assert (arrived, processed) == (sent, answered)
    # Under heavy load the reference cloud may replace a malformed one in the mailbox first (counted as dropped).
    assert rejected + dropped == malformed and rejected > malformed // 4, totals
    assert node.proc.poll() is None, "the node died"
    assert "skipped a malformed cloud" in node.log
    assert "failed on a cloud" not in node.log, "an exception other than CloudFormatError reached the worker"
    assert "RuntimeWarning" not in node.log, "numpy warned about a fuzzed value (e.g. a signalling NaN)"
    code, _ = node.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in node.log, node.log[-3000:]
