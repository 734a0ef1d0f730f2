"""Where hybrid's window survey loses to the ball survey on fold scenes: MSAE split by what answered each pixel and by
whether it lies within the radius of another face, on frames eval never scores.

Frames: the six close-range fold scenes of `simulation.fold_scenes`, seed 100 (eval scores seed 0), whole frames,
hybrid with the given checkpoint, r = 5 cm. Each pixel is put in one group by the window survey's own cue (recorded
from `hybrid.survey_and_cue` and `hybrid.survey_on_slope` as the estimate runs): gated (both the z and the bend past
the gate in the first window or in the fitted one, the network answers), or left to the survey, split into away from
edges and, near edges, by which of the two cues passed. For each group: its share of the valid pixels, the MSAE of
the window survey's hybrid, of the ball survey's (`neighbours: kdtree`), and of the network alone (`learned`) on the
near-edge groups; in brackets each group's part of the frames' MSAE. A missing normal counts as 90°. A second table
gives, for the near-edge groups, the MSAE of PCA of the same windows, of PCA of the nearest 512 points (`pca`, k =
512, the KD-tree) and the share of windows over 400 points.

Run: .venv/bin/python docs/tools/fold_gap.py [--checkpoint lite]   (about 2 minutes on 2 quiet CPU cores)
"""

from __future__ import annotations

import argparse

import numpy as np

from triplet_normal_ros.core.config.conventions import DEPTH_RADIUS
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.core.paths import range_image as hybrid
from triplet_normal_ros.core.range_image.survey import PART_SPAN, window_z
from triplet_normal_ros.evaluation.metrics import angles_rad
from triplet_normal_ros.simulation.range_scans import fold_frames

