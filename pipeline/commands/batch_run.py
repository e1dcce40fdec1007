"""`batch`'s engine: every mission one Ray task running `run`'s stream, resumable, failures isolated.

A mission's folder `DIR/<mission>/` holds `recording.rrd`, `map.ply`, `poses_tum.txt`, `poses_kitti.txt`,
`summary.json` (and `damage.json`), and — written last, atomically — `mission.json`: the mission's index row
and the configuration's fingerprint. A folder with a matching `mission.json` and every file it names is
complete and skipped on a re-run; any other folder (interrupted, failed) is redone. `DIR/batch.json`
records the configuration the folder's results were made with; another configuration is refused unless
`--force`.

Ray: without `--address` a local instance sized to `--workers` (default: the cores), its servers and
workers listening on 127.0.0.1 only, no dashboard, a small object store (results are small rows). With
`--address` the driver joins that cluster the same way and keeps at most `--workers` (default: the
cluster's CPUs) missions in flight. Each mission asks Ray for one CPU and `worker_memory` bytes (so Ray
never packs more missions onto a node than its memory holds) and aborts with an error if its worker grows
beyond that bound. Every mission runs single-threaded (KISS-ICP, torch, BLAS, no reader thread), so missions,
not threads, share the cores.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import signal
import socket
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from time import perf_counter
from typing import Any, Final

import numpy as np

from aftershock.pipeline.commands.batch_sources import MissionSource
from aftershock.pipeline.commands.site_index import (
    INDEX_FILE,
    OBJECT_COLUMNS,
    STATUS_FAILED,
    STATUS_INTERRUPTED,
    STATUS_OK,
    empty_row,
    read_index,
)
from aftershock.pipeline.config import Config
from aftershock.pipeline.errors import AftershockError, OutputError
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.types import Frame

MANIFEST_FILE: Final = "batch.json"
MARKER_FILE: Final = "mission.json"
RECORDING_FILE: Final = "recording.rrd"
ERROR_FILE: Final = "error.txt"
OUTPUT_COLUMNS: Final[tuple[str, ...]] = ("recording", "map", "poses_tum", "poses_kitti", "summary", "damage")

CONNECT_TIMEOUT_S: Final = 5.0  # reaching --address (TCP, then the gRPC handshake) must not hang
OBJECT_STORE_BYTES: Final = 200 * 2**20  # results are rows of numbers; Ray's default is 30 % of the RAM
PROGRESS_EVERY_S: Final = 0.5  # how often a mission reports its scans (and checks its memory)
POLL_S: Final = 0.5


# ----------------------------------------------------------------------------------- the configuration


def config_fingerprint(cfg: Config, damage: bool) -> tuple[str, dict[str, Any]]:
    """A short hash of everything that shapes a mission's results, and the settings it was made from."""
    settings = json.loads(cfg.model_dump_json()) | {"damage": damage}
    text = json.dumps(settings, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16], settings


def _differences(a: Mapping[str, Any], b: Mapping[str, Any], prefix: str = "") -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            out.extend(_differences(va, vb, f"{prefix}{key}."))
        elif va != vb:
            out.append(f"{prefix}{key}")
    return out


def prepare_output(out: Path, fingerprint: str, settings: dict[str, Any], force: bool) -> None:
    """Make the output folder, or refuse one that holds other results (another configuration, or files
    that are not a batch's) unless `force`; then record this configuration in it."""
    manifest = out / MANIFEST_FILE
    if out.exists() and not out.is_dir():
        raise OutputError("exists and is not a folder", out)
    if out.is_dir() and any(out.iterdir()) and not force:
        try:
            old = json.loads(manifest.read_text())
        except FileNotFoundError:
            raise OutputError(
                "holds files that are not a batch's results; pass --force to write into it anyway", out
            ) from None
        except (OSError, ValueError) as exc:
            raise OutputError(f"unreadable {MANIFEST_FILE} ({exc}); pass --force to replace it", out) from None
        if old.get("config_hash") != fingerprint:
            changed = ", ".join(_differences(old.get("settings", {}), settings)[:6]) or "unknown settings"
            raise OutputError(
                f"holds results of another configuration (differs in {changed}); "
                "pass --force to replace them, or choose another --out",
                out,
            )
    try:
        out.mkdir(parents=True, exist_ok=True)
        data = {"config_hash": fingerprint, "settings": settings, "written_by": "aftershock batch"}
        _atomic_write(manifest, json.dumps(data, indent=2) + "\n")
    except OSError as exc:
        raise OutputError(f"cannot write: {exc.strerror}", out) from None


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------------ the missions


