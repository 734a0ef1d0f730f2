"""Builds test/data/ouster_os1_128/: a small rosbag2 (MCAP) of real Ouster OS-1-128 clouds on /ouster/points, laid
out as ouster-ros (ROS 2) publishes them.

Source: ouster-lidar/ouster-sdk at commit 46b7bceee7995914e2f3f3facf4d78418335b2d7 (BSD-3-Clause),
tests/pcaps/OS-1-128_v2.3.0_1024x10_lb_n3.pcap and tests/pcaps/OS-1-128_v2.3.0_1024x10.json
(OS-1-128, fw v2.3.0, 1024x10, RNG15_RFL8_NIR8 "low data" profile, 3 complete scans).

Two stages, each in the interpreter that has its library:
  1. decode (ouster-sdk 1.0.1, --sdk-python): pcap -> staggered scan fields + sensor intrinsics in an .npz
     (a temporary directory unless --keep-npz PATH);
  2. write (rosbags, this interpreter): .npz -> bag directory OUT (replaced if it exists).
--decode-only runs stage 1 alone, in the interpreter it is started with, and writes the .npz to OUT.

Layout (ouster-ros humble-devel eaaf35d, point_type "original" = ouster_ros::Point, os_point.h):
  x,y,z FLOAT32 @0,4,8 | data[3] = 1.0f @12 (PCL_ADD_POINT4D, no PointField) | intensity FLOAT32 @16 |
  t UINT32 @20 | reflectivity UINT16 @24 | ring UINT16 @26 | ambient UINT16 @28 | range UINT32 @32 |
  pad to 48 (EIGEN_ALIGN16).  Organized: height = beams, width = columns, destaggered
  (v_shift = (v + w - pixel_shift_by_row[u]) % w), frame_id os_lidar (no lidar->sensor transform), xyz in m
  from make_xyz_lut(range_unit 0.001) in float32, header stamp = first column timestamp (sensor time mode),
  t = column_ts - scan_ts.
No-return pixels (range 0):
  --no-return zero (default): (0,0,0) and is_dense = true  -> ouster-ros <= 0.12 (SDK cartesianT: r == 0 -> 0)
  --no-return nan:            NaN xyz and is_dense = false -> ouster-ros >= 0.13 (cartesianT(..., quiet_NaN),
                              min_range 0 m, max_range 1000 m: r <= 0 or r >= 1e6 mm -> NaN)
--no-compress writes plain MCAP chunks (about 6.3 MB a 128x1024 scan) instead of zstd-compressed ones.

rosbags names the .mcap file after OUT, so the Run line below gives ouster_os1_128.mcap where the committed bag has
os_lidar_bag.mcap; the messages are byte for byte the same.

Run: .venv/bin/python docs/tools/ouster_bag.py OS-1-128_v2.3.0_1024x10_lb_n3.pcap OS-1-128_v2.3.0_1024x10.json
     test/data/ouster_os1_128 --sdk-python /path/to/venv-with-ouster-sdk/bin/python
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

TOPIC, FRAME_ID = "/ouster/points", "os_lidar"
RANGE_UNIT = 0.001  # metres per range count, as ouster-ros passes to make_xyz_lut
NAN_MAX_RANGE_MM = 1_000_000  # ouster-ros >= 0.13 max_range 1000 m
POINT_STEP = 48
# ouster_ros::Point; "w4" is PCL_ADD_POINT4D's data[3], which has no PointField
POINT_DTYPE = np.dtype({
    "names": ["x", "y", "z", "w4", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
    "formats": ["<f4", "<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
    "offsets": [0, 4, 8, 12, 16, 20, 24, 26, 28, 32],
    "itemsize": POINT_STEP,
})  # fmt: skip
F32, U16, U32 = 7, 4, 6  # sensor_msgs/PointField datatypes
FIELDS = (("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 16, F32), ("t", 20, U32),
          ("reflectivity", 24, U16), ("ring", 26, U16), ("ambient", 28, U16), ("range", 32, U32))  # fmt: skip


# --- stage 1: decode (ouster-sdk interpreter) ---


def complete_scans(pcap: Path, meta: Path, max_scans: int) -> tuple[list[Any], Any]:
    """The first `max_scans` complete LidarScans and the sensor info; partial scans are dropped because ouster-ros
    would not publish a cloud for them either."""
    from ouster.sdk import open_source

    source = open_source(str(pcap), meta=[str(meta)])
    scans = []
    for frame_set in source:
        for scan in frame_set.valid_frames():
            if scan.complete():
                scans.append(scan)
            if len(scans) == max_scans:
                return scans, source.sensor_info[0]
    return scans, source.sensor_info[0]


def scan_fields(scan: Any) -> dict[str, Any]:
    """The per-pixel and per-column fields the cloud needs, in the dtypes ouster-ros reads them as."""
    rng = scan.field("RANGE")
    signal = scan.field("SIGNAL") if scan.has_field("SIGNAL") else np.zeros_like(rng)  # low-data profile lacks it
    return {
        "RANGE": rng.astype(np.uint32),
        "REFLECTIVITY": scan.field("REFLECTIVITY").astype(np.uint16),
        "NEAR_IR": scan.field("NEAR_IR").astype(np.uint16),
        "SIGNAL": signal.astype(np.float32),
        "TS": np.asarray(scan.timestamp, dtype=np.uint64),
        "STATUS": np.asarray(scan.status, dtype=np.uint32),
        "FRAME_ID": scan.frame_id,
    }


def decode(pcap: Path, meta: Path, npz: Path, max_scans: int) -> None:
    """pcap -> staggered scan fields + sensor intrinsics in `npz`, so the write stage needs no ouster-sdk."""
    scans, info = complete_scans(pcap, meta, max_scans)
    per_scan = [scan_fields(scan) for scan in scans]
    stacked = {key: np.stack([f[key] for f in per_scan]) if key != "FRAME_ID" else np.array([f[key] for f in per_scan])
               for key in per_scan[0]}  # fmt: skip
    with npz.open("wb") as f:  # a file object, so np.savez keeps PATH as given instead of appending .npz
        np.savez(
            f,
            **stacked,
            beam_altitude_angles=np.array(info.beam_altitude_angles, dtype=np.float64),
            beam_azimuth_angles=np.array(info.beam_azimuth_angles, dtype=np.float64),
            beam_to_lidar_transform=np.array(info.beam_to_lidar_transform, dtype=np.float64),
            pixel_shift_by_row=np.array(info.format.pixel_shift_by_row, dtype=np.int64),
            prod_line=str(info.prod_line), fw_rev=str(info.fw_rev), sn=str(info.sn),
            profile=str(info.format.udp_profile_lidar), lidar_mode=str(info.config.lidar_mode),
        )  # fmt: skip
    print(f"decoded {len(scans)} scans, frames {stacked['FRAME_ID'].tolist()} -> {npz}")


# --- stage 2: write (rosbags interpreter) ---


def xyz_lut(w: int, h: int, b2l: np.ndarray, az_deg: np.ndarray, alt_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(direction, offset) per pixel as ouster::sdk::core::make_xyz_lut(w, h, RANGE_UNIT, beam_to_lidar, identity,
    az, alt) builds them: computed in double, then cast to float32 as ouster-ros does, so xyz matches bit for bit."""
    col = np.arange(w, dtype=np.float64)
    encoder = np.broadcast_to(2.0 * np.pi - col * (2.0 * np.pi / w), (h, w))
    azimuth = np.broadcast_to((-np.asarray(az_deg) * np.pi / 180.0)[:, None], (h, w))
    altitude = np.broadcast_to((np.asarray(alt_deg) * np.pi / 180.0)[:, None], (h, w))
    dist = b2l[0, 3] if b2l[2, 3] == 0 else np.hypot(b2l[0, 3], b2l[2, 3])
    d = np.stack([np.cos(encoder + azimuth) * np.cos(altitude),
                  np.sin(encoder + azimuth) * np.cos(altitude),
                  np.sin(altitude)], axis=-1)  # fmt: skip
    o = np.stack([np.cos(encoder) * b2l[0, 3] - d[..., 0] * dist,
                  np.sin(encoder) * b2l[0, 3] - d[..., 1] * dist,
                  -d[..., 2] * dist + b2l[2, 3]], axis=-1)  # fmt: skip
    return (d * RANGE_UNIT).astype(np.float32), (o * RANGE_UNIT).astype(np.float32)


