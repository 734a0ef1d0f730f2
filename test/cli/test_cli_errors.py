"""Every expected CLI failure is one line: `triplet-normal: error: ...` on stderr, nothing on stdout, no traceback.

Each subcommand is run through `cli.main.main` with bad values (rejected before any work: no training, no eval run)
and `estimate` with empty, unreadable and cut-short files of every format; one case runs as a real process of the
installed console script, to prove that no warning or traceback reaches the terminal. Every command whose options
need an optional module runs as a real process with that module unimportable (a package on PYTHONPATH, ahead of the
installed one, that raises what the interpreter raises for a missing module): one line naming the module and the pip
extra that installs it, before any work.
"""

import ast
import os
import struct
import subprocess
import sys
from importlib import metadata
from pathlib import Path, PurePath

import numpy as np
import pytest
from helpers import write_points
from pypcd4 import Encoding, PointCloud

from triplet_normal_ros.cli.main import DISTRIBUTIONS, ROS_MODULES, main
from triplet_normal_ros.core.config.conventions import PCA_DEFAULT_K
from triplet_normal_ros.io.cloud_files import write_normals

SCRIPT = Path(sys.executable).with_name("triplet-normal")
#: If a bad train value were not rejected, this budget keeps the run it would start small (seconds, not hours).
TINY_TRAIN = [
    "--shapes", "sphere", "--val-shapes", "blob_d", "--encoder-epochs", "0", "--regressor-epochs", "0",
    "--finetune-epochs", "0", "--patches-per-shape", "1", "--val-patches-per-cloud", "1", "--n-points", "2000",
]  # fmt: skip


def assert_one_error_line(out: str, err: str) -> None:
    assert out == "", f"stdout must stay empty on failure, got {out!r}"
    assert "Traceback" not in err and "Warning" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("triplet-normal: error: "), err


def run_main(capsys, argv: list[str]) -> tuple[int, str]:
    status = main([str(a) for a in argv])
    captured = capsys.readouterr()
    assert_one_error_line(captured.out, captured.err)
    return status, captured.err


# ---------------------------------------------------------------- bad values, per subcommand


