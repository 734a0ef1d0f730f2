"""Round trips per format, hand-written PLY/PCD variants, .pidx validation and one-line errors."""

import struct
from pathlib import Path

import numpy as np
import pytest
from pypcd4 import Encoding, PointCloud

from triplet_normal_ros.io.cloud_files import (
    CloudFileError,
    read_cloud,
    read_indices,
    read_normals_file,
    read_points,
    write_normals,
)

#: Reading a bad file must give one CloudFileError, never a numpy warning on the way (e.g. loadtxt on an empty file).
pytestmark = pytest.mark.filterwarnings("error")


@pytest.fixture
def cloud() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50, 3))
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    curvature = rng.random(50)
    points[7] = normals[7] = np.nan
    curvature[7] = np.nan
    return points, normals, curvature


@pytest.mark.parametrize("suffix", [".npy", ".ply", ".pcd"])
def test_points_and_normals_round_trip(tmp_path: Path, cloud, suffix: str) -> None:
    points, normals, curvature = cloud
    path = tmp_path / f"out{suffix}"
    write_normals(path, points, normals, curvature)
    back = read_cloud(path)
    atol = 1e-6 if suffix == ".pcd" else 1e-12  # PCD is float32 (PCL's PointNormal)
    np.testing.assert_allclose(back.points, points, atol=atol, rtol=1e-6)
    np.testing.assert_allclose(back.normals, normals, atol=1e-6)
    assert np.isnan(back.points[7]).all()  # NaN rows are kept, not dropped: rows stay aligned with the input


def test_npy_carries_curvature_in_column_seven(tmp_path: Path, cloud) -> None:
    points, normals, curvature = cloud
    write_normals(tmp_path / "o.npy", points, normals, curvature)
    table = np.load(tmp_path / "o.npy")
    assert table.shape == (50, 7)
    np.testing.assert_allclose(table[:, 6], curvature)


def test_pcd_has_pcl_point_normal_fields_and_keeps_organization(tmp_path: Path, cloud) -> None:
    points, normals, curvature = cloud
    write_normals(tmp_path / "o.pcd", points, normals, curvature, organized=(5, 10))
    pcd = PointCloud.from_path(tmp_path / "o.pcd")
    assert pcd.fields == ("x", "y", "z", "normal_x", "normal_y", "normal_z", "curvature")
    assert (pcd.metadata.height, pcd.metadata.width) == (5, 10)
    back = read_cloud(tmp_path / "o.pcd")
    assert (back.height, back.width) == (5, 10)
    np.testing.assert_allclose(pcd.numpy(("curvature",))[:, 0], curvature, atol=1e-6)


@pytest.mark.parametrize("encoding", [Encoding.ASCII, Encoding.BINARY, Encoding.BINARY_COMPRESSED])
def test_pcd_encodings_with_nans_are_read(tmp_path: Path, cloud, encoding: Encoding) -> None:
    points = cloud[0].astype(np.float32)
    rgb = np.zeros((len(points), 1), np.float32)
    pcd = PointCloud.from_points(np.hstack([points, rgb]), ("x", "y", "z", "rgb"), [np.float32] * 4)
    pcd.save(tmp_path / "in.pcd", encoding=encoding)
    back = read_points(tmp_path / "in.pcd")
    assert back.dtype == np.float64
    np.testing.assert_allclose(back, points, atol=1e-5)
    assert np.isnan(back[7]).all()


def test_xyz_ignores_extra_columns_and_normals_file_round_trips(tmp_path: Path, cloud) -> None:
    points, normals, curvature = cloud
    (tmp_path / "a.xyz").write_text("# comment\n1 2 3 9 9\n4 5 6 9 9\n7 8 9.5 9 9\n")
    np.testing.assert_array_equal(read_points(tmp_path / "a.xyz"), [[1, 2, 3], [4, 5, 6], [7, 8, 9.5]])
    write_normals(tmp_path / "a.normals", points, normals, curvature)
    lines = (tmp_path / "a.normals").read_text().splitlines()
    assert len(lines) == 50 and lines[0] == " ".join(f"{v:.6f}" for v in normals[0])
    np.testing.assert_allclose(read_normals_file(tmp_path / "a.normals"), normals, atol=1e-6)