def cartesian(rng: np.ndarray, lut_d: np.ndarray, lut_o: np.ndarray, no_return: str) -> np.ndarray:
    """Staggered (h, w, 3) xyz as the SDK's cartesianT computes it in float (r * dir + ofs), with no-return pixels
    set the way the chosen ouster-ros version sets them."""
    pts = rng.astype(np.float32)[..., None] * lut_d + lut_o
    if no_return == "zero":
        pts[rng == 0] = 0.0
    else:
        pts[(rng <= 0) | (rng >= NAN_MAX_RANGE_MM)] = np.nan
    return pts


def destagger_columns(shift: np.ndarray, w: int) -> np.ndarray:
    """(h, w) source column of each destaggered pixel: target (u, v) <- source (u, (v + w - shift[u]) % w)."""
    v = np.arange(w)
    return (v[None, :] + w - shift[:, None]) % w


def column_offsets(ts: np.ndarray, src_col: np.ndarray) -> tuple[np.ndarray, int]:
    """Per-pixel t (ns since the scan stamp) and the scan stamp, which ouster-ros takes from the first column."""
    if ts[0] == 0:
        raise ValueError("first column has no timestamp: ouster-ros would extrapolate the scan stamp")
    scan_ts = int(ts[0])
    col_ts = ts[src_col].astype(np.int64)
    return np.where(col_ts > scan_ts, col_ts - scan_ts, 0).astype(np.uint32), scan_ts


