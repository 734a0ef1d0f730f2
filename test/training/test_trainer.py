"""Training end to end at toy scale: the losses fall, the checkpoint loads, resuming continues, triplets obey the
paper's constraints on generated data. The tests that train are marked slow; the refusals and the recipe checks take
well under a second each and run in `make test-fast`."""

import argparse
import json
import math
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import torch

from triplet_normal_ros.cli import train
from triplet_normal_ros.cli.main import main
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.learned.checkpoint import default_checkpoint_path, load_checkpoint, read_metadata
from triplet_normal_ros.core.search.neighbours import NeighbourIndex
from triplet_normal_ros.errors import TrainingError, UsageError
from triplet_normal_ros.evaluation.ablation import _variants, reference_estimator
from triplet_normal_ros.training.batches import PatchSampler
from triplet_normal_ros.training.dataset import build_dataset
from triplet_normal_ros.training.recipes import RECIPES
from triplet_normal_ros.training.trainer import TrainingRun, _mean_loss, _recipe_loss, _samplers, _val_patches
from triplet_normal_ros.training.triplets import mine_triplets

TOY = (
    "--recipe cpu --shapes box_3x2x1 sphere --val-shapes v_notch_block --n-points 3000 --k 32 --patches-per-shape 96 "
    "--regressor-patches-per-shape 256 --val-patches-per-cloud 16 --encoder-widths 16 32 --regressor-widths 32 "
    "--seed 3 --finetune-epochs 0 --no-residual --loss cos"
)


def _args(extra: str, run_dir) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    return parser.parse_args(f"{TOY} {extra} --run-dir {run_dir}".split())


TOY_RUN = "--encoder-epochs 1 --regressor-epochs 6 --finetune-epochs 2 --finetune-patches-per-shape 64 --lr 0.05"


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("train")
    assert train.run(_args(TOY_RUN, run_dir)) == 0
    return run_dir


def _shipped_val_loss(run_dir: Path, extra: str) -> float:
    """The validation normal loss of the checkpoint a run wrote, on the validation patches phases (b) and (c) use."""
    recipe = train.recipe_from_args(_args(extra, run_dir))
    model, _ = load_checkpoint(run_dir / "model.safetensors")
    run = TrainingRun(model, recipe, [], _samplers(recipe, "val"), torch.device("cpu"), run_dir)
    val = _val_patches(run)
    return _mean_loss(model, len(val.patches), 512, partial(_recipe_loss, model, val, recipe, run.device))


def _weights(path: Path) -> dict[str, torch.Tensor]:
    model, _ = load_checkpoint(path)
    return model.state_dict()


@pytest.mark.slow  # a training run
def test_regressor_loss_falls(toy_run):
    rows = [h for h in json.loads((toy_run / "history.json").read_text())["history"] if h["phase"] == "regressor"]
    assert len(rows) == 6
    assert rows[-1]["train"] < 0.8 * rows[0]["train"]
    assert min(h["val"] for h in rows) < rows[0]["val"]


@pytest.mark.slow  # a training run
def test_finetune_phase_runs_end_to_end(toy_run):
    history = json.loads((toy_run / "history.json").read_text())["history"]
    assert [h["phase"] for h in history] == ["encoder"] + ["regressor"] * 6 + ["finetune"] * 2
    # The checkpoint holds the weights of the least validation loss over (b) and (c), measured again from the file.
    best = min(h["val"] for h in history if h["phase"] != "encoder")
    assert _shipped_val_loss(toy_run, TOY_RUN) == pytest.approx(best, rel=1e-4)
    summary = json.loads((toy_run / "history.json").read_text())
    assert summary["final_val_normal_loss"] == pytest.approx(best, rel=1e-4)
    clouds = 2 * 6  # two shapes, clean + five noise levels
    assert {h["n"] for h in history if h["phase"] == "finetune"} == {clouds * 64}  # phase (c)'s own count
    assert {h["n"] for h in history if h["phase"] == "regressor"} == {clouds * 256}


