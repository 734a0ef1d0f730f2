"""Where the network's answer stands against the ball's plane (`core/learned/trust.py`)."""

import math

import numpy as np
import pytest
import torch

from triplet_normal_ros.core.learned.trust import DEPARTS_Z, Plane, plane_error, settle


def _tilted(degrees: float) -> torch.Tensor:
    """The unit vector `degrees` away from +z towards +x."""
    angle = math.radians(degrees)
    return torch.tensor([[math.sin(angle), 0.0, math.cos(angle)]], dtype=torch.float64)


Z = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
EIGVALS = torch.tensor([[1e-4, 0.25, 0.25]], dtype=torch.float64)  # a disc of unit radius, 1 % noise
COUNT = torch.tensor([256])
NOISE = torch.tensor([1e-4], dtype=torch.float64)
YES, NO = torch.tensor([True]), torch.tensor([False])


def test_the_standard_error_is_andersons_and_grows_without_bound_as_the_plane_dissolves() -> None:
    error = plane_error(EIGVALS, COUNT, NOISE)
    assert float(error[0]) == pytest.approx(np.sqrt(1e-4 * 0.25 / 256) / (0.25 - 1e-4), rel=1e-12)  # about 0.036°
    assert float(plane_error(EIGVALS, torch.tensor([1024]), NOISE)[0]) < float(error[0])  # more points, less error
    assert float(plane_error(EIGVALS, COUNT, torch.tensor([0.2], dtype=torch.float64))[0]) > 100 * float(error[0])
    assert plane_error(EIGVALS, COUNT, torch.tensor([0.25], dtype=torch.float64))[0] == math.inf  # no plane at all


def test_the_network_stands_only_where_it_departs_beyond_noise() -> None:
    limit = math.degrees(DEPARTS_Z * float(plane_error(EIGVALS, COUNT, NOISE)[0]))
    plane = Plane(Z, EIGVALS, YES)
    for degrees, stands in ((0.5 * limit, False), (2 * limit, True), (30.0, True)):
        normal, valid = settle(_tilted(degrees), YES, plane, plane, COUNT, NOISE)
        assert bool(valid[0])
        assert torch.equal(normal, _tilted(degrees) if stands else Z), degrees
    normal, _ = settle(_tilted(30.0), NO, plane, plane, COUNT, NOISE)  # where the network did not run
    assert torch.equal(normal, Z)


def test_noise_widens_what_counts_as_agreement() -> None:
    plane, noisy = Plane(Z, EIGVALS, YES), torch.tensor([0.04], dtype=torch.float64)  # 20 % noise on the same disc
    assert torch.equal(settle(_tilted(2.0), YES, plane, plane, COUNT, NOISE)[0], _tilted(2.0))
    assert torch.equal(settle(_tilted(2.0), YES, plane, plane, COUNT, noisy)[0], Z)


def test_where_the_ball_gives_no_plane_the_network_or_the_pool_answers() -> None:
    nothing = Plane(torch.full_like(Z, torch.nan), EIGVALS, NO)
    pool = Plane(_tilted(1.0), EIGVALS, YES)
    assert torch.equal(settle(_tilted(30.0), YES, nothing, pool, COUNT, NOISE)[0], _tilted(30.0))
    normal, valid = settle(_tilted(30.0), NO, nothing, pool, COUNT, NOISE)
    assert torch.equal(normal, _tilted(1.0)) and bool(valid[0])
    assert not bool(settle(_tilted(30.0), NO, nothing, Plane(Z, EIGVALS, NO), COUNT, NOISE)[1][0])


def test_the_pool_plane_answers_where_the_ball_reaches_a_crease_the_pool_does_not() -> None:
    pool = Plane(Z, EIGVALS, YES)  # a flat, clean pool ...
    creased = Plane(_tilted(5.0), torch.tensor([[4e-4, 0.3, 0.4]], dtype=torch.float64), YES)  # ... its ball tilted
    assert torch.equal(settle(Z, NO, creased, pool, COUNT, NOISE)[0], Z)
    smooth = Plane(_tilted(5.0), torch.tensor([[1.5e-4, 0.3, 0.4]], dtype=torch.float64), YES)  # residual < 3 × pool's
    assert torch.equal(settle(Z, NO, smooth, pool, COUNT, NOISE)[0], _tilted(5.0))
    agreeing = Plane(_tilted(0.01), torch.tensor([[4e-4, 0.3, 0.4]], dtype=torch.float64), YES)  # within noise
    assert torch.equal(settle(Z, NO, agreeing, pool, COUNT, NOISE)[0], _tilted(0.01))
