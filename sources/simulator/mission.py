"""A simulated mission: a robot walks a tour through a building and its LiDAR sweeps while it moves.

Every ray of a sweep leaves the sensor at its own time, from the pose the sensor has at that time, so a
scan is distorted by the motion exactly as a real one is (deskewing matters). Points are reported in the
sensor frame at the moment each was measured; the scan's `gt_pose` is the true pose at the sweep start.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Final

import numpy as np

from aftershock.pipeline.classes import UNLABELLED
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.types import Scan
from aftershock.sources.simulator.conditions import Conditions, apply_optics, dark_losses, mix_edges
from aftershock.sources.simulator.profiles import SensorProfile
from aftershock.sources.simulator.robots import RobotSpec
from aftershock.sources.simulator.scene import Scene
from aftershock.sources.simulator.trajectory import WALK_SPEED_MPS, Trajectory, plan_tour

START_NS: Final = 1_700_000_000_000_000_000  # a fixed epoch, so the same seed gives the same stamps
DEFAULT_SCANS: Final = 100
LIDAR_FRAME: Final = "lidar"
POINTS_TOPIC: Final = "/lidar/points"
QUANTUM_INV: Final = 512.0  # 2 mm: the VLP-16 packet range resolution


_SWEEP_BYTES = 4 * 8  # float64 arrays per sweep while its start times are computed (k, trigger, starts)


class Mission:
    """Scans of `profile` along a tour of one story of `scene`; iterate to get them.

    Sweeps follow each other at the sensor rate, or (with a spacing, from the argument or the profile)
    start whenever the robot has walked `spacing_m` further or turned as much (`TURN_M_PER_RAD`); a
    sweep never starts before the previous one ended. `scans` (default `DEFAULT_SCANS`) or `duration_s`
    sets how many there are; `scan(k)` gives any sweep, also beyond that count. `robot` sets the mount,
    turn rate and sway (default: the legged robot), `conditions` the sensor's imperfections beyond its
    profile (conditions.py), `color=False` a LiDAR without a camera (scans carry no colours).
    """

    def __init__(
        self,
        scene: Scene,
        profile: SensorProfile,
        *,
        seed: int = 0,
        scans: int | None = None,
        duration_s: float | None = None,
        story: int = 0,
        speed: float = WALK_SPEED_MPS,
        spacing_m: float | None = None,
        start_ns: int = START_NS,
        robot: RobotSpec | None = None,
        conditions: Conditions | None = None,
        color: bool = True,
    ) -> None:
        if not 0 <= story < scene.num_stories:
            raise ValueError(f"story {story} is not in this building (0..{scene.num_stories - 1})")
        if scans is not None and scans < 0:
            raise ValueError("the number of scans cannot be negative")
        self.scene, self.profile, self.seed, self.story = scene, profile, int(seed), story
        self.spacing_m = spacing_m or profile.spacing_m
        self.start_ns = int(start_ns)
        self.robot, self.color = robot, bool(color)
        self.conditions = conditions if conditions is not None and conditions != Conditions() else None
        self.trajectory: Trajectory = plan_tour(scene, story, self.seed, speed, robot)
        self._starts = np.zeros(0)
        if scans is None:
            scans = DEFAULT_SCANS if duration_s is None else self.count_before(duration_s, "sim:// duration")
        self.num_scans = int(scans)
        self._dirs = profile.directions()  # (C, B, 3)
        self._times = profile.times()  # (C, B)
        self._ring = np.broadcast_to(profile.rings()[None, :], self._times.shape)

    def __len__(self) -> int:
        return self.num_scans

    def sweep_starts(self, n: int) -> np.ndarray:
        """Start times (s from the mission start) of the first n sweeps."""
        if len(self._starts) < n:
            k = np.arange(max(n, 2 * len(self._starts)))
            sweep = self.profile.sweep_s
            if self.spacing_m:
                trigger = self.trajectory.time_at_progress(k * self.spacing_m)
                # s_k = max(trigger_k, s_k-1 + sweep), in closed form: a running maximum
                self._starts = np.maximum.accumulate(trigger - k * sweep) + k * sweep
            else:
                self._starts = k / self.profile.rate_hz
        return self._starts[:n]

    def sweep_start_s(self, k: int) -> float:
        return float(self.sweep_starts(k + 1)[k])

    def count_before(self, t: float, setting: str = "the mission's time") -> int:
        """How many sweeps start before time t; InputError naming `setting` when the sweep times up to t would
        not fit in memory (`duration=1e15` is refused, not allocated)."""
        from aftershock.pipeline.limits import check_allocation

        if not np.isfinite(t):
            raise InputError(f"{setting}: {t} is not a time")
        # a sweep never starts before the previous one ended: at most t / sweep_s + 1 sweeps start before t
        most = t / self.profile.sweep_s + 1
        check_allocation(2 * most * _SWEEP_BYTES, setting, f"{t:g} s of sweeps ({most:.3g} sweep times)")
        n = 64
        while self.sweep_starts(n)[-1] < t:
            n *= 2
        return int(np.searchsorted(self.sweep_starts(n), t, side="left"))

    def first_at_or_after(self, t: float, setting: str = "--start") -> int:
        return self.count_before(t - 1e-9, setting) if t > 0 else 0

    def __iter__(self) -> Iterator[Scan]:
        for k in range(self.num_scans):
            yield self.scan(k)

    def scan(self, k: int) -> Scan:
        """Sweep number k (deterministic: its random stream depends only on scene, seed and k)."""
        prof = self.profile
        rng = np.random.default_rng([self.scene.seed, self.seed, k, 3])
        t0 = self.sweep_start_s(k)
        col_t = self._times[:, 0]
        poses = self.trajectory.poses(t0 + col_t)  # (C, 4, 4) pose of each column
        world_dirs = np.matmul(self._dirs, poses[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
        origins = np.repeat(poses[:, :3, 3], prof.beams, axis=0)
        t, tri, cos = self.scene.raycaster.cast(origins, world_dirs)
        cond, ghost, t_surface = self.conditions, None, t
        if cond is not None:  # its own random stream: the plain simulator's draws stay as they were
            erng = np.random.default_rng([self.scene.seed, self.seed, k, 5])
            t, tri, cos, ghost = apply_optics(self.scene, cond, origins, world_dirs, t, tri, cos, erng)
            t_surface = t
            t = mix_edges(t.reshape(self._times.shape), cond, erng).reshape(-1)
            t[dark_losses(self.scene, cond, t, tri, erng)] = np.inf
        dropout = prof.dropout * (1.0 if cond is None else cond.dropout_scale)
        noise = prof.range_noise_m * (1.0 if cond is None else cond.noise_scale)
        ok = (t >= prof.min_range_m) & (t <= prof.max_range_m)
        if dropout > 0:
            ok &= rng.random(len(t)) >= dropout
        idx = np.flatnonzero(ok)
        rng_m = t[idx]
        if noise > 0:
            rng_m = rng_m + rng.normal(0, noise, len(idx))
        # Coordinates on a 1/512 m grid (float32-exact, far below the range noise): what a driver's
        # fixed-point packets give, and it lets zstd find the redundancy that real logs have.
        points = np.round(self._dirs.reshape(-1, 3)[idx] * rng_m[:, None] * QUANTUM_INV) / QUANTUM_INV
        surface = origins[idx] + world_dirs[idx] * t_surface[idx, None]
        tri_hit = tri[idx]
        colors, intensity, _ = self.scene.look(tri_hit, surface, cos[idx], rng)
        class_ids = self.scene.mesh.class_ids[tri_hit].copy()
        instance_ids = self.scene.mesh.instance_ids[tri_hit].copy()
        if ghost is not None:  # a mirror's ghost is where no surface is: no class, no object
            class_ids[ghost[idx]] = UNLABELLED
            instance_ids[ghost[idx]] = 0
        intensity = np.round(intensity)  # integer reflectivity 0..255, as the VLP-16 reports it
        times_ns = np.round(self._times.reshape(-1)[idx] * 1e9)
        stamp_ns = self.start_ns + round(t0 * 1e9)
        return Scan(
            stamp_ns=stamp_ns,
            points=points,
            seq=k,
            frame_id=LIDAR_FRAME,
            intensity=intensity,
            colors=colors if self.color else None,
            times=times_ns * 1e-9,
            ring=self._ring.reshape(-1)[idx].copy(),
            class_ids=class_ids,
            instance_ids=instance_ids,
            gt_pose=self.trajectory.poses(np.array([t0]))[0],
            log_time_ns=stamp_ns + round(prof.sweep_s * 1e9),
            topic=POINTS_TOPIC,
        )
