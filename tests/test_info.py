"""`aftershock info` through the real command line: reports, JSON, and every kind of bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fixtures import (
    organized_columns,
    truncate_in_chunk,
    write_bag,
    write_ros1_mcap,
    write_ros2_mcap,
    write_string_mcap,
    xyz_columns,
)
from mcap.writer import CompressionType

AFTERSHOCK = str(Path(sys.executable).parent / "aftershock")


def cli(*args: str | Path) -> subprocess.CompletedProcess:
    """The installed console script, in its own process."""
    return subprocess.run([AFTERSHOCK, *map(str, args)], capture_output=True, text=True, timeout=120)


def main(capsys: pytest.CaptureFixture, *args: str | Path) -> subprocess.CompletedProcess:
    """The same entry point in this process (the import of every command is paid once)."""
    import warnings

    from aftershock.pipeline.cli import main as entry

    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        code = entry([str(a) for a in args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, out, err)


def test_info_json_on_real_logs(lidar_dir: Path, capsys: pytest.CaptureFixture) -> None:
    runs = {
        name: main(capsys, "info", lidar_dir / name, "--json")
        for name in ("velodyne_vlp16_indoor.mcap", "ouster_os1_128_outdoor.mcap", "ouster_os1_64_ros1.mcap")
    }
    for name, r in runs.items():
        assert r.returncode == 0, r.stderr
        report = json.loads(r.stdout)  # nothing but JSON on stdout
        assert all(set(t) == {"name", "type", "count"} for t in report["topics"]), name
    vlp = json.loads(runs["velodyne_vlp16_indoor.mcap"].stdout)
    assert vlp["topics"] == [{"name": "/velodyne_points", "type": "sensor_msgs/msg/PointCloud2", "count": 4}]
    assert vlp["point_clouds"][0]["points_min"] > 14_000 and vlp["point_clouds"][0]["per_point_time"] == "time"
    os1 = json.loads(runs["ouster_os1_128_outdoor.mcap"].stdout)
    assert os1["point_clouds"][0]["organized"] == "128 x 1024" and os1["point_clouds"][0]["scans"] == 3
    ros1 = json.loads(runs["ouster_os1_64_ros1.mcap"].stdout)
    assert {"name": "/os1_node/lidar_packets", "type": "ouster_ros/PacketMsg", "count": 206} in ros1["topics"]
    assert len(ros1["topics"]) == 10


def test_info_text_on_bag_with_ground_truth(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = [xyz_columns(80, seed=s) | {"class_id": np.full(80, 2, np.uint16), "instance_id": np.ones(80, np.uint32)}
            for s in range(3)]  # fmt: skip
    r = main(capsys, "info", write_bag(tmp_path / "gt.bag", data, ros2=False))
    assert r.returncode == 0, r.stderr
    assert "ground truth: class_id, instance_id" in r.stdout
    assert "min 80, median 80, max 80" in r.stdout
    assert "per-point time: t (ns_offset)" in r.stdout


@pytest.fixture(scope="module")
def bad_inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path | str, list[str], str]]:
    """name -> (path, extra args, the problem the one-line error must state)."""
    d = tmp_path_factory.mktemp("bad")
    (d / "empty").mkdir()
    (d / "empty" / "readme.txt").write_text("no clouds here")
    (d / "text.mcap").write_text("this is not an MCAP file\n")
    noxyz = [{"a": np.ones(5, np.float32)}]
    invalid = [organized_columns(2, 8, zero_rows=[0, 1])]
    invalid[0]["x"][:3] = np.nan
    return {
        "missing": (d / "nope.mcap", [], "no such file or directory"),
        "nothing readable": (d / "empty", [], "nothing readable here"),
        "not mcap": (d / "text.mcap", [], "not an MCAP file"),
        "no point cloud": (write_string_mcap(d / "s.mcap"), [], "no point-cloud topic"),
        "no such topic": (write_ros1_mcap(d / "r1.mcap", [xyz_columns(10)]), ["--topic", "/nope"], "no topic '/nope'"),
        "no xyz": (write_ros2_mcap(d / "n.mcap", noxyz), [], "point cloud has no x/y/z fields (fields: a)"),
        "all invalid": (write_ros2_mcap(d / "i.mcap", invalid, height=2), [], "every point of every scan"),
    }


def test_bad_inputs_fail_in_one_line(bad_inputs: dict, capsys: pytest.CaptureFixture) -> None:
    results = {name: main(capsys, "info", path, *extra) for name, (path, extra, _) in bad_inputs.items()}
    # and two through the console script in a process of its own
    for name in ("not mcap", "no xyz"):
        path, extra, _ = bad_inputs[name]
        results[name + " (process)"] = cli("info", path, *extra)
    for name, r in results.items():
        path, _, problem = bad_inputs[name.removesuffix(" (process)")]
        assert r.returncode == 2, (name, r.stderr)
        assert "Traceback" not in r.stderr, name
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, (name, r.stderr)
        assert lines[0].startswith(f"aftershock: error: {path}: "), (name, lines[0])
        assert problem in lines[0], (name, lines[0])
        assert r.stdout == "", name


def test_cut_off_log_reports_what_precedes_and_warns(tmp_path: Path) -> None:
    full = write_ros2_mcap(tmp_path / "full.mcap", [xyz_columns(3000, seed=s) for s in range(6)], chunk_size=1000,
                           compression=CompressionType.LZ4)  # fmt: skip
    cut = tmp_path / "cut.mcap"
    truncate_in_chunk(full, cut, 3)
    r = cli("info", cut, "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr
    report = json.loads(r.stdout)
    assert report["point_clouds"][0]["scans"] == 3
    assert "cut off" in report["damage"]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"aftershock: warning: {cut}: the log is cut off at byte")


def test_progress_bar_only_on_a_terminal() -> None:
    from aftershock.pipeline import progress

    assert not progress.enabled(quiet=True)
    assert not progress.enabled()  # pytest's captured stderr is not a terminal
    with progress.bar(2, "log") as b:
        assert b.disable
    with progress.bar(2, "log", show=True) as b:
        assert not b.disable and b.total == 2
    assert list(progress.track(range(3), show=False)) == [0, 1, 2]
