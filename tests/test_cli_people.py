"""What a person at a terminal sees (issue 29): a progress bar through a pseudo-terminal, a notice before a run
that would save nothing, closing hints last with commands that work as printed, `--help` without `<bool>`."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import select
import shlex
import struct
import subprocess
import sys
import termios
from pathlib import Path

import numpy as np
import pytest

from aftershock.pipeline.cli import main
from aftershock.pipeline.mission import SAMPLE

CLI = [sys.executable, "-m", "aftershock.pipeline"]
ENV = os.environ | {"CI": "true", "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
FAST = ["--labeller", "region-growing"]


def run_in_pty(cmd: list[str], timeout: float = 180) -> tuple[int, str]:
    """Run `cmd` with stdout and stderr on a 40 x 120 pseudo-terminal; its exit code and everything it wrote."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, env=ENV, close_fds=True)
    os.close(slave)
    out = b""
    try:
        while select.select([master], [], [], timeout)[0]:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not chunk:
                break
            out += chunk
    finally:
        os.close(master)
    return proc.wait(timeout=30), out.decode(errors="replace")


def test_a_terminal_run_shows_progress_and_says_nothing_will_be_saved() -> None:
    code, text = run_in_pty([*CLI, "run", str(SAMPLE), "--damage", *FAST])
    assert code == 0, text
    assert "nothing will be saved" in text.split("processed")[0]  # before the work
    assert "%|" in text and "scan/s" in text and "/22 [" in text  # tqdm's bar on the terminal, 22 scans
    assert "assessing damage: 00:0" in text  # the on-demand analysis, which has no steps, shows its time
    code, text = run_in_pty([*CLI, "run", str(SAMPLE), "--damage", "-q", *FAST])
    assert code == 0 and "%|" not in text and "assessing damage:" not in text  # --quiet: no progress


def test_closing_hints_come_last_and_work_as_printed(tmp_path: Path) -> None:
    rrd, folder = tmp_path / "r.rrd", tmp_path / "export"
    cmd = [*CLI, "run", str(SAMPLE), "--save", str(rrd), "--export", str(folder), "--damage", "-q", *FAST]
    done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.strip().splitlines()
    hints = [
        i for i, line in enumerate(lines) if line.startswith(("open it with", "open the recording", "site report"))
    ]
    assert hints and hints[-1] == len(lines) - 1 and all(not lines[i].startswith("  ") for i in hints)
    assert max(i for i, line in enumerate(lines) if line.startswith("damage:")) < hints[0]
    report = next(line for line in lines if line.startswith("site report: "))
    argv = shlex.split(report.removeprefix("site report: "))
    assert subprocess.run(argv, capture_output=True, env=ENV, timeout=300).returncode == 0  # as printed
    assert (folder / "report.html").is_file()
    view = next(line for line in lines if line.startswith("open it with its log: "))
    program = shlex.split(view.removeprefix("open it with its log: "))
    assert program[-3:] == ["view", str(SAMPLE), str(rrd)]
    assert subprocess.run([*program[:-3], "--version"], capture_output=True, env=ENV).returncode == 0


@pytest.mark.parametrize("command", [[], ["run"], ["report"], ["batch"]])
def test_help_has_no_bool_tags(command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "--help" in out and "<bool>" not in out


def _slabs_and_walls(seed: int) -> np.ndarray:
    """Two 10 x 8 m slabs 3 m apart, the upper one shifted 10 mm, with walls between."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-5, -4], [5, 4], size=(40000, 2))
    z, t, side = rng.uniform(0, 3.0, 60000), rng.uniform(-1, 1, 60000), rng.integers(0, 4, 60000)
    x = np.where(side < 2, np.where(side == 0, -5.0, 5.0), t * 5)
    y = np.where(side < 2, t * 4, np.where(side == 2, -4.0, 4.0))
    return np.vstack([np.c_[xy, np.zeros(len(xy))], np.c_[xy + 0.01, np.full(len(xy), 3.0)], np.c_[x, y, z]])


def test_drift_saves_a_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rrd_read import read_rrd

    from aftershock.pipeline.cloud_io import write_cloud
    from aftershock.pipeline.types import LabelledCloud
    from aftershock.sinks import rerun_blueprint as L

    cloud = write_cloud(tmp_path / "two.ply", LabelledCloud(_slabs_and_walls(0)))
    rrd = tmp_path / "drift.rrd"
    assert main(["drift", str(cloud), "--save", str(rrd)]) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].endswith(str(rrd))  # the hint last
    rec = read_rrd(rrd)
    assert {f"{L.STORIES}/s0", f"{L.STORIES}/s1", L.DRIFT} <= rec.entities and rec.under(L.MAP)
    assert main(["drift", str(cloud), "--save", str(rrd)]) == 2  # no overwrite without --force
    assert str(rrd) in capsys.readouterr().err
    assert main(["drift", str(cloud), "--save", str(cloud), "--force"]) == 2  # never the input


def test_cracks_saves_a_recording(crack_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rrd_read import read_rrd

    from aftershock.sinks import rerun_blueprint as L

    rrd = tmp_path / "cracks.rrd"
    assert main(["cracks", str(crack_dir / "column4.ply"), "--save", str(rrd), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["recording"] == str(rrd) and data["cracks"]
    rec = read_rrd(rrd)
    assert L.CRACKS in rec.entities and L.CRACK_POINTS in rec.entities and rec.under(L.MAP)
