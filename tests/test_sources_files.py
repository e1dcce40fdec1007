"""Point-cloud files (PCD ascii/binary/binary_compressed, PLY, KITTI .bin) and ROS 1/ROS 2 bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures import PERIOD_NS, T0_NS, write_bag, xyz_columns

from aftershock import sources
from aftershock.pipeline.errors import InputError
from aftershock.sources.files import FILE_PERIOD_NS, lzf_decompress, read_pcd


def points_of(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-5, 5, (n, 3)).astype(np.float32)


def pcd_header(fields: list[tuple[str, str, int, int]], n: int, data: str) -> bytes:
    names = " ".join(f[0] for f in fields)
    sizes = " ".join(str(f[2]) for f in fields)
    types = " ".join(f[1] for f in fields)
    counts = " ".join(str(f[3]) for f in fields)
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {names}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode()


def lzf_literals(data: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (what a compressor emits for random bytes)."""
    out = bytearray()
    for i in range(0, len(data), 32):
        block = data[i : i + 32]
        out.append(len(block) - 1)
        out += block
    return bytes(out)


def test_lzf_back_references() -> None:
    # "abc" then a back reference of length 7 at distance 3: an overlapping copy repeating "abc"
    stream = bytes([2]) + b"abc" + bytes([(5 << 5) | 0, 2])
    assert lzf_decompress(stream, 10) == b"abcabcabca"
    with pytest.raises(ValueError):
        lzf_decompress(stream, 12)


def test_pcd_ascii_binary_compressed_agree(tmp_path: Path) -> None:
    n = 50
    pts = points_of(n, 1)
    inten = np.arange(n, dtype=np.float32)
    rgb = np.array([0x102030] * n, np.uint32)
    ring = (np.arange(n) % 16).astype(np.uint16)
    fields = [("x", "F", 4, 1), ("y", "F", 4, 1), ("z", "F", 4, 1), ("intensity", "F", 4, 1), ("rgb", "U", 4, 1),
              ("ring", "U", 2, 1), ("_", "U", 1, 2)]  # fmt: skip
    ascii_rows = "\n".join(
        f"{p[0]!r} {p[1]!r} {p[2]!r} {i} {c} {r} 0 0" for p, i, c, r in zip(pts.tolist(), inten, rgb, ring, strict=True)
    )
    (tmp_path / "a.pcd").write_bytes(pcd_header(fields, n, "ascii") + ascii_rows.encode() + b"\n")
    rec = np.zeros(
        n,
        [
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("intensity", "<f4"),
            ("rgb", "<u4"),
            ("ring", "<u2"),
            ("pad", "u1", (2,)),
        ],
    )
    rec["x"], rec["y"], rec["z"], rec["intensity"], rec["rgb"], rec["ring"] = *pts.T, inten, rgb, ring
    (tmp_path / "b.pcd").write_bytes(pcd_header(fields, n, "binary") + rec.tobytes())
    field_major = b"".join(rec[name].tobytes() for name in rec.dtype.names)
    packed = lzf_literals(field_major)
    body = np.array([len(packed), len(field_major)], "<u4").tobytes() + packed
    (tmp_path / "c.pcd").write_bytes(pcd_header(fields, n, "binary_compressed") + body)
    for name in ("a.pcd", "b.pcd", "c.pcd"):
        cols = read_pcd(tmp_path / name)
        assert "_" not in cols and not any(k.startswith("_") for k in cols)
        np.testing.assert_array_equal(np.stack([cols["x"], cols["y"], cols["z"]], 1), pts, err_msg=name)
        np.testing.assert_array_equal(cols["ring"], ring, err_msg=name)
    scans = list(sources.open(tmp_path))
    assert len(scans) == 3
    for s in scans:
        np.testing.assert_array_equal(s.colors, np.tile([0x10, 0x20, 0x30], (n, 1)))
        np.testing.assert_array_equal(s.intensity, inten)


def test_ply_and_kitti_in_name_order(tmp_path: Path) -> None:
    from plyfile import PlyData, PlyElement

    pts = points_of(30, 2)
    v = np.zeros(30, [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                      ("class_id", "i4"), ("instance_id", "i4")])  # fmt: skip
    v["x"], v["y"], v["z"] = pts.T
    v["red"], v["class_id"], v["instance_id"] = 200, 4, np.arange(30)
    PlyData([PlyElement.describe(v, "vertex")]).write(str(tmp_path / "scan10.ply"))
    kitti = np.concatenate([points_of(20, 3), np.full((20, 1), 0.5, np.float32)], axis=1)
    kitti[3] = [0, 0, 0, 0.5]  # an all-zero return is dropped
    kitti.astype("<f4").tofile(tmp_path / "scan2.bin")
    (tmp_path / "notes.txt").write_text("not a cloud")
    scans = list(sources.open(tmp_path))
    assert [len(s) for s in scans] == [19, 30]  # scan2 before scan10
    assert [s.stamp_ns for s in scans] == [0, FILE_PERIOD_NS]
    np.testing.assert_array_equal(scans[0].intensity, np.full(19, 0.5, np.float32))
    ply = scans[1]
    np.testing.assert_array_equal(ply.points, pts.astype(np.float64))
    assert ply.colors[0].tolist() == [200, 0, 0]
    np.testing.assert_array_equal(ply.class_ids, np.full(30, 4)) and ply.class_ids.dtype == np.uint16
    np.testing.assert_array_equal(ply.instance_ids, np.arange(30))
    assert [len(s) for s in sources.open(str(tmp_path / "*.bin"))] == [19]
    assert len(list(sources.open(tmp_path / "scan10.ply"))) == 1


def test_file_errors(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="nothing readable here"):
        sources.open(tmp_path / "empty")
    (tmp_path / "bad.bin").write_bytes(b"\0" * 17)
    with pytest.raises(InputError, match=r"not a KITTI \.bin scan"):
        list(sources.open(tmp_path / "bad.bin"))
    (tmp_path / "bad.pcd").write_bytes(b"VERSION 0.7\nFIELDS x y z\n")
    with pytest.raises(InputError, match="no DATA line"):
        list(sources.open(tmp_path / "bad.pcd"))
    (tmp_path / "weird.xyz").write_text("1 2 3")
    with pytest.raises(InputError, match="not an MCAP file, ROS bag or point-cloud file"):
        sources.open(tmp_path / "weird.xyz")


@pytest.mark.parametrize("ros2", [False, True])
def test_bags(tmp_path: Path, ros2: bool) -> None:
    data = [xyz_columns(120, seed=s) for s in range(4)]
    path = write_bag(tmp_path / ("b" if ros2 else "b.bag"), data, ros2=ros2)
    assert sources.kind_of(path) == "bag"
    scans = list(sources.open(path, every=2))
    assert [s.stamp_ns for s in scans] == [T0_NS, T0_NS + 2 * PERIOD_NS]
    for s, cols in zip(scans, data[::2], strict=True):
        np.testing.assert_allclose(s.points, np.stack([cols["x"], cols["y"], cols["z"]], 1))
        np.testing.assert_allclose(s.times, cols["t"] * 1e-9)
    assert len(list(sources.open(path, start_s=0.15))) == 2
    with pytest.raises(InputError, match="no topic '/x'"):
        sources.open(path, topic="/x")
    described = sources.describe(path)
    assert described.topic == "/points" and described.log_start_ns == T0_NS
