"""The paper's losses on cases computed by hand: Eq. (4) triplet loss and the weighted cos^n normal loss (Eq. 5-6)."""

import math

import numpy as np
import pytest
import torch

from triplet_normal_ros.training.losses import angle_loss, normal_loss, patch_loss, relative_angle_loss, triplet_loss

Z = [0.0, 0.0, 1.0]


def _unit(theta_deg: float, phi_deg: float = 0.0) -> list[float]:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return [math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]


def test_triplet_loss_with_zero_margin_on_known_distances() -> None:
    anchor = torch.tensor([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]])
    positive = torch.tensor([[3.0, 4.0], [1.0, 0.0], [1.0, 3.0]])  # distances 5, 1, 2
    negative = torch.tensor([[1.0, 0.0], [0.0, 5.0], [1.0, 3.0]])  # distances 1, 5, 2
    # max(5 - 1, 0) = 4, max(1 - 5, 0) = 0, max(2 - 2, 0) = 0 -> mean 4/3.
    assert triplet_loss(anchor, positive, negative).item() == pytest.approx(4.0 / 3.0)
    # A margin only lifts the hinge: (4 + 1) + max(-4 + 1, 0) + (0 + 1) -> 6/3.
    assert triplet_loss(anchor, positive, negative, margin=1.0).item() == pytest.approx(2.0)


def test_triplet_loss_is_zero_when_every_negative_is_farther() -> None:
    anchor = torch.zeros(4, 8)
    assert triplet_loss(anchor, anchor + 0.1, anchor + 0.2).item() == 0.0


def _patch(normals: list[list[float]]) -> torch.Tensor:
    return torch.tensor([normals], dtype=torch.float64)


def _vec(v: list[float]) -> torch.Tensor:
    return torch.tensor([v], dtype=torch.float64)


def test_normal_loss_is_zero_for_perfect_and_for_sign_flipped_predictions_and_one_when_orthogonal() -> None:
    flat = _patch([Z] * 5)
    assert normal_loss(_vec(Z), _vec(Z), flat).item() == pytest.approx(0.0, abs=1e-12)
    assert normal_loss(_vec([0.0, 0.0, -1.0]), _vec(Z), flat).item() == pytest.approx(0.0, abs=1e-12)
    assert normal_loss(_vec([1.0, 0.0, 0.0]), _vec(Z), flat).item() == pytest.approx(1.0)
    # An odd exponent would not be sign invariant: 1 - (-1)^3 = 2.
    assert normal_loss(_vec([0.0, 0.0, -1.0]), _vec(Z), flat, exponent=3).item() == pytest.approx(2.0)


def _two_normal_expected(pred_deg: float, exponent: int) -> float:
    """Three ground-truth normals equal to the centre's (z) and one at 30° from it, prediction at pred_deg from z."""
    sigma = math.radians(15.0)
    w_far = math.exp(-(1.0 - math.cos(math.radians(30.0))) / (1.0 - math.cos(sigma)))
    cos_near = math.cos(math.radians(pred_deg))
    cos_far = math.cos(math.radians(30.0 - pred_deg))
    num = 3 * 1.0 * (1.0 - cos_near**exponent) + w_far * (1.0 - cos_far**exponent)
    return num / (3 + w_far)


@pytest.mark.parametrize("pred_deg", [0.0, 10.0, 30.0, 60.0])
def test_weighted_loss_of_a_two_normal_patch_matches_the_hand_computation(pred_deg: float) -> None:
    patch = _patch([Z, Z, Z, _unit(30.0)])
    pred = _vec(_unit(pred_deg))
    got8 = normal_loss(pred, _vec(Z), patch).item()  # the paper's defaults: exponent 8, σ_s = 15°
    assert got8 == pytest.approx(_two_normal_expected(pred_deg, 8), rel=1e-9, abs=1e-12)
    got2 = normal_loss(pred, _vec(Z), patch, exponent=2).item()
    assert got2 == pytest.approx(_two_normal_expected(pred_deg, 2), rel=1e-9, abs=1e-12)
    assert got2 != pytest.approx(got8, rel=1e-3)


def test_weight_of_a_normal_at_sigma_s_is_one_over_e() -> None:
    # One normal equal to the centre's (weight 1), one at σ_s = 15° (weight e^-1); predicting x gives loss 1 for
    # both, predicting the centre normal leaves only the second term.
    patch = _patch([Z, _unit(15.0)])
    expected = math.exp(-1.0) * (1.0 - math.cos(math.radians(15.0)) ** 8) / (1.0 + math.exp(-1.0))
    assert normal_loss(_vec(Z), _vec(Z), patch).item() == pytest.approx(expected, rel=1e-9)


def test_valid_mask_drops_entries_and_the_batch_is_averaged() -> None:
    patches = torch.tensor([[Z, [1.0, 0.0, 0.0]], [Z, Z]], dtype=torch.float64)
    centres = torch.tensor([Z, Z], dtype=torch.float64)
    preds = torch.tensor([Z, [1.0, 0.0, 0.0]], dtype=torch.float64)
    valid = torch.tensor([[True, False], [True, True]])
    # Row 0: only the matching normal counts -> 0. Row 1: orthogonal prediction -> 1. Mean 0.5.
    assert normal_loss(preds, centres, patches, valid=valid).item() == pytest.approx(0.5)
    # Unmasked, row 0 adds the orthogonal normal with weight exp(-1 / (1 - cos 15°)).
    w = math.exp(-1.0 / (1.0 - math.cos(math.radians(15.0))))
    assert normal_loss(preds, centres, patches).item() == pytest.approx((w / (1 + w) + 1.0) / 2)


