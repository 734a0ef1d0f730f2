"""What the node adds to the estimator for a full frame: publish-to-answer from a separate process, against the
estimator alone on the same frame in this process, in one run.

Needs the colcon install that `make demo` builds (out/ws/install/triplet_normal_ros). The node runs as its own process
on a private localhost ROS graph with the shipped Fast DDS profile; this process publishes the shipped real Kinect frame
`table_scene_mug` (640x480, PCL's 32-byte XYZRGB layout, 9.8 MB) best effort, as a camera driver does, and times each
answer. Then it times `NormalEstimator.estimate` with the same settings on the same points. The node's share is
everything else: PointCloud2 decoding, orientation toward the sensor, building the answer, and DDS both ways.

Run: .venv/bin/python docs/tools/node_latency.py   (about a minute on 2 quiet CPU cores, after `make demo`)
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.ros.params import NodeSettings, apply
from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node, stop_node, wait_for_node
from triplet_normal_ros.ros.tools.replay import SENSOR_INPUT, ReplayClient, load_frame

INPUT, OUTPUT = "/latency/points", "/latency/normals"
RADIUS = 0.05
#: (label, node parameters, repeats): PCA at Open3D's usual cap, and the node's default method.
RUNS = (
    ("pca, k = 30", {"method": "pca", "radius": RADIUS, "k": 30}, 5),
    ("hybrid (default)", {"method": "hybrid", "radius": RADIUS, "k": 0}, 2),
)


def round_trips(client: ReplayClient, frame, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        cloud = frame.to_pcl_cloud(client.header())
        start = time.perf_counter()
        if client.request(cloud, timeout=600) is None:
            raise SystemExit("node_latency: no answer from the node (see the node log)")
        times.append(time.perf_counter() - start)
    return times


def estimator_alone(frame, params: dict, repeats: int) -> list[float]:
    """The estimator the node builds from these parameters (its checkpoint for the device included), alone."""
    estimator = NormalEstimator(**apply(NodeSettings(), {**params, "device": "cpu"}).estimator_args())
    points = frame.xyz.reshape(-1, 3).astype(np.float64)  # what read_xyz gives the node, as float64
    estimator.estimate(points, shape=frame.shape)  # warm-up on the frame itself
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        estimator.estimate(points, shape=frame.shape)
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", type=Path, default=Path("out/ws/install/triplet_normal_ros"))
    parser.add_argument("--out", type=Path, default=Path("out/latency"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    frame = load_frame("table_scene_mug")
    prefix, out = args.prefix.resolve(), args.out.resolve()
    env = node_env(prefix)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("ROS_", "RCUTILS_"))})
    first = params_file(out / "latency_params.yaml", {**RUNS[0][1], "device": "cpu", "stats_period": 30.0})
    node = start_node(prefix, first, {"input": INPUT, "output": OUTPUT}, out / "node.log", env)
    rows = []
    try:
        with ReplayClient(INPUT, OUTPUT, input_qos=SENSOR_INPUT) as client:
            wait_for_node(client, node, out / "node.log")
            for label, params, repeats in RUNS:
                ok, reason = client.set_parameters(params)
                assert ok, reason
                trips = round_trips(client, frame, repeats)
                alone = estimator_alone(frame, params, repeats)
                rows.append((label, repeats, float(np.median(trips)), float(np.median(alone))))
    finally:
        stop_node(node)
    print("| method | frames | node: publish to answer, s | estimator alone, s | node adds | node / estimator |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for label, repeats, trip, alone in rows:
        print(f"| {label} | {repeats} | {trip:.2f} | {alone:.2f} | {trip - alone:.2f} s | {trip / alone:.2f} |")


if __name__ == "__main__":
    main()
