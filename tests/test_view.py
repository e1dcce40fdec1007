"""`aftershock view`: a real MCAP log and the recording `run` made of it, opened as one recording."""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from fixtures import interruptible
from rrd_read import read_rrd

from aftershock.pipeline.cli import main
from aftershock.sinks import rerun_blueprint as L

CLI = [sys.executable, "-m", "aftershock.pipeline"]
VELODYNE = "velodyne_vlp16_indoor.mcap"
OUSTER = "ouster_os1_128_outdoor.mcap"


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """The command line in this process (the subprocess start-up would dominate these short commands)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def velodyne(lidar_dir: Path) -> Path:
    return lidar_dir / VELODYNE


@pytest.fixture(scope="module")
def recording(velodyne: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("view") / "run.rrd"
    done = _cli("run", velodyne, "--save", out, "--labeller", "region-growing", "--quiet")
    assert done.returncode == 0, done.stderr
    assert f" view {velodyne} {out}" in done.stdout  # the run says how to open it with its log
    return out


def test_log_and_recording_become_one_recording(velodyne: Path, recording: Path, tmp_path: Path) -> None:
    both = tmp_path / "both.rrd"
    done = _cli("view", velodyne, recording, "--save", both)
    assert done.returncode == 0, done.stderr
    rec, ours = read_rrd(both), read_rrd(recording)
    assert rec.recording_id == ours.recording_id  # one recording: the log's data joined ours
    assert rec.blueprints == 1
    # the log's own clouds (Rerun's MCAP import) and our layers, on the same MCAP timelines
    assert "Points3D:positions" in rec.components("velodyne_points")
    assert rec.rows("velodyne_points", "CoordinateFrame:frame")  # the frame our pose link names
    for timeline in (L.MCAP_LOG_TIMELINE, L.MCAP_STAMP_TIMELINE):
        raw = rec.times("velodyne_points", "Points3D:positions", timeline)
        labels = rec.times(L.LABELS, "Points3D:class_ids", timeline)
        assert len(raw) == len(labels) > 0 and np.array_equal(raw, labels), timeline
    assert L.RAW not in rec.entities  # raw scans come from the log, not copied into the recording
    assert _cli("view", velodyne, recording, "--save", both).returncode == 2  # not overwritten without --force


@pytest.mark.parametrize(
    ("args", "what"),
    [
        (("missing.mcap",), "no such file"),
        (("{recording}",), "not an MCAP file"),
        (("{ouster}", "{recording}"), "a recording of another log"),
        (("{velodyne}", "{velodyne}"), "not a Rerun recording"),
        (("{velodyne}", "missing.rrd"), "no such file"),
    ],
)
def test_bad_input_is_one_line(
    args: tuple[str, ...], what: str, velodyne: Path, recording: Path, lidar_dir: Path, tmp_path: Path
) -> None:
    paths = {"recording": recording, "velodyne": velodyne, "ouster": lidar_dir / OUSTER}
    argv = [a.format(**paths) if "{" in a else str(tmp_path / a) for a in args]
    done = _cli("view", *argv)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and what in lines[0] and "Traceback" not in done.stderr, done.stderr


def test_web_viewer_listens_on_localhost_only(velodyne: Path, recording: Path) -> None:
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    child = subprocess.Popen(
        [*CLI, "view", str(velodyne), str(recording), "--web"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=interruptible,
    )  # fmt: skip
    try:
        assert child.stdout is not None
        line = child.stdout.readline()
        assert line.startswith("open http://127.0.0.1:"), (line, child.stderr.read() if child.poll() else "")
        deadline = time.monotonic() + 20
        listening: set[str] = set()
        procs: list[psutil.Process] = []
        while time.monotonic() < deadline and len(listening) < 2:
            procs = [psutil.Process(child.pid), *psutil.Process(child.pid).children(recursive=True)]
            listening = {
                f"{c.laddr.ip}:{c.laddr.port}"
                for p in procs
                for c in p.net_connections(kind="tcp")
                if c.status == psutil.CONN_LISTEN
            }
            time.sleep(0.5)
        assert len(listening) >= 2, listening  # the web page and the gRPC server
        assert all(a.startswith("127.0.0.1:") for a in listening), listening
    finally:
        child.send_signal(signal.SIGINT)
        child.wait(timeout=30)
    assert child.returncode == 0
    _, alive = psutil.wait_procs(procs[1:], timeout=10)
    assert not alive, f"the viewer outlived the command: {alive}"  # the console script's child once did
