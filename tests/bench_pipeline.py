"""Speed and memory of the streaming pipeline (`make bench`): a simulated VLP-16 mission of 300 scans read from
MCAP like a real log, registered, labelled and clustered with the Rerun recording written to a file; and the
peak memory of a 3,000-scan mission. Prints its tables; targets: 20 scans/s or more for the whole stream on
this 2-core machine (twice the sensor rate), under 2 GB for 3,000 scans.

Wall-clock figures depend on what else the machine runs, so the CPU time of the process is printed beside
them (with the load average)."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Final

import pytest

from aftershock.pipeline.commands.evaluate import evaluate_map
from aftershock.pipeline.config import load_config
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.label import make_labeller
from aftershock.pipeline.stream import STAGES, run_stream
from aftershock.pipeline.types import RunInfo

SCANS: Final = 300
MEMORY_SCANS: Final = 3000
MISSION: Final = {"scene": "disaster", "seed": 900, "sensor": "vlp16"}
TARGET_SCANS_PER_S: Final = 20.0
MEMORY_LIMIT_GB: Final = 2.0

pytestmark = [pytest.mark.slow, pytest.mark.timeout(3600)]


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bench") / "vlp16_300.mcap"
    cmd = [sys.executable, "-m", "aftershock.pipeline", "simulate", "--out", str(out), "--scans", str(SCANS), "--quiet"]
    cmd += [f"--{k}={v}" for k, v in MISSION.items()]
    subprocess.run(cmd, check=True, env=dict(os.environ, CI="true", RERUN_ANALYTICS="0"))
    return out


def _labellers() -> list[str]:
    names = ["region-growing"]
    try:
        make_labeller("mcpnet", load_config())
        names.append("mcpnet")
    except InputError as exc:
        print(f"\n(mcpnet not benchmarked: {exc})")
    return names


def test_speed_of_the_stream_with_a_recording(mission: Path, tmp_path: Path) -> None:
    from aftershock import sources
    from aftershock.sinks.rerun_sink import RerunSink

    rows = []
    for name in _labellers():
        cfg = load_config(None, [f'label.labeller="{name}"'])
        rrd = tmp_path / f"{name}.rrd"
        sink = RerunSink(rrd, False, None, cfg.rerun, False)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        result = run_stream(sources.open(mission), cfg, [sink], RunInfo(str(mission), "mcap"), notice=print)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        s = result.summary
        assert s.scans == SCANS and rrd.stat().st_size > 0
        scores = evaluate_map(result.vmap)
        rows.append((name, s, cpu / s.scans * 1e3, wall, scores, result.trajectory, rrd.stat().st_size))
        rrd.unlink()  # hundreds of MB

    print(f"\n\nStreaming pipeline, simulated VLP-16 mission ({SCANS} scans, {MISSION}), Rerun recording to a file")
    print(f"load average while measuring: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    head = f"{'labeller':<16}" + "".join(f"{k + ' ms':>12}" for k in STAGES)
    print(head + f"{'scans/s':>10}{'CPU ms/scan':>13}{'rrd MB':>8}")
    for name, s, cpu_ms, _wall, _sc, _t, size in rows:
        line = f"{name:<16}" + "".join(f"{s.mean_timings_ms.get(k, 0.0):>12.1f}" for k in STAGES)
        print(line + f"{s.scans_per_second:>10.1f}{cpu_ms:>13.1f}{size / 1e6:>8.1f}")
    print(f"target: the whole stream at {TARGET_SCANS_PER_S:.0f} scans/s or more (ms per scan <= 50 wall)")
    print("\nScores on the voxel map (eval):")
    for name, _s, _c, _w, sc, traj, _size in rows:
        print(
            f"{name:<16} OA {sc['overall_accuracy']:.3f}  mAcc {sc['mean_accuracy']:.3f}  mIoU {sc['mean_iou']:.3f}  "
            f"NMI {sc['nmi']:.3f}  AMI {sc['ami']:.3f}  ARI {sc['ari']:.3f}  P {sc['precision']:.3f}  "
            f"R {sc['recall']:.3f}  ATE {traj.ate_rmse_m if traj else float('nan'):.3f} m"
        )


_MEMORY_RUN: Final = textwrap.dedent(
    """
    import json, resource, sys, time
    from aftershock import sources
    from aftershock.pipeline.config import load_config
    from aftershock.pipeline.stream import run_stream
    from aftershock.pipeline.types import RunInfo
    from aftershock.sinks.rerun_sink import RerunSink

    uri, rrd, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    cfg = load_config(None, ['label.labeller="region-growing"'])
    t = time.perf_counter()
    result = run_stream(sources.open(uri), cfg, [RerunSink(rrd, False, None, cfg.rerun, False)], RunInfo(uri, "sim"))
    print(json.dumps({
        "scans": result.summary.scans,
        "map_voxels": result.summary.map_voxels,
        "map_mb": result.vmap.nbytes / 1e6,
        "wall_s": time.perf_counter() - t,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }))
    """
)


def test_peak_memory_of_a_long_mission(tmp_path: Path) -> None:
    uri = f"sim://{MISSION['scene']}?seed={MISSION['seed'] + 1}&sensor={MISSION['sensor']}&scans={MEMORY_SCANS}"
    rrd = tmp_path / "long.rrd"
    env = dict(os.environ, CI="true", RERUN_ANALYTICS="0")
    proc = subprocess.run(
        [sys.executable, "-c", _MEMORY_RUN, uri, str(rrd), str(MEMORY_SCANS)],
        capture_output=True,
        text=True,
        env=env,
        timeout=3600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    size_mb = rrd.stat().st_size / 1e6
    rrd.unlink()  # gigabytes
    print(f"\n\nPeak memory, {MEMORY_SCANS}-scan simulated VLP-16 mission ({uri}), region-growing, Rerun to a file")
    print(
        f"scans {got['scans']}, map voxels {got['map_voxels']}, voxel map {got['map_mb']:.1f} MB, "
        f"peak RSS {got['peak_rss_mb']:.0f} MB (limit {MEMORY_LIMIT_GB * 1024:.0f} MB), "
        f"recording {size_mb:.0f} MB, {got['wall_s']:.0f} s"
    )
    assert got["scans"] == MEMORY_SCANS
    assert got["peak_rss_mb"] < MEMORY_LIMIT_GB * 1024
    assert resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss > 0
