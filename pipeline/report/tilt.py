"""How well a slab's plane is known, measured from the slab's own points: its inliers (within the plane fit's
threshold) are split at their median x and y into four quadrants, a plane is fitted to each, and the spread of
the quadrant normals about the whole slab's normal gives the standard error of that normal (independent
subsets: point noise, a warped or sagging slab and the part of it the scan happened to see all show in it).

A storey's tilt is the angle between its floor and ceiling slab planes, so its uncertainty combines both planes'
(the floor of the lowest storey is also the level drift is measured against, with `ground-plane`); it is stated
as an expanded uncertainty (coverage factor `COVERAGE`, about 95 %), and a tilt is evidence of exceeding a
limit only when value - uncertainty > limit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from aftershock.pipeline.damage.drift import fit_plane_lsq

COVERAGE: Final = 2.0  # expanded uncertainty, k = 2 (GUM, JCGM 100:2008 section 6)
MIN_QUADRANT_POINTS: Final = 30  # a quadrant with fewer inliers gives no plane of its own


@dataclass(frozen=True)
class PlaneSpread:
    """A slab plane's normal: its standard error (degrees) or None with the reason, from how many inliers."""

    stderr_deg: float | None
    inliers: int
    reason: str | None = None


def _angle_deg(n1: np.ndarray, n2: np.ndarray) -> float:
    cos = abs(float(n1 @ n2)) / (np.linalg.norm(n1) * np.linalg.norm(n2))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def plane_spread(points: np.ndarray, plane: list[float] | np.ndarray, threshold_m: float) -> PlaneSpread:
    """The standard error of `plane`'s normal over the four quadrants of its inliers among `points`."""
    p = np.asarray(plane, np.float64)
    norm = float(np.linalg.norm(p[:3]))
    on = points[np.abs(points @ p[:3] / norm + p[3] / norm) < threshold_m]
    if len(on) < 4 * MIN_QUADRANT_POINTS:
        return PlaneSpread(None, len(on), f"{len(on)} points on the slab plane: too few to split into quadrants")
    whole = fit_plane_lsq(on)[:3]
    # quadrants in the slab's own frame, so that a slab at any heading splits into comparable quarters
    e1 = np.cross(whole, [1.0, 0.0, 0.0] if abs(whole[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(whole, e1)
    u, v = (on - on.mean(axis=0)) @ e1, (on - on.mean(axis=0)) @ e2
    side = (u > np.median(u)).astype(np.int64) * 2 + (v > np.median(v)).astype(np.int64)
    angles = []
    for q in range(4):  # four plane fits
        part = on[side == q]
        if len(part) < MIN_QUADRANT_POINTS:
            return PlaneSpread(None, len(on), f"a quadrant of the slab holds {len(part)} points: too few for a plane")
        angles.append(_angle_deg(fit_plane_lsq(part)[:3], whole))
    a = np.asarray(angles)
    return PlaneSpread(float(np.sqrt((a**2).sum() / (len(a) * (len(a) - 1)))), len(on))


def tilt_uncertainty(floor: PlaneSpread, ceiling: PlaneSpread) -> tuple[float | None, str | None]:
    """(expanded uncertainty of the angle between the two planes in degrees, None) or (None, why)."""
    missing = [f"{name}: {s.reason}" for name, s in (("floor slab", floor), ("ceiling slab", ceiling)) if s.reason]
    if missing or floor.stderr_deg is None or ceiling.stderr_deg is None:
        return None, "tilt uncertainty not measured (" + "; ".join(missing) + ")"
    return COVERAGE * float(np.hypot(floor.stderr_deg, ceiling.stderr_deg)), None
