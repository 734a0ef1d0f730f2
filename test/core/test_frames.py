"""The PCA frame: a proper rotation whose z is the smallest-variance axis, x the second; R^-1 restores the normal."""

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from triplet_normal_ros.core.learned.patches import build_patches, to_world
from triplet_normal_ros.core.pca.frames import masked_covariance, principal_frames, surface_variation
from triplet_normal_ros.core.search.neighbours import NeighbourIndex

# Quaternions from four bounded floats reach the identity, half turns and everything between, and shrink well.
_QUATERNIONS = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.2)


def _rotation(quaternion: list[float]) -> np.ndarray:
    w, x, y, z = quaternion  # scalar-first, as drawn; scipy normalises
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def _anisotropic_patches(seed: int, batch: int = 32, size: int = 30) -> torch.Tensor:
    """Random patches with well separated principal variances in random directions."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(batch, 3, 3)))
    pts = rng.normal(size=(batch, size, 3)) * np.array([1.0, 0.5, 0.1]) @ q
    return torch.from_numpy(pts)


@given(seed=st.integers(0, 2**31 - 1))
@settings(max_examples=20, deadline=None)
def test_frame_is_a_proper_rotation_with_z_smallest_and_x_second(seed: int) -> None:
    pts = _anisotropic_patches(seed)
    mask = torch.ones(pts.shape[:2], dtype=torch.bool)
    eigvals, rot = principal_frames(masked_covariance(pts, mask), torch.ones(len(pts), dtype=torch.bool))
    eye = torch.eye(3, dtype=rot.dtype).expand_as(rot)
    torch.testing.assert_close(rot @ rot.transpose(1, 2), eye, atol=1e-10, rtol=0)
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(len(rot), dtype=rot.dtype), atol=1e-10, rtol=0)
    assert bool((eigvals[:, :-1] <= eigvals[:, 1:]).all())
    ref_vals, ref_vecs = np.linalg.eigh(np.stack([np.cov(p.T, bias=True) for p in pts.numpy()]))
    np.testing.assert_allclose(eigvals.numpy(), ref_vals, rtol=1e-9, atol=1e-12)
    # Each frame axis equals numpy's eigenvector up to sign: z <- smallest, x <- second.
    np.testing.assert_allclose(np.abs(np.einsum("bi,bi->b", rot[:, 2].numpy(), ref_vecs[:, :, 0])), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.einsum("bi,bi->b", rot[:, 0].numpy(), ref_vecs[:, :, 1])), 1.0, atol=1e-9)
    # In its own frame the patch covariance is diagonal with ascending variances along x, y, z reversed.
    local_cov = rot @ masked_covariance(pts, mask) @ rot.transpose(1, 2)
    np.testing.assert_allclose(local_cov.numpy(), np.stack([np.diag(v[[1, 2, 0]]) for v in ref_vals]), atol=1e-9)


def test_masked_covariance_ignores_masked_entries() -> None:
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(2, 10, 3))
    mask = np.ones((2, 10), dtype=bool)
    mask[0, 6:] = False
    pts[0, 6:] = 1e6  # garbage where masked: must not leak into the covariance
    cov = masked_covariance(torch.from_numpy(pts), torch.from_numpy(mask)).numpy()
    np.testing.assert_allclose(cov[0], np.cov(pts[0, :6].T, bias=True), atol=1e-12)
    np.testing.assert_allclose(cov[1], np.cov(pts[1].T, bias=True), atol=1e-12)


def test_invalid_rows_get_the_identity_even_from_nan_covariances() -> None:
    cov = torch.full((2, 3, 3), float("nan"), dtype=torch.float64)
    cov[1] = torch.diag(torch.tensor([3.0, 1.0, 2.0], dtype=torch.float64))
    eigvals, rot = principal_frames(cov, torch.tensor([False, True]))
    assert torch.isfinite(rot).all() and torch.isfinite(eigvals).all()
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(2, dtype=torch.float64))
    # The valid row: smallest variance along world y, second along world z.
    torch.testing.assert_close(rot[1, 2].abs(), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(rot[1, 0].abs(), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))


def test_surface_variation_of_known_spectra() -> None:
    eigvals = torch.tensor([[0.0, 1.0, 2.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 2.0, 7.0]], dtype=torch.float64)
    torch.testing.assert_close(surface_variation(eigvals), torch.tensor([0.0, 1 / 3, 0.0, 0.1], dtype=torch.float64))


@given(quaternion=_QUATERNIONS)
@settings(max_examples=30, deadline=None)
def test_inverse_rotation_restores_the_normal_of_a_rotated_plane(quaternion: list[float]) -> None:
    q = _rotation(quaternion)
    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-1, 1, (300, 2)), np.zeros(300)]
    cloud = plane @ q.T
    normal = q[:, 2]
    centres = np.arange(0, 300, 10)
    pool, _ = NeighbourIndex(cloud).ball(cloud[centres], 0.4, 64)
    patches = build_patches(torch.from_numpy(cloud), torch.from_numpy(cloud[centres]), torch.from_numpy(pool), 0.4, 16)
    assert bool(patches.valid.all())
    # In the patch frame the plane is z = 0, so the local normal is +-z ...
    assert float(patches.points[..., 2].abs().max()) < 1e-5
    # ... and R^-1 maps +z and -z back onto the plane normal (up to sign).
    for sign in (1.0, -1.0):
        local = torch.tensor([[0.0, 0.0, sign]]).expand(len(centres), 3)
        world = to_world(local, patches.rotation).numpy()
        np.testing.assert_allclose(np.abs(world @ normal), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(patches.pca_normal.numpy() @ normal), 1.0, atol=1e-9)