@pytest.mark.slow  # a training run
def test_checkpoint_records_recipe_and_loads(toy_run):
    meta = read_metadata(toy_run / "model.safetensors")
    assert meta["k"] == 32
    assert meta["training"]["recipe"]["encoder"] == [16, 32]
    assert meta["training"]["data_seed"] == 3
    est = NormalEstimator("learned", radius=0.05, checkpoint=toy_run / "model.safetensors", device="cpu")
    cloud = build_dataset("val", n_points=2000, shapes=["v_notch_block"], noise_levels=[0.0], progress=False)[0]
    normals, _ = est.estimate(cloud.points, query=np.arange(200))
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)
    assert (toy_run / "training_curves.png").stat().st_size > 10_000


@pytest.mark.slow  # a training run
def test_resume_continues_where_it_stopped(tmp_path):
    run_dir = tmp_path / "resume"
    train.run(_args("--encoder-epochs 1 --regressor-epochs 2", run_dir))
    first = json.loads((run_dir / "history.json").read_text())["history"]
    train.run(_args("--encoder-epochs 1 --regressor-epochs 3 --resume", run_dir))
    resumed = json.loads((run_dir / "history.json").read_text())["history"]
    assert [h["epoch"] for h in resumed if h["phase"] == "regressor"] == [0, 1, 2]
    assert resumed[: len(first)] == first  # earlier epochs are kept, not re-run


def _interrupted_after_worse_epochs(run_dir: Path) -> None:
    """Make state.pt that of a run whose last epoch before the interruption was worse than its best and whose later
    epochs cannot improve: the last layer of the saved weights answers the patch frame's x axis, a tangent, for every
    patch, and the saved learning rate is 0, so resumed epochs keep answering it."""
    state = torch.load(run_dir / "state.pt", weights_only=True)  # what state.pt holds loads without unpickling
    last = max((k for k in state["model"] if k.startswith("regressor.mlp.")), key=lambda k: int(k.split(".")[2]))
    layer = last.rsplit(".", 1)[0]
    state["model"][f"{layer}.weight"] = torch.zeros_like(state["model"][f"{layer}.weight"])
    state["model"][f"{layer}.bias"] = torch.tensor([1.0, 0.0, 0.0])
    for group in state["optimizer"]["param_groups"]:
        group["lr"] = 0.0
    torch.save(state, run_dir / "state.pt")


@pytest.mark.slow  # a training run
@pytest.mark.parametrize("more", [0, 2])  # resumed with no epoch of phase (b) left, or with two more
def test_a_resumed_run_ships_its_best_weights_from_before_the_interruption(tmp_path, more):
    run_dir = tmp_path / "best"
    train.run(_args("--encoder-epochs 1 --regressor-epochs 2", run_dir))
    before = json.loads((run_dir / "history.json").read_text())
    shipped_before = _weights(run_dir / "model.safetensors")
    _interrupted_after_worse_epochs(run_dir)
    train.run(_args(f"--encoder-epochs 1 --regressor-epochs {2 + more} --resume", run_dir))
    after = json.loads((run_dir / "history.json").read_text())
    later = [h["val"] for h in after["history"] if h["phase"] == "regressor" and h["epoch"] >= 2]
    assert len(later) == more and all(val > before["final_val_normal_loss"] for val in later)  # worse, as arranged
    shipped_after = _weights(run_dir / "model.safetensors")
    assert shipped_after.keys() == shipped_before.keys()
    assert all(torch.equal(shipped_after[k], shipped_before[k]) for k in shipped_before), "not the earlier best"
    assert after["final_val_normal_loss"] == before["final_val_normal_loss"]
    assert after["best_epoch"] == before["best_epoch"] and after["best_epoch"]["phase"] == "regressor"
    state = torch.load(run_dir / "state.pt", weights_only=True)
    assert (state["best"]["phase"], state["best"]["epoch"]) == tuple(before["best_epoch"].values())