def cloud_bytes(z: Any, i: int, lut: tuple[np.ndarray, np.ndarray], no_return: str) -> tuple[np.ndarray, int, bool]:
    """Scan `i` of the .npz as one organized, destaggered ouster_ros::Point cloud.

    Returns (data bytes, scan stamp, is_dense)."""
    rng = z["RANGE"][i]
    h, w = rng.shape
    src_col = destagger_columns(z["pixel_shift_by_row"], w)
    rows = np.arange(h)[:, None]
    t, scan_ts = column_offsets(z["TS"][i], src_col)
    p = cartesian(rng, *lut, no_return)[rows, src_col]
    out = np.zeros((h, w), dtype=POINT_DTYPE)
    out["x"], out["y"], out["z"] = p[..., 0], p[..., 1], p[..., 2]
    out["w4"] = 1.0  # ouster_ros::Point() sets data[3] to 1.0f
    out["intensity"] = z["SIGNAL"][i][rows, src_col]
    out["t"] = t
    out["reflectivity"] = z["REFLECTIVITY"][i][rows, src_col]
    out["ring"] = np.broadcast_to(np.arange(h, dtype=np.uint16)[:, None], (h, w))
    out["ambient"] = z["NEAR_IR"][i][rows, src_col]
    out["range"] = rng[rows, src_col]
    return out.view(np.uint8).reshape(-1), scan_ts, not bool(np.isnan(p).any())


