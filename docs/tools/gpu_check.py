"""GPU readiness, the Python half of docs/tools/gpu_check.sh: the estimator on the GPU against the CPU, full frames on
the GPU, the colcon-installed node on the GPU, and the one table they make.

No test in test/ runs on CUDA (the GPU searches are tested on CPU tensors), so the comparisons that matter run here:
on a simulated 640x480 depth frame (radius 0.05 m), each method on the device against the same method on the CPU at
the same query points, where both use the same neighbourhood (the integral-image window, the KD-tree, or the cell
lists that give the KD-tree's neighbours on the device), and each device's default search (`neighbours='auto'`: the
pixel grid on a GPU where the window does not answer, the KD-tree on a CPU) by accuracy. Every step appends one JSON
line (what, device, seconds, result, ok) to the results file; `table` prints them as one markdown table and fails when
one is not ok.

Subcommands (the shell script runs them in this order; each takes --device, cpu for a dry run without a GPU):
  probe     the device torch sees, or one line and exit 1
  compare   device vs CPU at the same query points, then full-frame timings on the device
  node      the installed node on the device: full real frames, publish to answer, its normals checked
  record    one row from the shell (colcon build, bench)
  bench-row the row of a `triplet-normal bench --out FILE` run
  table     the markdown table (--out FILE: also FILE's `gpu-check` block); exit 1 when a row is not ok
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from triplet_normal_ros.evaluation.report import tool_command, update_section

RADIUS = 0.05  # m, the node's default and bench's depth-frame radius
#: Same neighbourhood on both devices: at least this share of query points agrees within 1°, at most this share of
#: them has a normal on one device only, and the MSAE differs by at most this much (relative).
WITHIN_1DEG, NAN_MISMATCH, MSAE_REL = 0.999, 0.001, 0.01
#: The default search on the device (the pixel grid on a GPU) may cost at most this factor of the CPU default's MSAE.
GRID_MSAE = 1.10
INPUT, OUTPUT = "/gpu_check/points", "/gpu_check/normals"


def record(results: Path, what: str, device: str, seconds: float | None, result: str, ok: bool) -> None:
    row = {"what": what, "device": device, "seconds": seconds, "result": result, "ok": bool(ok)}
    with results.open("a") as f:
        f.write(json.dumps(row) + "\n")
    print(f"gpu_check: {'ok' if ok else 'FAILED'}: {what} on {device}: {result}", file=sys.stderr, flush=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sign-invariant angle between two unit normals per row, degrees; NaN where either is missing."""
    return np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", a, b)), 0.0, 1.0)))


def agreement(cpu: np.ndarray, dev: np.ndarray) -> tuple[float, float, int]:
    """(share within 1°, worst angle, rows with a normal on one device only) over the rows both answered."""
    a_ok, b_ok = np.isfinite(cpu).all(axis=1), np.isfinite(dev).all(axis=1)
    both = a_ok & b_ok
    angles = angle_deg(cpu[both], dev[both])
    share = float((angles < 1.0).mean()) if both.any() else 0.0
    return share, float(angles.max()) if both.any() else float("nan"), int((a_ok != b_ok).sum())


# -- probe ----------------------------------------------------------------------------------------------------------


def cmd_probe(args: argparse.Namespace) -> int:
    import torch

    if args.device == "cpu":
        print(f"cpu (dry run), torch {torch.__version__}")
        return 0
    if not torch.cuda.is_available():
        build = "the CPU build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
        print(
            f"gpu_check: torch {torch.__version__} in this venv ({build}) sees no CUDA device; docs/CHOOSING.md, "
            "'Installing and testing', says how to install a CUDA build",
            file=sys.stderr,
        )
        return 1
    print(f"{torch.cuda.get_device_name(0)}, torch {torch.__version__}, CUDA {torch.version.cuda}")
    return 0


# -- compare --------------------------------------------------------------------------------------------------------

