"""`triplet-normal eval`: the learned estimator against PCA, measured in one run, written into docs/RESULTS.md.

Per cloud: ours at r = 5% of the bbox diagonal; PCA at the same radius; PCA at its best radius of a grid (1-10%),
chosen per cloud by MSAE against the ground truth, i.e. an oracle no real user has (it flatters PCA). PCA sees the
whole ball up to the learned method's pool of 4k nearest points, so both methods use the same neighbourhood at 5%.
Query points are a fixed-seed subset; neighbourhoods come from the whole cloud.
"""

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.config.conventions import POOL_FACTOR, RADIUS_FRACTION, bbox_diagonal
from ..errors import CloudFileError
from ..io.cloud_files import read_normals_file, read_points
from . import icp_eval, matrix_eval, segment_eval
from .metrics import QUERY_SEED, angles_rad, invalid_count, msae, query_indices, ratio_interval, rmse_deg
from .report import update_section

PCA_GRID = (0.01, 0.02, 0.03, 0.04, 0.05, 0.07, 0.10)
PCPNET_SHAPES = ("cube100k", "fandisk100k", "bunny100k", "armadillo100k")
PCPNET_NOISE = (0.0, 0.0012, 0.006, 0.012)
NOISE_SEED = 1
HEATMAP = ("fandisk100k", 0.012)
#: --quick: two validation shapes at two noise levels, two noise levels on PCPNet; for tests only.
QUICK_VAL_SHAPES, QUICK_NOISE, QUICK_POINTS = ("v_notch_block", "ellipsoid_flat"), (0.0, 0.01), 5000
QUICK_PCPNET_NOISE = (0.0, 0.012)
#: The validation clouds: points per cloud and the dataset seed (the floor redraws each CAD shape's frame from them).
VAL_POINTS, VAL_SEED = 100_000, 0
#: The noise levels pooled for the noisy-CAD target and the floor comparison (× the bbox diagonal).
CAD_POOLED = (0.005, 0.01)


@dataclass
class CloudScores:
    """Scores of ours, PCA at 5 % and PCA at its best radius on one cloud, and per-point angles for the heat map and
    the intervals."""

    shape: str
    kind: str
    noise: float
    queries: int
    ours: tuple[float, float, int]  # MSAE, RMSE°, NaN count
    pca: tuple[float, float, int]
    best: tuple[float, float, float]  # MSAE, RMSE°, radius (fraction of the diagonal)
    angles: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)  # ours, PCA 5%: rad per point
    points: np.ndarray | None = field(default=None, repr=False)  # the query points, kept where a heat map may be drawn
    floor: tuple[float, float] | None = None  # CAD only: the Bayes floor's MSAE, and its posterior expectation
    floor_angles: np.ndarray | None = field(default=None, repr=False)  # CAD only: the floor's rad² per query point


class CloudScorer:
    """Scores ours, PCA at 5 % and the best-radius PCA on a cloud; the two estimators are reused across clouds (the
    checkpoint is loaded once)."""

    def __init__(self, checkpoint: str, device: str) -> None:
        from ..core.estimator import NormalEstimator

        self.ours = NormalEstimator("learned", radius=RADIUS_FRACTION, checkpoint=checkpoint, device=device)
        self.pca = NormalEstimator("pca", radius=RADIUS_FRACTION, device=device)
        self.pca_pool = POOL_FACTOR * self.ours.k

    def score(self, points: np.ndarray, gt: np.ndarray, query: np.ndarray, diag: float) -> tuple:
        """(ours, pca@5%, best pca) scores and the per-point angles of ours and PCA 5% on one cloud; `gt` is (M, 3)
        at `query`."""
        self.ours.radius = RADIUS_FRACTION * diag
        ours, _ = self.ours.estimate(points, query)
        from scipy.spatial import cKDTree

        tree = cKDTree(points[np.isfinite(points).all(axis=1)])
        grid = {r: self._pca(points, query, r * diag, tree) for r in PCA_GRID}
        best = min(grid, key=lambda r: msae(grid[r], gt))
        pca = grid[RADIUS_FRACTION]
        angles = (angles_rad(ours, gt), angles_rad(pca, gt))
        return (
            _scores(ours, angles[0]),
            _scores(pca, angles[1]),
            (msae(grid[best], gt), rmse_deg(grid[best], gt), best),
            angles,
        )

    def _pca(self, points: np.ndarray, query: np.ndarray, radius: float, tree) -> np.ndarray:
        """PCA over the whole ball: the pool is sized to the largest ball among the queries, capped at 4k."""
        counts = tree.query_ball_point(points[query], radius, return_length=True, workers=-1)
        self.pca.radius, self.pca.k = radius, int(np.clip(np.max(counts, initial=3), 3, self.pca_pool))
        return self.pca.estimate(points, query)[0]


