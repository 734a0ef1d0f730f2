"""Checkpoints side by side on what edges need: eval's fold frames (MSAE overall and near edges) and the planar
segmentation of `eval --sets segment` (adjusted Rand index, recovered segments), for `learned` and `hybrid`.

    .venv/bin/python docs/tools/edge_study.py range out/range_angle/model.safetensors
    .venv/bin/python docs/tools/edge_study.py --also depth,lidar range out/range_angle/model.safetensors

`--also` adds eval's depth-frame and LiDAR sets (MSAE overall and near edges, at their radii and ball growth).
`--seed 100` takes frames from seed 100 on instead of eval's (0 on): choose among candidates there.

Each checkpoint is a shipped name or a path. By default the frames are eval's (fold seeds 0-5 for MSAE, 0-2 for
segments), so the figures sit beside the `eval-fold` and `eval-segment` blocks of docs/RESULTS.md.
"""

import argparse

import numpy as np

from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.evaluation import range_eval, segment_eval


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--also", default="", help="more of eval's range sets, comma-separated: depth, lidar")
    parser.add_argument("--seed", type=int, default=0, help="first frame seed (eval's: 0; studies': 100)")
    args = parser.parse_args()
    rows = _rows(args.checkpoints, args.device, "fold")
    scores, _ = range_eval.evaluate_set("fold", rows, quick=False, seed=args.seed)
    segments, _ = segment_eval.evaluate_segments("fold", rows, quick=False, seed=args.seed)
    print("| normals | fold MSAE | near edges | segment ARI | worst frame | recovered |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for fold, seg in zip(scores, segments[1:], strict=True):
        print(
            f"| {fold.name} | {fold.msae():.5f} | {fold.msae(True):.5f} | {np.mean(seg.ari):.3f} | {min(seg.ari):.3f} "
            f"| {seg.recovered_share():.0%} ({seg.recovered} of {seg.segments}) |"
        )
    for kind in filter(None, args.also.split(",")):
        print(f"\n| normals | {kind} MSAE | near edges |\n| --- | ---: | ---: |")
        rows = _rows(args.checkpoints, args.device, kind)
        for score in range_eval.evaluate_set(kind, rows, quick=False, seed=args.seed)[0]:
            print(f"| {score.name} | {score.msae():.5f} | {score.msae(True):.5f} |")


def _rows(checkpoints: list[str], device: str, kind: str) -> dict[str, NormalEstimator]:
    """`learned` and `hybrid` with each checkpoint at the set's radius and ball growth, as eval runs them."""
    spec = range_eval.SETS[kind]
    rows = {}
    for checkpoint in checkpoints:
        for method in ("learned", "hybrid"):
            estimator = NormalEstimator(method, radius=spec.radius, checkpoint=checkpoint, device=device)
            estimator.range_scale = spec.range_scale
            rows[f"{method}, {checkpoint}"] = estimator
    return rows


if __name__ == "__main__":
    main()
