"""``make demo``: run the colcon-installed node, replay the shipped Kinect frames through it, draw the result.

This process is the "camera": it starts the node as a separate process, publishes each full 640x480 frame best
effort (as camera drivers do, through the shipped Fast DDS profile), waits for the answer and measures the round
trip. The node first runs its default, ``hybrid`` (a window survey everywhere, the network near edges and folds), then,
after a run-time parameter change, ``pca`` at its default k: the plane of each pixel's integral-image window over the
same 5 cm ball (PCA's, with the camera's noise along the rays taken out). Pictures go to ``out/normal_map.png`` and
``out/side_by_side.png`` (labelled panels: camera image, hybrid, PCA, same frames, same radius).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.config import defaults
from ...io.normal_map import normals_to_rgb, write_png
from ...io.pointcloud2 import NORMAL_FIELDS, read_field
from ...io.samples import FRAMES
from .node_process import node_env, params_file, start_node, stop_node, wait_for_node
from .replay import SENSOR_INPUT, Frame, ReplayClient, load_frame

INPUT, OUTPUT = "/demo/camera/depth/points", "/demo/camera/depth/normals"
RADIUS = defaults.RADIUS
#: The node's defaults (hybrid, the default checkpoint) at a depth camera's usual radius.
HYBRID = {"method": "hybrid", "radius": RADIUS}
#: PCA at the node's default k: on these organized frames, the integral-image windows (about k pixels at most).
PCA = {"method": "pca", "radius": RADIUS}


@dataclass(frozen=True)
class Result:
    """One answered frame."""

    frame: Frame
    method: str
    latency_s: float
    normals: np.ndarray  # (h, w, 3)

    @property
    def valid(self) -> int:
        return int(np.isfinite(self.normals).all(axis=-1).sum())

    def line(self) -> str:
        h, w = self.frame.shape
        rate = self.valid / self.latency_s
        return (
            f"  {self.frame.name:<28} {w}x{h:<4} {self.method:<8} {self.latency_s * 1e3:8.0f} ms"
            f"  {self.valid:7d} normals  {rate:8.0f} points/s"
        )


def _start_node(prefix: Path, out: Path, env: dict[str, str]) -> subprocess.Popen:
    """The node with its defaults (hybrid) at the demo's radius, a statistics line every 30 s."""
    params = params_file(out / "demo_params.yaml", {**HYBRID, "stats_period": 30.0})
    return start_node(prefix, params, {"input": INPUT, "output": OUTPUT}, out / "node.log", env)


def _prime(client: ReplayClient, frame: Frame) -> None:
    """A small crop answered first: each full frame below is sent only once, and a best-effort sample sent the moment
    discovery matches can be lost."""
    crop = Frame(f"{frame.name}[crop]", frame.xyz[200:240, 300:340], frame.rgb[200:240, 300:340])
    if client.request_resending(crop.to_cloud(client.header()), timeout=90, every=30) is None:
        raise SystemExit("demo: the node never answered a small cloud (see out/node.log)")


def _replay(client: ReplayClient, frames: list[Frame], method: str) -> list[Result]:
    results = []
    for frame in frames:
        cloud = frame.to_cloud(client.header())
        start = time.perf_counter()
        answer = client.request(cloud, timeout=600)
        if answer is None:
            raise SystemExit(f"demo: no answer from the node for {frame.name} (see out/node.log)")
        latency = time.perf_counter() - start
        normals = np.stack([read_field(answer, f) for f in NORMAL_FIELDS[:3]], axis=1).reshape(*frame.shape, 3)
        results.append(Result(frame, method, latency, normals))
        print(results[-1].line(), flush=True)
    return results


def _pictures(out: Path, hybrid: list[Result], pca: list[Result]) -> tuple[Path, Path]:
    """normal_map.png: hybrid normals of the first frame; side_by_side.png: per frame, camera | hybrid | PCA."""
    from ...evaluation.plots import labelled_panels

    normal_map = write_png(out / "normal_map.png", normals_to_rgb(hybrid[0].normals))
    rows = [
        [
            (f"{h.frame.name}: camera image", h.frame.rgb_image()),
            (f"hybrid, r = {RADIUS * 100:g} cm, {h.latency_s:.1f} s", normals_to_rgb(h.normals)),
            (f"PCA, r = {RADIUS * 100:g} cm, integral-image windows, {p.latency_s:.1f} s", normals_to_rgb(p.normals)),
        ]
        for h, p in zip(hybrid, pca, strict=True)
    ]
    title = "Full 640x480 Kinect frames through the node; colour = normal (red right, green up, blue to the camera)"
    return normal_map, labelled_panels(out / "side_by_side.png", rows, title)


def _summary(results: list[Result]) -> None:
    print("summary:")
    for method in dict.fromkeys(r.method for r in results):
        rs = [r for r in results if r.method == method]
        latency = np.mean([r.latency_s for r in rs])
        rate = sum(r.valid for r in rs) / sum(r.latency_s for r in rs)
        print(f"  {method:<8} {len(rs)} frames, mean latency {latency * 1e3:.0f} ms, {rate:.0f} normals/s end to end")


def run(prefix: Path, out: Path, names: list[str]) -> int:
    out.mkdir(parents=True, exist_ok=True)
    frames = [load_frame(n) for n in names]
    env = node_env(prefix)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("ROS_", "RCUTILS_"))})
    node = _start_node(prefix, out, env)
    try:
        with ReplayClient(INPUT, OUTPUT, input_qos=SENSOR_INPUT) as client:  # best effort, as camera drivers
            wait_for_node(client, node, out / "node.log")
            _prime(client, frames[0])
            print(f"hybrid (the node's default), radius {RADIUS} m, full 640x480 frames:")
            hybrid = _replay(client, frames, "hybrid")
            ok, reason = client.set_parameters(PCA)
            if not ok:
                raise SystemExit(f"demo: switching to pca was rejected: {reason}")
            print(f"pca over the same {RADIUS} m ball (integral-image windows), full 640x480 frames, after a change:")
            pca = _replay(client, frames, "pca")
        _summary(hybrid + pca)
        for path in _pictures(out, hybrid, pca):
            print(f"wrote {path}")
    finally:
        code = stop_node(node)
        print(f"node stopped on SIGINT with exit code {code}; its log is {out / 'node.log'}")
    return 0 if code == 0 else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", type=Path, required=True, help="colcon install prefix of triplet_normal_ros")
    parser.add_argument("--out", type=Path, default=Path("out"), help="where pictures and logs go")
    parser.add_argument("--frames", nargs="+", default=list(FRAMES), choices=FRAMES)
    args = parser.parse_args(argv)
    return run(args.prefix.resolve(), args.out.resolve(), args.frames)


if __name__ == "__main__":
    sys.exit(main())