def _scores(pred: np.ndarray, angles: np.ndarray) -> tuple[float, float, int]:
    """MSAE, RMSE° and NaN count from per-point angles (`metrics.angles_rad`), computed once per method."""
    mse = float(np.mean(angles**2))
    return mse, float(np.degrees(np.sqrt(mse))), invalid_count(pred)


# ---------------------------------------------------------------- data sets


def validation_clouds(quick: bool):
    """The generated validation split (shapes never trained on), every noise level; normalised to diagonal 1."""
    from ..training.dataset import NOISE_LEVELS, build_dataset

    if quick:
        return build_dataset(
            "val", QUICK_POINTS, VAL_SEED, shapes=QUICK_VAL_SHAPES, noise_levels=QUICK_NOISE, progress=False
        )
    return build_dataset("val", VAL_POINTS, VAL_SEED, noise_levels=NOISE_LEVELS, progress=False)


def cad_floor(cloud, query: np.ndarray, quick: bool) -> tuple[np.ndarray, np.ndarray]:
    """The Bayes floor of one CAD validation cloud at its query points (`floor.py`): the squared angle per point and
    its posterior expectation."""
    from .floor import floor_angles, validation_surface

    surface, diagonal = validation_surface(cloud.name, QUICK_POINTS if quick else VAL_POINTS, VAL_SEED)
    return floor_angles(surface, cloud.points[query], cloud.noise * diagonal, cloud.normals[query])