#: The network methods with the checkpoint both devices load (an empty one would mean lite or range on the CPU).
LEARNED, HYBRID = {"method": "learned", "checkpoint": "default"}, {"method": "hybrid", "checkpoint": "default"}
#: (what, estimator options, CPU search, device search, same neighbourhood on both).
COMPARISONS = (
    ("pca, window (k = 500)", {"method": "pca"}, "auto", "auto", True),
    ("pca k = 30, kdtree", {"method": "pca", "k": 30}, "kdtree", "kdtree", True),
    ("pca k = 30, voxel vs cpu kdtree", {"method": "pca", "k": 30}, "kdtree", "voxel", True),
    ("learned, kdtree", LEARNED, "kdtree", "kdtree", True),
    ("learned, voxel vs cpu kdtree", LEARNED, "kdtree", "voxel", True),
    ("learned, default search on each (grid on a GPU)", LEARNED, "auto", "auto", False),
    ("hybrid, kdtree", HYBRID, "kdtree", "kdtree", True),
    ("hybrid, default search on each (grid on a GPU)", HYBRID, "auto", "auto", False),
)


def _timed(estimator, points, query, shape) -> tuple[np.ndarray, float]:
    start = time.perf_counter()
    normals, _ = estimator.estimate(points, query, shape=shape)
    return normals, time.perf_counter() - start


def cmd_compare(args: argparse.Namespace) -> int:
    from triplet_normal_ros.core.estimator import NormalEstimator
    from triplet_normal_ros.evaluation.metrics import msae
    from triplet_normal_ros.simulation.depth_camera import depth_frame

    width, height = args.size
    frame = depth_frame(0, width, height)
    shape = frame.points.shape[:2]
    points = frame.points.reshape(-1, 3).astype(np.float64)
    truth = frame.normals.reshape(-1, 3)
    valid = np.flatnonzero(np.isfinite(points).all(axis=1))
    query = np.sort(np.random.default_rng(0).choice(valid, min(args.queries, len(valid)), replace=False))
    warm = query[:256]
    references: dict[tuple, tuple[np.ndarray, str]] = {}
    for what, options, cpu_search, dev_search, same in COMPARISONS:
        try:
            key = (tuple(sorted(options.items())), cpu_search)
            if key not in references:
                cpu = NormalEstimator(radius=RADIUS, device="cpu", neighbours=cpu_search, **options)
                references[key] = (_timed(cpu, points, query, shape)[0], cpu.last_run.search)
            ref, ref_search = references[key]
            dev = NormalEstimator(radius=RADIUS, device=args.device, neighbours=dev_search, **options)
            dev.estimate(points, warm, shape=shape)
            normals, seconds = _timed(dev, points, query, shape)
            m_cpu, m_dev = msae(ref, truth[query]), msae(normals, truth[query])
            searches = f"search {ref_search} / {dev.last_run.search}"
            if same:
                share, worst, mismatch = agreement(ref, normals)
                close = abs(m_dev - m_cpu) <= MSAE_REL * m_cpu
                ok = share >= WITHIN_1DEG and mismatch <= NAN_MISMATCH * len(query) and close
                result = (
                    f"{share:.2%} within 1° of cpu (worst {worst:.2g}°), {mismatch} one-sided NaN, "
                    f"MSAE {m_cpu:.4f} / {m_dev:.4f} (cpu / device), {searches}"
                )
            else:
                ok = m_dev <= GRID_MSAE * m_cpu
                result = f"MSAE {m_cpu:.4f} / {m_dev:.4f} (cpu / device, ≤ {GRID_MSAE:g} × to pass), {searches}"
            record(args.results, f"{what}: {len(query):,} queries", args.device, seconds, result, ok)
        except Exception as error:  # one failing comparison must not hide the others
            record(args.results, what, args.device, None, f"{type(error).__name__}: {error}", False)
    for method in ("pca", "learned", "hybrid"):
        try:
            estimator = NormalEstimator(method, radius=RADIUS, device=args.device)
            estimator.estimate(points, warm, shape=shape)
            runs = []
            for _ in range(args.repeats):
                normals, seconds = _timed(estimator, points, None, shape)
                runs.append(seconds)
            seconds = statistics.median(runs)
            answered = int(np.isfinite(normals).all(axis=1).sum())
            ok = answered >= 0.9 * len(valid)
            result = (
                f"{len(points) / seconds:,.0f} points/s (median of {len(runs)}), "
                f"search {estimator.last_run.search}, {answered:,} of {len(valid):,} valid pixels answered"
            )
            record(args.results, f"{method}, full {width}x{height} frame", args.device, seconds, result, ok)
        except Exception as error:
            record(args.results, f"{method}, full frame", args.device, None, f"{type(error).__name__}: {error}", False)
    return 0


