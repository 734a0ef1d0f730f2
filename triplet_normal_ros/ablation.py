"""`triplet-normal ablate`: the paper's two ablations, and ours, measured on the validation set in one run.

1. cos exponent n in the paper's normal loss (2, 4, 8, 12): phase (b) only, on one frozen triplet encoder, with the
   paper's direct regressor.
2. Our deviations (docs/MODEL.md), on the same encoder and budget: the residual head (a correction to the PCA
   normal) with the cos^8 loss, with the squared angle, and with the squared angle relative to PCA's (the CPU recipe).
3. With vs without the triplet-trained encoder: the CPU recipe's regressor on the frozen triplet encoder, against the
   whole network trained directly (the paper's "regress the normal directly").

On a CPU every variant trains at a reduced, stated budget; the table says what it was.
"""

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .checkpoint import default_checkpoint_path
from .estimator import POOL_FACTOR, NormalEstimator
from .metrics import msae
from .results_doc import update_section
from .train import RECIPES, Recipe, train

EXPONENTS = (2, 4, 8, 12)


def _variants(args: argparse.Namespace, base: Recipe) -> list[tuple[str, Recipe, Path | None]]:
    budget = {
        "regressor_patches_per_shape": args.patches_per_shape,
        "regressor_epochs": args.epochs,
        "finetune_epochs": 0,
    }
    paper = dataclasses.replace(base, loss="cos", residual=False, **budget)
    rows = [(f"paper head, cos^{n}", dataclasses.replace(paper, exponent=n), args.encoder_from) for n in EXPONENTS]
    rows.append(("residual head, cos^8", dataclasses.replace(paper, residual=True), args.encoder_from))
    ours = dataclasses.replace(base, **budget)
    rows.append(("residual head, squared angle", dataclasses.replace(ours, loss="angle"), args.encoder_from))
    rows.append((f"residual head, {ours.loss} loss (CPU recipe)", ours, args.encoder_from))
    direct = dataclasses.replace(ours, triplet=False)
    rows.append(("no triplet encoder (direct), CPU recipe head and loss", direct, None))
    return rows


def _validation_msae(est: NormalEstimator, per_cloud: int) -> dict[str, float]:
    """Mean MSAE of `est` over the CAD and the smooth validation clouds (all noise levels), with eval's query points
    and radius (5 % of each cloud's diagonal)."""
    from .cloud_files import bbox_diagonal
    from .evaluate import RADIUS_REL, query_indices, validation_clouds

    scores: dict[str, list[float]] = {"cad": [], "smooth": []}
    for cloud in validation_clouds(quick=False):
        query = query_indices(len(cloud.points), per_cloud)
        est.radius = RADIUS_REL * bbox_diagonal(cloud.points)
        normals, _ = est.estimate(cloud.points, query)
        scores[cloud.kind].append(msae(normals, cloud.normals[query]))
    return {kind: float(np.mean(v)) for kind, v in scores.items()}


def reference_estimator(base: Recipe, device: str) -> NormalEstimator:
    """PCA over the same ball as the learned rows: every point up to the pool the network draws its k from."""
    return NormalEstimator("pca", k=POOL_FACTOR * base.k, device=device)


def run(args: argparse.Namespace) -> int:
    base = dataclasses.replace(RECIPES["cpu"])
    started = time.time()
    reference = _validation_msae(reference_estimator(base, args.device), args.per_cloud)
    results = [("PCA at the same radius (reference)", reference, time.time() - started)]
    for name, recipe, encoder_from in tqdm(_variants(args, base), desc="ablation", unit="variant"):
        run_dir = args.run_dir / "".join(c if c.isalnum() else "_" for c in name.split(" (")[0])
        out = run_dir / "model.safetensors"
        t0 = time.time()
        train(recipe, out, run_dir, args.device, encoder_from=encoder_from)
        score = _validation_msae(NormalEstimator("learned", checkpoint=out, device=args.device), args.per_cloud)
        results.append((name, score, time.time() - t0))
    markdown = _markdown(results, args, time.time() - started)
    print(markdown)
    update_section(args.out, "ablation", markdown)
    return 0


def _markdown(results, args, seconds: float) -> str:
    argv = sys.argv[2:] if sys.argv[1:2] == ["ablate"] else sys.argv[1:]
    lines = [
        "### Ablations (validation set, MSAE rad², 5% radius)",
        "",
        f"Command: `triplet-normal ablate {' '.join(argv)}` ({seconds / 60:.0f} min on this machine). "
        f"Every variant trains phase (b) on {args.patches_per_shape} patches per training cloud for {args.epochs} "
        f"epochs; every row but the last reuses the frozen encoder of `{args.encoder_from}`; the direct row trains "
        f"the whole network from scratch with that same budget. *Paper head*: the regressor outputs the normal; "
        f"*residual head*: it outputs a correction to the PCA normal. {args.per_cloud} query points per validation "
        "cloud.",
        "",
        "| variant | CAD MSAE | smooth MSAE | mean | train+eval s |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, score, secs in results:
        mean = (score["cad"] + score["smooth"]) / 2
        lines.append(f"| {name} | {score['cad']:.4f} | {score['smooth']:.4f} | {mean:.4f} | {secs:.0f} |")
    return "\n".join(lines) + "\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--encoder-from",
        type=Path,
        default=default_checkpoint_path(),
        help="frozen triplet encoder for the exponent rows (default: the shipped checkpoint)",
    )
    parser.add_argument("--patches-per-shape", type=int, default=200)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--per-cloud", type=int, default=1000, help="validation query points per cloud")
    parser.add_argument("--run-dir", type=Path, default=Path("out/ablation"))
    parser.add_argument("--device", default="auto")
    parser.add_argument("--out", type=Path, default=Path("docs/RESULTS.md"))


if __name__ == "__main__":
    _parser = argparse.ArgumentParser(prog="triplet-normal ablate")
    add_arguments(_parser)
    sys.exit(run(_parser.parse_args()))
