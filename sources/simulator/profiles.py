"""Sensor profiles as data: beam layout, rotation rate, range limits and noise of each LiDAR.

Add a profile by adding a `SensorProfile` to `PROFILES`; everything else reads these fields.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
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

# VLP-32C: the 32 elevations in firing order, -25 to +15 degrees, dense around the horizon (Velodyne VLP-32C
# user manual, "Laser ID / vertical angle" table); lasers fire in pairs, 16 groups per 55.296 us cycle.
_VLP32C_ELEVATIONS: Final = (
    -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843,
    -7.254, 0.333, -0.333, -6.148, -5.333, 1.333, 0.667, -4.0,
    -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667,
    -3.0, 7.0, 4.667, -2.333, -2.0, 15.0, 10.333, -1.333,
)  # fmt: skip


def _uniform(fov_deg: float, beams: int) -> tuple[float, ...]:
    """Ouster's uniform beam configuration: `beams` elevations evenly over the vertical field of view
    (OS0: 90 degrees, +45 to -45; OS1: 45 degrees, +22.5 to -22.5; datasheets rev 7), top beam first as the
    sensor reports them; all beams of a column fire together."""
    return tuple(round(float(e), 4) for e in np.linspace(fov_deg / 2, -fov_deg / 2, beams))


def _ouster(model: str, beams: int) -> SensorProfile:
    os0 = model == "os0"
    return SensorProfile(
        name=f"{model}-{beams}",
        elevations_deg=_uniform(90.0 if os0 else 45.0, beams),
        azimuth_step_deg=360.0 / 1024,  # 1024 columns at 10 Hz
        rate_hz=10.0,
        min_range_m=0.5,
        max_range_m=50.0 if os0 else 120.0,
        range_noise_m=0.015 if os0 else 0.01,
        dropout=0.02,
        description=f"Ouster {model.upper()}-{beams}: {beams} beams uniform over "
        f"{'±45' if os0 else '±22.5'}°, 1024 x 10 Hz, {'50' if os0 else '120'} m",
    )


_VLP16: Final = SensorProfile(
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
)

PROFILES: Final[dict[str, SensorProfile]] = {
    "vlp16": _VLP16,
    "vlp16-20hz": replace(
        _VLP16,
        name="vlp16-20hz",
        azimuth_step_deg=0.4,
        rate_hz=20.0,
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
    "vlp32c": SensorProfile(
        name="vlp32c",
        elevations_deg=_VLP32C_ELEVATIONS,
        azimuth_step_deg=0.2,
        rate_hz=10.0,
        min_range_m=0.5,
        max_range_m=200.0,
        range_noise_m=0.015,
        dropout=0.02,
        firing_interval_s=1.152e-6,  # two lasers per 2.304 us group
        description="Velodyne VLP-32C: 32 beams −25…+15° (dense near the horizon), 0.2° at 10 Hz, ~200 m",
    ),
    **{f"{m}-{n}": _ouster(m, n) for m in ("os0", "os1") for n in (32, 64, 128)},
}


def get_profile(name: str) -> SensorProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise InputError(f"unknown sensor {name!r} (known: {', '.join(PROFILES)})") from None
