"""`triplet-normal train`: phase (a) the encoder with the triplet loss, phase (b) the regressor on its frozen latent.

SGD (momentum 0.9, lr 0.01), lr × 0.1 after `patience` epochs without validation improvement, seeds fixed, tqdm
progress, and a resumable state file after every epoch. Two recipes: the paper's (GPU scale) and a CPU one that
produced the shipped checkpoint; docs/TRAINING.md records both.
"""

import argparse
import dataclasses
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from .checkpoint import default_checkpoint_path, save_checkpoint
from .losses import LOSSES, RELATIVE_FLOOR_DEG, patch_loss, triplet_loss
from .model import DEFAULT_ENCODER, DEFAULT_REGRESSOR, TripletNormalNet
from .torch_device import resolve_device
from .train_data import CloudSampler, NormalSet, TripletSet, collect_normal_patches, collect_triplets


class TrainingError(ValueError):
    """Training settings that cannot work together; the message says which."""


@dataclass
class Recipe:
    """Everything that decides a training run; stored verbatim in the checkpoint's metadata."""

    k: int = 128
    patches_per_shape: int = 200
    encoder_epochs: int = 2
    regressor_epochs: int = 40
    regressor_patches_per_shape: int = 800
    finetune_epochs: int = 0
    finetune_patches_per_shape: int | None = None  # fresh patches per cloud per phase-(c) epoch; None: as phase (b)
    finetune_lr: float = 0.001
    finetune_freeze_bn: bool = True
    batch_size: int = 64
    lr: float = 0.01
    momentum: float = 0.9
    patience: int = 3
    n_points: int = 100_000
    radius_rel: float = 0.05
    loss: str = "cos"
    exponent: int = 8
    relative_floor_deg: float = RELATIVE_FLOOR_DEG
    residual: bool = False
    support_deg: float = 15.0
    triplet: bool = True
    val_patches_per_cloud: int = 100
    encoder: list[int] = field(default_factory=lambda: list(DEFAULT_ENCODER))
    regressor: list[int] = field(default_factory=lambda: list(DEFAULT_REGRESSOR))
    seed: int = 0
    shapes: list[str] | None = None
    val_shapes: list[str] | None = None


#: Recipe fields that decide what a run optimises: a resumed run must keep them (epoch counts may grow).
RESUME_FIXED = (
    "k",
    "loss",
    "exponent",
    "relative_floor_deg",
    "support_deg",
    "residual",
    "triplet",
    "encoder",
    "regressor",
    "seed",
)

RECIPES = {
    # The paper: 8000 patches per shape, 5 + 50 epochs, k = 500. Sized for a GPU.
    "paper": Recipe(
        finetune_epochs=0,
        k=500,
        patches_per_shape=8000,
        encoder_epochs=5,
        regressor_epochs=50,
        regressor_patches_per_shape=8000,
        val_patches_per_cloud=500,
    ),
    # The CPU recipe behind the shipped checkpoint: ≤ 90 min on 2 cores (docs/TRAINING.md). Two deviations from the
    # paper, both measured there: the regressor corrects the PCA normal, and it is trained on the squared angle
    # relative to PCA's own.
    "cpu": Recipe(
        residual=True,
        loss="relative",
        regressor_epochs=20,
        regressor_patches_per_shape=3000,
        val_patches_per_cloud=300,
    ),
}