def pcpnet_shapes(directory: Path, quick: bool) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, points, normals) of the PCPNet shapes; all four are required unless --quick."""
    if not directory.is_dir():
        raise CloudFileError(f"{directory}: PCPNet directory not found (pass --pcpnet-dir)")
    names = [s for s in PCPNET_SHAPES if (directory / f"{s}.xyz").is_file()]
    missing = sorted(set(PCPNET_SHAPES) - set(names))
    if (missing and not quick) or not names:
        raise CloudFileError(f"{directory}: missing PCPNet shape(s) {', '.join(missing)} (.xyz + .normals)")
    shapes = []
    for name in names:
        points = read_points(directory / f"{name}.xyz")
        normals = read_normals_file(directory / f"{name}.normals")
        if len(normals) != len(points):
            raise CloudFileError(f"{directory / name}: {len(points)} points but {len(normals)} normals")
        shapes.append((name, points, normals))
    return shapes


def pcpnet_noisy(points: np.ndarray, sigma_rel: float, diag: float) -> np.ndarray:
    """Gaussian noise with sigma = sigma_rel × the clean bbox diagonal, one fixed draw per shape (common to levels)."""
    unit = np.random.default_rng(NOISE_SEED).standard_normal(points.shape)
    return points + sigma_rel * diag * unit


# ---------------------------------------------------------------- runs


def evaluate_validation(scorer: CloudScorer, per_cloud: int, quick: bool) -> list[CloudScores]:
    from tqdm import tqdm

    results = []
    for cloud in tqdm(validation_clouds(quick), desc="eval val", unit="cloud", disable=None, file=sys.stderr):
        points = np.asarray(cloud.points, dtype=np.float64)
        query = query_indices(len(points), per_cloud)
        ours, pca, best, angles = scorer.score(points, cloud.normals[query], query, bbox_diagonal(points))
        scores = CloudScores(cloud.name, cloud.kind, cloud.noise, len(query), ours, pca, best, angles)
        if cloud.kind == "cad":
            scores.floor_angles, expected = cad_floor(cloud, query, quick)
            scores.floor = float(scores.floor_angles.mean()), float(expected.mean())
        results.append(scores)
    return results


def evaluate_pcpnet(scorer: CloudScorer, directory: Path, per_cloud: int, quick: bool) -> list[CloudScores]:
    from tqdm import tqdm

    shapes = pcpnet_shapes(directory, quick)
    levels = QUICK_PCPNET_NOISE if quick else PCPNET_NOISE
    jobs = [(shape, level) for shape in shapes for level in levels]
    results = []
    for (name, clean, normals), level in tqdm(jobs, desc="eval pcpnet", unit="cloud", disable=None, file=sys.stderr):
        diag = bbox_diagonal(clean)
        points = pcpnet_noisy(clean, level, diag)
        query = query_indices(len(points), per_cloud)
        ours, pca, best, angles = scorer.score(points, normals[query], query, diag)
        kind = "cad" if name in ("cube100k", "fandisk100k") else "smooth"
        results.append(CloudScores(name, kind, level, len(query), ours, pca, best, angles, points[query]))
    return results


def run(
    checkpoint: str | None,
    device: str,
    points_per_cloud: int,
    pcpnet_dir: Path,
    out: Path | None,
    quick: bool,
    command: str,
    sets: tuple[str, ...] = ("val", "depth", "fold", "lidar", "segment", "icp", "matrix", "pcpnet"),
) -> None:
    """Each of `sets` (all by default): tables to stdout and, with `out`, into that markdown file (plus the fandisk
    heat map with pcpnet); blocks of sets not run are left as they are."""
    from . import range_eval

    checkpoint = checkpoint or "default"  # eval scores the shipped default unless told otherwise
    per_cloud = min(points_per_cloud, 200) if quick else points_per_cloud
    if not quick and "pcpnet" in sets:
        pcpnet_shapes_present(pcpnet_dir)
    scorer = CloudScorer(checkpoint, device)
    header = _header(command, checkpoint, quick, scorer, per_cloud)

    if "val" in sets:
        start = time.perf_counter()
        val = evaluate_validation(scorer, per_cloud, quick)
        val_md = validation_markdown(val, header, time.perf_counter() - start)
        print(val_md)
        if out is not None:
            update_section(out, "eval-val", val_md)

    for kind, spec in range_eval.SETS.items():
        if kind not in sets:
            continue
        start = time.perf_counter()
        estimators = range_eval.range_estimators(checkpoint, device, radius=spec.radius, range_scale=spec.range_scale)
        scores, summary = range_eval.evaluate_set(kind, estimators, quick)
        markdown = range_eval.set_markdown(kind, scores, summary, header.split("\n")[0])
        markdown += f"\n\nWall time {(time.perf_counter() - start) / 60:.1f} min."
        print(markdown)
        if out is not None:
            update_section(out, f"eval-{kind}", markdown)

    if "segment" in sets:
        _segment_set(device, quick, header, out)
    if "icp" in sets:
        _icp_set(device, quick, header, out)
    if "matrix" in sets:
        clouds, label = validation_clouds(quick), command + (" (--quick subset: not a result)" if quick else "")
        markdown = matrix_eval.run_matrix(device, clouds, label)
        print(markdown)
        if out is not None:
            update_section(out, "eval-matrix", markdown)
    if "pcpnet" not in sets:
        return
    start = time.perf_counter()
    pcp = evaluate_pcpnet(scorer, pcpnet_dir, per_cloud, quick)
    docs = Path(out).parent if out is not None else None
    image = _heatmap(pcp, docs / "images" / "heatmap_fandisk.png") if docs is not None else None
    pcp_md = pcpnet_markdown(pcp, header, time.perf_counter() - start, image, docs)
    print(pcp_md)
    if out is not None:
        update_section(out, "eval-pcpnet", pcp_md)


def _segment_set(device: str, quick: bool, header: str, out: Path | None) -> None:
    """The segmentation sets: their table to stdout and, with `out`, into the eval-segment block beside a picture of
    each set's first frame."""
    start = time.perf_counter()
    tables, images = {}, {}
    for kind in segment_eval.SETS:
        scores, summary = segment_eval.evaluate_segments(kind, segment_eval.segment_estimators(kind, device), quick)
        tables[kind] = scores, summary
        if out is not None:
            path = Path(out).parent / "images" / f"segments_{kind}.png"
            images[kind] = segment_eval.draw_segments(kind, summary["picture"], path)
    markdown = segment_eval.segment_markdown(tables, header.split("\n")[0], images)
    markdown += f"\n\nWall time {(time.perf_counter() - start) / 60:.1f} min."
    print(markdown)
    if out is not None:
        update_section(out, "eval-segment", markdown)


def _icp_set(device: str, quick: bool, header: str, out: Path | None) -> None:
    """The registration set: its tables to stdout and, with `out`, into the eval-icp block."""
    start = time.perf_counter()
    tables = {
        kind: icp_eval.evaluate_icp(kind, icp_eval.icp_estimators(spec, device), quick)
        for kind, spec in icp_eval.SETS.items()
    }
    markdown = icp_eval.icp_markdown(tables, quick, header.split("\n")[0])
    markdown += f"\n\nWall time {(time.perf_counter() - start) / 60:.1f} min."
    print(markdown)
    if out is not None:
        update_section(out, "eval-icp", markdown)


