"""MCAP reading on generated logs: ROS 2, ROS 1 and foxglove encodings, topic choice, windows, poses, damage."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from fixtures import (
    PERIOD_NS,
    T0_NS,
    chunk_offsets,
    organized_columns,
    truncate_in_chunk,
    write_foxglove_mcap,
    write_ros1_mcap,
    write_ros2_mcap,
    xyz_columns,
)
from mcap.writer import CompressionType
from scipy.spatial.transform import Rotation

from aftershock import sources
from aftershock.pipeline.errors import DamagedLogWarning, InputError
from aftershock.sources.mcap_source import read_catalog


def clouds(k: int, n: int = 200) -> list[dict]:
    return [xyz_columns(n, seed=s) for s in range(k)]


def xyz(cols: dict) -> np.ndarray:
    return np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)


def read(path: Path, **kw) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("error", DamagedLogWarning)
        return list(sources.open(path, **kw))


@pytest.mark.parametrize("writer", [write_ros2_mcap, write_ros1_mcap, write_foxglove_mcap])
def test_three_encodings_give_the_same_scans(tmp_path: Path, writer) -> None:
    data = clouds(3)
    scans = read(writer(tmp_path / "log.mcap", data))
    assert [s.seq for s in scans] == [0, 1, 2]
    for k, (scan, cols) in enumerate(zip(scans, data, strict=True)):
        np.testing.assert_allclose(scan.points, xyz(cols))
        np.testing.assert_allclose(scan.intensity, cols["intensity"])
        np.testing.assert_allclose(scan.times, cols["t"] * 1e-9)
        assert scan.stamp_ns == scan.log_time_ns == T0_NS + k * PERIOD_NS
        assert scan.frame_id == "lidar" and scan.topic == "/points"
    assert sources.describe(tmp_path / "log.mcap").log_start_ns == T0_NS


def test_organized_big_endian_padded(tmp_path: Path) -> None:
    data = [organized_columns(16, 32, zero_rows=[0, 7, 15], nan_points=20, seed=s) for s in range(2)]
    path = write_ros2_mcap(tmp_path / "o.mcap", data, height=16, big_endian=True, point_step=32, row_padding=12)
    scans = read(path)
    for scan, cols in zip(scans, data, strict=True):
        pts = xyz(cols)
        keep = np.isfinite(pts).all(1) & (pts != 0).any(1)
        np.testing.assert_allclose(scan.points, pts[keep])
        np.testing.assert_allclose(scan.times, cols["t"][keep] * 1e-9)
        assert len(scan) < 16 * 32 - 3 * 32


def test_topic_choice(tmp_path: Path) -> None:
    path = write_ros2_mcap(tmp_path / "two.mcap", clouds(2), extra_cloud_topic="/other")
    with pytest.raises(InputError, match=r"2 point-cloud topics \(/other, /points\); choose one with --topic"):
        sources.open(path)
    assert [s.topic for s in read(path, topic="/other")] == ["/other", "/other"]
    with pytest.raises(InputError, match="no topic '/nope'"):
        sources.open(path, topic="/nope")


def test_window_every_max(tmp_path: Path) -> None:
    path = write_ros2_mcap(tmp_path / "w.mcap", clouds(10, 50))
    stamps = lambda scans: [(s.stamp_ns - T0_NS) // PERIOD_NS for s in scans]  # noqa: E731
    assert stamps(read(path, start_s=0.25, end_s=0.65)) == [3, 4, 5, 6]
    assert stamps(read(path, every=3)) == [0, 3, 6, 9]
    assert stamps(read(path, every=2, max_scans=3, start_s=0.1)) == [1, 3, 5]
    assert [s.seq for s in read(path, every=2, max_scans=3, start_s=0.1)] == [0, 1, 2]
    assert read(path, start_s=5.0) == []
    with pytest.raises(InputError, match="--every"):
        sources.open(path, every=0)


def test_zero_header_stamp_falls_back_to_log_time(tmp_path: Path) -> None:
    scans = read(write_ros2_mcap(tmp_path / "z.mcap", clouds(2), zero_header_stamp=True))
    assert [s.stamp_ns for s in scans] == [T0_NS, T0_NS + PERIOD_NS]


def _poses(k: int) -> list[np.ndarray]:
    out = []
    for i in range(k):
        m = np.eye(4)
        m[:3, :3] = Rotation.from_euler("z", 10 * i, degrees=True).as_matrix()
        m[:3, 3] = [i * 1.0, 0.5 * i, 0.0]
        out.append(m)
    return out


def test_ground_truth_pose_exact_and_interpolated(tmp_path: Path) -> None:
    poses = _poses(5)
    scans = read(write_ros2_mcap(tmp_path / "p.mcap", clouds(5), poses=poses))
    for scan, pose in zip(scans, poses, strict=True):
        np.testing.assert_allclose(scan.gt_pose, pose, atol=1e-9)
    # poses stamped 60 ms after each scan: scan k lies 40 % of the way from pose k-1 to pose k
    offset = 60_000_000
    scans = read(write_ros2_mcap(tmp_path / "q.mcap", clouds(5), poses=poses, pose_offset_ns=offset))
    assert scans[0].gt_pose is None  # before the first pose, 60 ms away: beyond the 50 ms tolerance
    for k in range(1, 5):
        mid = scans[k].gt_pose
        np.testing.assert_allclose(mid[:3, 3], 0.6 * poses[k - 1][:3, 3] + 0.4 * poses[k][:3, 3], atol=1e-9)
        yaw = Rotation.from_matrix(mid[:3, :3]).as_euler("xyz", degrees=True)[2]
        assert yaw == pytest.approx(10 * k - 6, abs=1e-6)


def test_cut_off_log_yields_complete_scans_then_warns(tmp_path: Path) -> None:
    data = clouds(6, 3000)
    full = write_ros2_mcap(tmp_path / "full.mcap", data, chunk_size=1000, compression=CompressionType.ZSTD)
    assert len(chunk_offsets(full)) >= 6  # one scan per chunk
    cut = tmp_path / "cut.mcap"
    truncate_in_chunk(full, cut, 4)  # the 5th scan is damaged
    assert read_catalog(full).indexed and read_catalog(full).damage is None  # read through its index
    assert not read_catalog(cut).indexed and "cut off" in read_catalog(cut).damage
    with pytest.warns(DamagedLogWarning, match=r"cut off at byte .*read 4 complete scans"):
        scans = list(sources.open(cut))
    assert len(scans) == 4
    for scan, cols in zip(scans, data[:4], strict=True):
        np.testing.assert_allclose(scan.points, xyz(cols))


def test_cut_off_uncompressed_and_mid_log(tmp_path: Path) -> None:
    full = write_ros2_mcap(tmp_path / "f.mcap", clouds(5, 3000), chunk_size=1000, compression=CompressionType.NONE)
    cut = tmp_path / "c.mcap"
    truncate_in_chunk(full, cut, 2)
    with pytest.warns(DamagedLogWarning):
        assert len(list(sources.open(cut))) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(list(sources.open(cut, max_scans=1))) == 1  # stops before reaching the damage


def test_bad_inputs(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        sources.open(tmp_path / "missing.mcap")
    (tmp_path / "text.mcap").write_text("hello")
    with pytest.raises(InputError, match="not an MCAP file"):
        sources.open(tmp_path / "text.mcap")
    from fixtures import write_string_mcap

    with pytest.raises(InputError, match=r"no point-cloud topic .* /chatter \(std_msgs/msg/String\)"):
        sources.open(write_string_mcap(tmp_path / "s.mcap"))
    noxyz = [{"a": np.ones(4, np.float32), "b": np.ones(4, np.float32)}]
    with pytest.raises(InputError, match=r"/points: point cloud has no x/y/z fields \(fields: a, b\)"):
        list(sources.open(write_ros2_mcap(tmp_path / "n.mcap", noxyz)))
    bad = [organized_columns(2, 8, zero_rows=[0], nan_points=0) for _ in range(2)]
    for cols in bad:
        cols["x"][8:] = np.nan
    with pytest.raises(InputError, match="every point of every scan on /points is invalid"):
        list(sources.open(write_ros2_mcap(tmp_path / "i.mcap", bad, height=2)))


def test_streams_one_scan_at_a_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Lazy: a scan is decoded when it is asked for, and clouds skipped by --every are never decoded."""
    import aftershock.sources.mcap_source as ms

    decoded = []
    real = ms._decode_cloud
    monkeypatch.setattr(ms, "_decode_cloud", lambda *a: decoded.append(1) or real(*a))
    it = sources.open(write_ros2_mcap(tmp_path / "l.mcap", clouds(6)), every=2)
    assert decoded == []
    next(it)
    assert len(decoded) == 1
    assert len(list(it)) == 2 and len(decoded) == 3
