"""`triplet-normal train`: phase (a) the encoder with the triplet loss, phase (b) the regressor on its frozen latent.

SGD (momentum 0.9, lr 0.01), lr × 0.1 after `patience` epochs without validation improvement, seeds fixed, tqdm
progress, and a resumable state file after every epoch. Two recipes: the paper's (GPU scale) and a CPU one that
produced the shipped checkpoint; docs/TRAINING.md records both.
"""

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..core.checkpoint import save_checkpoint
from ..core.device import resolve_device
from ..core.model import TripletNormalNet
from ..errors import TrainingError
from .batches import CloudSampler, NormalSet, TripletSet, collect_normal_patches, collect_triplets
from .losses import patch_loss, triplet_loss
from .recipes import RESUME_FIXED, Recipe


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
    from .dataset import build_dataset  # training-only dependencies (trimesh, manifold3d)

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
    from ..core.checkpoint import load_checkpoint

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
