"""Throughput of `aftershock batch` (`make bench-batch`): 8 simulated 300-scan VLP-16 missions (`sim://`,
disaster scenes, seeds 900–907; the simulation runs inside each mission's task, as reading a log would) with
the default labeller (MCPNet) and a Rerun recording per mission, on a local Ray instance with 1 worker and
then with 2. Prints both throughputs (scans/s over all missions) and their ratio; target ≥ 1.7x on this
2-core machine.

Two clocks: the whole command (Ray's start-up included, as a user waits for it) and the missions' own span
(`wall_time_s`: from Ray ready to the last mission done). The machine is shared, so the load average
before and after each run is printed beside the figures, with the missions running at once and the cores
they actually got (their CPU time over the span); 1 worker runs first."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Final

import pytest
from common import CHILD_ENV

MISSIONS: Final = 8
SCANS: Final = 300
TARGET_RATIO: Final = 1.7

pytestmark = pytest.mark.timeout(7200)


def _run(out: Path, workers: int) -> dict:
    sources = [f"sim://disaster?seed={900 + k}&sensor=vlp16&scans={SCANS}" for k in range(MISSIONS)]
    cmd = [sys.executable, "-m", "aftershock.pipeline", "batch", *sources, "--out", str(out)]
    cmd += ["--workers", str(workers), "--json", "--quiet"]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, **CHILD_ENV))
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    rows = report["missions"]
    assert len(rows) == MISSIONS and all(r["status"] == "ok" and r["scans"] == SCANS for r in rows)
    scans = sum(r["scans"] for r in rows)
    result = {
        "workers": workers,
        "command_s": wall,
        "missions_s": report["wall_time_s"],
        "scans_per_s_command": scans / wall,
        "scans_per_s_missions": scans / report["wall_time_s"],
        "mission_scans_per_s": sorted(r["scans_per_second"] for r in rows),
        "peak_rss_mb": max(r["peak_rss_mb"] for r in rows),
        # Missions running at once (their task time over the span) and cores they actually got (CPU time over
        # the span): on a shared machine the second is what the throughput can follow.
        "overlap": sum(r["processing_s"] for r in rows) / report["wall_time_s"],
        "cores_used": sum(r["cpu_s"] for r in rows) / report["wall_time_s"],
        "cpu_ms_per_scan": 1e3 * sum(r["cpu_s"] for r in rows) / scans,
        "load_before": load_before,
        "load_after": os.getloadavg(),
    }
    shutil.rmtree(out)  # 8 recordings of ~0.5 GB each
    return result


def test_two_workers_against_one(tmp_path: Path) -> None:
    one = _run(tmp_path / "one", 1)
    two = _run(tmp_path / "two", 2)
    what = f"{MISSIONS} simulated missions x {SCANS} scans (VLP-16, MCPNet, Rerun recording each)"
    print(f"\n{what}, cores: {os.cpu_count()}")
    print("workers | command s | scans/s (command) | missions s | scans/s (missions) | per-mission scans/s", end="")
    print(" | missions at once | cores used | peak RSS MB | load before -> after")
    for r in (one, two):
        per = r["mission_scans_per_s"]
        print(
            f"{r['workers']} | {r['command_s']:.1f} | {r['scans_per_s_command']:.2f} | {r['missions_s']:.1f} | "
            f"{r['scans_per_s_missions']:.2f} | {per[0]:.1f}–{per[-1]:.1f} | {r['overlap']:.2f} | "
            f"{r['cores_used']:.2f} | {r['peak_rss_mb']:.0f} | "
            f"{' '.join(f'{v:.1f}' for v in r['load_before'])} -> {' '.join(f'{v:.1f}' for v in r['load_after'])}"
        )
    ratio_missions = two["scans_per_s_missions"] / one["scans_per_s_missions"]
    ratio_command = two["scans_per_s_command"] / one["scans_per_s_command"]
    print(f"2 workers / 1 worker: {ratio_missions:.2f}x (missions), {ratio_command:.2f}x (whole command)", end="")
    print(f"; target {TARGET_RATIO}x")
    # What the cores the machine gave explain: the CPU a scan costs with 2 workers against 1 (1.0 = running two
    # missions side by side costs nothing extra, so with two free cores the throughput would double).
    cost = two["cpu_ms_per_scan"] / one["cpu_ms_per_scan"]
    print(f"CPU per scan: {one['cpu_ms_per_scan']:.0f} ms (1 worker), ", end="")
    print(f"{two['cpu_ms_per_scan']:.0f} ms (2 workers)", end="")
    print(f", {cost:.2f}x; cores used {one['cores_used']:.2f} -> {two['cores_used']:.2f}")
    # The ratio is the figure (it follows the cores the machine gives, printed beside it); what must hold
    # whatever the load is that two workers really run two missions at a time, and one worker one.
    assert two["overlap"] >= 1.7 and one["overlap"] <= 1.05