def test_ascii_ply_with_faces_and_normal_x_names(tmp_path: Path) -> None:
    text = (
        "ply\nformat ascii 1.0\ncomment hand written\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nproperty float normal_x\nproperty float normal_y\nproperty float normal_z\n"
        "property uchar red\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0 0 0 1 255\n1 0 0 0 0 1 0\n0 1 0 0 0 1 7\n3 0 1 2\n"
    )
    (tmp_path / "a.ply").write_text(text)
    back = read_cloud(tmp_path / "a.ply")
    np.testing.assert_array_equal(back.points, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(back.normals, np.tile([0, 0, 1], (3, 1)))


def test_binary_little_endian_ply_written_by_hand(tmp_path: Path) -> None:
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    header += b"property float z\nproperty int id\nend_header\n"
    body = b"".join(struct.pack("<fffi", i, 2 * i, 3 * i, i) for i in range(3))
    (tmp_path / "b.ply").write_bytes(header + body)
    np.testing.assert_array_equal(read_points(tmp_path / "b.ply"), [[0, 0, 0], [1, 2, 3], [2, 4, 6]])


def test_pidx_is_validated(tmp_path: Path) -> None:
    (tmp_path / "ok.pidx").write_text("0\n4\n2\n\n")
    np.testing.assert_array_equal(read_indices(tmp_path / "ok.pidx", 5), [0, 4, 2])
    (tmp_path / "far.pidx").write_text("0\n5\n")
    with pytest.raises(CloudFileError, match=r"index 5 on line 2 is outside \[0, 5\)"):
        read_indices(tmp_path / "far.pidx", 5)
    (tmp_path / "neg.pidx").write_text("-1\n")
    with pytest.raises(CloudFileError, match="outside"):
        read_indices(tmp_path / "neg.pidx", 5)
    (tmp_path / "txt.pidx").write_text("1\n2.5\n")
    with pytest.raises(CloudFileError, match="not an integer"):
        read_indices(tmp_path / "txt.pidx", 5)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("a.obj", b"v 0 0 0\n", "unknown point-cloud suffix"),
        ("missing.xyz", None, "no such file"),
        ("two.xyz", b"0 0 0\n1 1 1\n", "only 2 finite point"),
        ("short.xyz", b"0 0\n1 1\n", "3 numeric columns"),
        ("bad.ply", b"not a ply\n", "not a PLY file"),
        (
            "trunc.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nproperty float x\nend_header\n",
            r"declares 9 'vertex' rows but the file holds only 0 \(cut short\?\)",
        ),
        ("junk.pcd", b"\x00\x01garbage", "not a PCD file"),
    ],
)
def test_bad_files_raise_one_clear_line(tmp_path: Path, name: str, content: bytes | None, message: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(CloudFileError, match=message) as info:
        read_points(path)
    assert "\n" not in str(info.value) and name in str(info.value)


def test_npy_shapes_and_pickles_are_refused(tmp_path: Path) -> None:
    np.save(tmp_path / "flat.npy", np.zeros(9))
    with pytest.raises(CloudFileError, match=r"\(N, 3\)"):
        read_points(tmp_path / "flat.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(CloudFileError, match="pickled"):
        read_points(tmp_path / "obj.npy")
    np.save(tmp_path / "wide.npy", np.arange(20.0).reshape(4, 5))
    np.testing.assert_array_equal(read_points(tmp_path / "wide.npy")[:, 0], [0, 5, 10, 15])


def test_unknown_output_suffix_is_refused(tmp_path: Path, cloud) -> None:
    points, normals, _ = cloud
    with pytest.raises(CloudFileError, match="unknown output suffix"):
        write_normals(tmp_path / "o.txt", points, normals)


# ---------------------------------------------------------------- files cut short, or holding less than declared


def grid(n: int = 12) -> np.ndarray:
    """A small float32 cloud with repeated values, so lzf really compresses it (pypcd4 falls back to binary if not)."""
    i = np.arange(n)
    return np.column_stack([i % 4, i // 4, np.zeros(n)]).astype(np.float32)


def saved_pcd(path: Path, encoding: Encoding) -> bytes:
    PointCloud.from_points(grid(), ("x", "y", "z"), [np.float32] * 3).save(path, encoding=encoding)
    data = path.read_bytes()
    assert f"DATA {encoding.value}\n".encode() in data  # the encoding asked for, not a fallback
    return data


def pcd_header(fields: str, size: str, type_: str, count: str, width: int, height: int, points: int, data: str):
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {type_}\nCOUNT {count}\nWIDTH {width}\n"
        f"HEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n"
    ).encode()


def every_cut(tmp_path: Path, name: str, data: bytes):
    """Prefixes of `data` (every third length, and one byte short) written to tmp_path/name; yields (cut, path)."""
    path = tmp_path / name
    for cut in [*range(0, len(data) - 1, 3), len(data) - 1]:
        path.write_bytes(data[:cut])
        yield cut, path


@pytest.mark.parametrize("encoding", [Encoding.BINARY, Encoding.BINARY_COMPRESSED])
def test_binary_pcd_cut_anywhere_is_one_cloud_file_error(tmp_path: Path, encoding: Encoding) -> None:
    data = saved_pcd(tmp_path / "full.pcd", encoding)
    np.testing.assert_array_equal(read_points(tmp_path / "full.pcd"), grid())
    for cut, path in every_cut(tmp_path, "cut.pcd", data):
        with pytest.raises(CloudFileError) as info:
            read_points(path)
        assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value), cut


@pytest.mark.parametrize(
    ("name", "make"),
    [
        ("ascii.pcd", lambda path: saved_pcd(path, Encoding.ASCII)),
        ("ascii.ply", lambda path: _ascii_ply(path)),
        ("points.xyz", lambda path: (np.savetxt(path, grid(), fmt="%.1f"), path.read_bytes())[1]),
    ],
)
def test_text_file_cut_anywhere_is_refused_or_read_whole(tmp_path: Path, name: str, make) -> None:
    """A cut inside the last number can still parse; what must never happen is a short read or another exception."""
    data = make(tmp_path / name)
    for cut, path in every_cut(tmp_path, "cut" + Path(name).suffix, data):
        try:
            points = read_points(path)
        except CloudFileError as error:
            assert str(error).startswith(f"{path}: ") and "\n" not in str(error), cut
        else:
            assert len(points) == len(grid()) or name.endswith(".xyz"), cut  # only .xyz has no declared count


def _ascii_ply(path: Path) -> bytes:
    rows = "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in grid())
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {len(grid())}\nproperty float x\nproperty float y\n"
                    f"property float z\nend_header\n{rows}")  # fmt: skip
    return path.read_bytes()


@pytest.mark.parametrize("suffix", [".ply", ".npy"])
def test_binary_ply_and_npy_cut_anywhere_is_one_cloud_file_error(tmp_path: Path, suffix: str) -> None:
    write_normals(tmp_path / f"full{suffix}", grid(), np.zeros((12, 3)))
    data = (tmp_path / f"full{suffix}").read_bytes()
    for cut, path in every_cut(tmp_path, f"cut{suffix}", data):
        with pytest.raises(CloudFileError) as info:
            read_points(path)
        assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value), cut