SEED = 100
GROUPS = (
    "gated",
    "away from edges",
    "near edges: z only",
    "near edges: bend only",
    "near edges: neither, each in another window, or a thin window",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="lite")
    args = parser.parse_args()
    cue = _record_cue()
    estimators = {
        survey: NormalEstimator("hybrid", radius=DEPTH_RADIUS, checkpoint=args.checkpoint, device="cpu", **options)
        for survey, options in (("window", {}), ("ball", {"neighbours": "kdtree"}))
    }
    alone = NormalEstimator("learned", radius=DEPTH_RADIUS, checkpoint=args.checkpoint, device="cpu")
    pool_pca = NormalEstimator("pca", radius=DEPTH_RADIUS, k=512, neighbours="kdtree", device="cpu")
    # pixels; window, ball survey, network, window PCA and nearest-512 PCA squared errors; windows over 400 points
    sums = {group: np.zeros(7) for group in GROUPS}
    total = 0
    for frame in fold_frames(6, seed=SEED):
        points, shape = frame.points.reshape(-1, 3), frame.points.shape[:2]
        valid, exact = frame.valid.reshape(-1), frame.normals.reshape(-1, 3)
        errors = {}
        for survey, estimator in estimators.items():
            cue.clear()
            normals, _ = estimator.estimate(points, shape=shape)
            errors[survey] = _squared(normals, exact)
            if survey == "window":
                if len(cue.get("z", ())) != len(points):
                    raise SystemExit("a fold frame did not take the window survey: its grid was refused")
                groups = _groups(cue, frame.near_edge.reshape(-1), estimator.gate, estimator.bend)
                window_pca, large = _squared(cue["normal"], exact), cue["count"] > 400
        edge_rows = np.flatnonzero(valid & frame.near_edge.reshape(-1))
        network, nearest = np.full(len(points), np.nan), np.full(len(points), np.nan)
        network[edge_rows] = _squared(alone.estimate(points, edge_rows, shape=shape)[0], exact[edge_rows])
        nearest[edge_rows] = _squared(pool_pca.estimate(points, edge_rows, shape=shape)[0], exact[edge_rows])
        for group, mask in groups.items():
            rows = mask & valid
            sums[group] += [
                rows.sum(), *(e[rows].sum() for e in (errors["window"], errors["ball"], network, window_pca, nearest)),
                large[rows].sum(),
            ]  # fmt: skip
        total += valid.sum()
    print(f"fold scenes, seed {SEED}, 6 whole frames, hybrid, {args.checkpoint}, r = {DEPTH_RADIUS} m")
    print("| pixels | share | window survey | ball survey | the network alone |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for group, (n, window, ball, network, *_) in sums.items():
        alone_text = f"{network / n:.4f}" if group.startswith("near") and n else "-"
        print(
            f"| {group} | {n / total:.1%} | {window / max(n, 1):.4f} ({window / total:.5f}) "
            f"| {ball / max(n, 1):.4f} ({ball / total:.5f}) | {alone_text} |"
        )
    print("\n| near-edge pixels | PCA of the window | PCA of the nearest 512 | windows over 400 points |")
    print("| --- | ---: | ---: | ---: |")
    for group, (n, *_, window_pca, nearest, large) in sums.items():
        if group.startswith("near") and n:
            print(f"| {group} | {window_pca / n:.4f} | {nearest / n:.4f} | {large / n:.0%} |")
    window, ball = (sum(v[i] for v in sums.values()) / total for i in (1, 2))
    print(f"all valid pixels: window survey {window:.5f}, ball survey {ball:.5f}")


def _record_cue() -> dict:
    """The window survey's fit and the cues its gate reads in the last estimate (the first windows' and the fitted
    ones'), recorded by wrapping `hybrid.survey_and_cue` and `hybrid.survey_on_slope`."""
    cue: dict = {}
    first, fitted = hybrid.survey_and_cue, hybrid.survey_on_slope

    def recording(image, fit):
        survey, structure = first(image, fit)
        cue.update(z=structure.z.numpy().copy(), bend=structure.bend.numpy().copy(), valid=fit.valid.numpy().copy())
        cue.update(normal=fit.normal.numpy().copy(), count=fit.count.numpy().copy())
        cue["box"] = [side.numpy().copy() for side in fit.box]
        return survey, structure

    def recording_fitted(image, fit, survey, structure):
        normal, sloped = fitted(image, fit, survey, structure)
        cue.update(fitted_z=sloped.z.numpy().copy(), fitted_bend=sloped.bend.numpy().copy())
        return normal, sloped

    hybrid.survey_and_cue, hybrid.survey_on_slope = recording, recording_fitted
    return cue


def _groups(cue: dict, near_edge: np.ndarray, gate: float, bend: float) -> dict[str, np.ndarray]:
    """GROUPS as masks, by the window gate's own rule (`hybrid.window_hybrid`: either window's parts past both the z
    and the bend); the near-edge pixels it leaves to the survey by which cue passed in either window (a pixel whose z
    passed in one window and its bend in the other counts with "neither"); thin windows take the pool path and count
    with the survey's groups, as their answer is not the lattice's."""
    top, bottom, left, right = cue["box"]
    thin = (bottom - top < PART_SPAN - 1) | (right - left < PART_SPAN - 1) | ~cue["valid"]
    z = [cue[name] > window_z(gate) for name in ("z", "fitted_z")]
    bent = [cue[name] > bend for name in ("bend", "fitted_bend")]
    gated = ~thin & ((z[0] & bent[0]) | (z[1] & bent[1]))
    near = ~gated & near_edge
    z_any, bent_any = z[0] | z[1], bent[0] | bent[1]
    z_only, bend_only = near & ~thin & z_any & ~bent_any, near & ~thin & ~z_any & bent_any
    return {
        "gated": gated,
        "away from edges": ~gated & ~near_edge,
        "near edges: z only": z_only,
        "near edges: bend only": bend_only,
        "near edges: neither, each in another window, or a thin window": near & ~z_only & ~bend_only,
    }


def _squared(normals: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Squared sign-invariant angle per point, a missing normal as 90°."""
    angles = angles_rad(normals, exact)
    return np.where(np.isfinite(angles), angles, np.pi / 2) ** 2


if __name__ == "__main__":
    main()
