"""Outputs are regular files we create: nothing that is not one is written to or replaced, whatever the flags.

An output path that is a device, a named pipe, a socket or a folder is refused with or without --force (as root,
`--out /dev/null --force` must leave the system's /dev/null a device); where no file can be made (/proc, a name
over 255 bytes) is one line before any work; an export folder written by one command is refused to a second,
which names the first's PID, and a lock left by a process that died is taken over. The Rerun recording of `run
--save` grows as `NAME.part` and takes its name only when it is closed complete (also after Ctrl-C); a refused
or failed run leaves the recording already there as it was.
"""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import cli_errors
import numpy as np
import pytest
from cli_errors import RG, cli
from faults_data import MALFORMED, write_log
from faults_hostile import ENV
from fixtures import interruptible
from rrd_read import read_rrd, rrd_verify

from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.outputs import LOCK_FILE
from aftershock.pipeline.types import LabelledCloud
from aftershock.sinks import rerun_blueprint as L


def one_error_line(err: str, *names: object) -> str:
    """The one error line, and the error's prefix nowhere else in stderr."""
    assert err.count(cli_errors.PREFIX) == 1, err
    return cli_errors.one_error_line(err, *names)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_log(tmp_path_factory.mktemp("out") / "log.mcap", 6, points=2000)


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1, (500, 3))
    path = tmp_path_factory.mktemp("cloud") / "c.ply"
    write_cloud(path, LabelledCloud(pts, None, None, np.zeros(500, np.uint16), np.ones(500, np.uint32)))
    return path


def _special(kind: str, where: Path) -> Path:
    if kind == "device":
        return Path("/dev/null")
    path = where / f"a-{kind}"
    if kind == "pipe":
        os.mkfifo(path)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        _SOCKETS.append(sock)  # kept open: the socket stays bound for the test
    elif kind == "folder":
        path.mkdir()
    elif kind == "link to a device":
        path.symlink_to("/dev/null")
    return path


_SOCKETS: list[socket.socket] = []
KINDS = ["device", "pipe", "socket", "folder", "link to a device"]
WHAT = {"device": "a device", "pipe": "a named pipe", "socket": "a socket", "folder": "a folder"}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("force", [False, True], ids=["", "--force"])
def test_an_output_that_is_no_regular_file_is_refused_and_left_as_it_was(
    kind: str, force: bool, log: Path, cloud: Path, tmp_path: Path, capsys
) -> None:
    target = _special(kind, tmp_path)
    before = os.stat(target).st_mode
    flags = ["--force"] if force else []
    for cmd in (
        ["run", str(log), *RG, "-q", "--mcap-out", str(target), *flags],
        ["run", str(log), *RG, "-q", "--save", str(target), *flags],
        ["refine", str(cloud), "--out", str(target), *flags],
    ):
        code, _, err = cli(cmd, capsys)
        assert code == 2, (cmd, err)
        one_error_line(err, target, WHAT.get(kind, "a device"), "not a regular file")
        assert os.stat(target).st_mode == before and not stat.S_ISREG(before)


@pytest.mark.parametrize("where", ["/proc/x.mcap", "name over 255 bytes"], ids=["/proc", "ENAMETOOLONG"])
def test_where_no_file_can_be_made_is_one_line_before_any_work(where: str, log: Path, tmp_path: Path, capsys) -> None:
    out = Path(where) if where.startswith("/") else tmp_path / ("a" * 300 + ".mcap")
    for option in ("--mcap-out", "--save"):
        code, _, err = cli(
            ["run", str(log), *RG, "-q", option, str(out.with_suffix(".rrd" if option == "--save" else ".mcap"))],
            capsys,
        )
        assert code == 2, err
        line = one_error_line(err)
        assert ("no file can be made" in line) if where.startswith("/") else ("over the 255 allowed" in line)
        assert "disk" not in line


def test_an_input_path_over_255_bytes_is_one_line(tmp_path: Path, capsys) -> None:
    for cmd in (["info", str(tmp_path / ("b" * 300))], ["run", str(tmp_path / ("b" * 300 + ".mcap")), *RG, "-q"]):
        code, _, err = cli(cmd, capsys)
        assert code == 2
        one_error_line(err, "b" * 300)