@pytest.mark.slow  # a training run
def test_a_run_stopped_in_phase_c_resumes_there(tmp_path):
    run_dir = tmp_path / "finetune"
    common = "--encoder-epochs 1 --regressor-epochs 1 --finetune-patches-per-shape 64"
    train.run(_args(f"{common} --finetune-epochs 1", run_dir))
    train.run(_args(f"{common} --finetune-epochs 2 --resume", run_dir))
    history = json.loads((run_dir / "history.json").read_text())["history"]
    phases = [(h["phase"], h["epoch"]) for h in history]
    assert phases == [("encoder", 0), ("regressor", 0), ("finetune", 0), ("finetune", 1)]


def test_triplets_obey_the_angle_threshold_and_stay_close():
    cloud = build_dataset("train", n_points=5000, shapes=["box_3x2x1"], noise_levels=[0.01], progress=False)[0]
    points, normals = cloud.points.astype(np.float64), cloud.normals.astype(np.float64)
    index, rng = NeighbourIndex(points), np.random.default_rng(0)
    anchors = rng.choice(len(points), 300, replace=False)
    positive, negative = mine_triplets(index, normals, anchors, 0.05)
    assert (positive >= 0).all() and (negative >= 0).all()
    cos_th = math.cos(math.radians(20))
    assert (np.einsum("ij,ij->i", normals[anchors], normals[positive]) >= cos_th).all()
    assert (np.einsum("ij,ij->i", normals[anchors], normals[negative]) < cos_th).all()
    assert (positive != anchors).all() and (negative != anchors).all()
    d_pos = np.linalg.norm(points[positive] - points[anchors], axis=1)
    assert np.median(d_pos) < 0.05  # positives come from inside the ball
    # A negative is the nearest point across a >20° change: nothing closer qualifies.
    all_d = np.linalg.norm(points[None] - points[anchors][:, None], axis=-1)
    all_cos = normals[anchors] @ normals.T
    nearest_neg = np.where(all_cos < cos_th, all_d, np.inf).min(axis=1)
    d_neg = np.linalg.norm(points[negative] - points[anchors], axis=1)
    assert np.mean(np.isclose(d_neg, nearest_neg)) > 0.95


def _tilt_deg(patches: torch.Tensor) -> np.ndarray:
    """Per patch, the angle between the least principal axis of its points and +z."""
    centred = patches.double() - patches.double().mean(dim=1, keepdim=True)
    _, axes = torch.linalg.eigh(centred.transpose(1, 2) @ centred)
    return np.degrees(np.arccos(axes[:, 2, 0].abs().clamp(max=1.0).numpy()))


def test_triplet_patches_are_seen_in_the_anchor_frame():
    """In its own PCA frame a patch of a plane lies flat (least axis on +z). Positive and negative patches must be
    rotated into the anchor's frame instead, or the triplet loss cannot see the turn across an edge: there a negative
    (normal > 20° from the anchor's) lies tilted, a positive almost flat."""
    cloud = build_dataset("train", n_points=4000, shapes=["wedge"], noise_levels=[0.0], progress=False)[0]
    sampler = PatchSampler(cloud.points, cloud.normals, 0.05, 32)
    triplets = sampler.triplets(200, np.random.default_rng(1), torch.Generator().manual_seed(1))
    assert len(triplets.anchor) > 150
    assert np.median(_tilt_deg(triplets.anchor)) < 5.0
    assert np.mean(_tilt_deg(triplets.positive) < 20.0) > 0.8
    assert np.mean(_tilt_deg(triplets.negative) > 20.0) > 0.75  # each in its own frame: none would be
    assert triplets.positive.norm(dim=-1).max() <= 1.0 + 1e-5  # still the unit ball: scaled by the radius