def train(
    recipe: Recipe,
    out: Path,
    run_dir: Path,
    device: str = "auto",
    resume: bool = False,
    encoder_from: Path | None = None,
) -> dict:
    """Run both phases (or resume them) and write the checkpoint to `out`; returns the training summary."""
    start = time.time()
    dev = resolve_device(device)
    torch.manual_seed(recipe.seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    state = _load_state(run_dir) if resume else None
    if state:
        _check_resumable(state, recipe, run_dir)
    model = TripletNormalNet(tuple(recipe.encoder), tuple(recipe.regressor), recipe.residual).to(dev)
    if state:
        model.load_state_dict(state["model"])
    elif encoder_from:
        _load_encoder(model, encoder_from)
    history = state["history"] if state else []
    train_set, val_set = _samplers(recipe, "train"), _samplers(recipe, "val")
    if recipe.triplet and not encoder_from:
        _phase_encoder(model, recipe, train_set, val_set, dev, run_dir, state, history)
    _phase_regressor(model, recipe, train_set, val_set, dev, run_dir, state, history)
    _phase_finetune(model, recipe, train_set, val_set, dev, run_dir, state, history)
    summary = {
        "wall_seconds": round(time.time() - start, 1),
        "device": str(dev),
        "history": history,
        "final_val_normal_loss": min((h["val"] for h in history if h["phase"] != "encoder"), default=None),
    }
    meta = {
        "k": recipe.k,
        "radius": {
            "convention": "absolute, in the cloud's units, at inference",
            "train_radius_rel_bbox_diagonal": recipe.radius_rel,
        },
        "training": {
            "recipe": dataclasses.asdict(recipe),
            "data_seed": recipe.seed,
            "command": " ".join(sys.argv),
            **{k: v for k, v in summary.items() if k != "history"},
        },
    }
    save_checkpoint(out, model.cpu(), meta)
    (run_dir / "history.json").write_text(json.dumps(summary, indent=2))
    _plot_curves(history, run_dir / "training_curves.png")
    return summary


def _samplers(recipe: Recipe, split: str) -> list[CloudSampler]:
    from .training_data import build_dataset  # training-only dependencies (trimesh, manifold3d)

    shapes = recipe.shapes if split == "train" else recipe.val_shapes
    clouds = build_dataset(split=split, n_points=recipe.n_points, seed=recipe.seed, shapes=shapes)
    return [CloudSampler(c.points, c.normals, recipe.radius_rel, recipe.k) for c in clouds]


def _phase_encoder(model, recipe, train_set, val_set, dev, run_dir, state, history) -> None:
    if state and state["phase"] != "encoder":
        return
    params = list(model.encoder.parameters())
    opt, sched = _optimiser(params, recipe, state)
    first = state["epoch"] + 1 if state else 0
    val = collect_triplets(val_set, recipe.val_patches_per_cloud, recipe.seed + 10_000, "val triplets")
    for epoch in range(first, recipe.encoder_epochs):
        data = collect_triplets(train_set, recipe.patches_per_shape, recipe.seed + epoch, f"triplets e{epoch}")
        train_loss = _triplet_epoch(
            model.encoder, data, opt, recipe, dev, f"encoder {epoch + 1}/{recipe.encoder_epochs}"
        )
        val_loss = _triplet_eval(model.encoder, val, dev)
        sched.step(val_loss)
        history.append(
            {
                "phase": "encoder",
                "epoch": epoch,
                "train": train_loss,
                "val": val_loss,
                "lr": opt.param_groups[0]["lr"],
                "n": len(data.anchor),
            }
        )
        _save_state(run_dir, "encoder", epoch, model, opt, sched, history, recipe)
    _save_state(run_dir, "regressor", -1, model, None, None, history, recipe)


def _phase_regressor(model, recipe, train_set, val_set, dev, run_dir, state, history) -> None:
    """With the triplet encoder frozen, the latents are computed once and the regressor trains on them; without it
    (the ablation), encoder and regressor train together on the normal loss."""
    if state and state["phase"] == "finetune":
        return
    resumed = state if state and state["phase"] == "regressor" and state["epoch"] >= 0 else None
    if resumed and resumed["epoch"] + 1 >= recipe.regressor_epochs:
        return  # finished before; resuming goes on to the next phase
    params = list(model.regressor.parameters()) + ([] if recipe.triplet else list(model.encoder.parameters()))
    opt, sched = _optimiser(params, recipe, resumed)
    train = collect_normal_patches(train_set, recipe.regressor_patches_per_shape, recipe.seed + 20_000, "patches")
    val = collect_normal_patches(val_set, recipe.val_patches_per_cloud, recipe.seed + 30_000, "val patches")
    if recipe.triplet:
        train, val = _encoded(model.encoder, train, dev), _encoded(model.encoder, val, dev)
    head = model.regressor if recipe.triplet else model
    _fit_normals(
        model,
        head,
        "regressor",
        recipe.regressor_epochs,
        resumed,
        train,
        val,
        opt,
        sched,
        recipe,
        dev,
        run_dir,
        history,
    )


def _phase_finetune(model, recipe, train_set, val_set, dev, run_dir, state, history) -> None:
    """Phase (c), our addition (docs/MODEL.md): encoder and regressor together on the normal loss, starting from the
    triplet encoder and the trained regressor. On the CPU budget the frozen triplet latent alone only matched PCA."""
    if recipe.finetune_epochs <= 0 or not recipe.triplet:
        return
    resumed = state if state and state["phase"] == "finetune" else None
    opt, sched = _optimiser(list(model.parameters()), dataclasses.replace(recipe, lr=recipe.finetune_lr), resumed)

    def train(epoch: int) -> NormalSet:  # fresh patches every epoch, so the whole network cannot memorise them
        per_cloud = recipe.finetune_patches_per_shape
        per_cloud = recipe.regressor_patches_per_shape if per_cloud is None else per_cloud
        return collect_normal_patches(train_set, per_cloud, recipe.seed + 40_000 + epoch, f"patches c{epoch}")

    val = collect_normal_patches(val_set, recipe.val_patches_per_cloud, recipe.seed + 30_000, "val patches")
    end_to_end = dataclasses.replace(recipe, triplet=False)  # batch size of the end-to-end path
    _fit_normals(
        model,
        model,
        "finetune",
        recipe.finetune_epochs,
        resumed,
        train,
        val,
        opt,
        sched,
        end_to_end,
        dev,
        run_dir,
        history,
        freeze_bn=recipe.finetune_freeze_bn,
    )


def _fit_normals(
    model, head, phase, epochs, resumed, train, val, opt, sched, recipe, dev, run_dir, history, freeze_bn=False
) -> None:
    """Epochs of the normal loss on `head`, on one patch set or on `train(epoch)`'s; the model ends with the weights
    of its best validation epoch."""
    best = (_normal_eval(head, val, recipe, dev), None)
    for epoch in range((resumed["epoch"] + 1) if resumed else 0, epochs):
        data = train(epoch) if callable(train) else train
        train_loss = _normal_epoch(head, data, opt, recipe, dev, f"{phase} {epoch + 1}/{epochs}", freeze_bn)
        val_loss = _normal_eval(head, val, recipe, dev)
        sched.step(val_loss)
        if val_loss < best[0]:
            best = (val_loss, {k: v.detach().clone() for k, v in model.state_dict().items()})
        history.append(
            {
                "phase": phase,
                "epoch": epoch,
                "train": train_loss,
                "val": val_loss,
                "lr": opt.param_groups[0]["lr"],
                "n": len(data.patches),
            }
        )
        _save_state(run_dir, phase, epoch, model, opt, sched, history, recipe)
    if best[1] is not None:  # ship the best validation epoch, not the last
        model.load_state_dict(best[1])


def _encoded(encoder, data: NormalSet, dev) -> NormalSet:
    """Replace patches by their frozen latents: phase (b) then costs one encoder pass in total."""
    encoder.eval()
    with torch.inference_mode():
        latents = [encoder(data.patches[i : i + 512].to(dev)).cpu() for i in range(0, len(data.patches), 512)]
    return NormalSet(torch.cat(latents), data.centre_normal, data.patch_normals)


def _triplet_epoch(encoder, data: TripletSet, opt, recipe, dev, desc) -> float:
    encoder.train()
    order = torch.randperm(len(data.anchor))
    losses = []
    bar = tqdm(range(0, len(order), recipe.batch_size), desc=desc, unit="batch", leave=False)
    for lo in bar:
        idx = order[lo : lo + recipe.batch_size]
        if len(idx) < 2:
            continue
        batch = torch.cat([data.anchor[idx], data.positive[idx], data.negative[idx]]).to(dev)
        f = torch.nn.functional.normalize(encoder(batch), dim=-1).split(len(idx))
        loss = triplet_loss(*f)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
    return float(np.mean(losses))


def _triplet_eval(encoder, data: TripletSet, dev) -> float:
    encoder.eval()
    with torch.inference_mode():
        parts = []
        for lo in range(0, len(data.anchor), 256):
            f = [
                torch.nn.functional.normalize(encoder(t[lo : lo + 256].to(dev)), dim=-1)
                for t in (data.anchor, data.positive, data.negative)
            ]
            parts.append(triplet_loss(*f).item() * len(f[0]))
    return float(sum(parts) / max(1, len(data.anchor)))


def _normal_epoch(head, data: NormalSet, opt, recipe, dev, desc, freeze_bn: bool = False) -> float:
    head.train()
    if freeze_bn:  # keep the running statistics the later layers were trained on
        for module in head.modules():
            if isinstance(module, torch.nn.BatchNorm1d):
                module.eval()
    order = torch.randperm(len(data.patches))
    losses = []
    batch_size = recipe.batch_size if not recipe.triplet else max(recipe.batch_size, 256)
    bar = tqdm(range(0, len(order), batch_size), desc=desc, unit="batch", leave=False)
    for lo in bar:
        idx = order[lo : lo + batch_size]
        if len(idx) < 2:
            continue
        loss = _recipe_loss(head, data, idx, recipe, dev)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
    return float(np.mean(losses))


def _recipe_loss(head, data: NormalSet, rows, recipe: Recipe, dev) -> torch.Tensor:
    """The recipe's normal loss of `head` on `rows` of `data` (training and validation alike)."""
    pred = head(data.patches[rows].to(dev))
    centre, patch = data.centre_normal[rows].to(dev), data.patch_normals[rows].to(dev)
    return patch_loss(recipe.loss, pred, centre, patch, recipe.exponent, recipe.support_deg, recipe.relative_floor_deg)


def _normal_eval(head, data: NormalSet, recipe, dev) -> float:
    head.eval()
    total = 0.0
    with torch.inference_mode():
        for lo in range(0, len(data.patches), 512):
            rows = slice(lo, lo + 512)
            total += _recipe_loss(head, data, rows, recipe, dev).item() * len(data.patches[rows])
    return total / max(1, len(data.patches))


def _optimiser(params, recipe: Recipe, state: dict | None):
    opt = torch.optim.SGD(params, lr=recipe.lr, momentum=recipe.momentum)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode="min", factor=0.1, patience=recipe.patience)
    if state and state.get("optimizer"):
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
    return opt, sched