def _holder(folder: Path) -> subprocess.Popen:
    """Another process holding the export folder's lock (the same class a run takes it with)."""
    code = (
        "import sys; from pathlib import Path; from aftershock.pipeline.outputs import FolderLock; "
        f"FolderLock(Path({str(folder)!r})).acquire(); print('held', flush=True); sys.stdin.read()"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=ENV
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_an_export_folder_in_use_is_refused_naming_the_holder_and_a_dead_holders_lock_taken_over(
    log: Path, tmp_path: Path, capsys
) -> None:
    folder = tmp_path / "exp"
    holder = _holder(folder)
    try:
        code, _, err = cli(["run", str(log), *RG, "-q", "--export", str(folder), "--force"], capsys)
        assert code == 2
        one_error_line(err, folder, f"PID {holder.pid}", "another aftershock command")
        assert not (folder / "poses_tum.txt").exists()
    finally:
        holder.send_signal(signal.SIGKILL)  # dies holding it: the lock file stays, with a dead PID
        holder.wait(10)
    assert (folder / LOCK_FILE).read_text().strip() == str(holder.pid)
    code, _, err = cli(["run", str(log), *RG, "-q", "--export", str(folder)], capsys)
    assert code == 0, err
    assert len((folder / "poses_tum.txt").read_text().splitlines()) == 6
    assert not (folder / LOCK_FILE).exists() and not list(folder.glob("*.part"))


def test_two_outputs_on_one_file_or_an_output_on_an_input_are_refused(log: Path, tmp_path: Path, capsys) -> None:
    same = tmp_path / "both.out"
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(same), "--mcap-out", str(same)], capsys)
    assert code == 2
    one_error_line(err, same, "--save", "--mcap-out")
    link = tmp_path / "link.rrd"
    link.symlink_to(log)
    before = log.read_bytes()
    for target in (log, link):
        code, _, err = cli(["view", str(log), "--save", str(target), "--force"], capsys)
        assert code == 2
        one_error_line(err, target, "is the input")
    assert log.read_bytes() == before


def _scans_in(recording: Path) -> int:
    return len(read_rrd(recording).times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE))


def test_a_recording_takes_its_name_when_complete_and_one_there_is_left_when_the_run_is_refused_or_fails(
    log: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "x.rrd"
    part = tmp_path / "x.rrd.part"
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(out)], capsys)
    assert code == 0, err
    assert rrd_verify(out).returncode == 0 and not part.exists()
    assert _scans_in(out) == 6
    kept = out.read_bytes()
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(out)], capsys)  # refused: it exists
    assert code == 2
    one_error_line(err, out, "already exists")
    os.mkfifo(part)  # something not ours where the recording would grow: refused, --force or not
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(out), "--force"], capsys)
    assert code == 2
    one_error_line(err, out, "x.rrd.part beside it is a named pipe")
    assert stat.S_ISFIFO(os.stat(part).st_mode)
    part.unlink()
    bad = write_log(tmp_path / "bad.mcap", 4, bad_clouds=dict.fromkeys(range(4), MALFORMED["point_step 0"]))
    code, _, err = cli(["run", str(bad), *RG, "-q", "--save", str(out), "--force"], capsys)  # fails: no scan
    assert code == 2
    one_error_line(err, bad)
    assert out.read_bytes() == kept and not part.exists()


def test_ctrl_c_mid_run_leaves_the_recording_up_to_there_under_its_name(tmp_path: Path) -> None:
    log = write_log(tmp_path / "long.mcap", 400, points=3000)
    out = tmp_path / "x.rrd"
    part = tmp_path / "x.rrd.part"
    cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), *RG, "--save", str(out)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, preexec_fn=interruptible
    )
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and not (part.exists() and part.stat().st_size > 300_000):
        time.sleep(0.05)  # the recording grows beside its name: a few seconds of scans
    assert part.exists() and not out.exists(), "the run never started writing"
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=90)
    assert proc.returncode == 130, stderr
    assert "interrupted after" in stdout and "Traceback" not in stderr
    assert not part.exists()
    assert rrd_verify(out).returncode == 0
    assert 0 < _scans_in(out) < 400