def test_organized_binary_pcd_holding_fewer_points_than_declared_is_refused(tmp_path: Path) -> None:
    """A 640 x 480 frame header over 200 000 points used to load as an unorganized 200 000-point cloud."""
    body = np.zeros((200_000, 3), np.float32).tobytes()
    (tmp_path / "frame.pcd").write_bytes(
        pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 640, 480, 307_200, "binary") + body
    )
    with pytest.raises(CloudFileError, match=r"header declares 307200 points but the file holds only 200000 \(cut"):
        read_points(tmp_path / "frame.pcd")


def test_ascii_pcd_with_fewer_or_more_rows_than_declared_is_refused(tmp_path: Path) -> None:
    rows = "".join(f"{i} 0 1\n" for i in range(500))
    head = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 1000, 1, 1000, "ascii")
    (tmp_path / "half.pcd").write_bytes(head + rows.encode())
    with pytest.raises(CloudFileError, match="header declares 1000 points but the file holds only 500"):
        read_points(tmp_path / "half.pcd")
    head = pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 400, 1, 400, "ascii")
    (tmp_path / "more.pcd").write_bytes(head + rows.encode())
    with pytest.raises(CloudFileError, match="declares 400 points but the file holds 500 rows"):
        read_points(tmp_path / "more.pcd")