@dataclass(frozen=True, slots=True)
class MissionTask:
    """Everything a Ray worker needs to run one mission (plain data: it is pickled to the worker)."""

    name: str
    source: str
    folder: str
    config_json: str
    config_hash: str
    damage: bool
    memory_limit_bytes: int


def completed_row(folder: Path, source: str, fingerprint: str) -> dict[str, Any] | None:
    """The index row of a complete mission in `folder` (same source, same configuration, every output
    present), or None when it has to be (re)done."""
    try:
        marker = json.loads((folder / MARKER_FILE).read_text())
    except (OSError, ValueError):
        return None
    row = marker.get("row", {})
    if marker.get("config_hash") != fingerprint or row.get("source") != source or row.get("status") != STATUS_OK:
        return None
    if not all((folder / Path(row[c]).name).is_file() for c in OUTPUT_COLUMNS if row.get(c)):
        return None
    return row


def taken_names(out: Path) -> dict[str, str]:
    """Mission folders already in the output folder, by name, with the source each holds."""
    names: dict[str, str] = {}
    if not out.is_dir():
        return names
    for marker in out.glob(f"*/{MARKER_FILE}"):
        try:
            names[marker.parent.name] = json.loads(marker.read_text())["row"]["source"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return names


class MemoryBoundExceeded(AftershockError):
    """A mission's worker grew beyond the memory bound given to each worker."""


class ProgressSink(Sink):
    """Reports a mission's scans (and scans/s) to the driver's progress board, and keeps the worker within
    its memory bound: it is the only place that sees every scan go by."""

    def __init__(self, name: str, board: Any, memory_limit_bytes: int) -> None:
        import psutil

        self.name = name
        self.board = board
        self.limit = memory_limit_bytes
        self.process = psutil.Process()
        self.scans = 0
        self.peak_rss = self.process.memory_info().rss
        self.t0 = perf_counter()
        self.last = 0.0

    def stage(self, frame: Frame, stage: Stage) -> None:
        if stage is not Stage.CLUSTERED:
            return
        self.scans += 1
        now = perf_counter()
        if now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            self.check_memory()
            if self.board is not None:
                self.board.report.remote(self.name, self.scans, self.scans / max(now - self.t0, 1e-9))

    def check_memory(self) -> None:
        rss = self.process.memory_info().rss
        self.peak_rss = max(self.peak_rss, rss)
        if self.limit and rss > self.limit:
            raise MemoryBoundExceeded(
                f"the worker grew to {rss / 2**30:.2f} GB, beyond the bound of {self.limit / 2**30:.2f} GB "
                "per worker (--worker-memory)"
            )


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def process_mission(task: MissionTask, board: Any = None) -> dict[str, Any]:
    """Run one mission (in a Ray worker) and return its index row; never raises for a bad log."""
    import psutil
    import torch

    from aftershock import sources
    from aftershock.pipeline.commands.run import Outputs, run_source

    t0 = perf_counter()
    cpu0 = psutil.Process().cpu_times()
    folder = Path(task.folder)
    row = empty_row(task.name, task.source) | {"config_hash": task.config_hash, "node": _node_name()}
    row["folder"] = str(folder)
    notes: list[str] = []
    progress: ProgressSink | None = None
    try:
        # Not complete until mission.json is written again at the very end.
        (folder / MARKER_FILE).unlink(missing_ok=True)
        (folder / ERROR_FILE).unlink(missing_ok=True)
        folder.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(1)
        cfg = Config.model_validate_json(task.config_json)
        cfg.registration.threads = 1  # one core per mission: missions share the machine, not threads
        cfg.stream.overlap = False  # ... nor a second thread reading ahead
        row["source_kind"] = sources.kind_of(task.source).value
        progress = ProgressSink(task.name, board, task.memory_limit_bytes)
        outputs = Outputs(save=folder / RECORDING_FILE, export=folder, force=True)  # the folder is being redone
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                options = {"damage": task.damage, "quiet": True, "notice": notes.append, "extra_sinks": [progress]}
                result, extra, info = run_source(task.source, cfg, outputs, **options)
            finally:  # a log cut off part-way warns, then may still fail: keep the warning either way
                notes.extend(str(w.message) for w in caught)
        report = info.report
        if report.damage:
            notes.append(f"the log ends in damage: {report.damage}")
        if report.skipped:
            notes.append(f"{len(report.skipped)} messages skipped, the first: {report.skipped[0][1]}")
        _fill_row(row, result, extra, folder, task.damage)
        row["status"] = STATUS_INTERRUPTED if result.summary.interrupted else STATUS_OK
    except KeyboardInterrupt:
        row["status"] = STATUS_INTERRUPTED
    except AftershockError as exc:
        row["status"], row["error"] = STATUS_FAILED, str(exc)
    except Exception as exc:  # a bug, or a log broken in a way no reader foresaw: one line here, details in a file
        row["status"], row["error"] = STATUS_FAILED, _one_line(exc)
        with contextlib.suppress(OSError):
            (folder / ERROR_FILE).write_text(traceback.format_exc())
    if progress is not None:
        progress.peak_rss = max(progress.peak_rss, progress.process.memory_info().rss)
        row["peak_rss_mb"] = round(progress.peak_rss / 2**20, 1)
    row["warnings"] = "\n".join(dict.fromkeys(notes)) or None
    row["processing_s"] = round(perf_counter() - t0, 3)
    cpu1 = psutil.Process().cpu_times()
    row["cpu_s"] = round(cpu1.user + cpu1.system - cpu0.user - cpu0.system, 3)
    row["finished_at"] = datetime.now(UTC).isoformat(timespec="seconds")
    if board is not None:
        board.done.remote(task.name)
    if row["status"] == STATUS_FAILED and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()  # nothing was written: leave no empty folder behind
    if row["status"] == STATUS_OK:
        marker = {"config_hash": task.config_hash, "row": row}
        try:
            _atomic_write(folder / MARKER_FILE, json.dumps(marker, indent=2) + "\n")
        except OSError as exc:
            row["status"], row["error"] = STATUS_FAILED, f"{folder / MARKER_FILE}: cannot write: {exc.strerror}"
    return row


def _node_name() -> str:
    """The host and Ray node (several nodes may share a host) that ran a mission."""
    try:
        import ray

        node = ray.get_runtime_context().get_node_id()[:8]
    except Exception:  # not inside Ray (a direct call, as in tests)
        node = ""
    host = socket.gethostname()
    return f"{host}/{node}" if node else host


def _fill_row(row: dict[str, Any], result: Any, extra: dict[str, Any], folder: Path, damage: bool) -> None:
    from aftershock.sinks.files import DAMAGE_FILE, KITTI_FILE, MAP_FILE, SUMMARY_FILE, TUM_FILE

    s = result.summary
    stamps = result.stamps_ns
    poses = result.poses
    steps = np.diff(poses[:, :3, 3], axis=0) if len(poses) > 1 else np.zeros((0, 3))
    row |= {
        "scans": s.scans,
        "points": s.points,
        "duration_s": round(float(stamps[-1] - stamps[0]) / 1e9, 3) if len(stamps) > 1 else 0.0,
        "path_length_m": round(float(np.sqrt((steps**2).sum(axis=1)).sum()), 3),
        "ate_m": round(result.trajectory.ate_rmse_m, 4) if result.trajectory is not None else None,
        "registration_failures": len(s.registration_failures),
        "map_voxels": s.map_voxels,
        "objects": s.instances,
        "environment": result.environment.value,
        "labeller": result.labeller,
        "scans_per_second": round(s.scans_per_second, 2),
        "recording": str(folder / RECORDING_FILE),
        "map": str(folder / MAP_FILE),
        "poses_tum": str(folder / TUM_FILE),
        "poses_kitti": str(folder / KITTI_FILE),
        "summary": str(folder / SUMMARY_FILE),
    }
    for col in OBJECT_COLUMNS:
        row[col] = int(s.instances_per_class.get(col[len("objects_") :], 0))
    if damage and "damage" in extra:
        d = extra["damage"]
        stories = d.get("stories", [])
        row |= {
            "cracks": len(d.get("cracks", [])),
            "severe_cracks": int(d.get("severe_cracks", 0)),
            # not measured (one slab) is null, never 0
            "worst_drift_mm": max((abs(st["drift_mm"]) for st in stories if st["drift_mm"] is not None), default=None),
            "worst_tilt_deg": max((abs(st["tilt_deg"]) for st in stories if st["tilt_deg"] is not None), default=None),
            "damage": str(folder / DAMAGE_FILE),
        }


class ProgressBoard:
    """A Ray actor (no CPU) the running missions report to; the driver reads it for the progress bar."""

    def __init__(self) -> None:
        self.running: dict[str, tuple[int, float]] = {}

    def report(self, name: str, scans: int, rate: float) -> None:
        self.running[name] = (scans, rate)

    def done(self, name: str) -> None:
        self.running.pop(name, None)

    def snapshot(self) -> dict[str, tuple[int, float]]:
        return dict(self.running)


# ------------------------------------------------------------------------------------------------ Ray


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
def _sigint_ignored() -> Iterator[None]:
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
        # Ray's servers stay in the terminal's process group: started with SIGINT ignored (inherited), a
        # Ctrl-C reaches only this driver, which then cancels the missions and stops Ray in order.
        with _sigint_ignored():
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
            raise AftershockError(f"--address {address}: cannot join the Ray cluster ({_one_line(exc)})") from None
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
    ray = start_ray(address, workers)
    t0 = perf_counter()
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
            raise AftershockError(f"lost {where} ({_one_line(exc)}); finished missions are complete") from None
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
        row["error"] = f"the worker died: {_one_line(exc)}"
        row["config_hash"] = task.config_hash
        return row


# ------------------------------------------------------------------------------------------ the index


def merge_index(out: Path, rows: Sequence[dict[str, Any]], fingerprint: str) -> list[dict[str, Any]]:
    """This run's rows over the rows already in the index (missions of earlier batches into the same
    folder stay listed as long as they were made with the same configuration)."""
    path = out / INDEX_FILE
    merged: dict[str, dict[str, Any]] = {}
    if path.is_file():
        try:
            old = read_index(path)
        except AftershockError:
            old = []
        merged = {r["mission"]: r for r in old if r.get("config_hash") == fingerprint}
    merged |= {r["mission"]: r for r in rows}
    return sorted(merged.values(), key=lambda r: r["mission"])


def plan(
    missions: Sequence[MissionSource], out: Path, cfg: Config, damage: bool, force: bool, worker_memory: int
) -> tuple[list[MissionTask], list[dict[str, Any]], str]:
    """Split the missions into tasks to run and rows known without running (reused complete missions,
    sources that are no mission); returns those and the configuration's fingerprint."""
    from aftershock import sources

    fingerprint, _ = config_fingerprint(cfg, damage)
    tasks: list[MissionTask] = []
    known: list[dict[str, Any]] = []
    cfg_json = cfg.model_dump_json()
    for m in missions:
        folder = out / m.name
        error = m.error
        if error is None:
            try:
                sources.kind_of(m.source)  # a missing, unreadable or non-log file: no task, no folder
            except AftershockError as exc:
                error = str(exc)
        if error is not None:
            row = empty_row(m.name, m.source) | {"status": STATUS_FAILED, "error": error, "config_hash": fingerprint}
            known.append(row)
            continue
        done = None if force else completed_row(folder, m.source, fingerprint)
        if done is not None:
            known.append(done | {"reused": True})
            continue
        tasks.append(MissionTask(m.name, m.source, str(folder), cfg_json, fingerprint, damage, worker_memory))
    return tasks, known, fingerprint


def print_note(text: str) -> None:
    print(f"aftershock: {text}", file=sys.stderr)
