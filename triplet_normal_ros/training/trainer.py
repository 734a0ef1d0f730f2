"""`triplet-normal train`: phase (a) the encoder with the triplet loss, phase (b) the regressor on its frozen latent,
and an optional phase (c) that fine-tunes both.

SGD (momentum 0.9, lr 0.01), lr × 0.1 after `patience` epochs without validation improvement, seeds fixed, tqdm
progress, and a resumable state file after every epoch. Five presets (`recipes.RECIPES`): `paper` (the paper's, GPU
scale), `cpu` (the CPU base the others start from, and `ablate`'s), `scales` (cpu plus the scale head and simulated
depth, LiDAR and fold frames: the shipped default checkpoint), `lite` and `range` (the lite and range checkpoints);
docs/TRAINING.md records each.

Reproducibility: torch's global generator is seeded once, draws the weight initialisation and then one shuffle per
epoch (`_shuffled_batches`); every patch draws from generators seeded by its collection and its cloud
(`batches.cloud_generators`), so the clouds can be built on many threads and the run stays the same on any number of
cores. Changing the order of the global generator's calls changes the weights a recipe trains.
"""

import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import torch
from torch.optim.lr_scheduler import ReduceLROnPlateau
from tqdm import tqdm

from ..core.config.conventions import DEPTH_RADIUS, LIDAR_RADIUS
from ..core.config.device import resolve_device
from ..core.learned.checkpoint import load_checkpoint, save_checkpoint
from ..core.learned.model import TripletNormalNet
from ..errors import TrainingError
from .batches import NormalSet, PatchSampler, TripletSet, collect_normal_patches, collect_triplets
from .curves import plot_curves
from .losses import patch_loss, triplet_loss
from .recipes import RESUME_FIXED, Recipe

#: Rows per forward pass when computing a validation loss; memory only, the result does not depend on it.
_TRIPLET_EVAL_CHUNK, _NORMAL_EVAL_CHUNK = 256, 512


@dataclass
class TrainingRun:
    """What every phase reads and extends, in one place instead of eight arguments threaded through each phase.

    `state` is the state.pt being resumed (None on a fresh run). `history` gains one row per epoch and is saved
    with the weights after every epoch, so a killed run loses at most the epoch in progress. `best` is what the run
    ships: the weights of the least validation normal loss so far (phases (b) and (c), across every interruption),
    with that loss and where they came from (`phase`, `epoch`; epoch -1 is the weights the phase started from).
    """

    model: TripletNormalNet
    recipe: Recipe
    train_set: list[PatchSampler]
    val_set: list[PatchSampler]
    device: torch.device
    run_dir: Path
    state: dict | None = None
    history: list[dict] = field(default_factory=list)
    best: dict | None = None  # {"phase", "epoch", "val", "model"}; None until a normal-loss phase starts

    def resumed(self, phase: str) -> dict | None:
        """The saved state when it stopped inside `phase`; None when this phase starts afresh."""
        return self.state if self.state and self.state["phase"] == phase else None

    def end_epoch(
        self, phase: str, epoch: int, losses: tuple[float, float], n: int, opt: torch.optim.Optimizer, sched
    ) -> None:
        """Record the epoch's (train, validation) losses and save everything needed to resume after it."""
        train_loss, val_loss = losses
        lr = opt.param_groups[0]["lr"]
        self.history.append({"phase": phase, "epoch": epoch, "train": train_loss, "val": val_loss, "lr": lr, "n": n})
        self.save(phase, epoch, opt, sched)

    def save(self, phase: str, epoch: int, opt: torch.optim.Optimizer | None = None, sched=None) -> None:
        """Write state.pt atomically (temp file + rename): a run killed mid-write keeps its previous state."""
        state = {
            "recipe": dataclasses.asdict(self.recipe),
            "phase": phase,
            "epoch": epoch,
            "model": self.model.state_dict(),
            "history": self.history,
            "optimizer": opt.state_dict() if opt else None,
            "scheduler": sched.state_dict() if sched else None,
            "best": self.best,
        }
        tmp = self.run_dir / "state.pt.tmp"
        torch.save(state, tmp)
        tmp.replace(self.run_dir / "state.pt")


