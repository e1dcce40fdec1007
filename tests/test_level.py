"""Which way is up: the world frame levelled from the first scan (pipeline.level), on simulated scans whose
true pose is known, on real scans turned by a known angle, and through the stream."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aftershock import sources
from aftershock.pipeline.config import Environment, RegisterConfig
from aftershock.pipeline.geometry import transform
from aftershock.pipeline.level import estimate_up, leveling_pose
from aftershock.pipeline.register import Registrar
from aftershock.pipeline.types import Frame, Scan

UP = np.array([0.0, 0.0, 1.0])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize(
    ("generator", "robot"),
    [
        ("office", "robot=wheeled&height=1&tilt=12"),
        ("hall", "robot=legged&height=0.5&tilt=-20"),
        ("disaster", "robot=tracked&tilt=30"),
    ],
)
def test_up_of_a_tilted_simulated_scan_is_found_within_a_degree(generator: str, robot: str) -> None:
    scan = next(iter(sources.open(f"sim://{generator}?seed=3&sensor=vlp16&scans=2&{robot}&color=0")))
    assert scan.gt_pose is not None
    true_up = scan.gt_pose[:3, :3].T @ UP  # up seen from the sensor
    found = estimate_up(scan.points)
    assert found is not None
    assert _angle_deg(found.up, true_up) < 1.0
    assert abs(found.tilt_deg - _angle_deg(true_up, UP)) < 1.0
    assert np.allclose(leveling_pose(found.up)[:3, :3] @ found.up, UP)


@pytest.mark.parametrize(
    "name",
    [
        "velodyne_vlp16_indoor.mcap",
        "ouster_os1_64_ros1.mcap",
        "ouster_os1_128_outdoor.mcap",
    ],
)
def test_a_real_scan_turned_by_a_known_angle_is_levelled_back(lidar_dir: Path, name: str) -> None:
    scan = next(iter(sources.open(lidar_dir / name)))
    points = scan.points[np.isfinite(scan.points).all(axis=1)]
    level = estimate_up(points)
    assert level is not None and level.tilt_deg < 5.0  # these sensors were mounted near level
    turn = Rotation.from_rotvec(np.radians(15.0) * np.array([0.6, 0.8, 0.0])).as_matrix()
    turned = estimate_up(points @ turn.T)
    assert turned is not None
    # real indoor scans give 30-60 flat patches: within a degree or so (README, "Which way is up")
    assert _angle_deg(turned.up, turn @ level.up) < 1.5


@pytest.mark.parametrize("tilt", [10.0, -5.0])
def test_every_pose_of_a_tilted_os1_32_is_levelled(tilt: float) -> None:
    """Another sensor and pitch (nose up too): the map's z is the true vertical at every scan, the world points
    are the scan placed by the levelled pose; with levelling off the map keeps the sensor's tilt."""
    scans = list(sources.open(f"sim://office?seed=800&sensor=os1-32&scans=3&robot=wheeled&height=1&tilt={tilt}"))

    def up_error_deg(f: Frame) -> float:  # the map's z against the true vertical, both seen from the sensor
        return _angle_deg(f.stamp_pose[:3, :3].T @ UP, f.scan.gt_pose[:3, :3].T @ UP)

    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    frames = [reg.register(Frame(s)) for s in scans]
    assert reg.tilt_deg is not None and abs(reg.tilt_deg - abs(tilt)) < 1.0
    assert all(up_error_deg(f) < 1.0 for f in frames)
    assert np.allclose(frames[0].world_points, transform(frames[0].pose, scans[0].points))
    off = Registrar(RegisterConfig(level=False), Environment.INDOOR)
    frames = [off.register(Frame(s)) for s in scans]
    assert np.allclose(frames[0].pose, np.eye(4)) and off.tilt_deg is None
    assert up_error_deg(frames[-1]) > abs(tilt) - 1.0


def test_a_single_wall_or_nothing_cannot_tell_up() -> None:
    rng = np.random.default_rng(0)
    wall = np.c_[2.0 + rng.normal(0, 0.005, 5000), rng.uniform(-3, 3, 5000), rng.uniform(-1, 2, 5000)]
    assert estimate_up(wall) is None
    assert estimate_up(np.zeros((0, 3))) is None
    assert estimate_up(np.full((200, 3), np.nan)) is None


def test_the_registrar_levels_every_pose_with_the_first_scans_turn(caplog: pytest.LogCaptureFixture) -> None:
    scans = list(sources.open("sim://office?seed=3&sensor=vlp16&scans=4&robot=wheeled&height=1&tilt=12&color=0"))
    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    with caplog.at_level("INFO"):
        frames = [reg.register(Frame(s)) for s in scans]
    assert reg.tilt_deg is not None and abs(reg.tilt_deg - 12.0) < 1.0
    assert "world levelled" in caplog.text
    ups = [(f.pose[:3, :3].T @ UP, f.scan.gt_pose[:3, :3].T @ UP) for f in frames]
    assert _angle_deg(*ups[0]) < 1.0  # the first pose carries the pitch as the true one does
    assert all(_angle_deg(*u) < 3.0 for u in ups)  # later ones add KISS-ICP's own drift (turning at 45°/s)
    flat = Registrar(RegisterConfig(), Environment.INDOOR)
    rng = np.random.default_rng(0)
    wall = np.c_[2.0 + rng.normal(0, 0.005, 5000), rng.uniform(-3, 3, 5000), rng.uniform(-1, 2, 5000)]
    with caplog.at_level("WARNING"):
        assert np.allclose(flat.register(Frame(Scan(0, wall))).pose, np.eye(4))
    assert "which way is up" in caplog.text and flat.tilt_deg is None


def test_a_tilted_mission_is_labelled_like_a_level_one() -> None:
    """On a mission whose LiDAR is pitched 12°, the levelled run scores like one without the pitch; unlevelled,
    heights are wrong and the floor is lost (the figures of README, "Which way is up", on more scans)."""
    uri = "sim://office?seed=5&sensor=vlp16&scans=10&robot=wheeled&height=1&tilt=12&color=0"
    env = {**os.environ, "CI": "true"}

    def scores(*extra: str) -> dict:
        cmd = [sys.executable, "-m", "aftershock.pipeline", "eval", uri, "--json", *extra]
        done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, check=True)
        return json.loads(done.stdout)

    # Levelling is judged on the network's labels alone: unlevelled, the structure model finds no floor and stands
    # aside, so with it on the comparison would also measure the model's fusion on the levelled run.
    network = ("--set", "structure.enabled=false")
    level, flat = scores(*network), scores(*network, "--set", "registration.level=false")
    assert abs(level["level_tilt_deg"] - 12.0) < 1.0 and flat["level_tilt_deg"] is None
    assert level["per_class_iou"]["floor"] > 0.7 > 0.2 > flat["per_class_iou"]["floor"]  # unlevelled: "wall"
    assert level["overall_accuracy"] > flat["overall_accuracy"] + 0.05
    fused = scores()  # the default run, structure model on: the floor stays found and accuracy within a point
    assert fused["per_class_iou"]["floor"] > 0.7 and fused["overall_accuracy"] > level["overall_accuracy"] - 0.01
