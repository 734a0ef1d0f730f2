"""A stream of fuzzed clouds into the colcon-installed node, from this process over DDS.

The clouds come from the generator the in-process properties use (test/fuzz_clouds.py), driven by a seeded
``random.Random`` so the stream is the same on every run. Every readable one is requested and its answer checked field
by field. Each malformed one is sent without waiting for an answer, and the next cloud goes out only once the node's
statistics count its rejection (so no cloud ever replaces another in the one-slot mailbox); then a reference cloud is
requested: flat patches of known planes, whose normals the node must give exactly, facing the sensor. At the end the
node must still be running, must have counted every malformed cloud as rejected and dropped none, must never have
logged anything but a CloudFormatError for them, and must exit cleanly on SIGINT.
"""

from __future__ import annotations

import re
import signal

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from conftest import STARTUP_S
from fuzz_clouds import NORMALS, SeededChoices, expected_xyz, field_bits, fuzzed_cloud, node_refusal
from probe_client import ProbeClient
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from triplet_normal_ros.io.pointcloud2 import make_cloud, read_field, read_xyz

pytestmark = pytest.mark.slow  # colcon build and a node process

IN, OUT = "/tn_fuzz/points", "/tn_fuzz/normals"
RADIUS, K = 0.03, 16
#: A statistics line every 0.2 s: the stream waits on the rejection count it logs.
PARAMS = {"method": "pca", "radius": RADIUS, "k": K, "stats_period": 0.2}
STREAM = 150  # fuzzed clouds; about half are malformed
#: Hang guards only: a rejection or an answer that has not come this long after the cloud went out never will.
WAIT_S = 30.0
#: The reference clouds: two flat patches of ROWS x COLUMNS points, PITCH apart, side by side in one organized cloud.
ROWS, COLUMNS, PITCH = 8, 12, 0.01
TOTALS = re.compile(r"total: (\d+) arrived, (\d+) clouds, (\d+) dropped, (\d+) rejected")


def _header(i: int) -> Header:
    """A stamp per cloud: answers are matched to requests by stamp."""
    return Header(stamp=Time(sec=1_000 + i, nanosec=0), frame_id=f"fuzz_{i}")


def _facing_normal(rng: np.random.Generator) -> np.ndarray:
    """A unit normal pointing back at the sensor (-z), tilted by up to 40° about a random axis in the image plane."""
    tilt, azimuth = np.radians(rng.uniform(0, 40)), rng.uniform(0, 2 * np.pi)
    return np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])


def _reference(i: int) -> tuple[PointCloud2, np.ndarray]:
    """An organized ROWS x (2 COLUMNS) cloud of two flat patches of seeded planes, each 1 m or so in front of the
    sensor and facing it, 30 cm apart (no ball of RADIUS holds points of both), with two holes; and every point's exact
    normal, facing the sensor at the origin (NaN at the holes)."""
    rng = np.random.default_rng(i)
    xyz, exact = np.empty((ROWS, 2 * COLUMNS, 3)), np.empty((ROWS, 2 * COLUMNS, 3))
    u, v = np.meshgrid((np.arange(COLUMNS) - COLUMNS / 2) * PITCH, (np.arange(ROWS) - ROWS / 2) * PITCH)
    for side, centre in enumerate(([-0.15, 0.0, 1.0], [0.15, 0.05, 1.2])):
        normal = _facing_normal(rng)
        across = np.cross(normal, [0.0, 1.0, 0.0])
        across /= np.linalg.norm(across)
        down = np.cross(normal, across)
        columns = slice(side * COLUMNS, (side + 1) * COLUMNS)
        xyz[:, columns] = np.asarray(centre) + u[..., None] * across + v[..., None] * down
        exact[:, columns] = normal
    xyz, exact = xyz.reshape(-1, 3).astype(np.float32), exact.reshape(-1, 3)
    holes = rng.choice(len(xyz), 2, replace=False)
    xyz[holes], exact[holes] = np.nan, np.nan
    n = len(xyz)
    columns = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": np.arange(n, dtype=np.uint16)}
    return make_cloud(_header(i), columns, ROWS, 2 * COLUMNS), exact


def _normals(msg: PointCloud2) -> np.ndarray:
    return np.stack([read_field(msg, name) for name in NORMALS[:3]], axis=1)


