"""Structural frames for the story drift and tilt test set, built another way than the simulator's buildings:
surfaces sampled directly (no rooms, no ray casting), in layouts the buildings do not have.

- `column-grid`: slabs on a grid of columns, no walls;
- `walls-openings`: perimeter and inner walls with windows and doors cut out, a few columns;
- `partial-collapse`: one bay of an upper slab broken off (dropped and turned about an edge), its columns gone;
- `missing-slab`: slabs with large parts missing (stair wells, collapsed areas), floor and underside alike.

Every frame has range noise of 2-5 mm along the line of sight from a station in each story, and occluders
(furniture, debris) that hide what is behind them from that station. Levels move as in the simulator's damaged
buildings (`damage.level_motions`: each slab rigidly, tilted about its centre and drifted; walls and columns
blended from their floor's motion to their ceiling's), so the truth is each level's drift and tilt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from aftershock.pipeline.errors import InputError
from aftershock.sources.simulator.damage import LevelMotion, deform, level_motions

LAYOUTS: Final = ("column-grid", "walls-openings", "partial-collapse", "missing-slab")
SLAB_T_M: Final = 0.25
WALL_T_M: Final = 0.2


@dataclass(frozen=True, slots=True)
class Frame:
    """A sampled frame: points (N, 3) in a z-up world, and each level's motion (level 0 = the ground slab)."""

    layout: str
    points: np.ndarray
    levels: list[LevelMotion]
    range_noise_m: float


def _rect(rng: np.random.Generator, origin: np.ndarray, u: np.ndarray, v: np.ndarray, spacing: float) -> np.ndarray:
    """Uniform random points on the parallelogram origin + a u + b v (a, b in 0..1) at about `spacing`."""
    area = float(np.linalg.norm(np.cross(u, v)))
    n = max(int(area / spacing**2), 1)
    ab = rng.random((n, 2))
    return origin + ab[:, :1] * u + ab[:, 1:] * v


def _box_sides(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, spacing: float) -> np.ndarray:
    """The four vertical faces of an axis-aligned box."""
    dx, dy, dz = hi - lo
    ex, ey, ez = np.eye(3)
    return np.vstack(
        [
            _rect(rng, lo, dx * ex, dz * ez, spacing),
            _rect(rng, np.array([lo[0], hi[1], lo[2]]), dx * ex, dz * ez, spacing),
            _rect(rng, lo, dy * ey, dz * ez, spacing),
            _rect(rng, np.array([hi[0], lo[1], lo[2]]), dy * ey, dz * ez, spacing),
        ]
    )


