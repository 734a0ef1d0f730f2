"""``make demo``: run the colcon-installed node, replay the shipped Kinect frames through it, draw the result.

This process is the "camera": it starts the node as a separate process, publishes each frame, waits for the answer
and measures the round trip. The learned method runs on frames decimated to every ``--step``-th row and column,
because the network manages only a few thousand points per second on a small CPU; PCA then runs on the full frames
after a run-time parameter change. Pictures go to ``out/normal_map.png`` and ``out/side_by_side.png``.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..evaluation.normal_map import normals_to_rgb, side_by_side, stack_rows, upscale, write_png
from ..io.pointcloud2 import NORMAL_FIELDS, read_field
from .replay import FRAMES, Frame, ReplayClient, load_frame

INPUT, OUTPUT = "/demo/camera/depth/points", "/demo/camera/depth/normals"
LEARNED = {"method": "learned", "radius": 0.05}
PCA = {"method": "pca", "radius": 0.03, "k": 32}


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


def _params_file(path: Path, params: dict[str, object]) -> Path:
    """Parameter file for the node; the input is overridden to reliable so 5 MB frames survive (README, QoS)."""
    lines = ["/**:", "  ros__parameters:"]
    lines += [f"    {k}: {v!r}" if not isinstance(v, str) else f"    {k}: {v}" for k, v in params.items()]
    lines += ["    qos_overrides:", f"      {INPUT}:", "        subscription:", "          reliability: reliable"]
    path.write_text("\n".join(lines) + "\n")
    return path


def _node_env(prefix: Path) -> dict[str, str]:
    """What sourcing the install gives a Python package, on a private localhost-only ROS graph."""
    env = dict(os.environ)
    site = prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH")) if p)
    env.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["RCUTILS_COLORIZED_OUTPUT"] = "0"
    return env


def _start_node(prefix: Path, out: Path, env: dict[str, str]) -> subprocess.Popen:
    executable = prefix / "lib" / "triplet_normal_ros" / "node"
    if not executable.is_file():
        raise SystemExit(f"demo: no installed node at {executable}; run colcon build first (make demo does)")
    params = _params_file(out / "demo_params.yaml", {**LEARNED, "stats_period": 30.0})
    args = [str(executable), "--ros-args", "--params-file", str(params), "-r", f"input:={INPUT}"]
    args += ["-r", f"output:={OUTPUT}"]
    log = (out / "node.log").open("w")
    return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=out)


def _wait_for(client: ReplayClient, node: subprocess.Popen, out: Path, timeout: float = 120.0) -> None:
    """Until the node's topics and services match; fail fast (with its own error line) if it exits instead."""
    deadline = time.monotonic() + timeout
    while not client.wait_for_node(1.0):
        if node.poll() is not None or time.monotonic() > deadline:
            log = (out / "node.log").read_text(errors="replace").strip().splitlines()
            raise SystemExit(f"demo: the node did not come up: {log[-1] if log else 'no output'}")


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


def _pictures(out: Path, learned: list[Result], pca: list[Result], step: int) -> tuple[Path, Path]:
    """normal_map.png: learned normals of the first frame; side_by_side.png: per frame, RGB | learned | PCA."""
    learned_rgb = [upscale(normals_to_rgb(r.normals), step) for r in learned]
    normal_map = write_png(out / "normal_map.png", learned_rgb[0])
    rows = [
        side_by_side([p.frame.rgb_image(), lr, normals_to_rgb(p.normals)])
        for lr, p in zip(learned_rgb, pca, strict=True)
    ]
    return normal_map, write_png(out / "side_by_side.png", stack_rows(rows))


def _summary(results: list[Result]) -> None:
    print("summary:")
    for method in dict.fromkeys(r.method for r in results):
        rs = [r for r in results if r.method == method]
        latency = np.mean([r.latency_s for r in rs])
        rate = sum(r.valid for r in rs) / sum(r.latency_s for r in rs)
        print(f"  {method:<8} {len(rs)} frames, mean latency {latency * 1e3:.0f} ms, {rate:.0f} normals/s end to end")


def run(prefix: Path, out: Path, step: int, names: list[str]) -> int:
    out.mkdir(parents=True, exist_ok=True)
    frames = [load_frame(n) for n in names]
    env = _node_env(prefix)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("ROS_", "RCUTILS_"))})
    node = _start_node(prefix, out, env)
    try:
        with ReplayClient(INPUT, OUTPUT) as client:
            _wait_for(client, node, out)
            print(f"learned, radius {LEARNED['radius']} m, frames decimated to every {step}th row and column:")
            learned = _replay(client, [f.decimated(step) for f in frames], "learned")
            ok, reason = client.set_parameters(PCA)
            if not ok:
                raise SystemExit(f"demo: switching to pca was rejected: {reason}")
            print(f"pca, radius {PCA['radius']} m, k = {PCA['k']}, full 640x480 frames, after a parameter change:")
            pca = _replay(client, frames, "pca")
        _summary(learned + pca)
        for path in _pictures(out, learned, pca, step):
            print(f"wrote {path}")
    finally:
        code = _stop(node)
        print(f"node stopped on SIGINT with exit code {code}; its log is {out / 'node.log'}")
    return 0 if code == 0 else 1


def _stop(node: subprocess.Popen) -> int | None:
    if node.poll() is None:
        node.send_signal(signal.SIGINT)
    try:
        return node.wait(10)
    except subprocess.TimeoutExpired:
        node.kill()
        return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", type=Path, required=True, help="colcon install prefix of triplet_normal_ros")
    parser.add_argument("--out", type=Path, default=Path("out"), help="where pictures and logs go")
    parser.add_argument("--step", type=int, default=4, help="decimation of the frames the learned method sees")
    parser.add_argument("--frames", nargs="+", default=list(FRAMES), choices=FRAMES)
    args = parser.parse_args(argv)
    return run(args.prefix.resolve(), args.out.resolve(), args.step, args.frames)


if __name__ == "__main__":
    sys.exit(main())
