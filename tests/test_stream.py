"""The stream: every scan through register -> label -> cluster in that order, every sink told after each
stage and the map every `rerun.map_every` scans and once at the end; a scan registration cannot align is
marked and the run goes on; Ctrl-C ends the run with valid outputs of what was processed.

Reading and registering on a second thread (`stream.overlap`, opt-in) gives the same run as one stage
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
from rrd_read import read_rrd, rrd_verify

from aftershock import sources
from aftershock.pipeline.config import load_config
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.stream import StreamResult, run_stream
from aftershock.pipeline.types import Frame, LabelledCloud, RunInfo, RunSummary, Scan
from aftershock.sinks import rerun_blueprint as L
from aftershock.sinks.files import FileExportSink
from aftershock.sinks.rerun_sink import RerunSink

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


class Told(Sink):
    """What each sink call saw of the frame: the stages' outputs present when the sinks were told."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int, tuple[str, ...]]] = []

    def begin(self, info: RunInfo) -> None:
        self.calls.append(("begin", -1, ()))

    def stage(self, frame: Frame, stage: Stage) -> None:
        ran = tuple(name for name in ("source", "register", "label", "cluster") if name in frame.timings_ms)
        placed = frame.pose is not None and frame.world_points is not None
        self.calls.append((stage.value, frame.seq, (*ran, "labels") if frame.labels is not None else ran))
        assert placed  # every sink sees the scan placed in the world, the raw one too

    def map_update(self, cloud: LabelledCloud, seq: int) -> None:
        self.calls.append(("map", seq, ()))

    def end(self, summary: RunSummary, final_map: LabelledCloud) -> None:
        self.calls.append(("end", summary.scans, ()))

    def close(self) -> None:
        self.calls.append(("close", -1, ()))


def _told(settings: list[str], scans: Iterator[Scan] | None = None) -> tuple[StreamResult, Told]:
    cfg = load_config(None, ["label.labeller=region-growing", *settings])
    told = Told()
    scans = sources.open(MISSION) if scans is None else scans
    result = run_stream(scans, cfg, [told], RunInfo(source=MISSION, source_kind="sim"), lambda _t: None)
    return result, told


@pytest.mark.parametrize("overlap", [False, True])
def test_every_scan_goes_through_the_stages_in_order_and_the_sinks_are_told_after_each(overlap: bool) -> None:
    result, told = _told([f"stream.overlap={str(overlap).lower()}", "rerun.map_every=1000"])
    assert result.summary.scans == 10 and not result.summary.interrupted
    assert told.calls[0] == ("begin", -1, ()) and told.calls[-1] == ("close", -1, ())
    assert told.calls[-3:-1] == [("map", 9, ()), ("end", 10, ())]  # the final map once, then the end
    stages = told.calls[1:-3]
    read = ("source", "register")  # the raw scan goes out after registration, which leaves it as it is
    expected = [
        (stage, seq, ran)
        for seq in range(10)
        for stage, ran in (
            ("raw", read),
            ("registered", read),
            ("labelled", (*read, "label", "labels")),
            ("clustered", (*read, "label", "cluster", "labels")),
        )
    ]
    assert stages == expected


def test_the_map_goes_to_the_sinks_every_n_scans_after_the_scan_and_once_at_the_end() -> None:
    _, told = _told(["rerun.map_every=3"])
    maps = [seq for what, seq, _ in told.calls if what == "map"]
    assert maps == [2, 5, 8, 9]
    for seq in (2, 5, 8):  # right after the scan's last stage, before the next scan
        k = told.calls.index(("map", seq, ()))
        assert told.calls[k - 1][:2] == ("clustered", seq) and told.calls[k + 1][:2] == ("raw", seq + 1)
    result, every = _told(["rerun.map_every=1"])
    s = result.summary
    changed = s.final_merges > 0 or s.fragments != s.instances  # the end-of-run consolidation changed the map
    again = [9] if changed else []  # ... else the map the sinks have after the last scan is the final one
    assert [seq for what, seq, _ in every.calls if what == "map"] == [*range(10), *again]


def test_ctrl_c_ends_the_run_cleanly_with_what_went_through_every_stage() -> None:
    result, told = _told([], _failing(6, KeyboardInterrupt()))
    assert result.summary.interrupted and result.summary.scans == 6
    assert [seq for what, seq, _ in told.calls if what == "clustered"] == list(range(6))
    assert [c[0] for c in told.calls[-3:]] == ["map", "end", "close"]  # the sinks finish their outputs
    assert told.calls[-2] == ("end", 6, ())
    assert len(result.poses) == 6 and len(result.vmap) > 0


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
        f"import test_stream as t; t.compare_runs(Path({str(tmp_path)!r}))"
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


def test_a_scan_registration_cannot_align_is_marked_and_the_run_goes_on(lidar_dir: Path) -> None:
    from aftershock import sources

    scans = list(sources.open(lidar_dir / "velodyne_vlp16_indoor.mcap"))
    scans.insert(2, scans[1].select(np.arange(30)))  # a scan of 30 points in the middle of the log
    for k, s in enumerate(scans):
        s.seq = k
    cfg = load_config(None, ['label.labeller="region-growing"'])
    result = run_stream(scans, cfg, [], RunInfo("test", "mcap"), notice=lambda _t: None)
    assert result.summary.scans == 5 and result.summary.registration_failures == [2]


def _interrupted(scans: list[Scan], after: int) -> Iterator[Scan]:
    for k, s in enumerate(scans):
        if k == after:
            raise KeyboardInterrupt
        yield s


def test_interrupt_leaves_a_valid_recording_of_what_was_processed(lidar_dir: Path, tmp_path: Path) -> None:
    from aftershock import sources

    scans = list(sources.open(lidar_dir / "velodyne_vlp16_indoor.mcap"))
    out = tmp_path / "stopped.rrd"
    cfg = load_config(None, ['label.labeller="region-growing"'])
    sink = RerunSink(out, False, None, cfg.rerun, False)
    result = run_stream(_interrupted(scans, 3), cfg, [sink], RunInfo(str(out), "mcap"), notice=lambda _t: None)
    assert result.summary.interrupted and result.summary.scans == 3
    rec = read_rrd(out)
    assert len(rec.times(L.LABELS, "Points3D:class_ids", L.SCAN_TIMELINE)) == 3
    assert rec.under(L.MAP)
    assert rrd_verify(out).returncode == 0
