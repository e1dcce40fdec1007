"""Reading and registering on a second thread (`stream.overlap`, opt-in) gives the same run as one stage
after the other: the same map, labels, poses and sink calls, byte for byte; errors and Ctrl-C in the reader
arrive in their turn, and the reader thread is gone when the run returns."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from aftershock import sources
from aftershock.pipeline.config import load_config
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.types import Frame, LabelledCloud, RunInfo, RunSummary, Scan
from aftershock.sinks.files import FileExportSink

MISSION = "sim://disaster?seed=5&sensor=vlp16&scans=10"
READER = "aftershock-read-register"
TESTS = Path(__file__).resolve().parent


def _digest(*arrays: np.ndarray | None) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(b"-" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


class CallLog(Sink):
    """Every sink call, in order, with a digest of what it was given (and on which thread)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int, str]] = []
        self.threads: set[str] = set()

    def stage(self, frame: Frame, stage: Stage) -> None:
        self.threads.add(threading.current_thread().name)
        labels = frame.labels
        kept = frame.map_rows.points if frame.map_rows is not None else None
        got = (frame.scan.points, frame.pose, frame.world_points, kept)
        if labels is not None:
            got += (labels.class_ids, labels.instance_ids, labels.scores, labels.embeddings)
        self.calls.append((stage.value, frame.seq, _digest(*got)))

    def map_update(self, cloud: LabelledCloud, seq: int) -> None:
        self.calls.append(("map", seq, _digest(cloud.points, cloud.class_ids, cloud.instance_ids)))

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self.calls.append(("end", summary.scans, _digest(final_map.points, final_map.class_ids)))


def _run(overlap: bool, export: Path, scans: Iterator[Scan] | None = None) -> tuple[StreamResult, CallLog]:
    # One KISS-ICP thread: with several, its parallel sums add up in an order that varies from run to run
    # (the first registrar of a process sets it for the whole process: see the byte-for-byte test).
    settings = ["label.labeller=mcpnet", "registration.threads=1", f"stream.overlap={str(overlap).lower()}"]
    cfg = load_config(None, settings)
    log = CallLog()
    sinks = [log, FileExportSink(export)]
    scans = sources.open(MISSION) if scans is None else scans
    result = run_stream(scans, cfg, sinks, RunInfo(source=MISSION, source_kind="sim"), lambda _t: None)
    return result, log


def compare_runs(folder: Path) -> None:
    """The sequential and the overlapped run of MISSION, compared byte for byte (run in a fresh process)."""
    seq, seq_log = _run(False, folder / "seq")
    ovl, ovl_log = _run(True, folder / "ovl")
    assert seq.summary.scans == ovl.summary.scans == 10
    for name in ("positions", "class_ids", "scores", "instance_ids", "embeddings"):
        a, b = getattr(seq.vmap, name), getattr(ovl.vmap, name)
        assert a.tobytes() == b.tobytes(), name
    assert seq.poses.tobytes() == ovl.poses.tobytes()
    assert seq_log.calls == ovl_log.calls  # every sink call, in the same order, with the same data
    assert ovl_log.threads == {threading.main_thread().name}  # sinks are only ever called on the main thread
    for name in ("map.ply", "poses_tum.txt", "poses_kitti.txt"):
        assert (folder / "seq" / name).read_bytes() == (folder / "ovl" / name).read_bytes(), name
    assert not any(t.name == READER for t in threading.enumerate())


def test_overlapped_run_is_the_sequential_run_byte_for_byte(tmp_path: Path) -> None:
    """In a process of its own: KISS-ICP takes its thread count from the first registrar a process makes (a
    process-wide TBB limit), and only on one thread do its sums come out in the same order every run."""
    script = (
        f"import sys; sys.path.insert(0, {str(TESTS)!r}); from pathlib import Path; "
        f"import test_stream_overlap as t; t.compare_runs(Path({str(tmp_path)!r}))"
    )
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]


def _failing(after: int, error: BaseException) -> Iterator[Scan]:
    for k, scan in enumerate(sources.open(MISSION)):
        if k == after:
            raise error
        yield scan


def test_an_error_while_reading_arrives_in_its_turn_and_the_reader_ends(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="broken scan"):
        _run(True, tmp_path / "out", _failing(4, ValueError("broken scan")))
    assert not any(t.name == READER for t in threading.enumerate())


def test_ctrl_c_in_the_reader_stops_after_the_scans_before_it(tmp_path: Path) -> None:
    result, log = _run(True, tmp_path / "out", _failing(4, KeyboardInterrupt()))
    assert result.summary.interrupted and result.summary.scans == 4
    assert [c[1] for c in log.calls if c[0] == "clustered"] == list(range(4))
    assert (tmp_path / "out" / "map.ply").is_file()
    assert not any(t.name == READER for t in threading.enumerate())