@dataclass
class _NormalFit:
    """What phases (b) and (c) differ in; `_fit_normals` runs either."""

    phase: str
    head: torch.nn.Module  # what the loss runs through: the regressor on frozen latents, or the whole model
    epochs: int
    first: int  # 0, or the epoch after the resumed one
    patches: Callable[[int], NormalSet]  # an epoch's training patches
    val: NormalSet
    batch_size: int
    opt: torch.optim.Optimizer
    sched: ReduceLROnPlateau
    freeze_bn: bool = False


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
    run = _start(recipe, run_dir, resolve_device(device), resume, encoder_from)
    if recipe.triplet and not encoder_from:
        _phase_encoder(run)
    _phase_regressor(run)
    _phase_finetune(run)
    _restore_best(run)  # also when a resumed run had no epoch left to run (state.pt holds the last weights)
    summary = _summary(run, start)
    save_checkpoint(out, run.model.cpu(), _metadata(recipe, summary))
    (run_dir / "history.json").write_text(json.dumps(summary, indent=2))
    plot_curves(run.history, run_dir / "training_curves.png")
    return summary


def _start(recipe: Recipe, run_dir: Path, dev: torch.device, resume: bool, encoder_from: Path | None) -> TrainingRun:
    """Seed, then build or restore the model before the data: the weight initialisation is the first draw from the
    seeded global generator, so this order is part of what makes a recipe reproduce its checkpoint."""
    torch.manual_seed(recipe.seed)
    run_dir.mkdir(parents=True, exist_ok=True)
    state = _load_state(run_dir) if resume else None
    if state:
        _check_resumable(state, recipe, run_dir)
    model = TripletNormalNet(tuple(recipe.encoder), tuple(recipe.regressor), recipe.residual, **recipe.fit_options())
    model = model.to(dev)
    if state:
        model.load_state_dict(state["model"])
    elif encoder_from:
        _load_encoder(model, encoder_from)
    history = state["history"] if state else []
    best = state.get("best") if state else None  # absent from states written before it was saved
    train_set, val_set = _samplers(recipe, "train"), _samplers(recipe, "val")
    return TrainingRun(model, recipe, train_set, val_set, dev, run_dir, state, history, best)


def _summary(run: TrainingRun, start: float) -> dict:
    """history.json's content: the shipped weights are the best normal-loss validation epoch (`run.best`), whose
    loss and origin it reports; both None when no phase (b) or (c) epoch ran."""
    trained = any(h["phase"] != "encoder" for h in run.history)
    best = run.best if trained else None
    return {
        "wall_seconds": round(time.time() - start, 1),
        "device": str(run.device),
        "history": run.history,
        "final_val_normal_loss": best["val"] if best else None,
        "best_epoch": {"phase": best["phase"], "epoch": best["epoch"]} if best else None,
    }


