"""Outputs are regular files we create: nothing that is not one is written to or replaced, whatever the flags.

An output path that is a device, a named pipe, a socket or a folder is refused with or without --force (as root,
`--out /dev/null --force` must leave the system's /dev/null a device); where no file can be made (/proc, a name
over 255 bytes) is one line before any work; an export folder written by one command is refused to a second,
which names the first's PID, and a lock left by a process that died is taken over.
"""

from __future__ import annotations

import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from faults_data import write_log
from faults_hostile import ENV

from aftershock.pipeline.cli import main
from aftershock.pipeline.cloud_io import write_cloud
from aftershock.pipeline.outputs import LOCK_FILE
from aftershock.pipeline.types import LabelledCloud

RG = ("--labeller", "region-growing")


def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str, *names: object) -> str:
    assert "Traceback" not in err and "\x1b" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("aftershock: error:") and err.count("aftershock: error:") == 1, err
    for name in names:
        assert str(name) in last, (name, last)
    return last


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