@pytest.mark.parametrize(
    ("header", "message"),
    [
        (b"", "empty file, not a PCD"),
        (b"VERSION 0.7\nFIELDS x y z\n", "no DATA line"),
        (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 10, 2, 10, "binary"), "POINTS 10 but WIDTH x HEIGHT = 10 x 2"),
        (pcd_header("x y z", "4 4", "F F F", "1 1 1", 1, 1, 1, "binary"), "SIZE has 2 entries for 3 FIELDS"),
        (pcd_header("x y z", "4 4 4", "F F X", "1 1 1", 1, 1, 1, "binary"), "type X with size 4"),
        (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", -1, 1, 1, "binary"), "WIDTH must be integers >= 0"),
        (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 1, 1, 1, "lzma"), "unsupported PCD DATA 'lzma'"),
        (pcd_header("a b c", "4 4 4", "F F F", "1 1 1", 0, 1, 0, "ascii"), r"no field\(s\) x, y, z"),
        (pcd_header("x y z", "4 4 4", "F F F", "1 1 1", 0, 1, 0, "ascii"), "only 0 finite point"),
    ],
)
def test_bad_pcd_headers_name_the_problem(tmp_path: Path, header: bytes, message: str) -> None:
    (tmp_path / "h.pcd").write_bytes(header)
    with pytest.raises(CloudFileError, match=message):
        read_points(tmp_path / "h.pcd")


def test_compressed_pcd_whose_block_disagrees_with_the_header_is_refused(tmp_path: Path) -> None:
    data = saved_pcd(tmp_path / "c.pcd", Encoding.BINARY_COMPRESSED)
    head, body = data.split(b"DATA binary_compressed\n")
    unpacked = struct.unpack("<II", body[:8])[1]
    more = head.replace(b"WIDTH 12", b"WIDTH 13").replace(b"POINTS 12", b"POINTS 13")
    (tmp_path / "more.pcd").write_bytes(more + b"DATA binary_compressed\n" + body)
    with pytest.raises(CloudFileError, match=rf"declares 13 points \(156 bytes\) but .* unpacks to {unpacked} bytes"):
        read_points(tmp_path / "more.pcd")
    corrupt = body[:8] + bytes(b ^ 0xFF for b in body[8:])
    (tmp_path / "bad.pcd").write_bytes(head + b"DATA binary_compressed\n" + corrupt)
    with pytest.raises(CloudFileError, match="compressed block is corrupt"):
        read_points(tmp_path / "bad.pcd")


