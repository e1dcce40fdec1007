"""Sink throughput on Ouster-sized scans (about 100k points), and memory over a long recording.

pytest -m slow -s tests/bench/bench_sinks.py
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psutil
from sinks_data import VELODYNE, make_frame, map_of, read_scans

from aftershock.pipeline.config import RerunConfig
from aftershock.pipeline.sink import Sink, Stage
from aftershock.pipeline.types import Frame, RunInfo, RunSummary, Scan
from aftershock.sinks.files import FileExportSink
from aftershock.sinks.mcap_sink import McapSink
from aftershock.sinks.rerun_sink import RerunSink


def _big_frames(lidar_dir: Path, n: int, copies: int = 7) -> list[Frame]:
    """VLP-16 scans stacked `copies` times (slightly scaled) to the size of an OS1-128 scan."""
    scans = read_scans(lidar_dir / VELODYNE)
    out = []
    for i in range(n):
        s = scans[i % len(scans)]
        pts = np.concatenate([s.points * (1 + 0.01 * k) for k in range(copies)])
        big = Scan(
            stamp_ns=s.stamp_ns + i * 100_000_000,
            points=pts,
            seq=i,
            intensity=np.tile(s.intensity, copies),
            log_time_ns=(s.log_time_ns or s.stamp_ns) + i * 100_000_000,
        )
        out.append(make_frame(big))
    return out


def test_sink_throughput(lidar_dir: Path, tmp_path: Path) -> None:
    frames = _big_frames(lidar_dir, 10)
    cloud = map_of(frames)
    makers: dict[str, Callable[[], Sink]] = {
        "rerun (.rrd)": lambda: RerunSink(tmp_path / "b.rrd", False, None, RerunConfig()),
        "mcap": lambda: McapSink(tmp_path / "b.mcap"),
        "files": lambda: FileExportSink(tmp_path / "export"),
    }
    print(f"\nsinks on {len(frames)} scans of {len(frames[0].scan)} points; map of {len(cloud)} points")
    print(f"{'sink':<14}{'ms/scan':>10}{'map update ms':>16}{'end+close ms':>15}")
    for name, make in makers.items():
        sink = make()
        sink.begin(RunInfo("bench", "mcap"))
        t0 = time.perf_counter()
        for frame in frames:
            for stage in Stage:
                sink.stage(frame, stage)
        per_scan = (time.perf_counter() - t0) / len(frames) * 1e3
        t0 = time.perf_counter()
        sink.map_update(cloud, frames[-1].seq)
        map_ms = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        sink.end(RunSummary(scans=len(frames)), cloud)
        sink.close()
        end_ms = (time.perf_counter() - t0) * 1e3
        print(f"{name:<14}{per_scan:>10.1f}{map_ms:>16.0f}{end_ms:>15.0f}")


def test_recording_memory_stays_flat(lidar_dir: Path, tmp_path: Path) -> None:
    """RSS over 2000 VLP-16 scans written to an .rrd: the file streams, nothing accumulates in memory."""
    frames = [make_frame(s) for s in read_scans(lidar_dir / VELODYNE)]
    proc = psutil.Process()
    trim = ctypes.CDLL("libc.so.6").malloc_trim
    sink = RerunSink(tmp_path / "long.rrd", False, None, RerunConfig())
    sink.begin(RunInfo("bench", "mcap"))
    rss: dict[int, float] = {}
    for i in range(2000):
        f = frames[i % len(frames)]
        f.scan.seq = i
        f.scan.stamp_ns += 100_000_000
        f.scan.log_time_ns = (f.scan.log_time_ns or 0) + 100_000_000
        for stage in Stage:
            sink.stage(f, stage)
        if i in (200, 1000, 1999):
            trim(0)  # free memory the allocator kept, so RSS shows what is really held
            rss[i] = proc.memory_info().rss / 2**20
    sink.close()
    size = (tmp_path / "long.rrd").stat().st_size / 2**20
    held = " / ".join(f"{v:.0f}" for v in rss.values())
    print(f"\n.rrd of 2000 scans: {size:.0f} MiB; RSS (MiB) at scan 200/1000/1999: {held}")
    assert rss[1999] - rss[200] < 0.25 * size, "the recording is being held in memory"
