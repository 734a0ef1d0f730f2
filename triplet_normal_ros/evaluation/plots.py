"""Pictures for docs/: angular-error heat maps (matplotlib, headless Agg backend)."""

from pathlib import Path

import numpy as np

#: A 3-D scatter of more points than this is unreadable and slow; a fixed-seed subset is drawn instead.
MAX_SCATTER = 20_000


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def error_heatmap(
    path: str | Path,
    points: np.ndarray,
    errors_deg: dict[str, np.ndarray],
    title: str,
    vmax: float | None = None,
) -> Path:
    """One 3-D scatter panel per method, coloured by angular error (degrees) on one shared colour bar.

    A shared scale is the point: PCA's smeared edges and the network's sharp ones are compared by colour.
    """
    plt = _pyplot()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    keep = _subset(len(points))
    vmax = vmax or float(max(np.percentile(e, 99) for e in errors_deg.values()) or 1.0)
    fig = plt.figure(figsize=(5.2 * len(errors_deg) + 1.0, 5.2), dpi=110)
    scatter = None
    for i, (name, errors) in enumerate(errors_deg.items()):
        ax = fig.add_subplot(1, len(errors_deg), i + 1, projection="3d")
        p, e = points[keep], np.asarray(errors)[keep]
        scatter = ax.scatter(*p.T, c=e, cmap="turbo", vmin=0, vmax=vmax, s=_marker_size(len(p)), linewidths=0)
        ax.set_title(f"{name}: RMSE {np.sqrt(np.mean(np.square(errors))):.1f}°")
        _equal_axes(ax, p)
    fig.suptitle(title)
    fig.colorbar(scatter, ax=fig.axes, shrink=0.7, label="angular error (degrees, sign-invariant)")
    fig.savefig(path)
    plt.close(fig)
    return path


def _marker_size(n: int) -> float:
    """Dots of about constant total ink: 200 points stay visible, 20k do not blot each other out."""
    return float(np.clip(6000 / max(n, 1), 1.0, 12.0))


def _subset(n: int) -> np.ndarray:
    return np.arange(n) if n <= MAX_SCATTER else np.sort(np.random.default_rng(0).choice(n, MAX_SCATTER, replace=False))


def _equal_axes(ax, points: np.ndarray) -> None:
    finite = points[np.isfinite(points).all(axis=1)]
    if len(finite):
        centre, half = finite.mean(axis=0), (finite.max(axis=0) - finite.min(axis=0)).max() / 2 or 1.0
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))


def labelled_panels(path: str | Path, rows: list[list[tuple[str, np.ndarray]]], title: str = "") -> Path:
    """A grid of (label, RGB image) panels, one row per frame, every panel titled: which method, which radius.

    Pictures that compare methods must say what each panel is; a bare side-by-side invites the wrong comparison.
    """
    plt = _pyplot()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    height, width = rows[0][0][1].shape[:2]
    scale = 4.2 / width * 100
    fig, axes = plt.subplots(
        n_rows, n_cols, figsize=(n_cols * width * scale / 100, n_rows * (height * scale / 100 + 0.35)), squeeze=False
    )
    for ax_row, row in zip(axes, rows, strict=True):
        for ax, (label, image) in zip(ax_row, row, strict=False):
            ax.imshow(image)
            ax.set_title(label, fontsize=9)
        for ax in ax_row:
            ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