def message(types: Typestore, data: np.ndarray, h: int, w: int, scan_ts: int, dense: bool) -> Any:
    """The PointCloud2 ouster-ros publishes for one scan (sensor time mode: stamp = scan_ts)."""
    msgs = types.types
    fields = [msgs["sensor_msgs/msg/PointField"](name=n, offset=off, datatype=dt, count=1) for n, off, dt in FIELDS]
    header = msgs["std_msgs/msg/Header"](
        stamp=msgs["builtin_interfaces/msg/Time"](sec=scan_ts // 10**9, nanosec=scan_ts % 10**9), frame_id=FRAME_ID
    )
    return msgs["sensor_msgs/msg/PointCloud2"](
        header=header, height=h, width=w, fields=fields, is_bigendian=False, point_step=POINT_STEP,
        row_step=POINT_STEP * w, data=data, is_dense=dense,
    )  # fmt: skip


def write(npz: Path, out_dir: Path, max_scans: int, no_return: str, compress: bool) -> None:
    """The decoded scans as PointCloud2 messages in an MCAP bag at `out_dir`, logged at their scan stamps."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    types = get_typestore(Stores.ROS2_KILTED)
    z = np.load(npz)
    n = min(max_scans, len(z["RANGE"]))
    h, w = z["RANGE"].shape[1:]
    lut = xyz_lut(w, h, z["beam_to_lidar_transform"], z["beam_azimuth_angles"], z["beam_altitude_angles"])
    if out_dir.exists():
        shutil.rmtree(out_dir)
    writer = Writer(out_dir, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:  # zstd inside the MCAP chunks: metadata records no rosbag2 compression, so plain readers read it
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection(TOPIC, "sensor_msgs/msg/PointCloud2", typestore=types)
        for i in range(n):
            data, scan_ts, dense = cloud_bytes(z, i, lut, no_return)
            msg = message(types, data, h, w, scan_ts, dense)
            writer.write(conn, scan_ts, types.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    print(f"wrote {n} scans ({h}x{w}) to {out_dir}, no-return={no_return}")


# --- command line ---


def run_decode(sdk_python: str, pcap: Path, meta: Path, npz: Path, scans: int) -> None:
    """Stage 1 in the ouster-sdk interpreter: this same file with --decode-only, so both stages share one source."""
    cmd = [sdk_python, str(Path(__file__).resolve()), str(pcap), str(meta), str(npz), "--decode-only"]
    subprocess.run([*cmd, "--scans", str(scans)], check=True)


def build(args: argparse.Namespace) -> None:
    """Both stages; the .npz goes to --keep-npz or to a temporary directory that is removed afterwards."""
    if args.keep_npz is not None:
        run_decode(args.sdk_python, args.pcap, args.meta, args.keep_npz, args.scans)
        write(args.keep_npz, args.out, args.scans, args.no_return, not args.no_compress)
        return
    with tempfile.TemporaryDirectory(prefix="ouster_bag_") as tmp:
        npz = Path(tmp) / "scans.npz"
        run_decode(args.sdk_python, args.pcap, args.meta, npz, args.scans)
        write(npz, args.out, args.scans, args.no_return, not args.no_compress)


def parse_args() -> argparse.Namespace:
    """The command line; the help text is the module docstring's first paragraph."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("pcap", type=Path, help="OS-1-128_v2.3.0_1024x10_lb_n3.pcap")
    ap.add_argument("meta", type=Path, help="OS-1-128_v2.3.0_1024x10.json (sensor metadata)")
    ap.add_argument("out", type=Path, help="bag directory to (re)create; with --decode-only, the .npz to write")
    ap.add_argument("--sdk-python", default=sys.executable,
                    help="interpreter with ouster-sdk 1.0.1 for the decode stage (default: this one)")  # fmt: skip
    ap.add_argument("--scans", type=int, default=3, help="complete scans to keep (default 3)")
    ap.add_argument("--no-return", choices=("zero", "nan"), default="zero",
                    help="xyz of range-0 pixels: zero (ouster-ros <= 0.12) or nan (>= 0.13)")  # fmt: skip
    ap.add_argument("--no-compress", action="store_true", help="plain MCAP chunks (~6.3 MB a 128x1024 scan)")
    ap.add_argument("--keep-npz", type=Path, metavar="PATH", help="keep the decoded scans at PATH")
    ap.add_argument("--decode-only", action="store_true", help="run only the decode stage, writing the .npz to OUT")
    return ap.parse_args()


def main() -> None:
    """--decode-only is how build() re-enters this file under the ouster-sdk interpreter."""
    args = parse_args()
    if args.decode_only:
        decode(args.pcap, args.meta, args.out, args.scans)
    else:
        build(args)


if __name__ == "__main__":
    main()
