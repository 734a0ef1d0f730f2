"""Helpers shared by tests in several folders, importable as ``helpers`` (test/conftest.py puts test/ on sys.path).

Only test code uses these, so they live here rather than in the package. Training-related helpers come first; add
other layers' helpers in their own section.
"""

from pathlib import Path

import numpy as np

from triplet_normal_ros.io.cloud_files import write_normals
from triplet_normal_ros.training.dataset import LabelledCloud, build_dataset

# --- training data -------------------------------------------------------------------------------------------------

#: A CAD shape of the validation catalogue: never trained on, so accuracy on it measures generalisation.
HELDOUT_SHAPE = "v_notch_block"


def heldout_cad_cloud(n_points: int = 20_000, noise: float = 0.01, seed: int = 123) -> LabelledCloud:
    """`HELDOUT_SHAPE` with `n_points` points at `noise` × its bbox diagonal, exactly as the validation set draws it
    for dataset seed `seed`: the accuracy regression tests measure the shipped checkpoint on it."""
    clouds = build_dataset("val", n_points, seed, shapes=[HELDOUT_SHAPE], noise_levels=[noise], progress=False)
    return clouds[0]


# --- point-cloud files ---------------------------------------------------------------------------------------------


def write_points(path: str | Path, points: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Write points (and optional normals) as .xyz text (`%.6f`) or, via `write_normals`, as .npy/.ply/.pcd."""
    path = Path(path)
    if path.suffix.lower() == ".xyz":
        np.savetxt(path, np.asarray(points, dtype=np.float64), fmt="%.6f")
        return
    write_normals(path, points, np.full(np.shape(points), np.nan) if normals is None else normals)
