"""Ray for `batch`: a local instance on 127.0.0.1, or a cluster joined at `--address` (checked first, in one
line), with the missions run on it at most `workers` at a time; Ctrl-C cancels what runs."""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from time import perf_counter
from typing import Any, Final

from aftershock.pipeline.batch.folder import MissionTask
from aftershock.pipeline.batch.site_index import STATUS_FAILED, STATUS_INTERRUPTED, empty_row
from aftershock.pipeline.batch.worker import ProgressBoard, one_line, process_mission
from aftershock.pipeline.errors import AftershockError

CONNECT_TIMEOUT_S: Final = 5.0  # reaching --address (TCP, then the gRPC handshake) must not hang
OBJECT_STORE_BYTES: Final = 200 * 2**20  # results are rows of numbers; Ray's default is 30 % of the RAM
POLL_S: Final = 0.5


def _loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def parse_address(address: str) -> tuple[str, int]:
    """HOST:PORT of a Ray cluster's head (its GCS address, as `ray start --head` prints it)."""
    if "://" in address:  # Ray Client (ray://) needs other packages and runs the driver remotely: not this path
        raise AftershockError(f"--address {address}: give the head's HOST:PORT (as `ray start --head` prints it)")
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise AftershockError(f"--address {address!r}: expected HOST:PORT of a Ray cluster's head (e.g. 10.0.0.5:6379)")
    return host.strip("[]"), int(port)


HTTP2_PREFACE: Final = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # + empty SETTINGS
HTTP2_SETTINGS: Final = 4