@pytest.mark.slow  # a training run
def test_cpu_recipe_options_residual_head_and_relative_loss_reach_the_checkpoint(tmp_path):
    run_dir = tmp_path / "residual"
    extra = "--encoder-epochs 1 --regressor-epochs 3 --residual --loss relative --relative-floor-deg 7.5"
    train.run(_args(extra, run_dir))
    meta = read_metadata(run_dir / "model.safetensors")
    assert meta["architecture"]["residual"] is True
    assert meta["training"]["recipe"]["loss"] == "relative"
    assert meta["training"]["recipe"]["relative_floor_deg"] == 7.5
    history = json.loads((run_dir / "history.json").read_text())["history"]
    assert all(math.isfinite(h["val"]) for h in history if h["phase"] != "encoder")
    # The head corrects the PCA normal, so on a clean plane it must stay on the plane's normal.
    xy = np.random.default_rng(0).uniform(-1, 1, (3000, 2))
    plane = np.c_[xy, 0.3 * xy[:, 0] + 0.1 * xy[:, 1]]
    est = NormalEstimator("learned", radius=0.2, checkpoint=run_dir / "model.safetensors", device="cpu")
    normals, _ = est.estimate(plane, query=np.arange(0, 3000, 30))
    truth = np.array([0.3, 0.1, -1.0]) / np.linalg.norm([0.3, 0.1, -1.0])
    assert np.degrees(np.arccos(np.clip(np.abs(normals @ truth), 0.0, 1.0))).max() < 10.0  # |cos| may round past 1


def test_ablation_rows_are_the_paper_ablations_and_ours_at_one_budget(tmp_path):
    args = argparse.Namespace(patches_per_shape=7, epochs=2, encoder_from=tmp_path / "encoder.safetensors")
    rows = {name: (recipe, encoder) for name, recipe, encoder in _variants(args, RECIPES["cpu"])}
    exponents = [r.exponent for name, (r, _) in rows.items() if name.startswith("paper head")]
    assert exponents == [2, 4, 8, 12]
    assert all(not r.residual and r.loss == "cos" for name, (r, _) in rows.items() if name.startswith("paper head"))
    losses = {r.loss for name, (r, _) in rows.items() if name.startswith("residual head")}
    assert losses == {"cos", "angle", RECIPES["cpu"].loss}
    direct = [(r, e) for name, (r, e) in rows.items() if "direct" in name]
    assert len(direct) == 1 and not direct[0][0].triplet and direct[0][1] is None
    for name, (recipe, encoder) in rows.items():
        assert (recipe.regressor_patches_per_shape, recipe.regressor_epochs, recipe.finetune_epochs) == (7, 2, 0)
        assert encoder == (None if "direct" in name else args.encoder_from)


@pytest.mark.parametrize("floor", ["0", "-5", "nan"])
def test_a_relative_floor_that_is_not_positive_is_refused_by_the_cli(floor, tmp_path, capsys):
    with pytest.raises(SystemExit):
        _args(f"--loss relative --relative-floor-deg {floor}", tmp_path)
    assert "must be a finite number > 0" in capsys.readouterr().err


@pytest.mark.parametrize(
    "flag", ["--finetune-patches-per-shape 0", "--regressor-patches-per-shape -3", "--k 0", "--regressor-epochs -1"]
)
def test_a_size_or_epoch_count_that_cannot_work_is_refused(flag, tmp_path):
    with pytest.raises(UsageError, match=f"{flag.split()[0]} must be >= "):
        train.recipe_from_args(_args(flag, tmp_path))


def test_a_relative_floor_without_the_relative_loss_is_refused(tmp_path):
    args = _args("--loss angle --relative-floor-deg 5", tmp_path)
    with pytest.raises(UsageError, match="only applies to --loss relative"):
        train.recipe_from_args(args)


@pytest.mark.slow  # a training run
def test_resuming_under_a_recipe_that_optimises_something_else_is_refused(tmp_path):
    run_dir = tmp_path / "switch"
    train.run(_args("--encoder-epochs 1 --regressor-epochs 1", run_dir))
    state = torch.load(run_dir / "state.pt", weights_only=True)
    assert state["recipe"]["loss"] == "cos"
    with pytest.raises(TrainingError, match="loss: 'cos' -> 'angle'"):
        train.run(_args("--encoder-epochs 1 --regressor-epochs 2 --loss angle --resume", run_dir))
    del state["recipe"]
    torch.save(state, run_dir / "state.pt")
    with pytest.raises(TrainingError, match="does not record its recipe"):
        train.run(_args("--encoder-epochs 1 --regressor-epochs 2 --resume", run_dir))


def test_the_ablation_reference_is_pca_over_the_learned_rows_pool():
    est = reference_estimator(RECIPES["cpu"], "cpu")
    assert est.method == "pca" and est.k == 4 * RECIPES["cpu"].k == 512


