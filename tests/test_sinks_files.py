"""The file exports: labelled PLY map, TUM and KITTI poses, JSON summary, and the refusal to overwrite."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sinks_data import VELODYNE, frames, map_of

from aftershock.pipeline.classes import CLASS_NAMES, class_colors
from aftershock.pipeline.cloud_io import read_cloud
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.sink import Stage
from aftershock.pipeline.types import Frame, LabelledCloud, RunInfo, RunSummary
from aftershock.sinks.files import KITTI_FILE, MAP_FILE, SUMMARY_FILE, TUM_FILE, FileExportSink, map_statistics


def _export(folder: Path, frames_: list[Frame], force: bool = False, interrupted: bool = False) -> FileExportSink:
    sink = FileExportSink(folder, force)
    sink.begin(RunInfo("log.mcap", "mcap", topic="/velodyne_points"))
    try:
        for frame in frames_:
            for stage in Stage:
                sink.stage(frame, stage)
        summary = RunSummary(scans=len(frames_), points=sum(len(f.scan) for f in frames_), interrupted=interrupted)
        summary.mean_timings_ms = {"register": 12.5}
        sink.end(summary, map_of(frames_))
    finally:
        sink.close()
    return sink


@pytest.fixture(scope="module")
def velodyne_frames(lidar_dir: Path) -> list[Frame]:
    out = list(frames(lidar_dir / VELODYNE, repeat=2))
    for f in out:  # the pose at the stamp differs from the end-of-sweep pose when deskewed
        f.stamp_pose = f.pose.copy()
        f.stamp_pose[0, 3] -= 0.01
    return out


def test_exports_read_back(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    folder = tmp_path / "export"
    _export(folder, velodyne_frames)
    assert sorted(p.name for p in folder.iterdir()) == sorted([MAP_FILE, TUM_FILE, KITTI_FILE, SUMMARY_FILE])

    expected = map_of(velodyne_frames)
    cloud = read_cloud(folder / MAP_FILE)
    assert len(cloud) == len(expected)
    assert np.allclose(cloud.points, expected.points, atol=1e-4)
    assert np.array_equal(cloud.class_ids, expected.class_ids)
    assert np.array_equal(cloud.instance_ids, expected.instance_ids)
    # The log has no colour: other tools see the classes' colours, and our reader no colour (they stand in)
    from plyfile import PlyData

    v = PlyData.read(str(folder / MAP_FILE))["vertex"].data
    assert np.array_equal(np.stack([v["red"], v["green"], v["blue"]], axis=1), class_colors(expected.class_ids))
    assert cloud.colors is None

    tum = np.loadtxt(folder / TUM_FILE, dtype=np.float64)
    assert tum.shape == (len(velodyne_frames), 8)
    stamps = [line.split()[0] for line in (folder / TUM_FILE).read_text().splitlines()]
    assert stamps == [f"{f.scan.stamp_ns // 10**9}.{f.scan.stamp_ns % 10**9:09d}" for f in velodyne_frames]
    for row, f in zip(tum, velodyne_frames, strict=True):
        assert np.allclose(row[1:4], f.stamp_pose[:3, 3], atol=1e-6)
        assert np.allclose(Rotation.from_quat(row[4:]).as_matrix(), f.stamp_pose[:3, :3], atol=1e-6)

    kitti = np.loadtxt(folder / KITTI_FILE)
    assert kitti.shape == (len(velodyne_frames), 12)
    assert np.allclose(kitti.reshape(-1, 3, 4), [f.stamp_pose[:3, :4] for f in velodyne_frames], atol=1e-6)

    summary = json.loads((folder / SUMMARY_FILE).read_text())
    assert summary["scans"] == len(velodyne_frames) and summary["interrupted"] is False
    assert summary["mean_timings_ms"] == {"register": 12.5}
    assert summary["map_points"] == len(expected) and summary["poses_written"] == len(velodyne_frames)
    assert summary["source"]["topic"] == "/velodyne_points"
    ids = np.unique(expected.instance_ids[expected.instance_ids > 0])
    assert sum(summary["instances_per_class"].values()) == len(ids)
    assert set(summary["map_points_per_class"]) == {CLASS_NAMES[c] for c in np.unique(expected.class_ids) if c < 14}


def test_map_statistics_count_majority_classes() -> None:
    cls = np.array([2, 2, 4, 4, 4, 1, 65535], np.uint16)
    inst = np.array([1, 1, 1, 2, 2, 0, 3], np.uint32)  # instance 1 is mostly wall; 3 is unlabelled
    stats = map_statistics(LabelledCloud(np.zeros((7, 3)), class_ids=cls, instance_ids=inst))
    assert stats["instances_per_class"] == {"wall": 1, "column": 1}
    assert stats["points_per_class"] == {"floor": 1, "wall": 2, "column": 3}


def test_interrupted_run_keeps_poses_and_summary(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    folder = tmp_path / "cut"
    _export(folder, velodyne_frames[:3], interrupted=True)
    assert len((folder / TUM_FILE).read_text().splitlines()) == 3
    assert json.loads((folder / SUMMARY_FILE).read_text())["interrupted"] is True


def test_refuses_to_overwrite_unless_forced(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    folder = tmp_path / "export"
    _export(folder, velodyne_frames[:2])
    before = (folder / TUM_FILE).read_text()
    with pytest.raises(OutputError, match="already exists"):
        FileExportSink(folder)
    assert (folder / TUM_FILE).read_text() == before
    _export(folder, velodyne_frames[:1], force=True)
    assert len((folder / TUM_FILE).read_text().splitlines()) == 1


def test_unwritable_places_fail_at_construction(tmp_path: Path) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        FileExportSink(a_file)
    with pytest.raises(OutputError):
        FileExportSink(a_file / "below")
    fresh = tmp_path / "fresh"
    FileExportSink(fresh).close()  # checked, never begun
    assert list(fresh.iterdir()) == []


def test_a_cloud_without_color_reads_back_without_color(tmp_path: Path) -> None:
    """The PLY format carries red, green, blue always: grey (or colour made up by the caller) stands in, the header
    says so, and the cloud reads back without colour; a PLY with real colour keeps it."""
    from aftershock.pipeline.cloud_io import STAND_IN_COLOR_COMMENT, read_cloud, write_cloud
    from aftershock.pipeline.types import LabelledCloud

    pts = np.random.default_rng(0).random((50, 3))
    grey = write_cloud(tmp_path / "grey.ply", LabelledCloud(pts))
    assert STAND_IN_COLOR_COMMENT.encode() in grey.read_bytes()[:1024]
    assert read_cloud(grey).colors is None
    rgb = np.full((50, 3), 90, np.uint8)
    assert np.array_equal(read_cloud(write_cloud(tmp_path / "rgb.ply", LabelledCloud(pts, rgb))).colors, rgb)
    made_up = write_cloud(tmp_path / "classes.ply", LabelledCloud(pts, rgb), stand_in_color=True)
    assert read_cloud(made_up).colors is None
