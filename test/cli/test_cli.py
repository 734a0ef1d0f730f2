"""`triplet-normal` end to end: the installed console script in a subprocess, plus in-process error paths."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import write_points

from triplet_normal_ros.cli.main import main
from triplet_normal_ros.core.config.device import device_type
from triplet_normal_ros.core.config.plan import checkpoint_for
from triplet_normal_ros.core.config.settings import Settings
from triplet_normal_ros.evaluation.metrics import rmse_deg
from triplet_normal_ros.evaluation.range_eval import PCA_WINDOW
from triplet_normal_ros.evaluation.report import read_section, update_section
from triplet_normal_ros.io.cloud_files import read_cloud, read_normals_file

pytestmark = pytest.mark.slow  # subprocess CLI runs and eval --quick: `make test-fast` deselects this module

SCRIPT = Path(sys.executable).with_name("triplet-normal")


def run_cli(*args: str | Path, cwd: Path | None = None, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(SCRIPT), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
        env={**os.environ, **(env or {})},
    )


def commit(repo: Path, path: str) -> None:
    """`path` (below `repo`) committed to a new git repository at `repo`: a file git tracks."""
    git = ["git", "-C", str(repo), "-c", "user.name=test", "-c", "user.email=test@example.com"]
    for step in (["init", "-q"], ["add", path], ["commit", "-q", "-m", "results"]):
        subprocess.run([*git, *step], check=True, capture_output=True)


def sphere(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    normals = np.random.default_rng(seed).normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return 2.0 * normals + np.array([5.0, -1.0, 3.0]), normals


def noisy_plane(n: int = 500, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.normal(scale=0.005, size=n)])


def assert_one_error_line(stderr: str) -> None:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("triplet-normal: error: "), stderr
    assert "Traceback" not in stderr


@pytest.fixture
def sphere_xyz(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    points, normals = sphere()
    write_points(tmp_path / "ball.xyz", points)
    return tmp_path / "ball.xyz", points, normals


def test_estimate_pca_subprocess_default_out_indices_and_viewpoint(tmp_path: Path, sphere_xyz) -> None:
    path, points, gt = sphere_xyz
    done = run_cli("estimate", path, "--method", "pca", "--radius-rel", "0.3")
    assert done.returncode == 0, done.stderr
    assert "400 points, 400 estimated, 400 valid" in done.stdout
    normals = read_normals_file(tmp_path / "ball.normals")  # default OUT: IN with suffix .normals
    assert rmse_deg(normals, gt) < 5.0  # measured 3.09 deg: a ball of 0.3 x the diagonal spans much of the sphere
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)

    again = run_cli("estimate", path, "--method", "pca")
    assert again.returncode == 2
    assert_one_error_line(again.stderr)
    assert "already exists" in again.stderr

    (tmp_path / "q.pidx").write_text("7\n3\n399\n0\n")
    done = run_cli(
        "estimate", path, "--method", "pca", "--radius-rel", "0.3", "--indices", tmp_path / "q.pidx",
        "--viewpoint", "5", "-1", "3", "--out", tmp_path / "q.ply",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = read_cloud(tmp_path / "q.ply")
    np.testing.assert_allclose(out.points, points[[7, 3, 399, 0]], atol=1e-6)
    np.testing.assert_allclose(np.abs(out.normals), np.abs(normals[[7, 3, 399, 0]]), atol=1e-5)
    inward = np.einsum("ij,ij->i", out.normals, out.points - [5, -1, 3])
    assert (inward < 0).all()  # the viewpoint is the centre, so every normal faces it


def test_estimate_organized_pcd_with_nan_rows(tmp_path: Path, capsys) -> None:
    """A depth frame: organized 20 x 25, NaN where the sensor saw nothing (first pixel included)."""
    from pypcd4 import Encoding, PointCloud

    u, v = np.meshgrid(np.linspace(-1, 1, 25), np.linspace(-1, 1, 20))
    points = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 2.0)]).astype(np.float32)
    points[[0, 1, 260]] = np.nan
    cloud = PointCloud.from_points(points, ("x", "y", "z"), [np.float32] * 3)
    cloud.metadata.height, cloud.metadata.width = 20, 25
    cloud.save(tmp_path / "frame.pcd", encoding=Encoding.BINARY_COMPRESSED)
    args = ["estimate", tmp_path / "frame.pcd", "--method", "pca", "--radius", "0.3", "--viewpoint", "0", "0", "0"]
    assert main([*map(str, args), "--out", str(tmp_path / "n.pcd")]) == 0, capsys.readouterr().err
    out = read_cloud(tmp_path / "n.pcd")
    assert (out.height, out.width) == (20, 25)
    assert np.isnan(out.normals[[0, 1, 260]]).all()
    finite = np.delete(out.normals, [0, 1, 260], axis=0)
    np.testing.assert_allclose(finite, np.tile([0, 0, -1.0], (len(finite), 1)), atol=1e-4)  # facing the camera


def test_estimate_learned_with_shipped_checkpoint(tmp_path: Path) -> None:
    write_points(tmp_path / "plane.npy", noisy_plane())
    done = run_cli("estimate", tmp_path / "plane.npy", "--out", tmp_path / "plane.pcd", "--radius", "0.3")
    assert done.returncode == 0, done.stderr
    out = read_cloud(tmp_path / "plane.pcd")
    assert out.normals.shape == (500, 3)
    served = checkpoint_for(Settings(method="learned"), device_type("auto"))  # lite on a CPU: not a range image
    assert f"(learned, checkpoint {served}, radius 0.3, " in done.stdout, done.stdout
    # Measured 0.84 deg with the default checkpoint, 2.35 deg with lite (the CPU's choice where it applies).
    assert rmse_deg(out.normals, np.tile([0, 0, 1.0], (500, 1))) < 4.0


@pytest.mark.parametrize(
    ("make", "args", "status", "message"),
    [
        (None, ["estimate", "{d}/missing.xyz"], 1, "no such file"),
        ("bad.obj", ["estimate", "{d}/bad.obj"], 1, "unknown point-cloud suffix"),
        ("few.xyz", ["estimate", "{d}/few.xyz", "--method", "pca"], 1, "only 2 finite point"),
        (
            "ok.xyz",
            ["estimate", "{d}/ok.xyz", "--checkpoint", "{d}/none.safetensors", "--out", "{d}/o.npy"],
            1,
            "not found",
        ),
        ("ok.xyz", ["estimate", "{d}/ok.xyz", "--out", "{d}/o.txt"], 2, "unknown output suffix"),
        ("ok.xyz", ["estimate", "{d}/ok.xyz", "--radius", "1", "--radius-rel", "0.1"], 2, "not allowed with"),
        ("ok.xyz", ["estimate", "{d}/ok.xyz", "--k", "2"], 2, "--k must be an integer >= 3"),
        ("ok.xyz", ["estimate", "{d}/ok.xyz", "--device", "gpu7"], 2, "device must be"),
        (None, ["frobnicate"], 2, "invalid choice"),
    ],
)
def test_errors_are_one_line_with_status(tmp_path: Path, capsys, make, args, status, message) -> None:
    if make == "few.xyz":
        (tmp_path / make).write_text("0 0 0\n1 1 1\n")
    elif make == "ok.xyz":
        write_points(tmp_path / make, sphere(50)[0])
    elif make:
        (tmp_path / make).write_text("v 0 0 0\n")
    assert main([a.format(d=tmp_path) for a in args]) == status
    err = capsys.readouterr().err
    assert_one_error_line(err)
    assert message in err


def test_missing_checkpoint_subprocess_exits_nonzero_with_one_line(tmp_path: Path) -> None:
    write_points(tmp_path / "ok.xyz", sphere(50)[0])
    done = run_cli("estimate", tmp_path / "ok.xyz", "--checkpoint", tmp_path / "nope.safetensors")
    assert done.returncode == 1
    assert_one_error_line(done.stderr)
    assert not (tmp_path / "ok.normals").exists()


def test_update_section_replaces_only_its_block(tmp_path: Path) -> None:
    doc = tmp_path / "RESULTS.md"
    update_section(doc, "bench", "old bench")
    update_section(doc, "train", "training log")
    update_section(doc, "bench", "new bench\n\n| a |")
    text = doc.read_text()
    assert "old bench" not in text and text.count("<!-- BEGIN bench -->") == 1
    assert read_section(doc, "bench") == "new bench\n\n| a |"
    assert read_section(doc, "train") == "training log"
    assert text.index("BEGIN bench") < text.index("BEGIN train")  # replaced in place, not re-appended


def test_eval_sets_rewrites_only_the_chosen_blocks(tmp_path: Path) -> None:
    """--sets lidar runs the LiDAR scans alone: no PCPNet directory needed, every other block left as it was; a file
    git tracks is rewritten with --update-tracked, and no line mentions the sets not asked for."""
    doc = tmp_path / "docs" / "RESULTS.md"
    for block in ("eval-val", "eval-depth", "eval-fold", "eval-lidar", "eval-segment", "eval-pcpnet"):
        update_section(doc, block, "kept")
    commit(tmp_path, "docs/RESULTS.md")
    done = run_cli(
        "eval", "--quick", "--sets", "lidar", "--pcpnet-dir", tmp_path / "absent", "--out", doc, "--update-tracked",
        env={"TRIPLET_NORMAL_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "pcpnet" not in done.stderr
    assert "radius 0.25 m" in read_section(doc, "eval-lidar")
    kept = ("eval-val", "eval-depth", "eval-fold", "eval-segment", "eval-pcpnet")
    assert [read_section(doc, b) for b in kept] == ["kept"] * 5


def test_eval_default_sets_skip_pcpnet_without_its_data(tmp_path: Path) -> None:
    """Without --sets every set runs, less pcpnet when --pcpnet-dir lacks its shapes: one stderr line says so, and the
    pcpnet block is left as it was."""
    doc = tmp_path / "docs" / "RESULTS.md"
    update_section(doc, "bench", "kept")
    update_section(doc, "eval-pcpnet", "kept")
    absent = tmp_path / "absent"
    done = run_cli(
        "eval", "--quick", "--pcpnet-dir", absent, "--out", doc, env={"TRIPLET_NORMAL_CACHE": str(tmp_path / "cache")}
    )
    assert done.returncode == 0, done.stderr
    assert [line for line in done.stderr.splitlines() if "pcpnet" in line] == [
        f"triplet-normal eval: skipping pcpnet: {absent} lacks cube100k, fandisk100k, bunny100k, armadillo100k "
        "(PCPNet does not ship; pass --pcpnet-dir DIR)"
    ]
    val = read_section(doc, "eval-val")
    assert "| v_notch_block | cad | 1 |" in val and "smooth shapes: no worse than PCA 5%" in val
    assert "| 0.5 + 1 pooled | 1 |" in val  # the CAD clouds against the Bayes floor
    assert val.count("95% CI ") == 3  # both target ratios and the Bayes floor's ratio carry their bootstrap interval
    assert read_section(doc, "bench") == "kept" and read_section(doc, "eval-pcpnet") == "kept"
    for kind, radius in (("depth", "0.05 m"), ("fold", "0.05 m"), ("lidar", "0.25 m")):  # the simulated range images
        block = read_section(doc, f"eval-{kind}")
        assert block is not None and f"radius {radius}" in block
        cells = [[c.strip() for c in line.split("|")[1:-1]] for line in block.splitlines() if line.startswith("| ")]
        names = cells[0]  # the header row: each check reads its column by name
        rows = {c[0]: dict(zip(names, c, strict=True)) for c in cells[2:]}
        assert rows["learned"]["/ learned"] == "1.000"  # every row is also a ratio to learned
        share = rows["hybrid (F > 10, bend > 0.03)"]["network share"]
        assert share.endswith("%") and 0 <= float(share[:-1]) < 100  # hybrid says how much went to the network
        assert rows["learned"]["network share"] == "100.0%" and rows["PCA, k = 30"]["network share"] == "-"
        ball = rows["hybrid, lite, ball survey"]["network share"]  # each hybrid also runs with the ball survey
        assert ball.endswith("%") and 0 <= float(ball[:-1]) < 100
        answered = rows[PCA_WINDOW]["answered"]
        assert answered.endswith("%") and 50 < float(answered[:-1]) <= 100  # the share with a normal
    segments = read_section(doc, "eval-segment")  # planar segmentation of the fold frames and the LiDAR scans
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in segments.splitlines() if line.startswith("| ")]
    rows = {(c[0].split()[0], c[1]): c for c in cells[2:]}
    for kind in ("close-range", "LiDAR"):
        exact = rows[(kind, "exact normals (the reference)")]
        segments_counted = {"close-range": "100% (4 of 4)", "LiDAR": "100% (2 of 2)"}[kind]  # the quick frames'
        assert exact[2:6] == ["1.000", "1.000", segments_counted, "100.0%"]
        ari = float(rows[(kind, "PCA, k = 30")][2])
        assert -1.0 <= ari < 1.0  # scattered normals cost segments
        answered = rows[(kind, "hybrid, no checkpoint named (the node's default)")][5]
        assert answered.endswith("%") and 50 < float(answered[:-1]) <= 100
    for kind in ("fold", "lidar"):
        assert f"images/segments_{kind}.png" in segments
        assert (doc.parent / "images" / f"segments_{kind}.png").stat().st_size > 10_000
    matrix = read_section(doc, "eval-matrix")  # every shipped checkpoint, both methods, against PCA per regime
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in matrix.splitlines() if line.startswith("| ")]
    header, rows = cells[0], {c[0]: c for c in cells[2:]}
    assert "learned, `lite` (CPU default)" in header and "hybrid, `default` (GPU default)" in header
    assert "hybrid, `range`" in header and "PCA over `lite`'s pool" in header and len(header) == 3 + 6 + 2
    assert set(rows) == {"CAD parts, clean", "CAD parts, 0.5 and 1 % noise", "smooth shapes, 0-1 % noise"}
    assert all(0 < float(ratio.split()[0]) < 10 for row in rows.values() for ratio in row[3:])


def test_eval_quick_pcpnet_writes_its_block_and_heatmap(tmp_path: Path) -> None:
    pcpnet = tmp_path / "pcpnet"
    pcpnet.mkdir()
    points, normals = sphere(3000, seed=1)
    np.savetxt(pcpnet / "fandisk100k.xyz", points, fmt="%.6f")
    np.savetxt(pcpnet / "fandisk100k.normals", normals, fmt="%.6f")
    doc = tmp_path / "docs" / "RESULTS.md"
    update_section(doc, "eval-val", "kept")
    done = run_cli("eval", "--quick", "--sets", "pcpnet", "--pcpnet-dir", pcpnet, "--out", doc)
    assert done.returncode == 0, done.stderr
    pcp = read_section(doc, "eval-pcpnet")
    assert "| fandisk100k | cad | 1.2 |" in pcp and "images/heatmap_fandisk.png" in pcp
    assert read_section(doc, "eval-val") == "kept"
    assert (doc.parent / "images" / "heatmap_fandisk.png").stat().st_size > 10_000


def test_eval_pcpnet_named_without_its_data_fails_before_working(tmp_path: Path) -> None:
    done = run_cli("eval", "--sets", "val,pcpnet", "--pcpnet-dir", tmp_path / "absent", "--out", tmp_path / "R.md")
    assert done.returncode == 1
    assert_one_error_line(done.stderr)
    assert "missing PCPNet shape(s)" in done.stderr
    assert not (tmp_path / "R.md").exists()


@pytest.mark.parametrize("command", [["eval", "--sets", "val"], ["bench", "--method", "pca"], ["ablate"]])
def test_out_refuses_a_file_git_tracks_unless_asked(tmp_path: Path, command: list[str]) -> None:
    """--out on a tracked file is one error line before any work, naming --update-tracked; the file is untouched."""
    doc = tmp_path / "RESULTS.md"
    update_section(doc, "eval-val", "kept")
    commit(tmp_path, "RESULTS.md")
    before = doc.read_text()
    done = run_cli(*command, "--out", doc)
    assert done.returncode == 2
    assert_one_error_line(done.stderr)
    assert f"--out {doc} is tracked by git; pass --update-tracked" in done.stderr
    assert doc.read_text() == before and done.stdout == ""