def _save_state(run_dir: Path, phase: str, epoch: int, model, opt, sched, history, recipe: Recipe) -> None:
    state = {
        "recipe": dataclasses.asdict(recipe),
        "phase": phase,
        "epoch": epoch,
        "model": model.state_dict(),
        "history": history,
        "optimizer": opt.state_dict() if opt else None,
        "scheduler": sched.state_dict() if sched else None,
    }
    tmp = run_dir / "state.pt.tmp"
    torch.save(state, tmp)
    tmp.replace(run_dir / "state.pt")


def _load_state(run_dir: Path) -> dict | None:
    path = run_dir / "state.pt"
    return torch.load(path, weights_only=True) if path.is_file() else None  # weights_only: never unpickle code


def _check_resumable(state: dict, recipe: Recipe, run_dir: Path) -> None:
    """Refuse to resume under a recipe that optimises something else: best-epoch and plateau decisions would compare
    losses on different scales."""
    saved = state.get("recipe")
    if saved is None:
        raise TrainingError(f"{run_dir}/state.pt does not record its recipe (older version); start a new --run-dir")
    changed = [
        f"{f}: {saved.get(f)!r} -> {getattr(recipe, f)!r}" for f in RESUME_FIXED if saved.get(f) != getattr(recipe, f)
    ]
    if changed:
        raise TrainingError(f"cannot resume {run_dir} with a different recipe ({'; '.join(changed)})")


