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
    write_points,
)


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
            "truncated",
        ),
        ("junk.pcd", b"\x00\x01garbage", "cannot read as pcd"),
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


def test_unknown_output_suffix_and_xyz_writer(tmp_path: Path, cloud) -> None:
    points, normals, _ = cloud
    with pytest.raises(CloudFileError, match="unknown output suffix"):
        write_normals(tmp_path / "o.txt", points, normals)
    write_points(tmp_path / "p.xyz", np.arange(9.0).reshape(3, 3))
    np.testing.assert_array_equal(read_points(tmp_path / "p.xyz"), np.arange(9.0).reshape(3, 3))