def test_pcd_with_padding_and_count_fields_written_by_hand(tmp_path: Path) -> None:
    """PCL's layouts: a repeated '_' padding field, a COUNT 4 field, a uint field; read independently of pypcd4."""
    import lzf

    n = 5
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "u1", 4), ("hist", "<f4", 4), ("pad2", "u1")])
    rows = np.zeros(n, dtype)
    rows["x"], rows["y"], rows["z"] = np.arange(n), 10 + np.arange(n), -np.arange(n)
    rows["hist"] = np.arange(4 * n).reshape(n, 4)
    fields = ("x y z _ hist _", "4 4 4 1 4 1", "F F F U F U", "1 1 1 4 4 1")
    expected = np.column_stack([np.arange(n), 10 + np.arange(n), -np.arange(n)])
    (tmp_path / "b.pcd").write_bytes(pcd_header(*fields, n, 1, n, "binary") + rows.tobytes())
    soa = b"".join(np.ascontiguousarray(rows[name]).tobytes() for name in dtype.names)
    packed = lzf.compress(soa)
    body = struct.pack("<II", len(packed), len(soa)) + packed
    (tmp_path / "c.pcd").write_bytes(pcd_header(*fields, n, 1, n, "binary_compressed") + body)
    text = "".join(f"{x:g} {y:g} {z:g} 0 0 0 0 {' '.join(map(str, h))} 0\n" for x, y, z, _, h, _ in rows.tolist())
    (tmp_path / "a.pcd").write_bytes(pcd_header(*fields, n, 1, n, "ascii") + text.encode())
    for name in ("b.pcd", "c.pcd", "a.pcd"):
        np.testing.assert_array_equal(read_points(tmp_path / name), expected, err_msg=name)


def test_ascii_ply_with_more_vertices_declared_than_held_is_refused(tmp_path: Path) -> None:
    """Face rows must not be read as vertices when the vertex count is too large."""
    head = "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n"
    faces = "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    (tmp_path / "faces.ply").write_text(head.format(4) + faces)
    with pytest.raises(CloudFileError, match="'vertex' row 4 has 4 values, the header declares 3"):
        read_points(tmp_path / "faces.ply")
    (tmp_path / "short.ply").write_text(head.format(9) + "end_header\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(CloudFileError, match=r"header declares 9 'vertex' rows but the file holds only 3"):
        read_points(tmp_path / "short.ply")


def test_big_endian_ply_reads_the_same(tmp_path: Path) -> None:
    header = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
    header += b"property double z\nend_header\n"
    (tmp_path / "be.ply").write_bytes(header + np.arange(9.0).astype(">f8").tobytes())
    np.testing.assert_array_equal(read_points(tmp_path / "be.ply"), np.arange(9.0).reshape(3, 3))


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("empty.xyz", b"", "no data"),
        ("comments.xyz", b"# only a comment\n\n", "no data"),
        ("binary.xyz", b"\xff\xfe\x00\x01", "not a text file"),
        ("empty.npy", b"", "not a .npy file"),
        ("empty.ply", b"", "not a PLY file"),
        ("count.ply", b"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", "count '-3', not an integer"),
    ],
)
def test_empty_and_unreadable_files(tmp_path: Path, name: str, content: bytes, message: str) -> None:
    (tmp_path / name).write_bytes(content)
    with pytest.raises(CloudFileError, match=message):  # and no warning: pytestmark makes one an error
        read_points(tmp_path / name)


def test_truncated_npy_says_how_many_points_it_holds(tmp_path: Path) -> None:
    np.save(tmp_path / "p.npy", np.zeros((50, 3)))
    data = (tmp_path / "p.npy").read_bytes()
    (tmp_path / "p.npy").write_bytes(data[: len(data) - 24 * 10 - 1])
    with pytest.raises(CloudFileError, match=r"header declares 50 points but the file holds only 39 \(cut short\?\)"):
        read_points(tmp_path / "p.npy")


def test_directory_and_missing_files_are_named(tmp_path: Path) -> None:
    (tmp_path / "d.xyz").mkdir()
    with pytest.raises(CloudFileError, match="is a directory"):
        read_points(tmp_path / "d.xyz")
    with pytest.raises(CloudFileError, match="is a directory"):
        read_indices(tmp_path / "d.xyz", 5)
    with pytest.raises(CloudFileError, match="no such file"):
        read_normals_file(tmp_path / "none.normals")