def check_reachable(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Fail fast, in one line, unless a gRPC server (Ray's head) answers at the address: Ray itself
    would retry for minutes. gRPC speaks HTTP/2, whose server answers a connection preface with a
    SETTINGS frame; anything else (nothing listening, another protocol, silence) is refused."""
    host, port = parse_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as conn:
            conn.settimeout(timeout_s)
            conn.sendall(HTTP2_PREFACE)
            header = conn.recv(9)
    except TimeoutError:
        header = b""
    except OSError as exc:
        reason = exc.strerror or str(exc) or type(exc).__name__
        raise AftershockError(f"--address {address}: cannot reach a Ray cluster there ({reason})") from None
    if len(header) < 4 or header[3] != HTTP2_SETTINGS:
        raise AftershockError(f"--address {address}: something listens there but does not answer as a Ray cluster")


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """Ray's servers start with SIGINT blocked (the mask is inherited), so a Ctrl-C in the terminal reaches only
    this driver, which then cancels the missions and stops Ray in order. Blocked, not ignored: a Ctrl-C during the
    start stays pending and arrives when it is done (ignored, it was lost and every mission ran). Ray's own
    SIGINT/SIGTERM handlers, if it set any, give way to the command line's again."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    import ray._private.utils as ray_utils

    # ray.init sets a SIGTERM handler that calls sys.exit(15) at once, leaving its servers and no message: while it
    # starts, SIGTERM stays the command line's (a clean stop, 143), and Ray is shut down by the caller
    set_handler = ray_utils.set_sigterm_handler
    ray_utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        ray_utils.set_sigterm_handler = set_handler
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """A second Ctrl-C must not cut the clean-up short."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def start_ray(address: str | None, workers: int | None) -> Any:
    """Join the cluster at `address`, or start a local instance on 127.0.0.1 with `workers` CPUs."""
    local = address is None or _loopback(parse_address(address)[0])
    if address is None:
        # Ray starts its workers 15 steps nicer than itself, to keep its own servers responsive; here the
        # missions are the work, so they run at the niceness the user gave the command.
        os.environ.setdefault("RAY_worker_niceness", "0")
    if local:
        # Ray takes the machine's outward address as the node's and listens on it; with clusters "off" it
        # uses 127.0.0.1 for every server, worker and the object manager (a loopback-only cluster).
        os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    if address is not None:
        check_reachable(address)
    import ray
    from ray._private import ray_constants

    if local:
        ray_constants.ENABLE_RAY_CLUSTER = False  # already read if ray was imported before
    common: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False, "configure_logging": True}
    if address is None:
        # Ray's servers stay in the terminal's process group: see `_sigint_held`
        with _sigint_held():
            ray.init(
                address="local",
                num_cpus=workers or len(os.sched_getaffinity(0)),  # the cores this process may use
                num_gpus=0,
                include_dashboard=False,
                object_store_memory=OBJECT_STORE_BYTES,
                **common,
            )
    else:
        try:
            ray.init(address=address, **common)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise AftershockError(f"--address {address}: cannot join the Ray cluster ({one_line(exc)})") from None
    return ray


@dataclass
class BatchRun:
    rows: list[dict[str, Any]] = field(default_factory=list)
    interrupted: bool = False
    wall_time_s: float = 0.0
    workers: int = 0


Update = Callable[[dict[str, Any] | None, dict[str, tuple[int, float]]], None]


def run_missions(
    tasks: Sequence[MissionTask],
    address: str | None,
    workers: int | None,
    worker_memory_bytes: int,
    on_update: Update,
) -> BatchRun:
    """Run the tasks on Ray, at most `workers` at a time; `on_update(row, running)` after each finished
    mission (row) and on every poll (row None). Ctrl-C cancels what runs and returns what finished."""
    run = BatchRun()
    if not tasks:
        return run
    t0 = perf_counter()
    on_term = signal.getsignal(signal.SIGTERM)  # the command line's: SIGTERM stops like Ctrl-C (Ray sets its own)
    try:
        ray = start_ray(address, workers)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM while Ray started: no mission is begun
        run.interrupted = True
        started = sys.modules.get("ray")  # perhaps cut off mid-import: only a Ray that did start is stopped
        with _sigint_ignored(), contextlib.suppress(Exception):
            if started is not None and started.is_initialized():
                started.shutdown()
        run.wall_time_s = perf_counter() - t0
        return run
    try:
        resources = ray.cluster_resources()
        cpus = int(resources.get("CPU", 0))
        run.workers = max(1, min(workers or cpus, len(tasks)))
        node_memory = max((n["Resources"].get("memory", 0) for n in ray.nodes() if n.get("Alive")), default=0)
        if cpus < 1:
            raise AftershockError("the Ray cluster has no CPUs to run missions on")
        if worker_memory_bytes > node_memory:
            raise AftershockError(
                f"no Ray node has {worker_memory_bytes / 2**30:.1f} GB of memory for one worker "
                f"(largest: {node_memory / 2**30:.1f} GB); lower --worker-memory"
            )
        board = ray.remote(num_cpus=0)(ProgressBoard).remote()
        remote = ray.remote(process_mission).options(
            num_cpus=1, memory=worker_memory_bytes, max_retries=0, retry_exceptions=False
        )
        queue = list(tasks)
        pending: dict[Any, MissionTask] = {}
        try:
            while queue or pending:
                if on_term is not None:  # the command line's SIGTERM, whatever Ray set meanwhile
                    signal.signal(signal.SIGTERM, on_term)
                while queue and len(pending) < run.workers:
                    task = queue.pop(0)
                    pending[remote.remote(task, board)] = task
                done, _ = ray.wait(list(pending), num_returns=1, timeout=POLL_S)
                for ref in done:
                    task = pending.pop(ref)
                    row = _result(ray, ref, task)
                    run.rows.append(row)
                    on_update(row, {})
                on_update(None, _running(ray, board, pending))
        except KeyboardInterrupt:
            run.interrupted = True
            with _sigint_ignored():  # a second Ctrl-C must not cut the clean-up short
                _cancel(ray, run, pending, queue)
        except (ray.exceptions.RayError, ConnectionError) as exc:  # the cluster went away under us
            where = f"the Ray cluster at {address}" if address else "the local Ray instance"
            raise AftershockError(f"lost {where} ({one_line(exc)}); finished missions are complete") from None
    finally:
        run.wall_time_s = perf_counter() - t0
        with _sigint_ignored():
            ray.shutdown()
    return run


def _running(ray: Any, board: Any, pending: dict[Any, MissionTask]) -> dict[str, tuple[int, float]]:
    """Scans and scans/s of the running missions; empty if the board cannot answer (it is only a display)."""
    try:
        running = ray.get(board.snapshot.remote(), timeout=10)
    except ray.exceptions.RayError:
        return {}
    names = {t.name for t in pending.values()}
    return {k: v for k, v in running.items() if k in names}


def _cancel(ray: Any, run: BatchRun, pending: dict[Any, MissionTask], queue: list[MissionTask]) -> None:
    """After Ctrl-C: stop the running missions (their folders stay incomplete, so they are redone next time)
    and list them, and those never started, as interrupted."""
    for ref, task in pending.items():
        ray.cancel(ref, force=True)
        row = empty_row(task.name, task.source) | {"status": STATUS_INTERRUPTED, "folder": task.folder}
        row["config_hash"] = task.config_hash
        row["error"] = "stopped (interrupted)"
        run.rows.append(row)
    for task in queue:
        row = empty_row(task.name, task.source) | {"status": STATUS_INTERRUPTED, "folder": task.folder}
        row["config_hash"] = task.config_hash
        row["error"] = "not started (interrupted)"
        run.rows.append(row)


def _result(ray: Any, ref: Any, task: MissionTask) -> dict[str, Any]:
    """The row a task returned, or a failed row when the worker itself died (killed, out of memory)."""
    try:
        return ray.get(ref)
    except Exception as exc:
        row = empty_row(task.name, task.source) | {"status": STATUS_FAILED, "folder": task.folder}
        row["error"] = f"the worker died: {one_line(exc)}"
        row["config_hash"] = task.config_hash
        return row