def _check_reference(sent: PointCloud2, exact: np.ndarray, out: PointCloud2 | None) -> None:
    """The exact plane normal, with its sign (facing the sensor), at every point but the holes; zero curvature."""
    assert out is not None, f"no answer to reference cloud {sent.header.frame_id}"
    assert out.header == sent.header
    # Rounding the coordinates to float32 (7e-8 m at 1.2 m) tilts a plane fitted over a 3 cm ball by up to ~6e-6 rad.
    np.testing.assert_allclose(_normals(out), exact, atol=2e-5)
    curvature = read_field(out, "curvature")
    holes = np.isnan(exact).any(axis=1)
    assert np.isnan(curvature[holes]).all() and (np.abs(curvature[~holes]) < 1e-6).all()
    np.testing.assert_array_equal(read_field(out, "intensity"), np.arange(sent.height * sent.width))


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


def _rejected(node) -> int:
    totals = _totals(node.log)
    return totals[3] if totals else 0


def test_the_reference_clouds_are_what_they_claim() -> None:
    """Two planes per cloud, each facing the sensor, far enough apart that no ball mixes them, holes where said."""
    for i in range(20):
        cloud, exact = _reference(i)
        points = read_xyz(cloud)
        holes = np.isnan(exact).any(axis=1)
        np.testing.assert_array_equal(holes, ~np.isfinite(points).all(axis=1))
        assert holes.sum() == 2
        ok = ~holes
        np.testing.assert_allclose(np.linalg.norm(exact[ok], axis=1), 1.0)
        assert (np.einsum("ij,ij->i", -points[ok], exact[ok]) > 0.5).all()  # facing the sensor, not edge-on
        left = np.zeros((ROWS, 2 * COLUMNS), bool)
        left[:, :COLUMNS] = True
        left = left.reshape(-1)
        for side in (left, ~left):
            rows = ok & side
            offsets = np.einsum("ij,ij->i", points[rows], exact[rows])  # n . p: one plane per side
            assert np.ptp(offsets) < 1e-6
            gap = np.linalg.norm(points[rows][:, None] - points[ok & ~side][None], axis=-1).min()
            assert gap > 2 * RADIUS


def test_a_stream_of_fuzzed_clouds_never_stops_the_node(start_node) -> None:
    node = start_node(PARAMS, {"input": IN, "output": OUT}, reliable_topics=(IN,))
    assert node.wait_for_log("ready:", STARTUP_S), node.log
    sent = answered = malformed = 0
    reasons: set[str] = set()
    with ProbeClient(IN, OUT) as client:
        assert client.wait_for_node(30), "the node's topics and parameter services never matched"
        for seed in range(STREAM):
            cloud = fuzzed_cloud(SeededChoices(seed), _header(2 * seed))
            reason = node_refusal(cloud)
            sent += 1
            if reason is None:
                _check_fuzzed(cloud, client.request(cloud, timeout=WAIT_S))
                answered += 1
                continue
            malformed += 1
            reasons.add(reason)
            client.send(cloud)
            counted = client.spin_until(lambda: _rejected(node) >= malformed, WAIT_S)  # noqa: B023 (called here)
            assert counted, f"malformed cloud {seed} ({reason}) was never rejected:\n{node.log[-2000:]}"
            reference, exact = _reference(2 * seed + 1)
            _check_reference(reference, exact, client.request(reference, timeout=WAIT_S))
            sent += 1
            answered += 1
        assert malformed > 40 and answered - malformed > 40, (malformed, answered)
        assert len(reasons) >= 6, reasons  # the stream covers most of the documented refusals
        # Each cloud went out only after the one before it was answered or rejected: none was dropped.
        expected = (sent, answered, 0, malformed)  # arrived, processed, dropped, rejected
        counted = client.spin_until(lambda: _totals(node.log) == expected, WAIT_S)
        assert counted, f"the node's totals {_totals(node.log)} never reached {expected}:\n{node.log[-2000:]}"
    assert node.proc.poll() is None, "the node died"
    assert "skipped a malformed cloud" in node.log
    assert "failed on a cloud" not in node.log, "an exception other than CloudFormatError reached the worker"
    assert "RuntimeWarning" not in node.log, "numpy warned about a fuzzed value (e.g. a signalling NaN)"
    code, _ = node.stop(signal.SIGINT, timeout=60.0)  # a hang guard, not a speed requirement
    assert code == 0 and "shut down" in node.log and "Traceback" not in node.log, node.log[-3000:]
