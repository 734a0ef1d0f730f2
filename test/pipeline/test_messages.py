"""`answer_message`, the one answer to a PointCloud2 for the node and `triplet-normal bag`, checked against answers
worked out here without the package: a plain ball PCA (cKDTree + numpy eigh) on a curved cloud, and the exact normal
of a plane seen by a pinhole camera. Messages are real sensor_msgs PointCloud2s built with `io.pointcloud2`.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from helpers import faces_viewpoint
from scipy.spatial import cKDTree
from std_msgs.msg import Header

from triplet_normal_ros.core.config import defaults
from triplet_normal_ros.core.config.settings import Settings
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.pca.frames import COLLINEAR_RATIO
from triplet_normal_ros.errors import CloudFormatError, EstimationCancelled, EstimatorError
from triplet_normal_ros.io.bags import TYPESTORE, BagMessage, as_message, decode_cloud, encode_message
from triplet_normal_ros.io.pointcloud2 import NORMAL_FIELDS, make_cloud, read_field
from triplet_normal_ros.pipeline.message_settings import MessageSettings, viewpoint_reason
from triplet_normal_ros.pipeline.messages import Answer, answer_message

HEADER = Header(stamp=Time(sec=17, nanosec=42), frame_id="sensor")
RADIUS = 0.1
#: Angles between the answer and the reference, in degrees: float32 output against a float64 reference.
TOLERANCE_DEG = 1e-3


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sign-invariant angle between rows, by atan2 (arccos of a cosine near 1 loses the small angles)."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.abs(np.sum(a * b, axis=1))))


def assert_matches(normals: np.ndarray, reference: np.ndarray) -> None:
    """NaN rows where the reference has them, and within TOLERANCE_DEG of it elsewhere."""
    known = np.isfinite(reference).all(axis=1)
    assert (np.isfinite(normals).all(axis=1) == known).all()
    assert angles_deg(normals[known], reference[known]).max() < TOLERANCE_DEG


def saddle(n: int = 3000, seed: int = 0) -> np.ndarray:
    """A noisy saddle z = 0.3 x² - 0.2 y² over [-1, 1]², float32 as a driver would send it."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, (n, 2))
    z = 0.3 * xy[:, 0] ** 2 - 0.2 * xy[:, 1] ** 2 + rng.normal(0, 0.002, n)
    return np.column_stack([xy, z]).astype(np.float32)


