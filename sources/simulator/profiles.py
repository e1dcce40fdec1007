"""Sensor profiles as data: beam layout, rotation rate, range limits and noise of each LiDAR.

Add a profile by adding a `SensorProfile` to `PROFILES`; everything else reads these fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Final

import numpy as np

from aftershock.pipeline.errors import InputError


class Spin(StrEnum):
    """Direction the head turns, seen from above (Velodyne heads turn clockwise)."""

    CLOCKWISE = "clockwise"
    COUNTER_CLOCKWISE = "counter_clockwise"


@dataclass(frozen=True, slots=True)
class SensorProfile:
    name: str
    elevations_deg: tuple[float, ...]  # in firing order; the ring of a beam is its rank by elevation
    azimuth_step_deg: float
    rate_hz: float  # sweeps per second
    min_range_m: float
    max_range_m: float
    range_noise_m: float  # standard deviation of the range error
    dropout: float  # probability that a return is lost
    firing_interval_s: float = 0.0  # time between two beams of one column
    spin: Spin = Spin.CLOCKWISE
    spacing_m: float | None = None  # scan every this many metres of travel instead of at `rate_hz`
    description: str = ""

    @property
    def columns(self) -> int:
        return round(360.0 / self.azimuth_step_deg)

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    @property
    def rays(self) -> int:
        return self.columns * self.beams

    @property
    def sweep_s(self) -> float:
        return 1.0 / self.rate_hz

    def rings(self) -> np.ndarray:
        """Ring number (0 = lowest beam) of each beam in firing order."""
        order = np.argsort(np.asarray(self.elevations_deg), kind="stable")
        ring = np.empty(self.beams, np.uint16)
        ring[order] = np.arange(self.beams)
        return ring

    def directions(self) -> np.ndarray:
        """Unit ray directions (columns, beams, 3) in the sensor frame (x forward, z up), in firing order."""
        sign = -1.0 if self.spin is Spin.CLOCKWISE else 1.0
        az = sign * np.deg2rad(np.arange(self.columns) * self.azimuth_step_deg)
        el = np.deg2rad(np.asarray(self.elevations_deg))
        ca, sa = np.cos(az)[:, None], np.sin(az)[:, None]
        ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
        return np.stack(np.broadcast_arrays(ca * ce, sa * ce, np.broadcast_to(se, (len(az), len(el)))), axis=-1)

    def times(self) -> np.ndarray:
        """Time (columns, beams) of each ray after the start of the sweep, in seconds."""
        col = np.arange(self.columns)[:, None] * (self.sweep_s / self.columns)
        return col + np.arange(self.beams)[None, :] * self.firing_interval_s


# VLP-16: beams fired alternately from the bottom and the top half, 2.304 us apart (Velodyne manual).
_VLP16_ELEVATIONS: Final = (
    -15.0,
    1.0,
    -13.0,
    3.0,
    -11.0,
    5.0,
    -9.0,
    7.0,
    -7.0,
    9.0,
    -5.0,
    11.0,
    -3.0,
    13.0,
    -1.0,
    15.0,
)

PROFILES: Final[dict[str, SensorProfile]] = {
    "vlp16": SensorProfile(
        name="vlp16",
        elevations_deg=_VLP16_ELEVATIONS,
        azimuth_step_deg=0.2,
        rate_hz=10.0,
        min_range_m=0.4,
        max_range_m=100.0,
        range_noise_m=0.015,
        dropout=0.02,
        firing_interval_s=2.304e-6,
        description="Velodyne VLP-16: 16 beams over ±15°, 0.2° azimuth at 10 Hz, ~100 m, ±3 cm",
    ),
    "vlp16-20hz": SensorProfile(
        name="vlp16-20hz",
        elevations_deg=_VLP16_ELEVATIONS,
        azimuth_step_deg=0.4,
        rate_hz=20.0,
        min_range_m=0.4,
        max_range_m=100.0,
        range_noise_m=0.015,
        dropout=0.02,
        firing_interval_s=2.304e-6,
        description="Velodyne VLP-16 in its 20 Hz mode: 0.4° azimuth, half the points of a sweep",
    ),
    "dense": SensorProfile(
        name="dense",
        elevations_deg=tuple(float(e) for e in range(-45, 81)),
        azimuth_step_deg=1.0,
        rate_hz=10.0,
        min_range_m=0.1,
        max_range_m=5.0,
        range_noise_m=0.0,
        dropout=0.0,
        spin=Spin.COUNTER_CLOCKWISE,
        spacing_m=0.2,
        description="research scanner of the original study: 360° x 1°, elevation −45° to 80°, 5 m, "
        "a scan every 0.2 m, no noise",
    ),
}


def get_profile(name: str) -> SensorProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise InputError(f"unknown sensor profile {name!r} (known: {', '.join(PROFILES)})") from None
