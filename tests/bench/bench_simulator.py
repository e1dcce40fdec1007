"""Simulator figures: scans per second of each sensor profile (one core), points per scan, the class
histogram of a mission, and the time of a static scan. Run with `pytest -m slow -s tests/bench/bench_simulator.py`."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import torch

from aftershock.pipeline.classes import CLASS_NAMES, NUM_CLASSES
from aftershock.sources.simulator import PROFILES, Mission, build_scene, get_profile

SCANS = 60


@pytest.mark.parametrize("family", ["disaster", "office"])
def test_scans_per_second(family: str) -> None:
    torch.set_num_threads(1)
    scene = build_scene(family, 0)
    print(
        f"\n{family} seed 0: {len(scene.mesh):,d} triangles, {len(scene.truth.instance_classes)} instances, "
        f"{scene.num_stories} stories; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"{'profile':<12} {'rays':>7} {'points/scan':>12} {'scans/s':>8} {'ms/scan':>8}")
    for name in PROFILES:
        mission = Mission(scene, get_profile(name), seed=0, scans=SCANS)
        mission.scan(0)  # warm-up: BVH and caches
        t0 = time.perf_counter()
        scans = list(mission)
        dt = time.perf_counter() - t0
        pts = np.mean([len(s) for s in scans])
        print(f"{name:<12} {mission.profile.rays:>7,d} {pts:>12,.0f} {SCANS / dt:>8.1f} {1e3 * dt / SCANS:>8.1f}")
        if name == "vlp16":
            hist = np.bincount(np.concatenate([s.class_ids for s in scans]), minlength=NUM_CLASSES)
            share = ", ".join(f"{CLASS_NAMES[i]} {100 * h / hist.sum():.1f} %" for i, h in enumerate(hist) if h)
            print(f"  vlp16 class histogram over {SCANS} scans: {share}")
        assert pts > 1000


def test_static_scan_time() -> None:
    scene = build_scene("disaster", 0)
    for spacing in (0.1, 0.05):
        t0 = time.perf_counter()
        cloud = scene.sample_static_cloud(spacing, 0)
        print(f"\nstatic scan at {spacing} m: {len(cloud):,d} points in {time.perf_counter() - t0:.1f} s")
        assert len(cloud) > 10_000