def ball_pca(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The reference: each point's normal is the least eigenvector of the covariance of every point within
    `radius`, its curvature λ0 / (λ0 + λ1 + λ2); NaN with fewer than 3 points or collinear ones (λ1 at most
    COLLINEAR_RATIO λ2: the documented contract)."""
    points = points.astype(np.float64)
    normals, curvature = np.full(points.shape, np.nan), np.full(len(points), np.nan)
    for i, members in enumerate(cKDTree(points).query_ball_point(points, radius)):
        if len(members) >= 3:
            centred = points[members] - points[members].mean(axis=0)
            values, vectors = np.linalg.eigh(centred.T @ centred)
            if values[1] > COLLINEAR_RATIO * values[2]:
                normals[i], curvature[i] = vectors[:, 0], values[0] / values.sum()
    return normals, curvature


def message(points: np.ndarray, height: int = 1) -> object:
    """A PointCloud2 of `points` with an intensity field the answer must carry through untouched."""
    intensity = np.arange(len(points), dtype=np.float32)
    return make_cloud(HEADER, {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2], "intensity": intensity},
                      height, len(points) // height)  # fmt: skip


def normals_of(answer: Answer) -> np.ndarray:
    return np.column_stack([read_field(answer.message, name) for name in NORMAL_FIELDS[:3]])


def tilted_plane(height: int = 30, width: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A pinhole camera's frame of the plane z = 1 + 0.2 x, row by row, and the plane's normal facing the camera."""
    v, u = np.mgrid[0:height, 0:width]
    rays = np.stack([(u - width / 2) / 40.0, (v - height / 2) / 40.0, np.ones(u.shape)], axis=-1).reshape(-1, 3)
    depth = 1.0 / (1.0 - 0.2 * rays[:, 0])  # where t·ray meets z = 1 + 0.2 x
    normal = np.array([0.2, 0.0, -1.0]) / np.hypot(0.2, 1.0)  # -(−0.2, 0, 1): towards the origin
    return (rays * depth[:, None]).astype(np.float32), normal


@pytest.fixture(scope="module")
def pca() -> NormalEstimator:
    return NormalEstimator("pca", radius=RADIUS, device="cpu")


def pca_settings(**values) -> MessageSettings:
    return MessageSettings(Settings(method="pca", radius=RADIUS, device="cpu"), **values)


def test_an_unorganized_cloud_gets_the_ball_pca_normals_facing_the_viewpoint(pca: NormalEstimator) -> None:
    points = saddle()
    viewpoint = (0.0, 0.0, 5.0)
    answer = answer_message(message(points), pca, pca_settings(viewpoint=viewpoint))
    reference, curvature = ball_pca(points, RADIUS)
    normals = normals_of(answer)
    known = np.isfinite(reference).all(axis=1)
    assert known.mean() > 0.99
    assert_matches(normals, reference)
    np.testing.assert_allclose(read_field(answer.message, "curvature")[known], curvature[known], atol=1e-6)
    assert faces_viewpoint(points[known], normals[known], viewpoint).all()
    assert (answer.points, answer.finite, answer.known) == (len(points), len(points), int(known.sum()))


def test_the_answer_keeps_the_message_and_appends_the_normal_fields(pca: NormalEstimator) -> None:
    points = saddle(500)
    answer = answer_message(message(points), pca, pca_settings())
    out = answer.message
    assert [f.name for f in out.fields] == ["x", "y", "z", "intensity", *NORMAL_FIELDS]
    assert out.header == HEADER and (out.height, out.width) == (1, len(points))
    np.testing.assert_array_equal(read_field(out, "intensity"), np.arange(len(points), dtype=np.float32))
    np.testing.assert_array_equal(read_field(out, "x"), points[:, 0])
    known = np.isfinite(normals_of(answer)).all(axis=1)
    assert known.any() and (np.isfinite(read_field(out, "curvature")) == known).all()


@pytest.mark.parametrize("method", ["pca", "hybrid"])
def test_an_organized_frame_of_a_plane_gets_its_exact_normal_and_holes_stay_holes(method: str) -> None:
    """pca, and hybrid as the node runs it by default (the shipped checkpoint for the CPU): a plane is a plane."""
    points, normal = tilted_plane()
    points[100] = 0.0  # a LiDAR's no-return
    points[200] = np.nan  # a depth camera's hole
    estimator = NormalEstimator(method, radius=RADIUS, device="cpu")
    answer = answer_message(message(points, height=30), estimator, MessageSettings(estimator.settings))
    normals = normals_of(answer)
    holes = np.zeros(len(points), bool)
    holes[[100, 200]] = True
    assert np.isnan(normals[holes]).all() and np.isnan(read_field(answer.message, "curvature")[holes]).all()
    assert (normals[~holes] @ normal > 0).all()  # facing the camera
    assert angles_deg(normals[~holes], np.broadcast_to(normal, normals[~holes].shape)).max() < TOLERANCE_DEG
    assert (answer.finite, answer.known) == (len(points) - 1, len(points) - 2)
    assert estimator.last_run.plan.survey == "window"  # the organized path, not pools


def test_a_point_at_the_origin_is_a_no_return_unless_told_otherwise(pca: NormalEstimator) -> None:
    points = saddle(1500)
    points[7] = 0.0  # the saddle passes through the origin: a real point could lie there
    cloud = message(points)
    dropped = normals_of(answer_message(cloud, pca, pca_settings()))
    assert np.isnan(dropped[7]).all()
    others = np.delete(np.arange(len(points)), 7)
    reference, _ = ball_pca(points[others], RADIUS)  # nor is it anyone's neighbour
    assert_matches(dropped[others], reference)
    kept = normals_of(answer_message(cloud, pca, pca_settings(zeros_are_no_returns=False)))
    reference, _ = ball_pca(points, RADIUS)
    assert_matches(kept, reference)
    assert np.isfinite(kept[7]).all()


def test_normals_face_the_viewpoint_or_keep_their_signs(pca: NormalEstimator) -> None:
    points, normal = tilted_plane()
    cloud = message(points, height=30)
    away = normals_of(answer_message(cloud, pca, pca_settings(viewpoint=(0.0, 0.0, 10.0))))
    assert (away @ normal < 0).all()  # they face a viewpoint behind the plane
    raw = normals_of(answer_message(cloud, pca, pca_settings(orient=False, viewpoint=(0.0, 0.0, 10.0))))
    assert angles_deg(raw, away).max() < TOLERANCE_DEG
    flipped = normals_of(answer_message(cloud, pca, pca_settings(orient=False)))
    np.testing.assert_array_equal(raw, flipped)  # without orienting, the viewpoint plays no part


def test_each_message_takes_its_own_snapshot_and_the_estimator_is_not_edited(pca: NormalEstimator) -> None:
    points = saddle(1500)
    before = pca.settings
    wide = answer_message(message(points), pca, MessageSettings(before.with_values(radius=0.2)))
    assert pca.settings == before  # the estimator keeps its own settings
    reference, _ = ball_pca(points, 0.2)
    assert_matches(normals_of(wide), reference)


def test_an_empty_cloud_keeps_its_fields_and_gains_the_normal_fields(pca: NormalEstimator) -> None:
    empty = message(np.empty((0, 3), np.float32))
    answer = answer_message(empty, pca, pca_settings())
    assert (answer.points, answer.finite, answer.known) == (0, 0, 0)
    assert [f.name for f in answer.message.fields] == ["x", "y", "z", "intensity", *NORMAL_FIELDS]
    assert answer.message.height * answer.message.width == 0


def test_a_bag_cloud_and_a_node_cloud_get_the_same_bytes(pca: NormalEstimator) -> None:
    """`bag` reads its clouds through rosbags; the same cloud as the node receives it gets the same answer."""
    cloud = message(tilted_plane()[0], height=30)
    raw = encode_message(cloud)  # the cloud as a bag stores it
    from_bag = decode_cloud(BagMessage(0, "/points", "sensor_msgs/msg/PointCloud2", 1, raw))
    bag_answer = TYPESTORE.deserialize_cdr(encode_message(answer_message(as_message(from_bag), pca, pca_settings())
                                                          .message), "sensor_msgs/msg/PointCloud2")  # fmt: skip
    node_answer = answer_message(cloud, pca, pca_settings()).message
    assert bag_answer.data.tobytes() == bytes(node_answer.data)
    stamp = bag_answer.header.stamp
    assert (stamp.sec, stamp.nanosec, bag_answer.header.frame_id) == (17, 42, "sensor")
    assert [f.name for f in bag_answer.fields] == [f.name for f in node_answer.fields]


def test_refusals(pca: NormalEstimator) -> None:
    cloud = message(saddle(200))
    with pytest.raises(EstimatorError, match="build another estimator"):
        answer_message(cloud, pca, MessageSettings(Settings(method="learned", device="cpu")))
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(EstimationCancelled):
        answer_message(cloud, pca, pca_settings(), cancel)
    no_z = make_cloud(HEADER, {"x": np.zeros(3, np.float32), "y": np.zeros(3, np.float32)}, 1, 3)
    with pytest.raises(CloudFormatError, match="no 'z' field"):
        answer_message(no_z, pca, pca_settings())
    with pytest.raises(EstimatorError, match="viewpoint must be three finite numbers"):
        MessageSettings(viewpoint=(0.0, float("nan"), 0.0))


@pytest.mark.parametrize("bad", [(0.0, 0.0), [0.0, float("inf"), 0.0], "abc", 3.0, (True, 0.0, 0.0)])
def test_the_viewpoint_rule(bad) -> None:
    assert viewpoint_reason(bad).startswith("viewpoint must be three finite numbers [x, y, z], got ")
    assert viewpoint_reason([1, 2.5, np.float32(-3)]) is None
    assert viewpoint_reason(defaults.VIEWPOINT) is None