# -- node -----------------------------------------------------------------------------------------------------------


def cmd_node(args: argparse.Namespace) -> int:
    from triplet_normal_ros.core.estimator import NormalEstimator
    from triplet_normal_ros.io.pointcloud2 import read_field
    from triplet_normal_ros.ros.tools.node_process import node_env, params_file, start_node, stop_node, wait_for_node
    from triplet_normal_ros.ros.tools.replay import RELIABLE_INPUT, ReplayClient, load_frame

    what = f"node, {args.method}, full real frame"
    prefix, out = args.prefix.resolve(), args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    log = out / "node.log"
    frame = load_frame("table_scene_mug")
    env = node_env(prefix)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("ROS_", "RCUTILS_"))})
    params = {"method": args.method, "radius": RADIUS, "device": args.device, "stats_period": 30.0}
    try:
        node = start_node(
            prefix,
            params_file(out / "node_params.yaml", params, (INPUT,)),
            {"input": INPUT, "output": OUTPUT},
            log,
            env,
        )
    except SystemExit as error:  # no colcon install
        record(args.results, what, args.device, None, str(error), False)
        return 0
    trips, answer = [], None
    try:
        with ReplayClient(INPUT, OUTPUT, input_qos=RELIABLE_INPUT) as client:
            wait_for_node(client, node, log)
            for _ in range(args.repeats):
                cloud = frame.to_pcl_cloud(client.header())
                start = time.perf_counter()
                answer = client.request(cloud, timeout=600)
                if answer is None:
                    break
                trips.append(time.perf_counter() - start)
    except SystemExit as error:  # the node did not come up
        record(args.results, what, args.device, None, str(error), False)
        return 0
    finally:
        stop_node(node)
    text = log.read_text(errors="replace")
    on_device = f"device={args.device}" in text  # the node's ready line names the estimator's device (cuda:0)
    if answer is None:
        record(args.results, what, args.device, None, f"no answer within 600 s (log: {log})", False)
        return 0
    theirs = np.column_stack([read_field(answer, f"normal_{c}") for c in "xyz"]).astype(np.float64)
    points = frame.xyz.reshape(-1, 3).astype(np.float64)
    ours, _ = NormalEstimator(args.method, radius=RADIUS, device=args.device).estimate(points, shape=frame.shape)
    share, _, mismatch = agreement(ours, theirs)
    valid = int(np.isfinite(points).all(axis=1).sum())
    answered = int(np.isfinite(theirs).all(axis=1).sum())
    ok = on_device and share >= 0.99 and mismatch <= NAN_MISMATCH * valid
    result = (
        f"publish to answer {statistics.median(trips):.2f} s (median of {len(trips)}; first {trips[0]:.2f} s), "
        f"{answered:,} of {valid:,} points answered, {share:.2%} within 1° of the estimator in this process, "
        f"{'log says ' + args.device if on_device else 'log does not name ' + args.device}"
    )
    record(args.results, what, args.device, statistics.median(trips), result, ok)
    return 0


# -- rows from the shell, and the table -----------------------------------------------------------------------------


def cmd_record(args: argparse.Namespace) -> int:
    record(args.results, args.what, args.device, args.seconds, args.result, args.ok == "yes")
    return 0