def test_normal_loss_has_gradients_for_training() -> None:
    pred = torch.tensor([_unit(20.0, 40.0)], dtype=torch.float64, requires_grad=True)
    normal_loss(pred, _vec(Z), _patch([Z, _unit(30.0)])).backward()
    assert pred.grad is not None and bool(torch.isfinite(pred.grad).all()) and pred.grad.abs().sum() > 0


@pytest.mark.parametrize("deg", [0.0, 10.0, 45.0, 89.0, 90.0, 135.0, 180.0])
def test_angle_loss_is_the_squared_sign_invariant_angle(deg: float) -> None:
    expected = math.radians(min(deg, 180.0 - deg)) ** 2
    assert angle_loss(_vec(_unit(deg, 30.0)), _vec(Z)).item() == pytest.approx(expected, abs=1e-12)


def test_angle_loss_hedges_between_two_faces_where_cos8_commits() -> None:
    """Centre on face z or face x with equal odds: the squared angle is least at the bisector, cos^8 at a face."""
    centres = torch.tensor([Z, [1.0, 0.0, 0.0]], dtype=torch.float64)
    patches = centres.unsqueeze(1)

    def mean_loss(kind: str, deg: float) -> float:
        pred = _vec(_unit(deg)).expand(2, 3)
        return patch_loss(kind, pred, centres, patches).item()

    assert mean_loss("angle", 45.0) < min(mean_loss("angle", 0.0), mean_loss("angle", 30.0))
    assert mean_loss("cos", 0.0) < min(mean_loss("cos", 45.0), mean_loss("cos", 30.0))


def test_angle_loss_gradients_are_finite_at_zero_and_right_angles() -> None:
    pred = torch.tensor([Z, [1.0, 0.0, 0.0], _unit(20.0)], dtype=torch.float64, requires_grad=True)
    angle_loss(pred, _vec(Z).expand(3, 3)).backward()
    assert torch.isfinite(pred.grad).all() and pred.grad[2].abs().sum() > 0


def test_relative_loss_weights_each_patch_by_what_pca_leaves_to_gain() -> None:
    """PCA's normal is +z in the patch frame. Prediction 10° off the truth; truth 30° off PCA, floor 10°: the weight
    is 10² / (30² + 10²) = 0.1. Where PCA is exact the weight is 1 and the loss is the squared angle."""
    pred, truth = _vec(_unit(40.0)), _vec(_unit(30.0))
    expected = 0.1 * math.radians(10.0) ** 2
    assert relative_angle_loss(pred, truth, floor_deg=10.0).item() == pytest.approx(expected, rel=1e-9)
    assert relative_angle_loss(_vec(_unit(10.0)), _vec(Z), 10.0).item() == pytest.approx(math.radians(10.0) ** 2)
    flipped = relative_angle_loss(-pred, -truth, floor_deg=10.0).item()
    assert flipped == pytest.approx(expected, rel=1e-9)


def test_relative_loss_refuses_a_floor_that_would_divide_by_zero() -> None:
    with pytest.raises(ValueError, match="floor"):
        relative_angle_loss(_vec(Z), _vec(Z), floor_deg=0.0)


def test_relative_loss_still_hedges_between_faces_pca_misses_equally() -> None:
    """An edge whose faces lie ±45° from the PCA normal: both get the same weight, so the bisector is least."""
    centres = torch.tensor([_unit(45.0), _unit(-45.0)], dtype=torch.float64)

    def loss(deg: float) -> float:
        return patch_loss("relative", _vec(_unit(deg)).expand(2, 3), centres, centres.unsqueeze(1)).item()

    assert loss(0.0) < min(loss(45.0), loss(-45.0), loss(20.0))


def test_relative_loss_leans_towards_the_face_pca_already_sits_near() -> None:
    """Faces at +20° and -70° from the PCA normal with equal odds. The squared angle is least at the midpoint, -25°;
    the relative loss weights them 5²/(20² + 5²) and 5²/(70² + 5²), so its least is the weighted mean, 12.8°."""
    centres = torch.tensor([_unit(20.0), _unit(-70.0)], dtype=torch.float64)
    grid = np.arange(-70.0, 20.01, 0.1)

    def argmin(kind: str) -> float:
        losses = [patch_loss(kind, _vec(_unit(d)).expand(2, 3), centres, centres.unsqueeze(1)).item() for d in grid]
        return float(grid[int(np.argmin(losses))])

    w = np.array([25 / (400 + 25), 25 / (4900 + 25)])
    assert argmin("angle") == pytest.approx(-25.0, abs=0.15)
    assert argmin("relative") == pytest.approx(float(w @ [20.0, -70.0] / w.sum()), abs=0.15)


def test_patch_loss_passes_the_floor_to_the_relative_loss() -> None:
    pred, truth = _vec(_unit(40.0)), _vec(_unit(30.0))
    for floor in (2.0, 10.0):
        relative = patch_loss("relative", pred, truth, truth.unsqueeze(1), floor_deg=floor).item()
        assert relative == pytest.approx(relative_angle_loss(pred, truth, floor).item(), rel=1e-12)
        assert relative < angle_loss(pred, truth).item()


def test_an_unknown_loss_name_is_refused_not_silently_replaced() -> None:
    with pytest.raises(ValueError, match="angel"):
        patch_loss("angel", _vec(Z), _vec(Z), _patch([Z]))