def _load_encoder(model: TripletNormalNet, path: Path) -> None:
    from .checkpoint import load_checkpoint

    donor, _ = load_checkpoint(path)
    model.encoder.load_state_dict(donor.encoder.state_dict())


def _plot_curves(history: list[dict], path: Path) -> None:
    """One panel per phase that ran (phase (c) is off in both recipes), train and validation loss per epoch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    titles = {
        "encoder": "(a) triplet loss",
        "regressor": "(b) normal loss, frozen encoder",
        "finetune": "(c) normal loss, end to end",
    }
    phases = [p for p in titles if any(h["phase"] == p for h in history)] or ["regressor"]
    fig, axes = plt.subplots(1, len(phases), figsize=(4.7 * len(phases), 3.6), squeeze=False)
    for ax, phase in zip(axes[0], phases, strict=True):
        rows = [h for h in history if h["phase"] == phase]
        if rows:
            epochs = [h["epoch"] + 1 for h in rows]
            ax.plot(epochs, [h["train"] for h in rows], "o-", label="train")
            ax.plot(epochs, [h["val"] for h in rows], "s-", label="validation")
            ax.legend()
            ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(titles[phase])
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--recipe", choices=sorted(RECIPES), default="cpu", help="preset (default: cpu)")
    parser.add_argument(
        "--out", type=Path, default=None, help="checkpoint to write (default: run-dir/model.safetensors)"
    )
    parser.add_argument("--run-dir", type=Path, default=Path("out/train"), help="state, history and curves")
    parser.add_argument("--resume", action="store_true", help="continue from run-dir/state.pt")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--encoder-from", type=Path, help="skip phase (a): reuse this checkpoint's encoder")
    parser.add_argument("--no-triplet", action="store_true", help="ablation: train encoder+regressor directly")
    parser.add_argument("--shapes", nargs="+", help="train on these shapes only (smoke runs)")
    parser.add_argument("--val-shapes", nargs="+", help="validate on these shapes only")
    for name in (
        "k",
        "patches_per_shape",
        "encoder_epochs",
        "regressor_epochs",
        "regressor_patches_per_shape",
        "finetune_epochs",
        "finetune_patches_per_shape",
        "batch_size",
        "n_points",
        "exponent",
        "val_patches_per_cloud",
        "seed",
    ):
        parser.add_argument("--" + name.replace("_", "-"), type=int)
    parser.add_argument(
        "--loss", choices=LOSSES, help="normal loss: the paper's cos^n, the squared angle, or it relative to PCA's"
    )
    parser.add_argument(
        "--relative-floor-deg", type=_positive_float, help="floor (> 0) on PCA's angle in the relative loss"
    )
    parser.add_argument(
        "--residual", action=argparse.BooleanOptionalAction, help="regress a correction to the PCA normal"
    )
    parser.add_argument(
        "--finetune-freeze-bn", action=argparse.BooleanOptionalAction, help="phase (c) keeps BatchNorm statistics"
    )
    parser.add_argument("--lr", type=float)
    parser.add_argument("--finetune-lr", type=float)
    parser.add_argument("--encoder-widths", type=int, nargs="+", dest="encoder")
    parser.add_argument("--regressor-widths", type=int, nargs="+", dest="regressor")


def _positive_float(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def recipe_from_args(args: argparse.Namespace) -> Recipe:
    overrides = {
        f.name: getattr(args, f.name) for f in dataclasses.fields(Recipe) if getattr(args, f.name, None) is not None
    }
    if args.no_triplet:
        overrides["triplet"] = False
    recipe = dataclasses.replace(RECIPES[args.recipe], **overrides)
    if args.relative_floor_deg is not None and recipe.loss != "relative":
        raise TrainingError(f"--relative-floor-deg only applies to --loss relative (this run uses {recipe.loss!r})")
    _check_counts(recipe)
    return recipe


#: Recipe sizes that must be at least 1, and epoch counts that must be at least 0 (a phase may be skipped).
COUNTS = (
    "k",
    "patches_per_shape",
    "regressor_patches_per_shape",
    "finetune_patches_per_shape",
    "batch_size",
    "n_points",
    "val_patches_per_cloud",
)
EPOCHS = ("encoder_epochs", "regressor_epochs", "finetune_epochs")


def _check_counts(recipe: Recipe) -> None:
    """One clear line for a size or epoch count that cannot work, instead of a failure deep inside numpy."""
    for names, least in ((COUNTS, 1), (EPOCHS, 0)):
        for name in names:
            value = getattr(recipe, name)
            if value is not None and value < least:
                raise TrainingError(f"--{name.replace('_', '-')} must be >= {least}, got {value}")


def run(args: argparse.Namespace) -> int:
    recipe = recipe_from_args(args)
    out = args.out or args.run_dir / "model.safetensors"
    summary = train(recipe, out, args.run_dir, args.device, args.resume, args.encoder_from)
    print(
        f"wrote {out} in {summary['wall_seconds']:.0f} s on {summary['device']}; "
        f"final validation normal loss {summary['final_val_normal_loss']:.4f}"
    )
    if out.resolve() == default_checkpoint_path():
        print("this replaced the shipped default checkpoint")
    return 0