def drift_frame(layout: str, seed: int, spacing_m: float = 0.05, *, scanned: bool = True) -> Frame:
    """One frame of `layout` drawn from `seed`: 2-4 stories, a 10-22 m by 8-16 m footprint, inter-story drift
    up to 1 % of the story height and slab tilts up to 0.5°; `scanned` off: no range noise, no occluders."""
    if layout not in LAYOUTS:
        raise InputError(f"unknown frame layout {layout!r} (known: {', '.join(LAYOUTS)})")
    rng = np.random.default_rng([int(seed), sum(map(ord, layout)), 23])
    stories = int(rng.integers(2, 5))
    heights = rng.uniform(2.8, 3.6, stories).tolist()
    width, depth = float(rng.uniform(10, 22)), float(rng.uniform(8, 16))
    floor_z = np.r_[0.0, np.cumsum(np.asarray(heights) + SLAB_T_M)][:stories].tolist()
    ceiling_z = [f + h for f, h in zip(floor_z, heights, strict=True)]
    levels_z = [*floor_z, ceiling_z[-1] + SLAB_T_M]
    motions = level_motions(rng, levels_z, (width / 2, depth / 2), heights, (0.001, 0.01), (0.02, 0.5))
    nx, ny = max(round(width / rng.uniform(4, 6)), 1), max(round(depth / rng.uniform(4, 6)), 1)
    grid_x, grid_y = np.linspace(0, width, nx + 1), np.linspace(0, depth, ny + 1)
    col = float(rng.uniform(0.3, 0.6))

    # holes in the slabs: (x0, y0, x1, y1) per level, floor and underside alike
    holes: list[list[tuple[float, float, float, float]]] = [[] for _ in levels_z]
    if layout == "missing-slab":
        for j in range(1, len(levels_z)):
            for _ in range(int(rng.integers(1, 3))):
                w, d = width * rng.uniform(0.2, 0.45), depth * rng.uniform(0.2, 0.5)
                x0, y0 = rng.uniform(0, width - w), rng.uniform(0, depth - d)
                holes[j].append((x0, y0, x0 + w, y0 + d))
    collapse = None
    if layout == "partial-collapse":
        j = int(rng.integers(1, len(levels_z) - 1)) if len(levels_z) > 2 else 1
        i, k = int(rng.integers(nx)), int(rng.integers(ny))
        collapse = (j, (grid_x[i], grid_y[k], grid_x[i + 1], grid_y[k + 1]))
        holes[j].append(collapse[1])

    pts_l, lvl_l, span_l = [], [], []

    def add(p: np.ndarray, level: int, span: bool) -> None:
        pts_l.append(p)
        lvl_l.append(np.full(len(p), level))
        span_l.append(np.full(len(p), span))

    ex, ey = np.array([width, 0.0, 0.0]), np.array([0.0, depth, 0.0])
    for j, z in enumerate(levels_z):
        faces = []
        if j < len(levels_z) - 1:
            faces.append(_rect(rng, np.array([0.0, 0.0, z]), ex, ey, spacing_m))  # floor, seen from above
        if j > 0:
            faces.append(_rect(rng, np.array([0.0, 0.0, z - SLAB_T_M]), ex, ey, spacing_m))  # underside
        p = np.vstack(faces)
        keep = np.ones(len(p), bool)
        for x0, y0, x1, y1 in holes[j]:
            keep &= ~((p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1))
        add(p[keep], j, False)

    for s in range(stories):
        z0, z1 = floor_z[s], ceiling_z[s]
        gone = collapse is not None and s == collapse[0] - 1
        if layout != "walls-openings" or rng.random() < 0.5:
            for x in grid_x:
                for y in grid_y:
                    if gone and collapse[1][0] <= x <= collapse[1][2] and collapse[1][1] <= y <= collapse[1][3]:
                        continue  # the columns under the collapsed bay failed
                    lo = np.array([x - col / 2, y - col / 2, z0])
                    add(_box_sides(rng, lo, lo + np.array([col, col, z1 - z0]), spacing_m), s, True)
        if layout == "column-grid":
            continue
        walls = [(0, 0.0), (0, depth), (1, 0.0), (1, width)] if layout != "missing-slab" or rng.random() < 0.5 else []
        walls += [(0, float(rng.uniform(0.3, 0.7) * depth)), (1, float(rng.uniform(0.3, 0.7) * width))]
        for axis, at in walls:  # axis 0: along x at y = at; 1: along y at x = at
            length = width if axis == 0 else depth
            along = np.eye(3)[axis] * length
            across = np.eye(3)[1 - axis] * WALL_T_M
            base = np.array([0.0, 0.0, z0])
            base[1 - axis] = at - WALL_T_M / 2
            up = np.array([0.0, 0.0, z1 - z0])
            p = np.vstack([_rect(rng, base, along, up, spacing_m), _rect(rng, base + across, along, up, spacing_m)])
            keep = np.ones(len(p), bool)
            if layout == "walls-openings":
                for _ in range(int(rng.integers(1, 2 + int(length / 3)))):  # windows and doors
                    w = rng.uniform(0.8, 2.0)
                    t0 = rng.uniform(0, length - w)
                    door = rng.random() < 0.3
                    h0 = 0.0 if door else rng.uniform(0.8, 1.1)
                    h1 = rng.uniform(2.0, 2.3) if door else rng.uniform(2.0, 2.4)
                    t = p[:, axis]
                    h = p[:, 2] - z0
                    keep &= ~((t >= t0) & (t <= t0 + w) & (h >= h0) & (h <= min(h1, z1 - z0 - 0.1)))
            add(p[keep], s, True)

    pts = np.vstack(pts_l)
    level = np.concatenate(lvl_l)
    span = np.concatenate(span_l)
    moved = deform(pts, level, span, motions, floor_z, ceiling_z)
    if collapse is not None:  # the broken bay: dropped and turned about one of its edges, no longer the level's
        j, (x0, y0, x1, y1) = collapse
        bay = np.vstack(
            [
                _rect(rng, np.array([x0, y0, levels_z[j] - dz]), [x1 - x0, 0, 0], [0, y1 - y0, 0], spacing_m)
                for dz in (0.0, SLAB_T_M)
            ]
        )
        angle = np.deg2rad(rng.uniform(8, 25))
        t = (bay[:, 0] - x0) / max(x1 - x0, 1e-6)
        bay[:, 2] -= t * (x1 - x0) * np.sin(angle)
        moved = np.vstack([moved, bay])
        level = np.r_[level, np.full(len(bay), j)]

    # range noise along the line of sight from a station in the middle of each story, and occluders that hide
    # what is behind them from it
    noise = float(rng.uniform(0.002, 0.005)) if scanned else 0.0
    story_of = np.clip(np.searchsorted(np.asarray(floor_z), moved[:, 2] - 0.05, side="right") - 1, 0, stories - 1)
    stations = np.c_[
        np.full(stories, width / 2) + rng.normal(0, 1, stories),
        np.full(stories, depth / 2) + rng.normal(0, 1, stories),
        np.asarray(floor_z) + 1.5,
    ]
    ray = moved - stations[story_of]
    dist = np.linalg.norm(ray, axis=1, keepdims=True)
    moved = moved + ray / np.maximum(dist, 1e-9) * rng.normal(0, noise, (len(moved), 1))
    hidden = np.zeros(len(moved), bool)
    for s in range(stories):
        for _ in range(int(rng.integers(2, 7)) if scanned else 0):  # occluders on this story's floor
            c = np.array([rng.uniform(1, width - 1), rng.uniform(1, depth - 1)])
            r, top = rng.uniform(0.3, 0.9), floor_z[s] + rng.uniform(0.6, 2.0)
            st = stations[s]
            sel = story_of == s
            d = moved[sel, :2] - st[:2]
            f = np.clip(((c - st[:2]) @ d.T) / np.maximum((d * d).sum(1), 1e-9), 0, 1)
            closest = st[:2] + f[:, None] * d
            z_at = st[2] + f * (moved[sel, 2] - st[2])
            blocked = (np.linalg.norm(closest - c, axis=1) < r) & (z_at < top) & (f < 0.999)
            hidden[np.flatnonzero(sel)[blocked]] = True
    return Frame(layout, moved[~hidden], motions, noise)
