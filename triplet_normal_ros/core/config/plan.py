"""Which path an estimate takes, decided once: the pool search, the survey, the kernel and the checkpoint.

Every choice the estimator makes about a cloud is made here, by `make_plan`, from its settings and three facts about
the cloud: the device type, whether it is organized (an image with more than one row) and whether that image is a range
image in its sensor's frame (`check.inspect_grid`). The estimator executes the returned `Plan`; the node's start-up
line prints it, `bench` labels its rows with it, and docs/NODE.md's path table is `plan_table()`
(docs/tools/path_table.py writes it).
"""

from __future__ import annotations

from dataclasses import dataclass

from .conventions import METHODS, PCA_DEFAULT_K
from .defaults import shipped_checkpoint
from .settings import Settings

#: How each part of a plan reads in a sentence.
_SEARCH_WORDS = {
    "kdtree": "KD-tree pools",
    "grid": "pixel-grid pools",
    "voxel": "cell-list pools",
    "none": "no pools",
}
_SURVEY_WORDS = {"window": "integral-image windows", "pool": "pool PCA", "none": "no survey"}


@dataclass(frozen=True)
class Plan:
    """What one estimate runs.

    - `kernel`: 'pca', 'learned' or 'hybrid' (the method).
    - `survey`: how every point gets its first answer: 'window' (integral images of an organized range image, O(1)
      per pixel), 'pool' (PCA of each point's pool) or 'none' (learned: the network everywhere, weighed against the
      ball's plane).
    - `search`: the pool search for the points that need pools: 'kdtree', 'grid', 'voxel', or 'none' (window pca:
      its few pixels whose window walls cut below a plane take pools from the image itself,
      `paths.range_image.ball_where_cut`).
    - `checkpoint`: the network's checkpoint (a shipped name or a path), '' for pca.
    - `engine`: which twin runs each step that has two: 'compiled' (the `*_numba` modules, on a CPU) or 'torch' (on a
      GPU). The paths read it once per call (`paths.call.Call.compiled`); only the windows name it in `steps`.
    - `scan_lines`: whether the cloud's image rows and columns are a sensor's scan lines, so that a neighbourhood on
      one of them is one scan line (a line: no normal, whatever its noise says).
    - `note`: why an organized cloud's grid was not trusted ('' when it was), for a log line.
    """

    kernel: str
    survey: str
    search: str
    checkpoint: str
    engine: str = "torch"
    scan_lines: bool = False
    note: str = ""

    @property
    def path(self) -> str:
        """One word for the path: 'window' when the survey is, else the pool search."""
        return "window" if self.survey == "window" else self.search

    @property
    def uses_range_image(self) -> bool:
        return self.survey == "window" or self.search == "grid"

    @property
    def steps(self) -> str:
        """The path in words, e.g. 'integral-image windows, KD-tree pools, checkpoint lite'."""
        parts = [_SURVEY_WORDS[self.survey]] if self.survey != "none" else []
        if self.engine == "compiled" and self.survey == "window":
            parts[0] += " (compiled)"
        if self.search != "none":
            parts.append(_SEARCH_WORDS[self.search])
        if self.checkpoint:
            parts.append(f"checkpoint {self.checkpoint}")
        return ", ".join(parts)

    def describe(self) -> str:
        """The method and its path, for logs: 'hybrid: integral-image windows, KD-tree pools, checkpoint lite'."""
        return f"{self.kernel}: {self.steps}"