def pcpnet_shapes_present(directory: Path) -> None:
    """Fail before the long validation run, not after it, when the PCPNet files are missing."""
    missing = pcpnet_missing(directory, quick=False)
    if missing:
        raise CloudFileError(f"{directory}: missing PCPNet shape(s) {', '.join(missing)} (pass --pcpnet-dir)")


def pcpnet_missing(directory: Path, quick: bool) -> list[str]:
    """The PCPNet shapes `directory` lacks for a run: any of the four, or with `quick` all of them (one will do)."""
    missing = [s for s in PCPNET_SHAPES if not (directory / f"{s}.xyz").is_file()]
    return missing if not quick or len(missing) == len(PCPNET_SHAPES) else []


def _heatmap(results: list[CloudScores], path: Path) -> tuple[Path, CloudScores] | None:
    """Fandisk at 1.2% (or, in a --quick subset without it, the noisiest cloud of the first shape)."""
    from .plots import error_heatmap

    chosen = next((r for r in results if (r.shape, r.noise) == HEATMAP), None)
    chosen = chosen or max((r for r in results if r.shape == results[0].shape), key=lambda r: r.noise)
    ours, pca = (np.degrees(a) for a in chosen.angles)
    errors = {"PCA (r = 5%)": pca, "ours (r = 5%)": ours}
    title = f"{chosen.shape}, noise {chosen.noise * 100:g}% of the diagonal: angular error per query point"
    return error_heatmap(path, chosen.points, errors, title, vmax=60.0), chosen


# ---------------------------------------------------------------- markdown


def _header(command: str, checkpoint: str, quick: bool, scorer: CloudScorer, per_cloud: int) -> str:
    from ..core.learned.checkpoint import checkpoint_sha256

    meta = scorer.ours.metadata
    trained_by = meta.get("training", {}).get("command") if isinstance(meta.get("training"), dict) else None
    lines = [
        f"Command: `{command}`" + (" (**--quick subset: not a result**)" if quick else ""),
        f"Checkpoint: `{checkpoint}` (sha256 {checkpoint_sha256(checkpoint)[:12]}, "
        f"k = {scorer.ours.k}"
        + (f", trained by `{trained_by}`" if trained_by else "")
        + f") · device {scorer.ours.device} · {per_cloud} query points per cloud, fixed seed "
        f"(`default_rng({QUERY_SEED}).choice`), neighbourhoods from the whole cloud · {time.strftime('%Y-%m-%d')}",
        "",
        "MSAE = mean squared angle (rad²), RMSE = sqrt(mean squared angle) (degrees), both sign-invariant; "
        "a NaN prediction (< 3 neighbours) counts as 90°. *PCA best* is an **oracle**: the radius of "
        f"{', '.join(f'{r * 100:g}' for r in PCA_GRID)}% of the diagonal with the lowest MSAE, chosen per cloud "
        "against the ground truth. PCA uses every point of the ball up to the learned method's pool (4k nearest).",
    ]
    return "\n".join(lines)


def _row(r: CloudScores, floor: bool = False) -> str:
    """One cloud's table row; with `floor`, a last cell with the floor's MSAE (CAD) or '-' (smooth, not computed)."""
    row = (
        f"| {r.shape} | {r.kind} | {r.noise * 100:g} | {r.ours[0]:.4f} | {r.pca[0]:.4f} | {r.best[0]:.4f} "
        f"({r.best[2] * 100:g}%) | {r.ours[1]:.2f} | {r.pca[1]:.2f} | {r.best[1]:.2f} | {r.ours[2]} / {r.pca[2]} |"
    )
    if not floor:
        return row
    return row + (f" {r.floor[0]:.4f} |" if r.floor is not None else " - |")


_TABLE_HEAD = (
    "| shape | kind | noise % | ours MSAE | PCA 5% MSAE | PCA best MSAE (r) | ours RMSE° | PCA 5% RMSE° "
    "| PCA best RMSE° | NaN ours / PCA |\n| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
)


