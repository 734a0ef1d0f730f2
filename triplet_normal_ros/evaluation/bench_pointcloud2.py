"""Time PointCloud2 <-> numpy conversion (read_xyz + with_normals) on a 640x480 organized cloud.

`triplet-normal bench` prints these rows beside the estimator's (the node's per-frame overhead next to the work).
The target is <= 30 ms for read + write of the plain xyzrgb case.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from ..io.pointcloud2 import read_xyz, with_normals

HEIGHT, WIDTH = 480, 640
_DATATYPE = {"f4": PointField.FLOAT32, "f8": PointField.FLOAT64}


def _cloud(xyz_code: str, rgb_offset: int, point_step: int, row_pad: int, bigendian: bool) -> PointCloud2:
    """xyz (float32 or float64) at offset 0, then rgb float32, laid out with the given padding and byte order."""
    rng = np.random.default_rng(0)
    order = ">" if bigendian else "<"
    size = np.dtype(xyz_code).itemsize
    offsets = {"x": 0, "y": size, "z": 2 * size, "rgb": rgb_offset}
    codes = {"x": xyz_code, "y": xyz_code, "z": xyz_code, "rgb": "f4"}
    row_step = WIDTH * point_step + row_pad
    buf = np.zeros((HEIGHT, row_step), np.uint8)
    for name, offset in offsets.items():
        dtype = np.dtype(order + codes[name])
        view = np.ndarray((HEIGHT, WIDTH), dtype, buffer=buf, offset=offset, strides=(row_step, point_step))
        view[...] = rng.random((HEIGHT, WIDTH))
    fields = [PointField(name=n, offset=o, datatype=_DATATYPE[codes[n]], count=1) for n, o in offsets.items()]
    msg = PointCloud2(header=Header(frame_id="camera"), height=HEIGHT, width=WIDTH, fields=fields)
    msg.is_bigendian, msg.point_step, msg.row_step = bigendian, point_step, row_step
    msg.data = buf.tobytes()
    return msg


CASES: dict[str, Callable[[], PointCloud2]] = {
    "organized 640x480 xyzrgb": lambda: _cloud("f4", 12, 16, 0, False),
    "padded point_step 32 + row padding": lambda: _cloud("f4", 16, 32, 64, False),
    "big-endian xyzrgb": lambda: _cloud("f4", 12, 16, 0, True),
    "float64 xyz + rgb": lambda: _cloud("f8", 24, 32, 0, False),
}


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def conversion_rows(repeats: int = 15) -> list[tuple[str, float, float]]:
    """(case, read ms, write ms): medians of `repeats` timed runs per layout, after one warm-up."""
    rng = np.random.default_rng(1)
    normals = rng.standard_normal((HEIGHT * WIDTH, 3)).astype(np.float32)
    curvature = rng.random(HEIGHT * WIDTH).astype(np.float32)
    rows = []
    for name, build in CASES.items():
        msg = build()
        read_xyz(msg), with_normals(msg, normals, curvature)  # warm-up
        read_ms = _median_ms(lambda m=msg: read_xyz(m), repeats)
        write_ms = _median_ms(lambda m=msg: with_normals(m, normals, curvature), repeats)
        rows.append((name, read_ms, write_ms))
    return rows


def conversion_markdown(rows: list[tuple[str, float, float]]) -> list[str]:
    """The conversion table: the per-frame overhead the node adds to estimation."""
    lines = ["| case | points | read ms | write ms | total ms |", "| --- | ---: | ---: | ---: | ---: |"]
    lines += [f"| {n} | {HEIGHT * WIDTH} | {r:.1f} | {w:.1f} | {r + w:.1f} |" for n, r, w in rows]
    return lines