def make_plan(settings: Settings, device_type: str, organized: bool, range_image: bool) -> Plan:
    """The plan for a cloud: `organized` when it comes as an image of more than one row, `range_image` when that image
    is a range image in its sensor's frame (pixel neighbours are then 3D neighbours).

    The window survey runs for pca and hybrid on a range image when `neighbours` is 'window', or 'auto' and the
    method wants the whole ball (hybrid always; pca when k is PCA_DEFAULT_K or more: a smaller k means the nearest k,
    which a window cannot give). Pools come from the grid where asked ('grid', 'window') or on a GPU under 'auto', and
    only on a range image; from cell lists when asked or on a GPU under 'auto' otherwise; else from the KD-tree, the
    fastest on a CPU (docs/RESULTS.md).
    """
    kernel = settings.method
    grid = organized and range_image
    whole_ball = kernel == "hybrid" or (settings.k or PCA_DEFAULT_K) >= PCA_DEFAULT_K
    wants_window = settings.neighbours == "window" or (settings.neighbours == "auto" and whole_ball)
    window = kernel != "learned" and grid and wants_window
    survey = "window" if window else ("none" if kernel == "learned" else "pool")
    search = "none" if window and kernel == "pca" else _pool_search(settings.neighbours, device_type, organized, grid)
    engine = "compiled" if compiled(device_type) else "torch"
    checkpoint = checkpoint_for(settings, device_type, range_image=grid)
    return Plan(kernel, survey, search, checkpoint, engine=engine, scan_lines=grid)


def _pool_search(neighbours: str, device_type: str, organized: bool, grid: bool) -> str:
    on_gpu = neighbours == "auto" and device_type == "cuda"
    if (neighbours in ("grid", "window") or on_gpu) and organized:
        if grid:
            return "grid"
        return "voxel" if on_gpu else "kdtree"
    return "voxel" if neighbours == "voxel" or on_gpu else "kdtree"


def checkpoint_for(settings: Settings, device_type: str, range_image: bool = False) -> str:
    """The checkpoint the network methods load for a cloud: the setting, or for an empty one the shipped one for the
    device and for a range image or any other cloud (`defaults.shipped_checkpoint`)."""
    if settings.method == "pca":
        return ""
    return str(settings.checkpoint) if settings.checkpoint else shipped_checkpoint(device_type, range_image)


def checkpoints_for(settings: Settings, device_type: str) -> tuple[str, ...]:
    """Every checkpoint an estimate under `settings` may load on this device type: for any other cloud first, then for
    a range image where that differs; none for pca."""
    if settings.method == "pca":
        return ()
    names = (checkpoint_for(settings, device_type), checkpoint_for(settings, device_type, range_image=True))
    return tuple(dict.fromkeys(names))


def checkpoints_in_words(settings: Settings, device_type: str) -> str:
    """`checkpoints_for` as logs and records name it: 'lite', or 'range on range images and lite otherwise'; '' for
    pca."""
    names = checkpoints_for(settings, device_type)
    return per_kind(names[0], names[-1]) if names else ""


def per_kind(other: object, ranged: object) -> str:
    """A value that may differ between range images and other clouds, in words: 'lite' where both are the same, else
    'range on range images and lite otherwise'."""
    return str(other) if other == ranged else f"{ranged} on range images and {other} otherwise"


#: The clouds `plan_table` covers: (label, organized, range image).
CLOUDS = (
    ("organized range image (a camera's or a LiDAR driver's frame)", True, True),
    ("organized, not a range image (transformed, or not in sensor order)", True, False),
    ("unorganized", False, False),
)


def plan_table(settings: Settings | None = None) -> str:
    """A markdown table of the plan for each method, cloud and device under `settings` (default: the defaults, with
    each method in turn): docs/NODE.md's "Which path runs" block is this table."""
    base = settings or Settings(method="pca")
    lines = ["| method | cloud | CPU | GPU |", "| --- | --- | --- | --- |"]
    for method in METHODS:
        chosen = base.with_values(method=method)
        for label, organized, range_image in CLOUDS:
            cells = [make_plan(chosen, device, organized, range_image).steps for device in ("cpu", "cuda")]
            lines.append(f"| `{method}` | {label} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def compiled(device_type: str) -> bool:
    """Whether a device of `device_type` runs the compiled twins (the `*_numba` modules): a CPU does; a GPU runs torch.
    The one engine rule: `make_plan` and the grid check (which runs before there is a plan) read it."""
    return device_type == "cpu"


def is_organized(shape: tuple[int, int] | None, n: int) -> bool:
    """Whether `shape` = (height, width) describes an image of the cloud's n points with more than one row."""
    return shape is not None and shape[0] > 1 and shape[0] * shape[1] == n