def _averages(results: list[CloudScores]) -> str:
    """Mean scores per (kind, noise level), then per kind over all noise levels."""
    groups: dict[tuple[str, str], list[CloudScores]] = {}
    for r in sorted(results, key=lambda r: (r.kind, r.noise)):
        groups.setdefault((r.kind, f"{r.noise * 100:g}"), []).append(r)
    for r in sorted(results, key=lambda r: r.kind):
        groups.setdefault((r.kind, "all"), []).append(r)
    lines = [
        "| kind | noise % | clouds | ours MSAE | PCA 5% MSAE | PCA best MSAE | ours RMSE° | PCA 5% RMSE° "
        "| ours / PCA 5% (MSAE) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for (kind, noise), rs in groups.items():
        o, p, b = (float(np.mean([getattr(r, a)[0] for r in rs])) for a in ("ours", "pca", "best"))
        orm, prm = (float(np.mean([getattr(r, a)[1] for r in rs])) for a in ("ours", "pca"))
        lines.append(
            f"| {kind} | {noise} | {len(rs)} | {o:.4f} | {p:.4f} | {b:.4f} | {orm:.2f} | {prm:.2f} | {o / p:.2f} |"
        )
    return "\n".join(lines)


def _mean(results: list[CloudScores], which: str, metric: int, keep) -> float:
    values = [getattr(r, which)[metric] for r in results if keep(r)]
    return float(np.mean(values)) if values else float("nan")


def _interval(results: list[CloudScores], keep, digits: int, floor: bool = False) -> str:
    """', 95% CI lo-hi' for the ours (or, with `floor`, the floor's) / PCA MSAE ratio over the kept clouds, or ''
    without per-point angles."""
    kept = [r for r in results if keep(r) and r.angles is not None and (r.floor_angles is not None or not floor)]
    pairs = [(r.floor_angles if floor else r.angles[0] ** 2, r.angles[1] ** 2) for r in kept]
    if not pairs:
        return ""
    lo, hi = ratio_interval(pairs)
    return f", 95% CI {lo:.{digits}f}-{hi:.{digits}f}"


def _share(pca: float, method: float, floor: float) -> str:
    """How far a method went from PCA towards the floor: (PCA - method) / (PCA - floor), as a percentage."""
    return f"{(pca - method) / (pca - floor):.0%}" if pca > floor else "n/a"


def floor_markdown(results: list[CloudScores]) -> str:
    """The CAD clouds against the Bayes floor (`floor.py`): per noise level and pooled over `CAD_POOLED`, each
    method's mean MSAE as a ratio to PCA 5% beside the floor's, and its share of the way from PCA to the floor."""
    cad = [r for r in results if r.floor is not None]
    groups = [(f"{level * 100:g}", lambda r, level=level: r.noise == level) for level in sorted({r.noise for r in cad})]
    groups.append((" + ".join(f"{level * 100:g}" for level in CAD_POOLED) + " pooled", lambda r: r.noise in CAD_POOLED))
    lines = [
        "### CAD shapes against the Bayes floor",
        "",
        "The floor is the least MSAE that any estimator could reach if it knew the exact clean surface: it still sees "
        "only the noisy position of the query point, so near an edge the best answer blends the faces' normals by "
        "their likelihood (`evaluation/floor.py`: exact Gaussian face posteriors on the generator's mesh, then the "
        "normal of least expected squared angle). It is scored like the methods, at the same query points; in "
        "brackets its posterior expectation, which agrees when the posterior is right. Ratios are of mean MSAE; "
        "*share* = (PCA - method) / (PCA - floor): 0% is PCA, 100% the floor.",
        "",
        "| noise % | clouds | PCA 5% MSAE | floor MSAE (expected) | floor / PCA | ours / PCA | ours: share "
        "| PCA best / PCA | PCA best: share |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, keep in groups:
        pca, ours, best = (_mean(cad, which, 0, keep) for which in ("pca", "ours", "best"))
        floor, expected = _mean(cad, "floor", 0, keep), _mean(cad, "floor", 1, keep)
        lines.append(
            f"| {label} | {sum(map(keep, cad))} | {pca:.4f} | {floor:.4f} ({expected:.4f}) | {floor / pca:.2f} "
            f"| {ours / pca:.2f} | {_share(pca, ours, floor)} | {best / pca:.2f} | {_share(pca, best, floor)} |"
        )
    return "\n".join(lines)


def validation_markdown(results: list[CloudScores], header: str, seconds: float) -> str:
    cad_noisy = lambda r: r.kind == "cad" and r.noise in CAD_POOLED  # noqa: E731
    cad_clean = lambda r: r.kind == "cad" and r.noise == 0  # noqa: E731
    smooth = lambda r: r.kind == "smooth"  # noqa: E731
    pca_noisy = _mean(results, "pca", 0, cad_noisy)
    cad_ratio, floor_ratio = _mean(results, "ours", 0, cad_noisy) / pca_noisy, _mean(results, "floor", 0, cad_noisy)
    floor_ratio /= pca_noisy
    clean_ratio = _mean(results, "ours", 0, cad_clean) / _mean(results, "pca", 0, cad_clean)
    smooth_ratio = _mean(results, "ours", 0, smooth) / _mean(results, "pca", 0, smooth)
    cad_ci, smooth_ci = _interval(results, cad_noisy, 2), _interval(results, smooth, 4)
    floor_ci = _interval(results, cad_noisy, 2, floor=True)
    return "\n".join(
        [
            "## Accuracy on the validation set (`triplet-normal eval`)",
            "",
            header,
            f"Wall time {seconds / 60:.1f} min for {len(results)} clouds.",
            "",
            *_TARGETS_HEAD,
            f"| clean CAD: ours MSAE ≤ 0.15 × PCA 5% (the floor is 0) | ours / PCA = {clean_ratio:.2f} "
            f"| {_met(clean_ratio <= 0.15)} |",
            f"| noisy CAD (0.5%, 1%) pooled: ours MSAE ≤ 0.70 × PCA 5% | ours / PCA = {cad_ratio:.2f} (mean MSAE ratio"
            f"{cad_ci}); Bayes floor / PCA = {floor_ratio:.2f}{floor_ci} | {_met(cad_ratio <= 0.70)} |",
            f"| smooth shapes: no worse than PCA 5% | ours / PCA = {smooth_ratio:.4f}{smooth_ci} "
            f"| {_met(smooth_ratio <= 1.0)} |",
            "",
            "Intervals: 95% paired bootstrap over the query points of each cloud (1000 draws): the sampling error of "
            "the fixed query subset, not of the choice of shapes or noise draws.",
            "",
            floor_markdown(results),
            "",
            "### Averages per kind and noise level",
            "",
            _averages(results),
            "",
            "### Per cloud",
            "",
            _TABLE_HEAD.replace(" |\n", " | floor MSAE |\n", 1) + " ---: |",
            *(_row(r, floor=True) for r in results),
        ]
    )


def pcpnet_markdown(
    results: list[CloudScores],
    header: str,
    seconds: float,
    image: tuple[Path, CloudScores] | None,
    doc_dir: Path | None,
) -> str:
    targets = []
    for level in (0.006, 0.012):
        at = lambda r, level=level: r.noise == level  # noqa: E731
        ours, pca = _mean(results, "ours", 1, at), _mean(results, "pca", 1, at)
        wins = sum(r.ours[1] < r.pca[1] for r in results if at(r))
        total = sum(at(r) for r in results)
        if total:
            targets.append(
                f"| RMSE below PCA 5% at {level * 100:g}% noise | ours {ours:.2f}° vs PCA {pca:.2f}° (mean of "
                f"{total} shape(s); lower on {wins}/{total}) | {_met(ours < pca)} |"
            )
    lines = [
        "## Accuracy on the PCPNet shapes (`triplet-normal eval`)",
        "",
        header,
        f"Noise: Gaussian, sigma = 0, 0.12, 0.6, 1.2% of the clean bbox diagonal, one fixed draw per shape "
        f"(`default_rng({NOISE_SEED}).standard_normal`, scaled per level). Test data only: never trained or tuned on. "
        f"Wall time {seconds / 60:.1f} min for {len(results)} clouds.",
        "",
        *_TARGETS_HEAD,
        *targets,
        "",
        "### Per cloud",
        "",
        _TABLE_HEAD,
        *(_row(r) for r in results),
    ]
    if image is not None:
        path, chosen = image
        rel = path.relative_to(doc_dir) if path.is_relative_to(doc_dir) else path
        lines += [
            "",
            f"### Error heat map: {chosen.shape} at {chosen.noise * 100:g}% noise",
            "",
            f"![PCA vs ours, angular error in degrees]({rel.as_posix()})",
            "",
            f"Colour = sign-invariant angular error (degrees, scale clipped at 60°) at the {chosen.queries} "
            "query points; left PCA at r = 5%, right ours at r = 5%.",
        ]
    return "\n".join(lines)


_TARGETS_HEAD = ("### Targets", "", "| target | measured | met |", "| --- | --- | --- |")


def _met(ok: bool) -> str:
    return "yes" if ok else "**no**"
