"""Rerun viewers this tool starts: the native viewer or the web viewer, served on 127.0.0.1 unless the user
names another address (the `rerun` command's own default is every interface)."""

from __future__ import annotations

import importlib.util
import os
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from aftershock.pipeline.errors import InputError, OutputError

LOCALHOST: Final = "127.0.0.1"
START_TIMEOUT_S: Final = 30.0
VIEWER_MEMORY: Final = "75%"  # the viewer drops the oldest data past this; compact recordings stay below it


def rerun_command() -> str:
    """The viewer binary that rerun-sdk ships (`rerun_cli/rerun`), else the `rerun` command beside this Python or
    on PATH. The binary itself, not the console script that wraps it: the script runs the binary as a child, so
    stopping the script would leave the viewer running."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).with_name("rerun")
        if binary.is_file() and os.access(binary, os.X_OK):
            return str(binary)
    beside = Path(sys.executable).with_name("rerun")
    return str(beside) if beside.exists() else "rerun"


def free_port(host: str = LOCALHOST) -> int:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def check_bind(bind: str) -> None:
    """InputError unless `bind` is an address of this machine (or every interface, 0.0.0.0 / ::)."""
    try:
        infos = socket.getaddrinfo(bind, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError, ValueError) as exc:
        raise InputError(f"--bind {bind}: not an address ({getattr(exc, 'strerror', None) or exc})") from None
    reason = "no address"
    for family, kind, proto, _, addr in infos:
        try:
            with socket.socket(family, kind, proto) as s:
                s.bind((addr[0], 0))
                return
        except OSError as exc:
            reason = exc.strerror or str(exc)
    raise InputError(f"--bind {bind}: not an address of this machine ({reason})")


def _can_bind(bind: str, port: int) -> bool:
    try:
        with socket.socket(socket.AF_INET6 if ":" in bind else socket.AF_INET) as s:
            s.bind((bind, port))
            return True
    except OSError:
        return False


def listening(host: str, port: int, timeout_s: float = 0.5) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


@dataclass(frozen=True, slots=True)
class Viewer:
    """A started viewer: where SDKs send data (`grpc_url`), and for the web viewer the page to open."""

    process: subprocess.Popen[bytes] | None  # None when a viewer was already listening there
    grpc_url: str
    web_url: str | None = None


def start_viewer(*, web: bool = False, bind: str = LOCALHOST, port: int | None = None) -> Viewer:
    """Start a native viewer (detached: it outlives this process) or a web viewer server (a child that
    ends with this process), listening on `bind`; reuse a native viewer already listening on `port`."""
    check_bind(bind)
    connect_host = LOCALHOST if bind in ("0.0.0.0", "::") else bind
    if port is not None and not 1 <= port <= 65535:
        raise InputError(f"--port {port}: a port is between 1 and 65535")
    grpc_port = port or free_port(LOCALHOST if connect_host == LOCALHOST else bind)
    grpc_url = f"rerun+http://{connect_host}:{grpc_port}/proxy"
    if not web and listening(connect_host, grpc_port):
        return Viewer(None, grpc_url)
    if port is not None and (listening(connect_host, grpc_port) or not _can_bind(bind, grpc_port)):
        # a web page pointed at it would show whatever else listens there: someone else's viewer or data
        raise InputError(f"--port {grpc_port}: the port is taken on {bind}; choose another or leave --port out")
    cmd = [rerun_command(), "--bind", bind, "--port", str(grpc_port), "--memory-limit", VIEWER_MEMORY]
    web_url = None
    if web:
        web_port = free_port(LOCALHOST if connect_host == LOCALHOST else bind)
        cmd += ["--serve-web", "--web-viewer-port", str(web_port), "--server-memory-limit", VIEWER_MEMORY]
        web_url = f"http://{connect_host}:{web_port}/?url=" + grpc_url.replace(":", "%3A").replace("/", "%2F")
    else:
        cmd += ["--expect-data-soon"]
    env = dict(os.environ, RERUN_ANALYTICS=os.environ.get("RERUN_ANALYTICS", "0"))
    # stderr into a file, not a pipe: a viewer that outlives us must not write into a closed pipe
    with tempfile.TemporaryFile() as errors:
        try:
            proc = subprocess.Popen(
                cmd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=errors,
                start_new_session=not web,  # the native viewer stays open after we exit
            )  # fmt: skip
        except OSError as exc:
            raise OutputError(f"cannot start the Rerun viewer ({exc.strerror})", cmd[0]) from None
        deadline = time.monotonic() + START_TIMEOUT_S
        while not listening(connect_host, grpc_port):
            if proc.poll() is not None:
                errors.seek(0)
                err = errors.read().decode(errors="replace").strip().splitlines()
                raise OutputError(f"the Rerun viewer stopped at start ({err[-1] if err else 'no message'})", cmd[0])
            if time.monotonic() > deadline:
                proc.kill()
                raise OutputError(f"the Rerun viewer did not start listening within {START_TIMEOUT_S:.0f} s", grpc_url)
            time.sleep(0.2)
    return Viewer(proc, grpc_url, web_url)
