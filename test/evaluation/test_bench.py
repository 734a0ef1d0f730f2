"""`triplet-normal bench` end to end on a small budget: every table it promises, with numbers that make sense."""

import re
from pathlib import Path

import pytest

from triplet_normal_ros.cli.main import main
from triplet_normal_ros.evaluation.report import read_section

pytestmark = pytest.mark.slow


def test_bench_writes_methods_side_by_side_searches_matmul_and_conversion(tmp_path: Path, capsys) -> None:
    out = tmp_path / "RESULTS.md"
    argv = ["bench", "--points", "3000", "--queries", "300", "--method", "pca", "--out", str(out)]
    assert main([*argv, "--no-anchors"]) == 0  # anchors would add rows per cloud; test_anchors checks their table
    block = read_section(out, "bench")
    assert block is not None and block.strip() in capsys.readouterr().out
    rows = [line for line in block.splitlines() if line.startswith("| depth frame") or line.startswith("| torus")]
    assert len(rows) == 4  # two PCA rows on each cloud
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        # PCA over the whole ball of an organized cloud is the integral-image window's (core/range_image/image.py); each
        # row is labelled with its plan's steps (core/config/plan.py)
        window = cells[0].startswith("depth frame") and "k = 512" in cells[1]
        path = cells[2].removesuffix(" (compiled)")  # the CPU's windows are compiled (core/range_image/image_numba.py)
        assert path == ("integral-image windows" if window else "pool PCA, KD-tree pools") and cells[3] == "300"
        assert float(cells[-1]) > 0 and float(cells[-2]) > 0
        if "k = 30" in cells[1]:
            assert float(cells[-1]) == 1.0  # every ratio is against this row, measured in the same run
    gflops = re.search(r"plain float32 matmul (\d+) GFLOP/s", block)
    assert gflops and int(gflops[1]) > 1
    searches = re.findall(r"^\| (kdtree|grid|voxel) \| (\d+) \| [\d.]+ \| (\d+) \|$", block, re.M)
    assert {(s, p) for s, p, _ in searches} == {(s, p) for s in ("kdtree", "grid", "voxel") for p in ("30", "512")}
    assert all(int(found) > 3 for _, _, found in searches)
    assert "| organized 640x480 xyzrgb | 307200 |" in block
    memory = re.findall(r"^\| (pca \(windows\)) \| (\d+) \| (\d+) \| (-?\d+) \|$", block, re.M)
    assert len(memory) == 1  # only the method asked for, each in its own process
    _, idle, peak, grown = memory[0]
    assert 100 < int(idle) <= int(peak) and int(grown) > 10  # torch alone is ~300 MB; a frame's arrays add to it
