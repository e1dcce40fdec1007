"""The MCAP sink: labelled scans and poses read back with the mcap reader, and opened by Rerun."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from fixtures import interruptible
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rrd_read import read_rrd
from sinks_data import VELODYNE, frames

from aftershock.pipeline.classes import UNLABELLED, class_colors
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.pointcloud2 import decode_pointcloud2, pose_to_matrix, unpack_rgb
from aftershock.pipeline.sink import Stage
from aftershock.pipeline.types import Frame, LabelledCloud, RunInfo, RunSummary
from aftershock.sinks.mcap_sink import MAX_PENDING, POINTS_TOPIC, POSE_TOPIC, McapSink

REPO = Path(__file__).resolve().parents[1]


def _write(path: Path, frames_: list[Frame], stages: tuple[Stage, ...] = tuple(Stage)) -> None:
    sink = McapSink(path, force=False)
    sink.begin(RunInfo("log.mcap", "mcap"))
    try:
        for frame in frames_:
            for stage in stages:
                sink.stage(frame, stage)
        sink.end(RunSummary(scans=len(frames_)), LabelledCloud(np.zeros((0, 3))))
    finally:
        sink.close()


def _read(path: Path) -> dict[str, list]:
    out: dict[str, list] = {POINTS_TOPIC: [], POSE_TOPIC: []}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary() is not None, "no summary: the file was not finished"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            out[channel.topic].append((schema.name, message, msg))
    return out


@pytest.fixture(scope="module")
def velodyne_frames(lidar_dir: Path) -> list[Frame]:
    return list(frames(lidar_dir / VELODYNE, repeat=2))


def test_labelled_scans_and_poses_read_back(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    path = tmp_path / "out.mcap"
    _write(path, velodyne_frames)
    got = _read(path)
    assert len(got[POINTS_TOPIC]) == len(got[POSE_TOPIC]) == len(velodyne_frames)
    for frame, (schema, message, msg) in zip(velodyne_frames, got[POINTS_TOPIC], strict=True):
        assert schema == "sensor_msgs/msg/PointCloud2" and msg.header.frame_id == "map"
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == frame.scan.stamp_ns
        assert message.log_time == frame.scan.log_time_ns
        cols = decode_pointcloud2(msg).columns
        assert cols["x"].dtype == np.float32 and cols["class_id"].dtype == np.uint16
        assert cols["instance_id"].dtype == np.uint32
        xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
        assert np.allclose(xyz, frame.world_points, atol=1e-4)
        assert np.array_equal(cols["class_id"], frame.labels.class_ids)
        assert np.array_equal(cols["instance_id"], frame.labels.instance_ids)
        assert np.array_equal(unpack_rgb(cols["rgb"]), class_colors(frame.labels.class_ids))
        assert np.array_equal(cols["intensity"], frame.scan.intensity)
        assert UNLABELLED in cols["class_id"]  # points outside the labelling range stay unlabelled
    for frame, (schema, _, msg) in zip(velodyne_frames, got[POSE_TOPIC], strict=True):
        assert schema == "geometry_msgs/msg/PoseStamped" and msg.header.frame_id == "map"
        assert np.allclose(pose_to_matrix(msg.pose), frame.pose, atol=1e-9)


def test_rerun_opens_the_file(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    path, rrd = tmp_path / "out.mcap", tmp_path / "converted.rrd"
    _write(path, velodyne_frames)
    rerun = Path(sys.executable).with_name("rerun")
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    done = subprocess.run(
        [str(rerun), "mcap", "convert", str(path), "-o", str(rrd)], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    # structural check (`--full` also flags Rerun's own split of each cloud, on the input logs too)
    cmd = [str(rerun), "mcap", "check", str(path)]
    check = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stdout + check.stderr
    for topic in (POINTS_TOPIC, POSE_TOPIC):
        assert any(line.startswith("ok") and topic in line for line in check.stdout.splitlines()), check.stdout
    rec = read_rrd(rrd)
    entity = POINTS_TOPIC.lstrip("/")
    rows = rec.rows(entity, "Points3D:positions")
    assert len(rows) == len(velodyne_frames)
    assert [len(r) for r in rows] == [len(f.scan) for f in velodyne_frames]
    classes = np.concatenate([np.asarray(r) for r in rec.rows(entity, "Points3D:class_id")])
    assert set(np.unique(classes)) == set(np.unique(np.concatenate([f.labels.class_ids for f in velodyne_frames])))
    assert len(rec.rows(POSE_TOPIC.lstrip("/"), "InstancePoses3D:translations")) == len(velodyne_frames)
    stamps = rec.times(entity, "Points3D:positions", "ros2_timestamp")
    assert stamps.tolist() == [f.scan.stamp_ns for f in velodyne_frames]


def test_written_without_begin(velodyne_frames: list[Frame], tmp_path: Path) -> None:
    path = tmp_path / "nobegin.mcap"
    sink = McapSink(path)
    for stage in Stage:
        sink.stage(velodyne_frames[0], stage)
    sink.close()
    got = _read(path)
    assert len(got[POINTS_TOPIC]) == len(got[POSE_TOPIC]) == 1


def test_frames_without_a_clustering_stage_are_written(lidar_dir: Path, tmp_path: Path) -> None:
    path = tmp_path / "partial.mcap"
    many = list(frames(lidar_dir / VELODYNE, repeat=4))
    assert len(many) > MAX_PENDING  # more frames than wait in the queue
    _write(path, many, stages=(Stage.RAW, Stage.REGISTERED, Stage.LABELLED))
    got = _read(path)
    stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for _, _, m in got[POINTS_TOPIC]]
    assert stamps == [f.scan.stamp_ns for f in many]
    assert [m.sequence for _, m, _ in got[POINTS_TOPIC]] == sorted(m.sequence for _, m, _ in got[POINTS_TOPIC])


def test_refuses_to_overwrite_and_reports_unwritable(tmp_path: Path) -> None:
    path = tmp_path / "out.mcap"
    path.write_bytes(b"old")
    with pytest.raises(OutputError, match="already exists"):
        McapSink(path)
    sink = McapSink(path, force=True)
    assert path.read_bytes() == b"old"  # untouched until the run begins
    sink.close()
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")
    with pytest.raises(OutputError):
        McapSink(not_a_folder / "out.mcap")


_CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from aftershock.pipeline.types import LabelledCloud, RunInfo, RunSummary
    from aftershock.pipeline.sink import Stage
    from aftershock.sinks.mcap_sink import McapSink
    from sinks_data import frames
    import numpy as np

    log, out = Path(sys.argv[1]), Path(sys.argv[2])
    sink = McapSink(out)
    sink.begin(RunInfo(str(log), "mcap"))
    n = 0
    try:
        for frame in frames(log, repeat=10_000):
            for stage in Stage:
                sink.stage(frame, stage)
            n += 1
            print(frame.seq, flush=True)
    except KeyboardInterrupt:
        sink.end(RunSummary(scans=n, interrupted=True), LabelledCloud(np.zeros((0, 3))))
    finally:
        sink.close()
    """
)


def test_ctrl_c_leaves_a_finished_file(lidar_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "interrupted.mcap"
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{REPO / 'tests'}")
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(lidar_dir / VELODYNE), str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, text=True, preexec_fn=interruptible,
    )  # fmt: skip
    assert child.stdout is not None
    for _ in range(6):
        assert child.stdout.readline(), "the child stopped before it was interrupted"
    child.send_signal(signal.SIGINT)
    child.wait(timeout=60)
    assert child.returncode == 0
    got = _read(out)
    assert len(got[POINTS_TOPIC]) >= 6 and len(got[POINTS_TOPIC]) == len(got[POSE_TOPIC])
