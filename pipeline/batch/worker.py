"""One mission inside a Ray worker: the mission library run single-threaded into the mission's folder, its
progress reported, its memory kept within bound, and its row of the site index."""

from __future__ import annotations

import contextlib
import json
import os
import resource
import socket
import traceback
import warnings
from datetime import UTC, datetime
from pathlib import Path
from time import perf_counter
from typing import Any, Final

import numpy as np

from aftershock.pipeline.batch.folder import ERROR_FILE, MARKER_FILE, RECORDING_FILE, MissionTask, atomic_write
from aftershock.pipeline.batch.site_index import (
    OBJECT_COLUMNS,
    STATUS_FAILED,
    STATUS_INTERRUPTED,
    STATUS_OK,
    STRUCTURE_COLUMNS,
    empty_row,
)
from aftershock.pipeline.config import Config
from aftershock.pipeline.errors import AftershockError
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.types import Frame

PROGRESS_EVERY_S: Final = 0.5  # how often a mission reports its scans (and checks its memory)


class MemoryBoundExceeded(AftershockError):
    """A mission's worker grew beyond the memory bound given to each worker."""


class MemoryBound:
    """The OS holds a mission to its bound: the worker's address space may grow by at most the bound
    (RLIMIT_AS, soft limit, restored after the mission: Ray reuses workers), so an allocation past it fails at
    once instead of taking the node down; and the kernel's peak-RSS counter (VmHWM) is reset at the start, so
    the row gets the mission's true peak, not a sample every half second."""

    def __init__(self, limit_bytes: int) -> None:
        self.limit = limit_bytes
        self._saved: tuple[int, int] | None = None

    def __enter__(self) -> MemoryBound:
        _reset_peak()
        return self

    def arm(self) -> None:
        """Set the bound from here on (called at the first scan, once the libraries are loaded: their mappings
        are address space, not memory the mission uses)."""
        if not self.limit or self._saved is not None:
            return
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        want = _mapped_bytes() + self.limit
        if hard != resource.RLIM_INFINITY:
            want = min(want, hard)
        if soft == resource.RLIM_INFINITY or want < soft:
            try:
                resource.setrlimit(resource.RLIMIT_AS, (want, hard))
                self._saved = (soft, hard)
            except (ValueError, OSError):  # a platform without RLIMIT_AS: the RSS checks still hold
                self._saved = None

    def __exit__(self, *exc: object) -> None:
        if self._saved is not None:
            with contextlib.suppress(ValueError, OSError):
                resource.setrlimit(resource.RLIMIT_AS, self._saved)
            self._saved = None

    @staticmethod
    def peak_bytes() -> int | None:
        """The kernel's peak resident memory of this process since `__enter__` (None where it keeps none)."""
        try:
            text = Path("/proc/self/status").read_text()
        except OSError:
            return None
        for line in text.splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
        return None


def _reset_peak() -> None:
    with contextlib.suppress(OSError):  # Linux 4.0+: writing 5 resets VmHWM to the current RSS
        Path("/proc/self/clear_refs").write_text("5")


def _mapped_bytes() -> int:
    try:
        return int(Path("/proc/self/statm").read_text().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


class ProgressSink(Sink):
    """Reports a mission's scans (and scans/s) to the driver's progress board, and keeps the worker within
    its memory bound: it is the only place that sees every scan go by."""

    def __init__(self, name: str, board: Any, memory_limit_bytes: int, bound: MemoryBound | None = None) -> None:
        import psutil

        self.bound = bound
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
        if self.scans == 0 and self.bound is not None:
            self.bound.arm()
        self.scans += 1
        now = perf_counter()
        if now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            self.check_memory()
            if self.board is not None:
                self.board.report.remote(self.name, self.scans, self.scans / max(now - self.t0, 1e-9))

    def check_memory(self) -> None:
        rss = max(self.process.memory_info().rss, MemoryBound.peak_bytes() or 0)
        self.peak_rss = max(self.peak_rss, rss)
        if self.limit and rss > self.limit:
            raise MemoryBoundExceeded(
                f"the worker grew to {rss / 2**30:.2f} GB, beyond the bound of {self.limit / 2**30:.2f} GB "
                "per worker (--worker-memory)"
            )


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


def process_mission(task: MissionTask, board: Any = None) -> dict[str, Any]:
    """Run one mission (in a Ray worker) and return its index row; never raises for a bad log."""
    import psutil
    import torch

    from aftershock import sources
    from aftershock.pipeline.mission import Outputs, run_source

    t0 = perf_counter()
    cpu0 = psutil.Process().cpu_times()
    folder = Path(task.folder)
    row = empty_row(task.name, task.source) | {"config_hash": task.config_hash, "node": _node_name()}
    row["folder"] = str(folder)
    notes: list[str] = []
    progress: ProgressSink | None = None
    bound = MemoryBound(task.memory_limit_bytes)
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
        progress = ProgressSink(task.name, board, task.memory_limit_bytes, bound)
        outputs = Outputs(save=folder / RECORDING_FILE, export=folder, force=True)  # the folder is being redone
        with bound, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result, extra, info = run_source(
                    task.source,
                    cfg,
                    outputs,
                    damage=task.damage,
                    quiet=True,
                    notice=notes.append,
                    extra_sinks=[progress],
                )
            finally:  # a log cut off part-way warns, then may still fail: keep the warning either way
                notes.extend(str(w.message) for w in caught)
        report = info.report
        if report.damage:
            notes.append(f"the log ends in damage: {report.damage}")
        if report.skipped:
            notes.append(f"{len(report.skipped)} messages skipped, the first: {report.skipped[0][1]}")
        _fill_row(row, result, extra, folder, task.damage, cfg.structure.enabled)
        row["status"] = STATUS_INTERRUPTED if result.summary.interrupted else STATUS_OK
    except KeyboardInterrupt:
        row["status"] = STATUS_INTERRUPTED
    except MemoryError as exc:  # the address-space bound refused an allocation: the mission is over its bound
        detail = f" ({one_line(exc)})" if str(exc) else ""
        row["status"] = STATUS_FAILED
        bound_gb = task.memory_limit_bytes / 2**30
        row["error"] = f"the mission needed more than its bound of {bound_gb:.2f} GB a worker (--worker-memory){detail}"
    except AftershockError as exc:
        row["status"], row["error"] = STATUS_FAILED, str(exc)
    except Exception as exc:  # a bug, or a log broken in a way no reader foresaw: one line here, details in a file
        row["status"], row["error"] = STATUS_FAILED, one_line(exc)
        with contextlib.suppress(OSError):
            (folder / ERROR_FILE).write_text(traceback.format_exc())
    if progress is not None:
        progress.peak_rss = max(progress.peak_rss, progress.process.memory_info().rss, MemoryBound.peak_bytes() or 0)
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
            atomic_write(folder / MARKER_FILE, json.dumps(marker, indent=2) + "\n")
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


def _fill_row(
    row: dict[str, Any], result: Any, extra: dict[str, Any], folder: Path, damage: bool, structure: bool
) -> None:
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
    for col, kinds in STRUCTURE_COLUMNS.items():  # the model off measured nothing: null, never 0
        row[col] = sum(int(s.structure_elements.get(k, 0)) for k in kinds) if structure else None
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
