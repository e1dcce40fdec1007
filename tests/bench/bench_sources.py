"""Source benchmarks (slow; `make bench`): decode throughput of each real log, and the peak memory of
`aftershock info` on the largest one and on a long log made from it (streaming: memory must not grow)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from aftershock import sources

LOGS = ("velodyne_vlp16_indoor.mcap", "ouster_os1_128_outdoor.mcap", "ouster_os1_64_ros1.mcap", "room_scan*.pcd")
REPEATS = 5


def throughput(path: str) -> tuple[int, int, float]:
    """(scans, points, best seconds) for reading every scan, best of REPEATS."""
    best = float("inf")
    scans = points = 0
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        scans = points = 0
        for scan in sources.open(path):
            scans += 1
            points += len(scan)
        best = min(best, time.perf_counter() - t0)
    return scans, points, best


def peak_rss_mb(*args: str) -> float:
    """Peak resident memory of a child process (MB), from its own getrusage at exit."""
    code = (
        "import resource, sys\n"
        "from aftershock.pipeline.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, file=sys.stderr)\n"
        "sys.exit(rc)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return float(r.stderr.strip().splitlines()[-1])


def long_log(src: Path, dst: Path, repeats: int) -> int:
    """`src`'s messages logged again and again, one after the other: a long log of the same sensor."""
    with src.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        msgs = [(ch, m) for _, ch, m in reader.iter_messages()]
    assert summary is not None
    span = msgs[-1][1].log_time - msgs[0][1].log_time + 100_000_000
    with dst.open("wb") as out:
        w = McapWriter(out, compression=CompressionType.NONE)
        w.start(profile="ros2", library="bench")
        ids = {}
        for sid, schema in summary.schemas.items():
            ids[sid] = w.register_schema(schema.name, schema.encoding, schema.data)
        chans = {
            cid: w.register_channel(c.topic, c.message_encoding, ids[c.schema_id])
            for cid, c in summary.channels.items()
        }
        for k in range(repeats):
            for ch, m in msgs:
                t = m.log_time + k * span
                w.add_message(chans[ch.id], log_time=t, data=m.data, publish_time=t)
        w.finish()
    return repeats * len(msgs)


def test_decode_throughput(lidar_dir: Path) -> None:
    print("\nlog                               scans   points/scan   scans/s     Mpoints/s")
    for name in LOGS:
        scans, points, seconds = throughput(str(lidar_dir / name))
        print(f"{name:<32} {scans:>5} {points / scans:>13,.0f} {scans / seconds:>9.1f} {points / seconds / 1e6:>11.2f}")
        assert scans > 0


def test_info_peak_memory(lidar_dir: Path, tmp_path: Path) -> None:
    largest = lidar_dir / "ouster_os1_128_outdoor.mcap"
    baseline = peak_rss_mb("--help")
    small = peak_rss_mb("info", str(largest), "--json")
    n = long_log(largest, tmp_path / "long.mcap", 40)
    size_mb = (tmp_path / "long.mcap").stat().st_size / 1e6
    t0 = time.perf_counter()
    big = peak_rss_mb("info", str(tmp_path / "long.mcap"), "--json")
    seconds = time.perf_counter() - t0
    print(f"\npeak RSS: CLI start-up {baseline:.0f} MB; info on {largest.name} {small:.0f} MB;")
    print(f"info on a {n}-scan OS1-128 log ({size_mb:.0f} MB) {big:.0f} MB in {seconds:.1f} s")
    assert big < small + 100  # streaming: a 13x longer log must not need 13x the memory