def test_an_unknown_training_shape_is_one_error_line_from_the_command(tmp_path, capsys):
    status = main(["train", "--shapes", "nope", "--run-dir", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert status == 1
    assert len(err.splitlines()) == 1
    assert err.startswith("triplet-normal: error: unknown train shapes ['nope']; known: [")
    assert "'box_3x2x1'" in err  # it names the shapes that exist


@pytest.mark.slow  # a training run
def test_a_run_without_normal_loss_epochs_reports_that_instead_of_crashing(tmp_path, capsys):
    run_dir = tmp_path / "encoder_only"
    argv = ["train", *TOY.split(), "--encoder-epochs", "1", "--regressor-epochs", "0", "--run-dir", str(run_dir)]
    assert main(argv) == 0
    assert "no normal-loss epoch ran" in capsys.readouterr().out
    history = json.loads((run_dir / "history.json").read_text())
    assert [h["phase"] for h in history["history"]] == ["encoder"] and history["final_val_normal_loss"] is None


@pytest.mark.slow  # a training run
def test_a_scale_head_trains_on_the_plane_fits_and_its_checkpoint_records_the_scales(tmp_path):
    run_dir = tmp_path / "scales"
    train.run(
        _args("--encoder-epochs 1 --regressor-epochs 3 --loss relative --scales 4 8 16 --inlier-seeds 8", run_dir)
    )
    meta = read_metadata(run_dir / "model.safetensors")
    assert meta["architecture"]["scales"] == [4, 8, 16] and meta["training"]["recipe"]["scales"] == [4, 8, 16]
    assert meta["architecture"]["inlier_seeds"] == [8]
    rows = [h for h in json.loads((run_dir / "history.json").read_text())["history"] if h["phase"] == "regressor"]
    assert rows[-1]["train"] < rows[0]["train"]
    # Resuming under other scales would compare losses of different heads: refused, like any other head change.
    with pytest.raises(TrainingError, match=r"scales: \[4, 8, 16\] -> \[8, 16\]"):
        argv = "--encoder-epochs 1 --regressor-epochs 4 --loss relative --scales 8 16 --inlier-seeds 8 --resume"
        train.run(_args(argv, run_dir))


@pytest.mark.slow  # a training run
def test_a_state_written_before_scales_existed_resumes_as_a_run_without_them(tmp_path):
    run_dir = tmp_path / "old_state"
    train.run(_args("--encoder-epochs 1 --regressor-epochs 1", run_dir))
    state = torch.load(run_dir / "state.pt", weights_only=True)
    # Fields added after such a state was written:
    for added in ("scales", "inlier_seeds", "range_frames", "fold_frames"):
        del state["recipe"][added]
    del state["best"]  # saved since; without it only the last epoch's weights are known
    torch.save(state, run_dir / "state.pt")
    train.run(_args("--encoder-epochs 1 --regressor-epochs 2 --resume", run_dir))
    history = json.loads((run_dir / "history.json").read_text())["history"]
    assert [h["epoch"] for h in history if h["phase"] == "regressor"] == [0, 1]


@pytest.mark.parametrize("scales", ["2 8", "16 8", "8 8"])
def test_scales_that_cannot_work_are_one_usage_error(scales, tmp_path):
    with pytest.raises(UsageError, match="--scales: scales must"):
        train.recipe_from_args(_args(f"--scales {scales}", tmp_path))


@pytest.mark.slow  # a training run
def test_range_frames_join_the_training_and_validation_clouds_at_their_metric_radii(tmp_path):
    from triplet_normal_ros.simulation.range_scans import depth_frames, lidar_scans
    from triplet_normal_ros.training.trainer import _range_samplers

    run_dir = tmp_path / "range"
    train.run(_args("--encoder-epochs 0 --regressor-epochs 1 --range-frames 1", run_dir))
    history = json.loads((run_dir / "history.json").read_text())["history"]
    (patches,) = {h["n"] for h in history if h["phase"] == "regressor"}
    assert (2 * 6 + 1) * 256 < patches <= (2 * 6 + 2) * 256  # + 1 depth + 1 LiDAR frame (a few isolated returns)
    recipe = train.recipe_from_args(_args("--range-frames 3", run_dir))
    samplers = {split: _range_samplers(recipe, split) for split in ("train", "val")}
    assert [s.radius for s in samplers["train"]] == [0.05] * 3 + [0.25] * 3
    assert [s.radius for s in samplers["val"]] == [0.05, 0.25]  # a third as many, at least one of each

    def heads(clouds) -> set[bytes]:
        return {c[np.isfinite(c).all(axis=1)][:5].tobytes() for c in clouds}

    scored = heads(f.points.reshape(-1, 3).astype(np.float64) for f in depth_frames(3) + lidar_scans(3))  # eval's
    trained, validated = heads(s.points for s in samplers["train"]), heads(s.points for s in samplers["val"])
    assert len(trained) == 6 and len(validated) == 2
    assert not trained & validated and not (trained | validated) & scored


@pytest.mark.slow  # generates 16 full fold frames where the cache lacks them
def test_fold_frames_join_at_the_depth_radius_from_seeds_that_eval_and_the_studies_never_score(tmp_path):
    from triplet_normal_ros.simulation.range_scans import fold_frames
    from triplet_normal_ros.training.trainer import _range_samplers

    recipe = train.recipe_from_args(_args("--fold-frames 3", tmp_path))
    assert recipe.range_frames == 0 and recipe.fold_frames == 3
    samplers = {split: _range_samplers(recipe, split) for split in ("train", "val")}
    assert [s.radius for s in samplers["train"]] == [0.05] * 3  # fold frames alone: no depth frames or LiDAR scans
    assert [s.radius for s in samplers["val"]] == [0.05]  # a third as many, at least one

    def heads(clouds) -> set[bytes]:
        return {c[np.isfinite(c).all(axis=1)][:5].tobytes() for c in clouds}

    scored = heads(f.points.reshape(-1, 3).astype(np.float64) for f in fold_frames(6) + fold_frames(6, 100))
    trained, validated = heads(s.points for s in samplers["train"]), heads(s.points for s in samplers["val"])
    assert len(trained) == 3 and len(validated) == 1
    assert not trained & validated and not (trained | validated) & scored
    assert train.recipe_from_args(_args("--fold-frames 0", tmp_path)).fold_frames == 0
    with pytest.raises(UsageError, match="--fold-frames"):
        train.recipe_from_args(_args("--fold-frames -1", tmp_path))


def test_inlier_seeds_without_scales_are_one_usage_error(tmp_path):
    with pytest.raises(UsageError, match="--inlier-seeds needs --scales"):
        train.recipe_from_args(_args("--inlier-seeds 16", tmp_path))


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        ("--scales 4 8 --inlier-seeds 2", "--inlier-seeds: scales must be integers >= 3"),
        ("--scales 8 256", r"--scales: 256 is more than the 128-point pool"),  # TOY's k = 32
        ("--scales 8 16 --inlier-seeds 200", r"--inlier-seeds: 200 is more than the 128-point pool"),
    ],
)
def test_fit_counts_are_refused_with_the_flag_that_is_wrong(flags, message, tmp_path):
    with pytest.raises(UsageError, match=message):
        train.recipe_from_args(_args(flags, tmp_path))


def test_the_default_recipe_is_the_shipped_checkpoints_scale_head_with_inlier_fits_and_range_frames(tmp_path):
    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    recipe = train.recipe_from_args(parser.parse_args(["--run-dir", str(tmp_path)]))
    assert recipe == RECIPES["scales"]
    assert (recipe.scales, recipe.inlier_seeds, recipe.range_frames) == ([8, 16, 32, 64, 128], [16, 32], 12)
    shipped = read_metadata(default_checkpoint_path())
    assert shipped["architecture"]["scales"] == recipe.scales
    assert shipped["architecture"]["inlier_seeds"] == recipe.inlier_seeds
    assert shipped["training"]["recipe"]["range_frames"] == recipe.range_frames
    assert shipped["training"]["recipe"]["regressor_epochs"] == recipe.regressor_epochs == 79