@pytest.fixture
def ok_xyz(tmp_path: Path) -> Path:
    points = np.random.default_rng(0).normal(size=(60, 3))
    write_points(tmp_path / "ok.xyz", points)
    return tmp_path / "ok.xyz"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--radius", "-1"], "--radius must be a finite number > 0"),
        (["--radius", "0"], "--radius must be a finite number > 0"),
        (["--radius", "nan"], "--radius must be a finite number > 0"),
        (["--radius-rel", "inf"], "--radius-rel must be a finite number > 0"),
        (["--k", "0"], "--k must be an integer >= 3"),
        (["--k", "-5"], "--k must be an integer >= 3"),
        (["--batch-size", "0"], "--batch-size must be an integer >= 1"),
        (["--viewpoint", "0", "nan", "0"], "--viewpoint must be three finite numbers"),
        (["--gate", "-1"], "--gate must be a finite F statistic (a z threshold on organized clouds) >= 0"),
        (["--bend", "nan"], "--bend must be a finite fraction of the radius >= 0"),
        (["--bend", "-0.1"], "--bend must be a finite fraction of the radius >= 0"),
        (["--device", "gpu"], "device must be 'auto', 'cpu', 'cuda' or 'cuda:N'"),
        (["--device", "cuda:x"], "device must be"),
        (["--k", "2.5"], "invalid int value"),
        (["--method", "magic"], "invalid choice"),
        (["--out", "{d}/o.txt"], "unknown output suffix"),
        (["--out", "{d}/no/such/dir/o.npy"], "does not exist"),
    ],
)
def test_estimate_bad_values(tmp_path: Path, capsys, ok_xyz: Path, args: list[str], message: str) -> None:
    argv = ["estimate", ok_xyz, "--method", "pca", *(a.format(d=tmp_path) for a in args)]
    status, err = run_main(capsys, argv)
    assert status == 2 and message in err
    assert not ok_xyz.with_suffix(".normals").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["eval", "--points-per-cloud", "1"], "--points-per-cloud must be >= 10"),
        (["eval", "--points-per-cloud", "-3"], "--points-per-cloud must be >= 10"),
        (["eval", "--points-per-cloud", "nan"], "invalid int value"),
        (["eval", "--device", "tpu"], "device must be"),
        (
            ["eval", "--sets", "depth,kinect"],
            "--sets must name some of val, depth, fold, lidar, segment, icp, matrix, pcpnet",
        ),
        (["eval", "--sets", ","], "--sets must name some of"),
        (["ablate", "--epochs", "0"], "--epochs must be >= 1"),
        (["ablate", "--epochs", "-1"], "--epochs must be >= 1"),
        (["ablate", "--per-cloud", "0"], "--per-cloud must be >= 1"),
        (["ablate", "--patches-per-shape", "0"], "--patches-per-shape must be >= 1"),
        (["ablate", "--device", "gpu"], "device must be"),
        (["bench", "--queries", "0"], "--queries must be >= 1"),
        (["bench", "--points", "10"], "--points must be >= "),
        (["bench", "--points", "-100000"], "--points must be >= "),
        (["bench", "--device", "cuda:-1"], "device must be"),
        (["bench", "--method", "fast"], "invalid choice"),
        (["train", "--device", "gpu", *TINY_TRAIN], "device must be"),
        (["train", "--relative-floor-deg", "0", *TINY_TRAIN], "must be a finite number > 0"),
        (["train", "--relative-floor-deg", "nan", *TINY_TRAIN], "must be a finite number > 0"),
        pytest.param(["train", "--k", "1", *TINY_TRAIN], "--k must be >= 3"),
        pytest.param(["train", "--batch-size", "0", *TINY_TRAIN], "--batch-size must be >= 1"),
        pytest.param(["train", "--lr", "-1", *TINY_TRAIN], "argument --lr: must be a finite number > 0"),
        pytest.param(["train", "--lr", "nan", *TINY_TRAIN], "argument --lr: must be a finite number > 0"),
        (["frobnicate"], "invalid choice"),
        ([], "the following arguments are required"),
    ],
)
def test_other_subcommands_bad_values(tmp_path: Path, capsys, argv: list[str], message: str) -> None:
    if argv[:1] in (["train"], ["ablate"]):
        argv += ["--run-dir", str(tmp_path / "run")]
    if argv[:1] in (["eval"], ["bench"], ["ablate"]):
        argv += ["--out", str(tmp_path / "R.md")]
    status, err = run_main(capsys, argv)
    assert status == 2 and message in err
    assert not (tmp_path / "R.md").exists() and not (tmp_path / "run").exists()  # rejected before any work


def test_train_unknown_shape_is_one_line(tmp_path: Path, capsys) -> None:
    status, err = run_main(capsys, ["train", "--shapes", "no_such_shape", "--run-dir", tmp_path / "run"])
    assert status == 1 and "unknown train shapes ['no_such_shape']" in err


