"""Faults and hostile input (issue 14): nothing lost, nothing hangs, one clear line.

Each failure the issue listed has a test here that reproduced it, named by the behaviour it specifies; the
fault-injection set (a full disk through a small tmpfs, SIGINT/SIGTERM/SIGKILL mid-run, truncated and corrupted
logs, hostile headers) runs with the default suite and on its own with `make test-faults`. Signals, exit codes and
full disks are tried on real subprocesses.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from faults_data import (
    MALFORMED,
    can_mount,
    corrupt_chunk,
    fill_disk,
    hall_clouds,
    huge_data_length,
    pcd_size_bomb,
    small_disk,
    strip_summary,
    write_log,
)
from fixtures import PERIOD_NS, T0_NS, chunk_offsets, interruptible, write_bag
from mcap.writer import CompressionType
from rrd_read import read_rrd, rrd_print, rrd_verify

from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.config import load_config
from aftershock.pipeline.errors import OutputError
from aftershock.pipeline.types import LabelledCloud, RunInfo
from aftershock.sinks import rerun_blueprint as L

RG: tuple[str, ...] = ("--labeller", "region-growing")
ENV = dict(os.environ, CI="true", RERUN_ANALYTICS="0", OMP_NUM_THREADS="1")
needs_root = pytest.mark.skipif(can_mount() is not None, reason=can_mount() or "")


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def cli_proc(args: list[str], timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    """The command line in its own process (stderr is a pipe, not a terminal)."""
    cmd = [sys.executable, "-m", "aftershock.pipeline", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=timeout, **kw)


def assert_one_line(err: str, *names: object) -> str:
    """The error is the last line of stderr, names what it is about, and there is no traceback or colour."""
    assert "Traceback" not in err and "\x1b[" not in err, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("aftershock: error:"), err
    for name in names:
        assert str(name) in line, (name, line)
    return line


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ----------------------------------------------------------------------------------- a full disk


@needs_root
def test_a_disk_too_full_for_a_recording_refuses_at_once_and_leaves_nothing(tmp_path: Path) -> None:
    log = write_log(tmp_path / "log.mcap", 6)
    with small_disk(tmp_path / "disk", "2m") as disk:
        done = cli_proc(["run", str(log), "--save", str(disk / "x.rrd"), *RG, "-q"], timeout=60)
        assert done.returncode == 2
        assert_one_line(done.stderr, disk / "x.rrd", "disk is nearly full")
        assert not (disk / "x.rrd").exists() and not (disk / "x.rrd.part").exists()


@needs_root
def test_a_disk_filling_mid_run_stops_the_recording_readable_and_finishes_the_others(tmp_path: Path) -> None:
    """The disk of --save fills while the run goes on: the run stops (no hang, Ctrl-C never needed), the
    recording is valid up to there and the outputs on other disks hold every processed scan."""
    log = write_log(tmp_path / "log.mcap", 400, points=3000)
    with small_disk(tmp_path / "disk", "64m") as disk:
        out = disk / "x.rrd"
        cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--save", str(out)]
        cmd += ["--mcap-out", str(tmp_path / "o.mcap"), "--export", str(tmp_path / "exp"), *RG, "-q"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
        deadline = time.monotonic() + 60
        part = disk / "x.rrd.part"  # the recording grows beside its name until it is closed
        while time.monotonic() < deadline and not (part.exists() and part.stat().st_size > 200_000):
            time.sleep(0.05)
        fill_disk(disk, 20 * 2**20)  # below the room a recording keeps: stopped at the next scan
        _, err = proc.communicate(timeout=90)
        assert proc.returncode == 2, err
        assert_one_line(err, out, "disk is nearly full", "stays readable")
        assert rrd_verify(out).returncode == 0 and not part.exists()  # closed complete: put in place
        scans = len(read_rrd(out).times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE))
    assert 0 < scans < 400
    summary = json.loads((tmp_path / "exp" / "summary.json").read_text())
    assert summary["interrupted"] and scans - 1 <= summary["scans"] <= scans + 1
    assert (tmp_path / "exp" / "map.ply").stat().st_size > 1000
    info = cli_proc(["info", str(tmp_path / "o.mcap"), "--json"])
    assert info.returncode == 0 and "DAMAGED" not in info.stdout


@needs_root
def test_a_disk_full_at_once_ends_the_run_in_seconds_with_what_was_written_readable(tmp_path: Path) -> None:
    """The disk fills in one go (another program): Rerun's writer thread dies; the run still ends, one line. The
    cut file stays `x.rrd.part` (Rerun reads it up to the cut) and the recording already there, which --force
    would have replaced, is left as it was."""
    log = write_log(tmp_path / "log.mcap", 400, points=3000)
    with small_disk(tmp_path / "disk", "64m") as disk:
        out = disk / "x.rrd"
        out.write_bytes(b"an older recording")
        cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--save", str(out), *RG, "-q"]
        cmd.append("--force")
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
        deadline = time.monotonic() + 60
        part = disk / "x.rrd.part"  # the recording grows beside its name until it is closed
        while time.monotonic() < deadline and not (part.exists() and part.stat().st_size > 200_000):
            time.sleep(0.05)
        fill_disk(disk, 0)
        _, err = proc.communicate(timeout=90)
        assert proc.returncode == 2, err
        line = assert_one_line(err, out)
        assert "disk" in line
        if "stays readable" in line:  # the room check came first and the writer still finished the file
            assert rrd_verify(out).returncode == 0 and not part.exists()
            return
        assert "left as x.rrd.part" in line
        assert out.read_bytes() == b"an older recording"  # a cut file never takes the final name
        listing = rrd_print(part)
        # Rerun reads the layers of the scans written before the disk filled (which ones made it depends on timing)
        assert listing.returncode == 0 and ("/world/robot" in listing.stdout or "/world/scan/" in listing.stdout)


@needs_root
@pytest.mark.parametrize("what", ["mcap-out", "export"])
def test_a_full_disk_under_mcap_out_or_export_is_one_line(what: str, tmp_path: Path) -> None:
    log = write_log(tmp_path / "log.mcap", 60)
    with small_disk(tmp_path / "disk", "2m" if what == "mcap-out" else "96k") as disk:
        out = disk / ("o.mcap" if what == "mcap-out" else "exp")
        done = cli_proc(["run", str(log), f"--{what}", str(out), *RG, "-q"], timeout=90)
        assert done.returncode == 2, done.stderr
        assert_one_line(done.stderr, disk, "No space left on device")
        if what == "mcap-out":  # what was written before is read up to the damage
            info = cli_proc(["info", str(out), "--json"])
            assert info.returncode == 0, info.stderr
            assert json.loads(info.stdout)["point_clouds"][0]["scans"] >= 1


@needs_root
def test_simulate_and_refine_on_a_full_disk_leave_no_half_file(tmp_path: Path, crack_dir: Path) -> None:
    with small_disk(tmp_path / "disk", "256k") as disk:
        done = cli_proc(["simulate", "--out", str(disk / "m.mcap"), "--scans", "20", "-q"], timeout=120)
        assert done.returncode == 2
        assert_one_line(done.stderr, disk / "m.mcap", "No space left on device")
        cloud = LabelledCloud(np.random.default_rng(0).uniform(0, 2, (20_000, 3)))
        src = write_cloud(tmp_path / "in.ply", cloud)
        done = cli_proc(["refine", str(src), "--out", str(disk / "r.ply"), "--set", "lrgnet.max_steps=2"])
        assert done.returncode == 2
        assert_one_line(done.stderr, disk / "r.ply", "No space left on device")
        assert not (disk / "r.ply").exists() and not list(disk.glob(".*.part"))  # no half file left


# ----------------------------------------------------------------------------------- bad messages


@pytest.mark.parametrize("quaternion", [(0.0, 0.0, 0.0, 0.0), (math.nan, 0.0, 0.0, 1.0)])
def test_a_bad_pose_is_skipped_with_a_warning(quaternion, tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 12, bad_poses={4: quaternion})
    code, out, err = cli(["run", str(log), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["scans"] == 12 and result["skipped_messages"] == 1 and not result["damaged_log"]
    assert f"logged at {T0_NS + 4 * PERIOD_NS} ns" in err and str(log) in err


def test_one_undecodable_cloud_mid_log_is_skipped_and_the_rest_read(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 12, bad_clouds={5: MALFORMED["short data"]})
    out_dir = tmp_path / "exp"
    code, out, err = cli(["run", str(log), *RG, "-q", "--json", "--export", str(out_dir)], capsys)
    assert code == 0, err
    result = json.loads(out)
    bad_time = T0_NS + 5 * PERIOD_NS + PERIOD_NS // 2
    assert result["scans"] == 11 and result["skipped_messages"] == 1
    assert result["skipped_log_times_ns"] == [bad_time] and result["damaged_log"] is False
    assert f"logged at {bad_time} ns" in err
    summary = json.loads((out_dir / "summary.json").read_text())
    assert summary["skipped_messages"] == 1 and summary["scans"] == 11
    code, out, err = cli(["run", str(log), *RG, "-q"], capsys)
    assert code == 0 and "skipped 1 messages" in out


def test_a_log_where_no_cloud_decodes_is_one_line(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 4, bad_clouds=dict.fromkeys(range(4), MALFORMED["point_step 0"]))
    code, _, err = cli(["run", str(log), *RG, "-q"], capsys)
    assert code == 2
    assert_one_line(err, log, "not one point cloud could be decoded")


# ----------------------------------------------------------------------------------- usage errors


@pytest.mark.parametrize(
    "args", [["run", "--frobnicate"], ["run", "--every", "two"], ["cracks"], ["nosuchcommand"], ["info"]]
)
def test_usage_errors_are_typers_message_and_exit_2(args: list[str]) -> None:
    done = cli_proc(args, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and "\x1b[" not in done.stderr
    assert "Usage:" in done.stderr and "Error:" in done.stderr


# ----------------------------------------------------------------------------------- info on files


def test_info_reads_a_point_cloud_file_and_a_folder_of_them(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    code, out, err = cli(["info", str(lidar_dir / "room_scan1.pcd"), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["point_clouds"][0]["points_max"] > 100_000
    folder = tmp_path / "scans"
    folder.mkdir()
    for name in ("room_scan1.pcd", "room_scan2.pcd"):
        (folder / name).symlink_to(lidar_dir / name)
    code, out, err = cli(["info", str(folder)], capsys)
    assert code == 0 and "2 scans" in out, err


# ----------------------------------------------------------------------------------- output == input


def test_an_output_that_is_the_input_is_refused_even_with_force(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 4)
    before = sha(log)
    link = tmp_path / "link.mcap"
    link.symlink_to(log)
    for args in (
        ["--mcap-out", str(log)],
        ["--save", str(log)],
        ["--mcap-out", str(link)],
        ["--save", str(link)],
    ):
        code, _, err = cli(["run", str(log), *RG, "-q", "--force", *args], capsys)
        assert code == 2, args
        assert_one_line(err, args[1], "is the input")
    code, _, err = cli(["run", str(link), *RG, "-q", "--force", "--mcap-out", str(log)], capsys)
    assert code == 2 and "is the input" in err
    assert sha(log) == before
    # A folder of scans exported into itself would replace its own map.ply
    folder = tmp_path / "scans"
    folder.mkdir()
    write_cloud(folder / "map.ply", LabelledCloud(np.random.default_rng(0).uniform(-5, 5, (3000, 3))))
    kept = sha(folder / "map.ply")
    code, _, err = cli(["run", str(folder), *RG, "-q", "--force", "--export", str(folder)], capsys)
    assert code == 2 and "is the input" in err and sha(folder / "map.ply") == kept
    ply = folder / "map.ply"
    code, _, err = cli(["refine", str(ply), "--out", str(ply), "--force"], capsys)
    assert code == 2 and "is the input" in err and sha(ply) == kept
    # A ROS 2 bag folder: its files are inputs too, and a run beside them works
    bag = write_bag(tmp_path / "bag2", hall_clouds(4)[0], ros2=True)
    db = next(q for q in bag.iterdir() if q.suffix in (".db3", ".mcap"))
    code, _, err = cli(["run", str(bag), *RG, "-q", "--force", "--mcap-out", str(db)], capsys)
    assert code == 2 and "is the input" in err
    code, out, err = cli(["run", str(bag), *RG, "-q", "--json", "--mcap-out", str(tmp_path / "b.mcap")], capsys)
    assert code == 0 and json.loads(out)["scans"] == 4, err


# ----------------------------------------------------------------------------------- signals


def _start_run(log: Path, tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    out = tmp_path / "x.rrd"
    cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--save", str(out), *RG]
    cmd += ["--mcap-out", str(tmp_path / "o.mcap"), "--export", str(tmp_path / "exp")]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, preexec_fn=interruptible
    )
    deadline = time.monotonic() + 60
    poses = tmp_path / "exp" / "poses_tum.txt.part"  # streamed beside its name until the run ends
    while time.monotonic() < deadline and not (poses.exists() and len(poses.read_text().splitlines()) >= 5):
        time.sleep(0.05)
    return proc, out


@pytest.fixture(scope="module")
def long_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_log(tmp_path_factory.mktemp("long") / "long.mcap", 400, points=3000)


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_sigterm_stops_like_ctrl_c_with_every_output_finished(sig, code, long_log: Path, tmp_path: Path) -> None:
    proc, out = _start_run(long_log, tmp_path)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and "interrupted after" in stdout
    scans = int(stdout.split("interrupted after ")[1].split()[0])
    assert 0 < scans < 400
    assert rrd_verify(out).returncode == 0 and not out.with_name("x.rrd.part").exists()
    info = json.loads(cli_proc(["info", str(tmp_path / "o.mcap"), "--json"]).stdout)
    assert info["damage"] is None and info["point_clouds"][0]["scans"] in (scans, scans + 1)
    summary = json.loads((tmp_path / "exp" / "summary.json").read_text())
    assert summary["interrupted"] and summary["scans"] == scans
    assert (tmp_path / "exp" / "map.ply").exists()


def test_sigkill_loses_only_the_scan_in_flight(long_log: Path, tmp_path: Path) -> None:
    """SIGKILL cannot be caught: the pose files are flushed with each scan, the MCAP and the recording read up to
    the cut; all are left under their `.part` names (renamed only when a run ends), so nothing looks finished that
    is not."""
    proc, out = _start_run(long_log, tmp_path)
    time.sleep(3.0)  # Rerun batches a second of layers before writing them: a kill loses at most that
    proc.kill()
    proc.communicate(timeout=30)
    assert not (tmp_path / "exp" / "poses_tum.txt").exists() and not (tmp_path / "o.mcap").exists()
    tum = (tmp_path / "exp" / "poses_tum.txt.part").read_text().splitlines()
    kitti = (tmp_path / "exp" / "poses_kitti.txt.part").read_text().splitlines()
    assert len(tum) >= 5 and abs(len(tum) - len(kitti)) <= 1
    assert all(len(line.split()) == 8 for line in tum)
    info = cli_proc(["info", str(tmp_path / "o.mcap.part"), "--json"])
    assert info.returncode == 0, info.stderr
    written = json.loads(info.stdout)["point_clouds"][0]["scans"]
    # MCAP chunks of a few scans are buffered; the poses lag the scans by at most the one in flight
    assert written <= len(tum) + 1
    assert not out.exists()
    listing = rrd_print(out.with_name("x.rrd.part"))
    assert "/world/scan/labels" in listing.stdout


# ----------------------------------------------------------------------------------- malformed PointCloud2


@pytest.mark.parametrize("kind", [*MALFORMED, "truncated CDR", "data length 2**31"])
def test_a_malformed_pointcloud2_is_one_line_in_info_and_skipped_by_run(kind: str, tmp_path: Path, capsys) -> None:
    path = tmp_path / "bad.mcap"
    if kind == "data length 2**31":
        log = huge_data_length(path, 6, at=3)
    else:
        edit = MALFORMED.get(kind, 60)
        log = write_log(path, 6, bad_clouds={3: edit})
    code, _, err = cli(["info", str(log)], capsys)
    assert code == 2
    assert_one_line(err, log, "/points", f"logged at {T0_NS + 3 * PERIOD_NS + PERIOD_NS // 2} ns")
    code, out, err = cli(["run", str(log), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["scans"] == 5 and result["skipped_messages"] == 1


def test_weak_duplicate_field_names_are_warned(tmp_path: Path, capsys) -> None:
    def dup(m: dict) -> dict:
        return {**m, "fields": [*m["fields"], {**m["fields"][0]}]}

    log = write_log(tmp_path / "dup.mcap", 4, bad_clouds=dict.fromkeys(range(4), dup))
    code, _, err = cli(["run", str(log), *RG, "-q"], capsys)
    assert code == 0 and "'x' is declared more than once" in err


# ----------------------------------------------------------------------------------- NaN vertices


def _with_nan(cloud: LabelledCloud, path: Path, nan_rows: int = 1) -> Path:
    pts = cloud.points.copy()
    pts[:nan_rows] = np.nan
    return write_cloud(path, LabelledCloud(pts, cloud.colors, cloud.intensity))


def _slabs(n: int = 40_000) -> LabelledCloud:
    """Two slabs 3 m apart and four walls between them, 8 x 6 m."""
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 1, (n, 2))
    floor = np.column_stack([a[:, 0] * 8, a[:, 1] * 6, np.zeros(n)])
    ceiling = floor + np.array([0, 0, 3])
    wall = np.column_stack([a[:, 0] * 8, np.zeros(n), a[:, 1] * 3])
    return LabelledCloud(np.vstack([floor, ceiling, wall, wall + np.array([0, 6, 0])]))


def test_a_nan_vertex_is_dropped_with_a_note_in_drift_and_refine(tmp_path: Path, capsys) -> None:
    ply = _with_nan(_slabs(), tmp_path / "nan.ply")
    code, out, err = cli(["drift", str(ply), "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["stories"] and "dropped 1 of" in err
    small = _with_nan(LabelledCloud(np.random.default_rng(0).uniform(0, 2, (5000, 3))), tmp_path / "small.ply")
    code, out, err = cli(["refine", str(small), "--json", "--set", "lrgnet.max_steps=2"], capsys)
    assert code == 0, err
    assert json.loads(out)["points"] == 4999 and "dropped 1 of 5000" in err


def test_a_nan_vertex_in_cracks_is_dropped_and_the_mask_follows(crack_dir: Path, tmp_path: Path, capsys) -> None:
    from aftershock.pipeline.cloud_io import read_cloud

    slab = read_cloud(crack_dir / "slab2.ply")
    ply = _with_nan(slab, tmp_path / "slab.ply", 3)
    code, out, err = cli(["cracks", str(ply), "--truth", str(crack_dir / "slab2_mask.npy"), "--json"], capsys)
    assert code == 0, err
    assert "dropped 3 of" in err and json.loads(out)["f1"] > 0.3


def test_a_cloud_with_nothing_usable_left_is_one_line(tmp_path: Path, capsys) -> None:
    all_nan = _with_nan(LabelledCloud(np.ones((100, 3))), tmp_path / "nan.ply", 100)
    same = write_cloud(tmp_path / "same.ply", LabelledCloud(np.ones((500, 3))))
    for args in (["drift", str(all_nan)], ["cracks", str(all_nan)], ["refine", str(all_nan)], ["drift", str(same)]):
        code, _, err = cli(args, capsys)
        assert code == 2, args
        assert_one_line(err, args[1])


# ----------------------------------------------------------------------------------- size bombs


def test_a_pcd_claiming_gigabytes_is_refused_before_allocating(tmp_path: Path, capsys) -> None:
    import tracemalloc

    bomb = pcd_size_bomb(tmp_path / "bomb.pcd")
    assert bomb.stat().st_size < 200
    tracemalloc.start()
    code, _, err = cli(["run", str(bomb), *RG, "-q"], capsys)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert code == 2 and peak < 50 * 2**20
    assert_one_line(err, bomb, "LZF")
    code, _, err = cli(["info", str(bomb)], capsys)
    assert code == 2
    assert_one_line(err, bomb)


# ----------------------------------------------------------------------------------- chunk CRCs


@pytest.mark.parametrize("indexed", [True, False])
def test_a_corrupted_chunk_is_skipped_and_the_rest_read(indexed: bool, tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 12, chunk_size=50_000, compression=CompressionType.NONE)
    assert len(chunk_offsets(log)) >= 6
    bad = corrupt_chunk(log, tmp_path / "bad.mcap", 2)
    if not indexed:
        bad = strip_summary(bad, tmp_path / "bad_stream.mcap")
    code, out, err = cli(["run", str(bad), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert 8 <= result["scans"] < 12 and result["skipped_messages"] == 1
    assert "corrupt" in err and "CRC" in err


def test_a_corrupted_compressed_chunk_is_skipped_too(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 12, chunk_size=50_000)
    bad = corrupt_chunk(log, tmp_path / "bad.mcap", 3)
    code, out, err = cli(["run", str(bad), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["skipped_messages"] == 1


def test_weak_cracks_resolution_must_be_positive(crack_dir: Path, capsys) -> None:
    for bad in ("0", "-0.001", "nan"):
        code, _, err = cli(["cracks", str(crack_dir / "slab2.ply"), "--resolution", bad], capsys)
        assert code == 2, bad
        assert_one_line(err, "--resolution")


# ----------------------------------------------------------------------------------- unreadable and odd inputs


def test_an_unreadable_folder_or_file_inside_one_is_one_line_naming_it(lidar_dir: Path, tmp_path: Path) -> None:
    """Root reads every file: the command then runs without the capabilities that bypass file permissions."""
    base = tmp_path / "base"
    base.mkdir()
    locked = base / "locked"
    locked.mkdir()
    (locked / "a.pcd").write_bytes((lidar_dir / "room_scan1.pcd").read_bytes())
    locked.chmod(0o300)  # no listing
    mixed = base / "mixed"
    mixed.mkdir()
    for k, name in enumerate(("room_scan1.pcd", "room_scan2.pcd")):
        (mixed / f"{k}.pcd").write_bytes((lidar_dir / name).read_bytes())
    (mixed / "1.pcd").chmod(0o200)
    for p in (tmp_path, base, mixed):
        p.chmod(0o755)
    (mixed / "0.pcd").chmod(0o644)
    (locked / "a.pcd").chmod(0o000)
    (mixed / "1.pcd").chmod(0o000)
    prefix: list[str] = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: every file is readable")
        prefix = ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"]
    for target, named in ((locked, locked), (mixed, mixed / "1.pcd")):
        cmd = [*prefix, sys.executable, "-m", "aftershock.pipeline", "run", str(target), *RG, "-q"]
        done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=60)
        assert done.returncode == 2, done.stderr
        assert_one_line(done.stderr, named, "ermission denied")


def test_a_zero_count_pcd_a_folder_as_save_and_a_device_are_one_line(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    pcd = tmp_path / "count0.pcd"
    pcd.write_text(
        "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 0\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n"
        "1 2\n3 4\n"
    )
    code, _, err = cli(["run", str(pcd), *RG, "-q"], capsys)
    assert code == 2
    assert_one_line(err, pcd, "COUNT")
    log = write_log(tmp_path / "log.mcap", 3)
    folder = tmp_path / "a_folder"
    folder.mkdir()
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(folder), "--force"], capsys)
    assert code == 2
    assert_one_line(err, folder, "is a folder")
    zero = tmp_path / "zero.pcd"
    zero.symlink_to("/dev/zero")
    for cmd in (["run", str(zero), *RG, "-q"], ["info", str(zero)], ["drift", str(zero)], ["cracks", str(zero)]):
        code, _, err = cli(cmd, capsys)
        assert code == 2, cmd
        assert_one_line(err, zero, "not a regular file")


# ----------------------------------------------------------------------------------- weak behaviour


def test_weak_named_weights_must_load_or_fail(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 3)
    bad = tmp_path / "w.pt"
    bad.write_bytes(b"not weights")
    code, _, err = cli(["run", str(log), "-q", "--set", f'label.weights="{bad}"'], capsys)
    assert code == 2
    assert_one_line(err, bad)


def test_weak_a_ply_declared_binary_holding_ascii_is_refused(tmp_path: Path, capsys) -> None:
    ply = tmp_path / "liar.ply"
    body = "\n".join(f"{x} {x} {x}" for x in np.linspace(0, 1, 300))
    ply.write_text(
        "ply\nformat binary_little_endian 1.0\nelement vertex 300\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n" + body + "\n"
    )
    for cmd in (["drift", str(ply)], ["run", str(ply), *RG, "-q"]):
        code, _, err = cli(cmd, capsys)
        assert code == 2, cmd
        assert_one_line(err, ply, "ASCII")


def test_weak_run_json_says_when_the_log_was_damaged(tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 12, chunk_size=50_000)
    start, length = chunk_offsets(log)[6]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: start + length // 2])
    code, out, err = cli(["run", str(cut), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["damaged_log"] is True and "cut off" in result["damage"]
    assert result["skipped_messages"] == 0 and result["scans"] >= 5
    for key in ("scans", "points", "interrupted", "registration_failures", "outputs"):  # kept, never renamed
        assert key in result


def test_a_recording_whose_writer_stalls_is_given_up_not_waited_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """When Rerun's file writer dies without saying so, every flush times out: the sink gives up once the file
    stops growing and marks the process as stuck (the command line then ends it after the error line)."""
    from aftershock.sinks import rerun_output, rerun_sink

    out = tmp_path / "x.rrd"
    sink = rerun_sink.RerunSink(out, False, None, load_config().rerun)
    sink.begin(RunInfo(str(out), "mcap"))
    monkeypatch.setattr(rerun_output, "FLUSH_STALL_S", 0.5)

    def timed_out(timeout_sec: float = 0.0) -> None:
        time.sleep(min(timeout_sec, 0.05))
        raise RuntimeError("Flush timed out - not all log messages were sent")

    real_flush = sink.rec.flush
    monkeypatch.setattr(sink.rec, "flush", timed_out)
    t0 = time.monotonic()
    with pytest.raises(OutputError, match=r"recording stopped at .* left as x\.rrd\.part") as caught:
        sink.close()
    assert caught.value.process_stuck and time.monotonic() - t0 < 5
    assert not out.exists() and out.with_name("x.rrd.part").exists()  # never under its name
    monkeypatch.setattr(sink.rec, "flush", real_flush)
    sink.rec.flush()
    sink.rec.disconnect()


def test_a_recording_whose_footer_never_reached_the_disk_stays_part_and_says_so(tmp_path: Path) -> None:
    """The disk fills as the recording closes: Rerun's writer drops the footer without a word. The cut file is not
    put in place over NAME (an older recording there stays), and the error says where it was left."""
    from aftershock.sinks import rerun_output, rerun_sink

    out = tmp_path / "x.rrd"
    out.write_bytes(b"an older recording")
    sink = rerun_sink.RerunSink(out, False, None, load_config().rerun, force=True)
    sink.begin(RunInfo(str(out), "mcap"))
    part = out.with_name("x.rrd.part")
    real_disconnect = sink.rec.disconnect

    def footer_lost() -> None:
        real_disconnect()
        with part.open("r+b") as f:  # what a footer write into a full disk leaves: the file without its tail
            f.truncate(part.stat().st_size - rerun_output.RRD_FOOTER_TAIL)

    sink.rec.disconnect = footer_lost  # type: ignore[method-assign]
    with pytest.raises(OutputError, match=r"recording stopped at .* left as x\.rrd\.part"):
        sink.close()
    assert out.read_bytes() == b"an older recording" and part.exists()
    assert not rerun_output.has_rrd_footer(part) and rrd_print(part).returncode == 0  # read up to the cut


def test_a_damaged_file_among_a_folders_scans_is_skipped(lidar_dir: Path, tmp_path: Path, capsys) -> None:
    folder = tmp_path / "scans"
    folder.mkdir()
    for k, name in enumerate(("room_scan1.pcd", "room_scan2.pcd", "room_scan1.pcd")):
        (folder / f"{k}.pcd").symlink_to(lidar_dir / name)
    (folder / "1b.pcd").write_bytes((lidar_dir / "room_scan2.pcd").read_bytes()[:5000])  # cut off
    code, out, err = cli(["run", str(folder), *RG, "-q", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["scans"] == 3 and result["skipped_messages"] == 1
    assert "1b.pcd" in err and "skipped" in err
