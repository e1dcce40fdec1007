"""Servers are what they say: a viewer port that is taken is an error, not a page showing someone else's data; a
--bind address that is not this machine's is one line; a --connect to something that is no Rerun viewer is one
line, whatever Rerun's own logger would have printed."""

from __future__ import annotations

import http.server
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import cli_errors
import pytest
from cli_errors import cli
from faults_data import write_log
from faults_hostile import ENV


def one_error_line(err: str, *names: object) -> str:
    """One error line, and no other line of stderr speaks of an error (Rerun's own logger is silenced)."""
    assert sum("error" in ln.lower() for ln in err.strip().splitlines()) == 1, err
    return cli_errors.one_error_line(err, *names, escapes=True)


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_log(tmp_path_factory.mktemp("srv") / "log.mcap", 3, points=800)


@pytest.fixture()
def taken_port() -> Iterator[int]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


def test_a_web_viewer_on_a_taken_port_is_refused(log: Path, taken_port: int, capsys) -> None:
    code, out, err = cli(["view", str(log), "--web", "--port", str(taken_port)], capsys)
    assert code == 2 and "http" not in out
    one_error_line(err, f"--port {taken_port}", "taken")


@pytest.mark.parametrize(
    ("bind", "named"), [("999.1.1.1", "not an address"), ("10.254.254.254", "not an address of this machine")]
)
def test_a_bind_address_that_is_not_this_machines_is_one_line(bind: str, named: str, log: Path, capsys) -> None:
    code, _, err = cli(["view", str(log), "--web", "--bind", bind], capsys)
    assert code == 2
    one_error_line(err, f"--bind {bind}", named)


@pytest.fixture()
def plain_http() -> Iterator[int]:
    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server.server_address[1]
    server.shutdown()


def test_connect_to_a_plain_http_server_is_one_line(log: Path, plain_http: int) -> None:
    """In a child process: Rerun's Rust logger writes to the process's stderr, past Python's capture."""
    url = f"rerun+http://127.0.0.1:{plain_http}/proxy"
    env = {k: v for k, v in ENV.items() if k != "RUST_LOG"}
    cmd = [sys.executable, "-m", "aftershock.pipeline", "run", str(log), "--labeller", "region-growing", "-q"]
    done = subprocess.run([*cmd, "--connect", url], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 2
    one_error_line(done.stderr, url, "could not be reached")
