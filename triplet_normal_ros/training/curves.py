"""The training-curve figure of a run (run-dir/training_curves.png, and docs/images/training_curves.png)."""

from pathlib import Path

TITLES = {
    "encoder": "(a) triplet loss",
    "regressor": "(b) normal loss, frozen encoder",
    "finetune": "(c) normal loss, end to end",
}


def plot_curves(history: list[dict], path: Path) -> None:
    """One panel per phase that ran (phase (c) is off in every preset), train and validation loss per epoch."""
    import matplotlib  # only here: training must not need a display, and importing the trainer stays cheap

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    phases = [p for p in TITLES if any(h["phase"] == p for h in history)] or ["regressor"]
    fig, axes = plt.subplots(1, len(phases), figsize=(4.7 * len(phases), 3.6), squeeze=False)
    for ax, phase in zip(axes[0], phases, strict=True):
        rows = [h for h in history if h["phase"] == phase]
        if rows:
            epochs = [h["epoch"] + 1 for h in rows]
            ax.plot(epochs, [h["train"] for h in rows], "o-", label="train")
            ax.plot(epochs, [h["val"] for h in rows], "s-", label="validation")
            ax.legend()
            ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(TITLES[phase])
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