def test_estimate_help_names_the_pca_default_and_orientation(capsys) -> None:
    assert main(["estimate", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert f"pca: neighbour cap (default {PCA_DEFAULT_K})" in text
    assert "--viewpoint X Y Z orient: flip normals to face this point" in text
    assert "unoriented" not in text


# ---------------------------------------------------------------- bad files, every format


def small_grid() -> np.ndarray:
    i = np.arange(40)
    return np.column_stack([i % 8, i // 8, np.zeros(40)]).astype(np.float32)  # compressible, so lzf really packs it


def _pcd(path: Path, encoding: Encoding) -> bytes:
    PointCloud.from_points(small_grid(), ("x", "y", "z"), [np.float32] * 3).save(path, encoding=encoding)
    return path.read_bytes()


def _ply(path: Path, ascii_: bool) -> bytes:
    if not ascii_:
        write_normals(path, small_grid(), np.zeros((40, 3)))
        return path.read_bytes()
    head = (
        "ply\nformat ascii 1.0\nelement vertex 40\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    )
    path.write_text(head + "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in small_grid()))
    return path.read_bytes()


def _npy(path: Path) -> bytes:
    np.save(path, small_grid())
    return path.read_bytes()


def _xyz(path: Path) -> bytes:
    np.savetxt(path, small_grid(), fmt="%.3f")
    return path.read_bytes()


#: name -> writes a valid file there and returns its bytes
MAKERS = {
    "points.xyz": _xyz,
    "points.npy": _npy,
    "ascii.ply": lambda p: _ply(p, True),
    "binary.ply": lambda p: _ply(p, False),
    "ascii.pcd": lambda p: _pcd(p, Encoding.ASCII),
    "binary.pcd": lambda p: _pcd(p, Encoding.BINARY),
    "compressed.pcd": lambda p: _pcd(p, Encoding.BINARY_COMPRESSED),
}


def _cuts(name: str, data: bytes) -> dict[str, bytes]:
    """Ways to break a valid file: empty, garbage, and cut at several places (header, body, last row or byte)."""
    cuts = {"empty": b"", "garbage": b"\xff\xfe\x00\x01\x80 garbage \x00" * 8}
    text = name.endswith(".xyz") or name.startswith("ascii")
    mid_row = data[: data.index(b"\n", len(data) // 2) + 4] if text else b""  # a row cut after a few characters
    if name.endswith(".xyz"):  # no declared count: only a broken row can be noticed
        return {**cuts, "mid row": mid_row}
    header_end = data.find({".pcd": b"DATA", ".ply": b"end_header", ".npy": b"\n"}[Path(name).suffix])
    cuts |= {"mid header": data[: header_end // 2 + 1], "half": data[: len(data) // 2]}
    if text:  # one byte short would only drop the final newline
        cuts |= {"mid row": mid_row, "last row missing": data[: data.rindex(b"\n", 0, -1) + 1]}
    else:
        cuts["one byte short"] = data[:-1]
    if name == "compressed.pcd":
        body = data.index(b"\n", header_end) + 1
        cuts["inside the size words"] = data[: body + 5]
        cuts["after the size words"] = data[: body + 8]
    if name.endswith(".pcd") or name.endswith(".ply"):
        cuts["fewer points than declared"] = data.replace(b" 40\n", b" 41\n").replace(b"WIDTH 40", b"WIDTH 41")
    return cuts


@pytest.mark.parametrize("name", sorted(MAKERS))
def test_estimate_on_broken_files_is_one_line(tmp_path: Path, capsys, name: str) -> None:
    data = MAKERS[name](tmp_path / f"valid_{name}")
    assert main(["estimate", str(tmp_path / f"valid_{name}"), "--method", "pca", "--out", str(tmp_path / "o.npy")]) == 0
    capsys.readouterr()
    for how, bad in _cuts(name, data).items():
        path = tmp_path / f"{how.replace(' ', '_')}_{name}"
        path.write_bytes(bad)
        status, err = run_main(capsys, ["estimate", path, "--method", "pca", "--out", tmp_path / "o.npy"])
        assert status == 1, (how, err)
        assert f"error: {path}: " in err, (how, err)  # the file is named first


@pytest.mark.parametrize(
    ("target", "content", "message"),
    [
        ("missing.xyz", None, "no such file"),
        ("folder.xyz", "dir", "is a directory"),
        ("cloud.stl", b"solid\n", "unknown point-cloud suffix"),
    ],
)
def test_estimate_on_missing_or_odd_paths(tmp_path: Path, capsys, target: str, content, message: str) -> None:
    path = tmp_path / target
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content)
    status, err = run_main(capsys, ["estimate", path, "--method", "pca", "--out", tmp_path / "o.npy"])
    assert status == 1 and message in err and str(path) in err


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("0\n1\n2.5\n", "not an integer index: '2.5'"),
        ("0\n60\n", r"index 60 on line 2 is outside [0, 60)"),
        ("-1\n", "is outside"),
        ("", "no indices in file"),
        (b"\xff\xfe\x00", "not a text file"),
        ("dir", "is a directory"),
    ],
)
def test_estimate_with_bad_pidx(tmp_path: Path, capsys, ok_xyz: Path, content, message: str) -> None:
    pidx = tmp_path / "q.pidx"
    if content == "dir":
        pidx.mkdir()
    elif isinstance(content, bytes):
        pidx.write_bytes(content)
    else:
        pidx.write_text(content)
    argv = ["estimate", ok_xyz, "--method", "pca", "--indices", pidx, "--out", tmp_path / "o.npy"]
    status, err = run_main(capsys, argv)
    assert status == 1 and message in err and str(pidx) in err
    assert not (tmp_path / "o.npy").exists()


@pytest.mark.parametrize("how", ["inside the size words", "after the size words", "empty xyz"])
def test_console_script_prints_one_line_and_no_warning(tmp_path: Path, how: str) -> None:
    """The installed entry point as a user runs it: stderr is exactly one line, whatever numpy or lzf would say."""
    if how == "empty xyz":
        path = tmp_path / "empty.xyz"
        path.write_bytes(b"")
    else:
        data = _pcd(tmp_path / "full.pcd", Encoding.BINARY_COMPRESSED)
        path = tmp_path / "cut.pcd"
        path.write_bytes(_cuts("compressed.pcd", data)[how])
    done = subprocess.run(
        [str(SCRIPT), "estimate", str(path), "--method", "pca", "--out", str(tmp_path / "o.npy")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1
    assert_one_error_line(done.stdout, done.stderr)
    assert str(path) in done.stderr


def test_compressed_cut_sizes_are_what_the_cases_claim(tmp_path: Path) -> None:
    """Guard for the cases above: the compressed file really is binary_compressed and its cuts land where named."""
    data = _pcd(tmp_path / "c.pcd", Encoding.BINARY_COMPRESSED)
    assert b"DATA binary_compressed\n" in data
    body = data.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    packed, unpacked = struct.unpack("<II", data[body : body + 8])
    assert unpacked == 40 * 12 and packed < unpacked and len(data) == body + 8 + packed


# ---------------------------------------------------------------- optional modules not installed

REPO = Path(__file__).resolve().parents[2]
#: (command line, the module it needs): every command and option that imports an optional module.
NEEDS = [
    (["estimate", "c.xyz", "--workers", "2"], "ray"),
    (["estimate", "c.xyz", "--address", "auto"], "ray"),
    (["estimate", "c.xyz", "--out", "c.pcd"], "pypcd4"),
    (["estimate", "c.xyz", "--params-file", "lidar"], "yaml"),
    (["bag", "in", "out", "--topic", "/points"], "rosbags"),
    (["bag", "in", "out", "--topic", "/points"], "std_msgs"),
    (["bag", "in", "out", "--topic", "/points", "--params-file", "lidar"], "yaml"),
    (["bags", "in", "out", "--topic", "/points"], "ray"),
    (["bags", "in", "out", "--topic", "/points"], "rosbags"),
    (["eval"], "trimesh"),
    (["eval", "--out", "results.md"], "matplotlib"),
    (["train"], "manifold3d"),
    (["train"], "matplotlib"),
    (["ablate"], "trimesh"),
]


def unimportable(root: Path, module: str) -> dict[str, str]:
    """An environment in which importing `module` fails as it does where it is not installed."""
    (root / module).mkdir(parents=True)
    (root / module / "__init__.py").write_text(
        f"raise ModuleNotFoundError(\"No module named '{module}'\", name='{module}')\n"
    )
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p)}


@pytest.mark.slow  # a process per case, each importing the modules before the missing one
@pytest.mark.parametrize(("argv", "module"), NEEDS, ids=[f"{a[0]}{'+'.join(a[1:2] + a[4:])}-{m}" for a, m in NEEDS])
def test_a_missing_optional_module_is_one_line_naming_the_extra(tmp_path: Path, argv: list[str], module: str) -> None:
    done = subprocess.run(
        [str(SCRIPT), *argv], capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env=unimportable(tmp_path / "site", module),
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert_one_error_line(done.stdout, done.stderr)
    if module in ROS_MODULES:
        words = f"needs the ROS 2 message package '{module}', which is not installed: source a ROS 2 setup.bash"
    else:
        words = f"needs the Python module '{module}', which is not installed: pip install {DISTRIBUTIONS[module]}"
    assert done.stderr.strip() == f"triplet-normal: error: {argv[0]} {words}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site"]  # nothing was written: no work began


def _top_level(path: PurePath) -> str:
    """The module a wheel's file installs: `ray/__init__.py` -> ray, `manifold3d.cpython-311-x86_64-linux-gnu.so`
    -> manifold3d."""
    return path.parts[0].partition(".")[0]


def test_every_install_step_named_is_a_pypi_distribution_that_provides_the_module() -> None:
    """The errors name `pip install <distribution>`, a step that works without this package on PyPI: the Makefile
    installed each distribution from the registry, and its files hold the module; setup.py's extras group them too
    (an install from a checkout)."""
    tree = ast.parse((REPO / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.keyword) and n.arg == "extras_require")
    grouped = {name.lower() for names in ast.literal_eval(call.value).values() for name in names}
    for module, name in DISTRIBUTIONS.items():
        files = metadata.distribution(name).files or []
        assert module in {_top_level(PurePath(f)) for f in files}, (module, name)
        assert name in grouped, name
