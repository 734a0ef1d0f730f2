"""`triplet-normal ablate`: the paper's two ablations, and ours, measured on the validation set in one run.

1. cos exponent n in the paper's normal loss (2, 4, 8, 12): phase (b) only, on one frozen triplet encoder, with the
   paper's direct regressor.
2. Our deviations (docs/MODEL.md), on the same encoder and budget: the residual head (a correction to the PCA
   normal) with the cos^8 loss, with the squared angle, and with the squared angle relative to PCA's (the CPU recipe).
3. With vs without the triplet-trained encoder: the CPU recipe's regressor on the frozen triplet encoder, against the
   whole network trained directly (the paper's "regress the normal directly").

On a CPU every variant trains at a reduced, stated budget; the table says what it was.
"""

import dataclasses
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from ..core.estimator import NormalEstimator
from ..training.recipes import RECIPES, Recipe
from ..training.trainer import train
from .metrics import msae
from .report import update_section

EXPONENTS = (2, 4, 8, 12)


@dataclasses.dataclass(frozen=True)
class Budget:
    """What every ablation variant gets: phase (b) size and length, the frozen encoder, the validation queries."""

    encoder_from: Path
    patches_per_shape: int = 200
    epochs: int = 10
    per_cloud: int = 1000


def _variants(budget_: Budget, base: Recipe) -> list[tuple[str, Recipe, Path | None]]:
    budget = {
        "regressor_patches_per_shape": budget_.patches_per_shape,
        "regressor_epochs": budget_.epochs,
        "finetune_epochs": 0,
    }
    paper = dataclasses.replace(base, loss="cos", residual=False, **budget)
    rows = [(f"paper head, cos^{n}", dataclasses.replace(paper, exponent=n), budget_.encoder_from) for n in EXPONENTS]
    rows.append(("residual head, cos^8", dataclasses.replace(paper, residual=True), budget_.encoder_from))
    ours = dataclasses.replace(base, **budget)
    rows.append(("residual head, squared angle", dataclasses.replace(ours, loss="angle"), budget_.encoder_from))
    rows.append((f"residual head, {ours.loss} loss (CPU recipe)", ours, budget_.encoder_from))
    direct = dataclasses.replace(ours, triplet=False)
    rows.append(("no triplet encoder (direct), CPU recipe head and loss", direct, None))
    return rows


def _validation_msae(est: NormalEstimator, per_cloud: int) -> dict[str, float]:
    """Mean MSAE of `est` over the CAD and the smooth validation clouds (all noise levels), with eval's query points
    and radius (5 % of each cloud's diagonal)."""
    from .evaluate import query_indices, validation_clouds

    scores: dict[str, list[float]] = {"cad": [], "smooth": []}
    for cloud in validation_clouds(quick=False):
        query = query_indices(len(cloud.points), per_cloud)
        est.radius = RADIUS_FRACTION * bbox_diagonal(cloud.points)
        normals, _ = est.estimate(cloud.points, query)
        scores[cloud.kind].append(msae(normals, cloud.normals[query]))
    return {kind: float(np.mean(v)) for kind, v in scores.items()}


def reference_estimator(base: Recipe, device: str) -> NormalEstimator:
    """PCA over the same ball as the learned rows: every point up to the pool the network draws its k from."""
    return NormalEstimator("pca", k=POOL_FACTOR * base.k, device=device)


def run(budget: Budget, run_dir: Path, device: str, out: Path | None, command: str) -> None:
    """Train and score every variant, print the table and, with `out`, write it as block `ablation`."""
    base = dataclasses.replace(RECIPES["cpu"])
    started = time.time()
    reference = _validation_msae(reference_estimator(base, device), budget.per_cloud)
    results = [("PCA at the same radius (reference)", reference, time.time() - started)]
    for name, recipe, encoder_from in tqdm(_variants(budget, base), desc="ablation", unit="variant"):
        variant_dir = run_dir / "".join(c if c.isalnum() else "_" for c in name.split(" (")[0])
        model = variant_dir / "model.safetensors"
        t0 = time.time()
        train(recipe, model, variant_dir, device, encoder_from=encoder_from)
        score = _validation_msae(NormalEstimator("learned", checkpoint=model, device=device), budget.per_cloud)
        results.append((name, score, time.time() - t0))
    markdown = _markdown(results, budget, command, time.time() - started)
    print(markdown)
    if out is not None:
        update_section(out, "ablation", markdown)


def _markdown(results, budget: Budget, command: str, seconds: float) -> str:
    lines = [
        "### Ablations (validation set, MSAE rad², 5% radius)",
        "",
        f"Command: `{command}` ({seconds / 60:.0f} min on this machine). "
        f"Every variant trains phase (b) on {budget.patches_per_shape} patches per training cloud for {budget.epochs} "
        f"epochs; every row but the last reuses the frozen encoder of `{budget.encoder_from}`; the direct row trains "
        f"the whole network from scratch with that same budget. *Paper head*: the regressor outputs the normal; "
        f"*residual head*: it outputs a correction to the PCA normal. {budget.per_cloud} query points per validation "
        "cloud.",
        "",
        "| variant | CAD MSAE | smooth MSAE | mean | train+eval s |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, score, secs in results:
        mean = (score["cad"] + score["smooth"]) / 2
        lines.append(f"| {name} | {score['cad']:.4f} | {score['smooth']:.4f} | {mean:.4f} | {secs:.0f} |")
    return "\n".join(lines) + "\n"
