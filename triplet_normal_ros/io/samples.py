"""The real frames the package ships (PCL test data, BSD; see sample_data/ATTRIBUTION.md): their names and their
arrays, without ROS, so that the demo's replay client, the offline tools and the docs' generators read the same list
from one place.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

#: Where the frames lie, as package data (the same lookup from a checkout, a venv or a colcon install).
SAMPLE_DIR = Path(str(resources.files("triplet_normal_ros") / "sample_data"))
#: The shipped organized 640x480 frames, in the order the demo, the speed tools and README's tables list them.
FRAMES = ("frame_20121214T142255", "table_scene_mug")


def sample_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
    """One shipped frame by name: xyz (h, w, 3) float32 with NaN holes and rgb (h, w) packed 0x00RRGGBB uint32."""
    path = SAMPLE_DIR / f"{name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"no sample frame {name!r} (have: {', '.join(FRAMES)})")
    with np.load(path) as data:
        xyz = np.stack([data["x"], data["y"], data["z"]], axis=-1).astype(np.float32)
        return xyz, data["rgb"].astype(np.uint32)
