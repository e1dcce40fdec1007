"""Registration stage: our deskew equals KISS-ICP's own, poses follow a known motion, bad scans are flagged
and the stream goes on; real logs register."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from kiss_icp.preprocess import Preprocessor
from scipy.spatial.transform import Rotation

from aftershock import sources
from aftershock.pipeline.config import Environment, RegisterConfig
from aftershock.pipeline.geometry import se3_exp, se3_exp_apply, se3_log, transform
from aftershock.pipeline.register import Registrar, deskew, guess_environment, register_stage
from aftershock.pipeline.trajectory import trajectory_error
from aftershock.pipeline.types import Frame, Scan


def _pose(rotvec: list[float], t: list[float]) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    out[:3, 3] = t
    return out


def test_se3_log_exp_round_trip() -> None:
    for rv, t in (([0.1, -0.2, 0.3], [1.0, 2.0, -0.5]), ([0, 0, 0], [0.3, 0, 0]), ([0, 0, 3.0], [0, 1, 0])):
        p = _pose(rv, t)
        assert np.allclose(se3_exp(se3_log(p)), p)


def test_deskew_matches_kiss_icp() -> None:
    rng = np.random.default_rng(0)
    delta = _pose([0.02, -0.01, 0.2], [0.6, 0.05, -0.02])
    pts = rng.uniform(-20, 20, (2000, 3))
    times = rng.uniform(-0.05, 0.05, 2000)
    theirs = Preprocessor(1e9, 0.0, True, 1).preprocess(pts, times, delta)
    # Ours evaluates the motion at 1,001 instants of the sweep: a turn of 11° within the sweep moves a point
    # 35 m away by at most 35 m x 0.2 rad / 2000 = 3.5 mm.
    assert np.abs(deskew(pts, times, delta) - theirs).max() < 5e-3
    assert np.abs(se3_exp_apply(se3_log(delta), (times - times.min()) / np.ptp(times) - 1, pts) - theirs).max() < 1e-9
    assert deskew(pts, np.zeros(2000), delta) is pts  # no spread in time: nothing to undo


def _scene(rng: np.random.Generator) -> np.ndarray:
    """A 20 x 12 x 3 m hall with a few boxes: planes with structure in every direction."""
    n = 60_000
    u = rng.uniform(0, 1, (n, 2))
    faces = rng.integers(0, 6, n)
    size = np.array([20.0, 12.0, 3.0])
    pts = np.zeros((n, 3))
    for f in range(6):
        m = faces == f
        axis, side = f // 2, f % 2
        others = [a for a in range(3) if a != axis]
        pts[m, axis] = side * size[axis]
        pts[m, others[0]] = u[m, 0] * size[others[0]]
        pts[m, others[1]] = u[m, 1] * size[others[1]]
    boxes = [rng.uniform([2, 2, 0], [18, 10, 0]) + rng.uniform(0, 1, (3000, 3)) * [1, 1, 1.5] for _ in range(6)]
    return np.vstack([pts, *boxes]) - [2.0, 6.0, 1.0]


def _scan(world: np.ndarray, pose: np.ndarray, seq: int, rng: np.random.Generator) -> Scan:
    local = transform(np.linalg.inv(pose), world)
    near = np.linalg.norm(local, axis=1) < 25
    local = local[near] + rng.normal(0, 0.01, (near.sum(), 3))
    return Scan(stamp_ns=seq * 100_000_000, points=local, seq=seq, gt_pose=pose)


def test_registration_follows_a_known_motion_and_flags_a_bad_scan() -> None:
    rng = np.random.default_rng(1)
    world = _scene(rng)
    world = world[::3]
    truth = [_pose([0, 0, 0.01 * k], [0.15 * k, 0.02 * k, 0]) for k in range(16)]
    scans = [_scan(world, p, k, rng) for k, p in enumerate(truth)]
    scans[12] = Scan(stamp_ns=scans[12].stamp_ns, points=scans[12].points[:40], seq=12, gt_pose=truth[12])
    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    frames = list(register_stage((Frame(s) for s in scans), reg))
    assert [f.seq for f in frames if not f.registration_ok] == [12]
    assert "only 40 points" in frames[12].registration_note
    assert np.allclose(frames[0].pose, reg.level)  # KISS-ICP starts at identity; the levelling turn is applied
    est = np.array([f.stamp_pose for f in frames])
    err = trajectory_error(est, np.array(truth))
    assert err.ate_rmse_m < 0.05, err
    # World points are the scan placed by the estimated pose.
    f = frames[15]
    assert np.allclose(f.world_points, transform(f.pose, f.scan.points))
    assert all(f.timings_ms["register"] > 0 for f in frames)


def _swept_scan(world: np.ndarray, k: int, speed: float, sweep_s: float = 0.1, every_s: float = 0.1) -> Scan:
    """Scan k (one every `every_s`) of a sensor moving along x at `speed`: each point is seen from where the
    sensor was when the rotating beam passed its azimuth; the stamp is the start of the sweep."""
    start = np.array([speed * every_s * k, 0.0, 0.0])
    rel = world - start
    near = np.linalg.norm(rel, axis=1) < 25
    rel, pts = rel[near], world[near]
    times = (np.arctan2(rel[:, 1], rel[:, 0]) + np.pi) / (2 * np.pi) * sweep_s
    local = pts - (start + np.outer(times, [speed, 0.0, 0.0]))
    return Scan(stamp_ns=int(k * every_s * 1e9), points=local, seq=k, times=times, gt_pose=_pose([0, 0, 0], start))


def test_deskew_with_the_true_motion_undoes_the_sweep() -> None:
    world = _scene(np.random.default_rng(2))[::4]
    scan = _swept_scan(world, 3, speed=2.0)
    end = scan.gt_pose[:3, 3] + [0.2, 0.0, 0.0]
    seen = world[np.linalg.norm(world - scan.gt_pose[:3, 3], axis=1) < 25]
    assert np.abs(scan.points - (seen - end)).max() > 0.15  # the sweep smears the scan by up to 0.2 m
    fixed = deskew(scan.points, scan.times, _pose([0, 0, 0], [0.2, 0, 0]))
    assert np.abs(fixed - (seen - end)).max() < 1e-3


def test_deskewed_stamp_poses_follow_the_motion() -> None:
    world = _scene(np.random.default_rng(2))[::2]
    speed = 1.0  # m/s: 0.1 m of motion within every 0.1 s sweep
    scans = [_swept_scan(world, k, speed) for k in range(12)]
    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    frames = [reg.register(Frame(s)) for s in scans]
    # The stamp (start of sweep) lies one sweep's motion behind the end-of-sweep pose.
    step = np.linalg.inv(frames[-1].stamp_pose) @ frames[-1].pose
    assert step[0, 3] == pytest.approx(speed * 0.1, abs=0.02)
    # KISS-ICP cannot deskew its first scans (no motion known yet) and keeps them in its map, hence cm.
    est = np.array([f.stamp_pose for f in frames])
    assert trajectory_error(est, np.array([s.gt_pose for s in scans])).ate_rmse_m < 0.04


def test_sweeps_shorter_than_the_time_between_scans_are_deskewed_by_their_share_of_the_motion() -> None:
    world = _scene(np.random.default_rng(3))[::2]
    scans = [_swept_scan(world, k, speed=1.0, every_s=0.3) for k in range(10)]  # a scan kept every 0.3 m
    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    frames = [reg.register(Frame(s)) for s in scans]
    step = np.linalg.inv(frames[-1].stamp_pose) @ frames[-1].pose
    assert step[0, 3] == pytest.approx(0.1, abs=0.02)  # one 0.1 s sweep at 1 m/s, not the 0.3 m between scans
    est = np.array([f.stamp_pose for f in frames])
    assert trajectory_error(est, np.array([s.gt_pose for s in scans])).ate_rmse_m < 0.04


def test_environment_guess() -> None:
    near = Scan(0, np.random.default_rng(0).uniform(-5, 5, (1000, 3)))
    far = Scan(0, np.random.default_rng(0).uniform(-60, 60, (1000, 3)))
    assert guess_environment(near) is Environment.INDOOR
    assert guess_environment(far) is Environment.OUTDOOR


def test_real_logs_register(lidar_dir: Path) -> None:
    scans = list(sources.open(lidar_dir / "ouster_os1_128_outdoor.mcap"))
    assert guess_environment(scans[0]) is Environment.OUTDOOR
    reg = Registrar(RegisterConfig(), Environment.OUTDOOR)
    frames = [reg.register(Frame(s)) for s in scans]
    assert all(f.registration_ok for f in frames)
    moved = np.linalg.norm(frames[-1].pose[:3, 3])
    assert 0.3 < moved < 0.9  # the sensor moves about half a metre over the three sweeps
    scans = list(sources.open(lidar_dir / "velodyne_vlp16_indoor.mcap"))
    assert guess_environment(scans[0]) is Environment.INDOOR
    reg = Registrar(RegisterConfig(), Environment.INDOOR)
    frames = [reg.register(Frame(s)) for s in scans]
    assert all(f.registration_ok and np.isfinite(f.world_points).all() for f in frames)
    assert len(frames[1].world_points) == len(scans[1])