def _metadata(recipe: Recipe, summary: dict) -> dict:
    """The checkpoint's metadata: the k and radius convention inference must use, and how it was trained."""
    return {
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


def _samplers(recipe: Recipe, split: str) -> list[PatchSampler]:
    from .dataset import build_dataset  # training-only dependencies (trimesh, manifold3d)

    shapes = recipe.shapes if split == "train" else recipe.val_shapes
    clouds = build_dataset(split=split, n_points=recipe.n_points, seed=recipe.seed, shapes=shapes)
    fits = recipe.fit_options()
    samplers = [PatchSampler(c.points, c.normals, recipe.radius_rel, recipe.k, **fits) for c in clouds]
    return samplers + _range_samplers(recipe, split)


def _range_samplers(recipe: Recipe, split: str) -> list[PatchSampler]:
    """Simulated depth frames and LiDAR scans at their metric radii, `recipe.range_frames` of each, and
    `recipe.fold_frames` close-range fold frames, for training; a third as many of each (at least one) for validation.
    All come from frame seeds that eval and the studies never score (`range_scans.TRAIN_SEED`): what robots see (noise
    along the ray, falling density, rings, folds a hand's width across) beside the uniform CAD samples."""
    if not (recipe.range_frames or recipe.fold_frames):
        return []
    from ..simulation.range_scans import TRAIN_SEED, VAL_SEED, depth_frames, fold_frames, lidar_scans

    train = split == "train"
    seed = TRAIN_SEED if train else VAL_SEED

    def count(n: int) -> int:
        return n if train or not n else max(1, n // 3)

    frames = [(f, DEPTH_RADIUS) for f in depth_frames(count(recipe.range_frames), seed)]
    frames += [(f, LIDAR_RADIUS) for f in lidar_scans(count(recipe.range_frames), seed)]
    frames += [(f, DEPTH_RADIUS) for f in fold_frames(count(recipe.fold_frames), seed)]
    fits = recipe.fit_options()
    return [
        PatchSampler(f.points.reshape(-1, 3), f.normals.reshape(-1, 3), recipe.radius_rel, recipe.k, radius=r, **fits)
        for f, r in frames
    ]


def _phase_encoder(run: TrainingRun) -> None:
    """Phase (a): the encoder alone on the triplet loss, on fresh triplets every epoch."""
    recipe, encoder, state = run.recipe, run.model.encoder, run.state
    if state and state["phase"] != "encoder":
        return
    opt, sched = _optimiser(list(encoder.parameters()), recipe.lr, recipe, state)
    val = collect_triplets(run.val_set, recipe.val_patches_per_cloud, recipe.seed + 10_000, "val triplets")
    val_loss_of = partial(_triplet_val_loss, encoder, val, run.device)
    for epoch in range(_first_epoch(state), recipe.encoder_epochs):
        data = collect_triplets(run.train_set, recipe.patches_per_shape, recipe.seed + epoch, f"triplets e{epoch}")
        batches = _shuffled_batches(len(data.anchor), recipe.batch_size)
        step = partial(_triplet_batch_loss, encoder, data, run.device)
        train_loss = _epoch(encoder, batches, step, opt, f"encoder {epoch + 1}/{recipe.encoder_epochs}")
        val_loss = _mean_loss(encoder, len(val.anchor), _TRIPLET_EVAL_CHUNK, val_loss_of)
        sched.step(val_loss)
        run.end_epoch("encoder", epoch, (train_loss, val_loss), len(data.anchor), opt, sched)
    run.save("regressor", -1)


def _phase_regressor(run: TrainingRun) -> None:
    """With the triplet encoder frozen, the latents are computed once and the regressor trains on them; without it
    (the ablation), encoder and regressor train together on the normal loss."""
    recipe, model = run.recipe, run.model
    if run.resumed("finetune"):
        return
    resumed = run.resumed("regressor")
    resumed = resumed if resumed and resumed["epoch"] >= 0 else None  # -1: phase (a) just ended
    if resumed and resumed["epoch"] + 1 >= recipe.regressor_epochs:
        _restore_best(run)  # state.pt holds the last epoch's weights; the next phase and the checkpoint take the best
        return  # finished before; resuming goes on to the next phase
    params = list(model.regressor.parameters()) + ([] if recipe.triplet else list(model.encoder.parameters()))
    opt, sched = _optimiser(params, recipe.lr, recipe, resumed)
    train = collect_normal_patches(run.train_set, recipe.regressor_patches_per_shape, recipe.seed + 20_000, "patches")
    val = _val_patches(run)
    if recipe.triplet:
        train, val = _encoded(model.encoder, train, run.device), _encoded(model.encoder, val, run.device)
    head = model.regressor if recipe.triplet else model
    # A step on precomputed latents costs next to nothing, so the frozen-encoder path takes larger batches.
    batch_size = max(recipe.batch_size, 256) if recipe.triplet else recipe.batch_size
    fit = _NormalFit(
        "regressor", head, recipe.regressor_epochs, _first_epoch(resumed), lambda _: train, val, batch_size, opt, sched
    )
    _fit_normals(run, fit)


def _phase_finetune(run: TrainingRun) -> None:
    """Phase (c), our addition (docs/MODEL.md): encoder and regressor together on the normal loss, starting from the
    triplet encoder and the trained regressor. On the CPU budget the frozen triplet latent alone only matched PCA."""
    recipe = run.recipe
    if recipe.finetune_epochs <= 0 or not recipe.triplet:
        return
    resumed = run.resumed("finetune")
    opt, sched = _optimiser(list(run.model.parameters()), recipe.finetune_lr, recipe, resumed)
    per_cloud = recipe.finetune_patches_per_shape
    per_cloud = recipe.regressor_patches_per_shape if per_cloud is None else per_cloud

    def train(epoch: int) -> NormalSet:  # fresh patches every epoch, so the whole network cannot memorise them
        return collect_normal_patches(run.train_set, per_cloud, recipe.seed + 40_000 + epoch, f"patches c{epoch}")

    fit = _NormalFit(
        "finetune",
        run.model,
        recipe.finetune_epochs,
        _first_epoch(resumed),
        train,
        _val_patches(run),
        recipe.batch_size,
        opt,
        sched,
        freeze_bn=recipe.finetune_freeze_bn,
    )
    _fit_normals(run, fit)


def _val_patches(run: TrainingRun) -> NormalSet:
    """The validation patches of phases (b) and (c): the same seed, so their losses compare."""
    recipe = run.recipe
    return collect_normal_patches(run.val_set, recipe.val_patches_per_cloud, recipe.seed + 30_000, "val patches")


def _fit_normals(run: TrainingRun, fit: _NormalFit) -> None:
    """Epochs of the normal loss on `fit.head`; the model ends with the weights of the run's best validation epoch.

    A phase resumed after an interruption continues from the best that state.pt recorded, so epochs before the
    interruption still compete. A phase starting afresh starts from the weights it is given (the previous phase's best
    when there was one): they are measured on this phase's validation path and compete as epoch -1.
    """
    val_loss_of = partial(_recipe_loss, fit.head, fit.val, run.recipe, run.device)
    evaluate = partial(_mean_loss, fit.head, len(fit.val.patches), _NORMAL_EVAL_CHUNK, val_loss_of)
    if fit.first == 0 or run.best is None:
        # Afresh, the starting weights keep the origin of the previous phase's best; resuming a state.pt written
        # before `best` was saved, only its last epoch's weights are known.
        inherited = fit.first == 0 and run.best is not None
        origin = (run.best["phase"], run.best["epoch"]) if inherited else (fit.phase, fit.first - 1)
        run.best = {"phase": origin[0], "epoch": origin[1], "val": evaluate(), "model": _weights(run.model)}
    for epoch in range(fit.first, fit.epochs):
        data = fit.patches(epoch)
        batches = _shuffled_batches(len(data.patches), fit.batch_size)
        step = partial(_recipe_loss, fit.head, data, run.recipe, run.device)
        desc = f"{fit.phase} {epoch + 1}/{fit.epochs}"
        train_loss = _epoch(fit.head, batches, step, fit.opt, desc, fit.freeze_bn)
        val_loss = evaluate()
        fit.sched.step(val_loss)
        if _improves(val_loss, run.best["val"]):
            run.best = {"phase": fit.phase, "epoch": epoch, "val": val_loss, "model": _weights(run.model)}
        run.end_epoch(fit.phase, epoch, (train_loss, val_loss), len(data.patches), fit.opt, fit.sched)
    _restore_best(run)  # ship the best validation epoch, not the last


def _weights(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """A copy of the model's weights and buffers that later training steps do not change."""
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def _improves(val_loss: float, best: float) -> bool:
    """Lower is better; any number beats a NaN best (weights that had diverged), and a NaN never wins."""
    return val_loss < best or (math.isnan(best) and not math.isnan(val_loss))


def _restore_best(run: TrainingRun) -> None:
    """Load the best weights so far into the model: what the next phase starts from and the checkpoint ships."""
    if run.best is not None:
        run.model.load_state_dict(run.best["model"])


def _first_epoch(resumed: dict | None) -> int:
    """Where a phase starts: after the epoch its saved state ended, or at 0."""
    return resumed["epoch"] + 1 if resumed else 0


def _shuffled_batches(rows: int, batch_size: int) -> list[torch.Tensor]:
    """An epoch's row indices in a fresh order from the global generator, in batches; a last batch of one row is
    dropped because BatchNorm cannot normalise a single sample in training mode."""
    order = torch.randperm(rows)
    batches = (order[lo : lo + batch_size] for lo in range(0, rows, batch_size))
    return [idx for idx in batches if len(idx) >= 2]


def _epoch(
    module: torch.nn.Module,
    batches: list[torch.Tensor],
    batch_loss: Callable[[torch.Tensor], torch.Tensor],
    opt: torch.optim.Optimizer,
    desc: str,
    freeze_bn: bool = False,
) -> float:
    """One SGD pass of `module` over `batches` of row indices; returns the mean batch loss. Both phases' losses come
    in as `batch_loss`, so they share one loop. `freeze_bn` keeps the running statistics the later layers were
    trained on (phase (c))."""
    module.train()
    if freeze_bn:
        for child in module.modules():
            if isinstance(child, torch.nn.BatchNorm1d):
                child.eval()
    losses: list[float] = []
    bar = tqdm(batches, desc=desc, unit="batch", leave=False)
    for idx in bar:
        loss = batch_loss(idx)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(loss.item())
        bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
    return float(np.mean(losses))


def _mean_loss(module: torch.nn.Module, rows: int, chunk: int, chunk_loss: Callable[[slice], torch.Tensor]) -> float:
    """A validation loss: the per-row mean of `chunk_loss` over `rows` rows, in eval mode and without autograd."""
    module.eval()
    total = 0.0
    with torch.inference_mode():
        for lo in range(0, rows, chunk):
            part = slice(lo, min(lo + chunk, rows))
            total += chunk_loss(part).item() * (part.stop - part.start)
    return float(total / max(1, rows))


def _triplet_batch_loss(encoder: torch.nn.Module, data: TripletSet, dev: torch.device, idx: torch.Tensor):
    """Triplet loss of rows `idx`, all three patches in one forward pass so BatchNorm sees them together."""
    batch = torch.cat([data.anchor[idx], data.positive[idx], data.negative[idx]]).to(dev)
    f = torch.nn.functional.normalize(encoder(batch), dim=-1).split(len(idx))
    return triplet_loss(*f)


def _triplet_val_loss(encoder: torch.nn.Module, data: TripletSet, dev: torch.device, rows: slice) -> torch.Tensor:
    """Triplet loss of `rows` in eval mode (BatchNorm uses running statistics, so the three passes may be separate)."""
    triple = (data.anchor, data.positive, data.negative)
    f = [torch.nn.functional.normalize(encoder(t[rows].to(dev)), dim=-1) for t in triple]
    return triplet_loss(*f)


def _recipe_loss(head: torch.nn.Module, data: NormalSet, recipe: Recipe, dev: torch.device, rows) -> torch.Tensor:
    """The recipe's normal loss of `head` on `rows` of `data` (training and validation alike)."""
    fits = None if data.fits is None else data.fits[rows].to(dev)
    pred = head(data.patches[rows].to(dev), fits)
    centre, patch = data.centre_normal[rows].to(dev), data.patch_normals[rows].to(dev)
    return patch_loss(recipe.loss, pred, centre, patch, recipe.exponent, recipe.support_deg, recipe.relative_floor_deg)


def _encoded(encoder: torch.nn.Module, data: NormalSet, dev: torch.device) -> NormalSet:
    """Replace patches by their frozen latents: phase (b) then costs one encoder pass in total."""
    encoder.eval()
    with torch.inference_mode():
        latents = [encoder(data.patches[i : i + 512].to(dev)).cpu() for i in range(0, len(data.patches), 512)]
    return NormalSet(torch.cat(latents), data.centre_normal, data.patch_normals, data.fits)


def _optimiser(
    params: Iterable[torch.nn.Parameter], lr: float, recipe: Recipe, state: dict | None
) -> tuple[torch.optim.Optimizer, ReduceLROnPlateau]:
    """SGD with the recipe's momentum and plateau schedule, restored from `state` when resuming mid-phase."""
    opt = torch.optim.SGD(params, lr=lr, momentum=recipe.momentum)
    sched = ReduceLROnPlateau(opt, mode="min", factor=0.1, patience=recipe.patience)
    if state and state.get("optimizer"):
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
    return opt, sched


def _load_state(run_dir: Path) -> dict | None:
    path = run_dir / "state.pt"
    # weights_only: never unpickle code. map_location cpu: a state saved on a GPU resumes on a CPU too; the model and
    # the optimizer move their tensors to the run's device when they load them.
    return torch.load(path, weights_only=True, map_location="cpu") if path.is_file() else None


def _check_resumable(state: dict, recipe: Recipe, run_dir: Path) -> None:
    """Refuse to resume under a recipe that optimises something else: best-epoch and plateau decisions would compare
    losses on different scales."""
    saved = state.get("recipe")
    if saved is None:
        raise TrainingError(f"{run_dir}/state.pt does not record its recipe (older version); start a new --run-dir")
    # A field the state predates was trained at its default (e.g. `scales`, added later: none).
    defaults = dataclasses.asdict(Recipe())
    before = {f: saved.get(f, defaults[f]) for f in RESUME_FIXED}
    changed = [f"{f}: {before[f]!r} -> {getattr(recipe, f)!r}" for f in RESUME_FIXED if before[f] != getattr(recipe, f)]
    if changed:
        raise TrainingError(
            f"cannot resume {run_dir} with a different recipe ({'; '.join(changed)}); pass the flags it started with"
            " (the default recipe is 'scales'; a run started as --recipe cpu needs --recipe cpu)"
        )


def _load_encoder(model: TripletNormalNet, path: Path) -> None:
    donor, _ = load_checkpoint(path)
    model.encoder.load_state_dict(donor.encoder.state_dict())
