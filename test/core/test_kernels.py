"""The compiled kernels as one set (`core/kernels.py`): the warm-up covers every kernel every method calls, so that
neither the node's first cloud nor `triplet-normal warm`'s cache leaves one to compile, and the counts say what the
cache served.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from triplet_normal_ros.core import kernels

#: In a fresh interpreter with an empty NUMBA_CACHE_DIR: warm, then every method with every shipped checkpoint on a
#: crop of a real Kinect frame (organized, float32 as the node reads it, and float64) and on the same points as a bare
#: cloud; prints what the warm-up and what the estimates compiled.
COVERAGE = """
import json, numpy as np
from triplet_normal_ros.core import kernels
from triplet_normal_ros.core.estimator import NormalEstimator
from triplet_normal_ros.ros.tools.replay import load_frame
warm = kernels.warm()
xyz = load_frame("table_scene_mug").xyz[200:260, 280:360]
points = xyz.reshape(-1, 3)
bare = points[np.isfinite(points).all(axis=1)]
after = {}
runs = [("pca", "")] + [(m, c) for m in ("learned", "hybrid") for c in ("", "default", "lite", "range")]
for method, checkpoint in runs:
    estimator = NormalEstimator(method=method, radius=0.05, checkpoint=checkpoint, device="cpu")
    before = kernels.count()
    estimator.estimate(points, shape=xyz.shape[:2])
    estimator.estimate(points.astype(np.float64), shape=xyz.shape[:2])
    estimator.estimate(bare)
    after[f"{method} {checkpoint}"] = (kernels.count() - before).compiled
    estimator.k = 30  # pca's KD-tree pools, learned's smaller patches
    before = kernels.count()
    estimator.estimate(bare)
    after[f"{method} {checkpoint} k=30"] = (kernels.count() - before).compiled
print(json.dumps({"warm": [warm.loaded, warm.compiled], "after": after}))
"""


def run_in_fresh_interpreter(code: str, cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # compiles every kernel from an empty cache (about half a minute)
def test_a_cold_warm_up_compiles_every_kernel_any_method_calls_and_a_second_loads_them(tmp_path: Path) -> None:
    cold = run_in_fresh_interpreter(COVERAGE, tmp_path)
    loaded, compiled = cold["warm"]
    assert loaded == 0 and compiled > 0, cold
    assert not any(cold["after"].values()), f"compiled after the warm-up: {cold['after']}"
    again = run_in_fresh_interpreter("import json; from triplet_normal_ros.core import kernels; "
                                     "c = kernels.warm(); print(json.dumps({'warm': [c.loaded, c.compiled]}))",
                                     tmp_path)  # fmt: skip
    assert again["warm"][0] > 0 and again["warm"][1] == 0, again


def test_every_kernel_module_is_in_the_set() -> None:
    """Each `*_numba` module of the package is imported with the set and has kernels; each is in
    `kernels.MODULES` or imported by one, whose kernels call theirs and compile with them (the cold test above shows
    that nothing is left to compile)."""
    core = Path(kernels.__file__).parent
    names = {".".join(p.relative_to(core.parent.parent).with_suffix("").parts) for p in core.rglob("*_numba.py")}
    assert names <= set(sys.modules), names - set(sys.modules)
    assert {d.py_func.__module__ for d in kernels.dispatchers()} == names
    warmed = {m.__name__ for m in kernels.MODULES}
    sources = " ".join(Path(m.__file__).read_text() for m in kernels.MODULES)
    for name in names - warmed:  # warmed by a module of the set that imports it
        assert f"import {name.rpartition('.')[2]}" in sources or f".{name.rpartition('.')[2]} import" in sources, name


def test_warm_stops_between_modules_when_cancelled() -> None:
    from threading import Event

    from triplet_normal_ros.errors import EstimationCancelled

    stop = Event()
    stop.set()
    before = kernels.count()
    with pytest.raises(EstimationCancelled):
        kernels.warm(stop)
    assert kernels.count() == before


@pytest.mark.slow  # a fresh interpreter, which loads (or, with a cold cache, compiles) every kernel
def test_the_warm_command_says_what_it_loaded_compiled_and_where() -> None:
    """Run as setup.py runs it, in a fresh interpreter: every kernel is loaded or compiled, and one line says so."""
    command = [sys.executable, "-m", "triplet_normal_ros.cli.main", "warm"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    (line,) = done.stdout.strip().splitlines()
    counts = re.fullmatch(r"warm: (\d+) kernels loaded from the cache, (\d+) compiled in [\d.]+ s; cache: (.+)", line)
    assert counts, line
    assert int(counts[1]) + int(counts[2]) > 0 and Path(counts[3]).is_dir()
