"""Robots as data: how high and how tilted the LiDAR sits, how fast the robot drives and turns, how it sways.

`legged` is today's default (a quadruped at 0.9 m, walking at 1 m/s, swaying with its gait); `wheeled` and
`tracked` ride low and steady. `randomized(name, rng)` draws a robot of that kind with the mount height
(0.3-1.8 m), tilt, speed, turn rate and sway a field team may bring, for training that must transfer.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Final

import numpy as np

from aftershock.pipeline.errors import InputError


@dataclass(frozen=True, slots=True)
class RobotSpec:
    name: str
    kind: str  # legged | wheeled | tracked
    mount_height_m: float  # LiDAR above the floor
    tilt_deg: float  # LiDAR pitched about its y axis, positive looks down ahead
    speed_mps: float
    turn_rate_deg_s: float  # fastest turn; the robot slows down (or turns on the spot) where the path bends
    sway_deg: float  # roll amplitude of the body at the gait frequency (pitch is 0.6 of it at twice that)
    bob_m: float  # vertical bob amplitude at twice the gait frequency
    gait_hz: float
    description: str = ""

    @property
    def turn_rate_rad_s(self) -> float:
        return float(np.deg2rad(self.turn_rate_deg_s))


ROBOTS: Final[dict[str, RobotSpec]] = {
    # 0.8 rad/s is the turn rate the simulator always had; 0.6 deg at 1.8 Hz the sway of a trotting quadruped.
    "legged": RobotSpec(
        "legged", "legged", 0.9, 0.0, 1.0, float(np.rad2deg(0.8)), 0.6, 0.01, 1.8, "quadruped, LiDAR on its back"
    ),
    "wheeled": RobotSpec(
        "wheeled", "wheeled", 0.5, 0.0, 1.0, 45.0, 0.05, 0.002, 6.0, "four-wheeled ground robot, LiDAR on a mast"
    ),
    "tracked": RobotSpec(
        "tracked", "tracked", 0.45, 0.0, 0.5, 30.0, 0.3, 0.004, 3.0, "tracked rescue robot rocking over rubble"
    ),
}
DEFAULT_ROBOT: Final = "legged"

MOUNT_HEIGHT_RANGE_M: Final = (0.3, 1.8)
TILT_RANGE_DEG: Final = (-5.0, 15.0)


def get_robot(name: str) -> RobotSpec:
    try:
        return ROBOTS[name]
    except KeyError:
        raise InputError(f"unknown robot {name!r} (known: {', '.join(ROBOTS)})") from None


def randomized(name: str, rng: np.random.Generator) -> RobotSpec:
    """A robot of the kind `name` with its mount, speed, turn rate and sway drawn from what the field uses."""
    base = get_robot(name)
    legged = base.kind == "legged"
    return replace(
        base,
        mount_height_m=round(float(rng.uniform(*MOUNT_HEIGHT_RANGE_M)), 3),
        tilt_deg=round(float(rng.uniform(*TILT_RANGE_DEG)), 2),
        speed_mps=round(float(rng.uniform(0.5, 1.4) if legged else rng.uniform(0.3, 1.5)), 3),
        turn_rate_deg_s=round(float(rng.uniform(20.0, 90.0)), 1),
        sway_deg=round(float(rng.uniform(0.3, 2.5) if legged else rng.uniform(0.0, 0.5)), 3),
        bob_m=round(float(rng.uniform(0.005, 0.03) if legged else rng.uniform(0.0, 0.006)), 4),
        gait_hz=round(float(rng.uniform(1.4, 2.6) if legged else rng.uniform(2.0, 8.0)), 2),
    )