def cmd_bench_row(args: argparse.Namespace) -> int:
    """The bench run's row: its exit status, and the learned and hybrid whole-frame seconds from its table."""
    from triplet_normal_ros.evaluation.report import read_section

    block = read_section(args.markdown, "bench") if args.rc == 0 else None
    if block is None:
        record(
            args.results, "triplet-normal bench", args.device, args.seconds, f"exit {args.rc} (log: {args.log})", False
        )
        return 0
    found = {}
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 13 and cells[0].startswith("depth frame") and cells[1] in ("pca, k = 30", "learned", "hybrid"):
            found[cells[1]] = (cells[2], cells[11])
    rows = ", ".join(f"{label} {s} s ({search})" for label, (search, s) in found.items())
    ok = len(found) == 3
    record(
        args.results,
        "triplet-normal bench",
        args.device,
        args.seconds,
        f"depth frame, s per cloud: {rows or 'no rows'}; tables in {args.markdown}",
        ok,
    )
    return 0


def cmd_table(args: argparse.Namespace) -> int:
    rows = [json.loads(line) for line in args.results.read_text().splitlines() if line.strip()]
    text = table_markdown(rows)
    print(text)
    if args.out:
        block = f"Command: `{tool_command('docs/tools/gpu_check.py')}`\n\n{text}"
        print(f"wrote {update_section(args.out, 'gpu-check', block)}")
    return 1 if any(not r["ok"] for r in rows) or not rows else 0


def table_markdown(rows: list[dict]) -> str:
    """The one table of a run's rows, then how many passed: what the `gpu-check` block of a results file holds."""
    lines = ["| what | device | seconds | result | ok |", "| --- | --- | ---: | --- | --- |"]
    for r in rows:
        seconds = "-" if r["seconds"] is None else f"{r['seconds']:.3g}"
        result = str(r["result"]).replace("|", "/").replace("\n", " ")
        lines.append(f"| {r['what']} | {r['device']} | {seconds} | {result} | {'ok' if r['ok'] else '**FAILED**'} |")
    failed = sum(not r["ok"] for r in rows)
    lines.append(f"\ngpu_check: {len(rows) - failed} of {len(rows)} ok" + (f", {failed} FAILED" if failed else ""))
    return "\n".join(lines)


def _size(text: str) -> tuple[int, int]:
    width, _, height = text.partition("x")
    return int(width), int(height)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {}
    for name, function in (
        ("probe", cmd_probe),
        ("compare", cmd_compare),
        ("node", cmd_node),
        ("record", cmd_record),
        ("bench-row", cmd_bench_row),
        ("table", cmd_table),
    ):
        p = sub.add_parser(name)
        p.add_argument("--device", default="cuda", help="cuda (default), cuda:N, or cpu for a dry run")
        p.add_argument("--results", type=Path, default=Path("out/gpu_check/results.jsonl"))
        commands[name] = (p, function)
    compare = commands["compare"][0]
    compare.add_argument("--queries", type=int, default=20_000, help="query points compared (default 20000)")
    compare.add_argument("--size", type=_size, default=(640, 480), metavar="WxH", help="simulated frame (640x480)")
    compare.add_argument("--repeats", type=int, default=3, help="full-frame runs timed (median)")
    node = commands["node"][0]
    node.add_argument("--prefix", type=Path, default=Path("out/ws/install/triplet_normal_ros"))
    node.add_argument("--out", type=Path, default=Path("out/gpu_check"))
    node.add_argument("--method", default="hybrid", help="the node's method (default hybrid, its default)")
    node.add_argument("--repeats", type=int, default=3, help="frames sent (default 3)")
    rec = commands["record"][0]
    rec.add_argument("--what", required=True)
    rec.add_argument("--seconds", type=float)
    rec.add_argument("--result", required=True)
    rec.add_argument("--ok", choices=("yes", "no"), required=True)
    commands["table"][0].add_argument("--out", type=Path, help="results file to write the `gpu-check` block into")
    bench = commands["bench-row"][0]
    bench.add_argument("--markdown", type=Path, required=True)
    bench.add_argument("--rc", type=int, required=True)
    bench.add_argument("--seconds", type=float)
    bench.add_argument("--log", type=Path)
    args = parser.parse_args()
    if args.command != "table":
        args.results.parent.mkdir(parents=True, exist_ok=True)
    return commands[args.command][1](args)


if __name__ == "__main__":
    sys.exit(main())
