"""Disaster damage: story drift and tilt (as a deformation of the laid-out building), debris piles and cracks.

Each level (slab) j moves rigidly by T_j: a tilt about its own centre, then a horizontal drift. Boxes fixed
to a level (slabs, beams, furniture) follow T_j; boxes that span a story (columns, walls) are blended
vertex by vertex from T_k at the floor to T_k+1 at the ceiling, so columns lean and walls shear as they
do under inter-story drift.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aftershock.pipeline.classes import SemanticClass
from aftershock.sources.simulator.meshes import METAL, RUBBLE, MeshBuilder, rotation_xyz


@dataclass(frozen=True, slots=True)
class LevelMotion:
    """How one level (slab) moved against the undamaged building."""

    index: int
    z_m: float  # nominal height of the slab top
    drift_x_mm: float
    drift_y_mm: float
    tilt_x_deg: float  # rotation about the x axis (right hand)
    tilt_y_deg: float  # rotation about the y axis
    pivot: tuple[float, float, float]

    def matrix(self) -> np.ndarray:
        """4 x 4 transform undamaged -> damaged."""
        rot = rotation_xyz(np.deg2rad(self.tilt_x_deg), np.deg2rad(self.tilt_y_deg), 0.0)
        pivot = np.asarray(self.pivot)
        m = np.eye(4)
        m[:3, :3] = rot
        m[:3, 3] = pivot - rot @ pivot + np.array([self.drift_x_mm, self.drift_y_mm, 0.0]) * 1e-3
        return m


def level_motions(
    rng: np.random.Generator,
    levels_z: list[float],
    center_xy: tuple[float, float],
    story_heights: list[float],
    drift_ratio: tuple[float, float],
    tilt_deg: tuple[float, float],
) -> list[LevelMotion]:
    """Cumulative drift and per-level tilt; level 0 (the ground slab) never moves."""
    out = [LevelMotion(0, levels_z[0], 0.0, 0.0, 0.0, 0.0, (center_xy[0], center_xy[1], levels_z[0]))]
    dx = dy = 0.0
    direction = rng.uniform(0, 2 * np.pi)  # drift keeps a main direction, as under one shaking axis
    for j in range(1, len(levels_z)):
        ratio = rng.uniform(*drift_ratio) if drift_ratio[1] > 0 else 0.0
        ang = direction + rng.normal(0, 0.4)
        step = ratio * story_heights[j - 1] * 1e3
        dx += step * np.cos(ang)
        dy += step * np.sin(ang)
        tx = ty = 0.0
        if tilt_deg[1] > 0:
            tx = float(rng.uniform(*tilt_deg) * rng.choice([-1, 1]))
            ty = float(rng.uniform(*tilt_deg) * rng.choice([-1, 1]))
        out.append(
            LevelMotion(
                j,
                levels_z[j],
                round(dx, 3),
                round(dy, 3),
                round(tx, 4),
                round(ty, 4),
                (center_xy[0], center_xy[1], levels_z[j]),
            )
        )
    return out


def deform(
    points: np.ndarray,
    level: np.ndarray,
    span: np.ndarray,
    motions: list[LevelMotion],
    floor_z: list[float],
    ceiling_z: list[float],
) -> np.ndarray:
    """Move undamaged points: rigid with their level, or blended across their story when `span`."""
    mats = np.stack([m.matrix() for m in motions])
    out = np.empty_like(points)
    hom = np.c_[points, np.ones(len(points))]
    for j in np.unique(level):
        sel = level == j
        rigid = sel & ~span
        out[rigid] = hom[rigid] @ mats[j].T[:, :3]
        blend = sel & span
        if blend.any():
            top = min(j + 1, len(mats) - 1)
            s = np.clip((points[blend, 2] - floor_z[j]) / (ceiling_z[j] - floor_z[j]), 0.0, 1.0)[:, None]
            out[blend] = (1 - s) * (hom[blend] @ mats[j].T[:, :3]) + s * (hom[blend] @ mats[top].T[:, :3])
    return out


def debris_pile(
    builder: MeshBuilder,
    rng: np.random.Generator,
    center: tuple[float, float],
    floor_z: float,
    radius: float,
    height: float,
    story: int,
    colors: tuple[tuple[int, int, int], ...],
) -> int:
    """A mound of broken concrete pieces (and some rebar), one debris instance."""
    inst = builder.new_instance(SemanticClass.DEBRIS)

    def piece(
        at: tuple[float, float, float],
        size: np.ndarray | tuple[float, float, float],
        rot: np.ndarray,
        col: tuple[int, int, int],
    ) -> None:
        """One broken piece of the mound."""
        builder.add_box(
            at,
            size,
            cls=SemanticClass.DEBRIS,
            instance=inst,
            material=RUBBLE,
            rotation=rot,
            color=col,
            story=story,
            jitter_color=0.15,
        )

    # the body of the mound: a few broken slab chunks leaning on each other
    for _ in range(int(np.clip(radius * 3, 2, 6))):
        r, a = radius * rng.uniform(0, 0.45), rng.uniform(0, 2 * np.pi)
        size = (radius * rng.uniform(0.5, 1.0), radius * rng.uniform(0.4, 0.8), rng.uniform(0.12, 0.3))
        rx, ry = rng.uniform(-0.5, 0.5, 2)
        rot = rotation_xyz(rx, ry, rng.uniform(-np.pi, np.pi))
        col = colors[int(rng.integers(len(colors)))]
        piece(
            (center[0] + r * np.cos(a), center[1] + r * np.sin(a), floor_z + height * rng.uniform(0.15, 0.45)),
            size,
            rot,
            col,
        )
    # then many smaller pieces, larger and higher towards the middle
    n = int(np.clip(radius * radius * 45 * rng.uniform(0.7, 1.3), 15, 160))
    rho = radius * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    sizes = rng.uniform(0.06, 0.45, (n, 3)) * np.clip(1.2 - rho / radius, 0.3, 1.0)[:, None]
    z = floor_z + height * (1 - (rho / radius) ** 2) * rng.uniform(0.2, 1.0, n)
    for i in range(n):
        rot = rotation_xyz(*rng.uniform(-np.pi, np.pi, 3))
        col = colors[int(rng.integers(len(colors)))]
        piece((center[0] + rho[i] * np.cos(phi[i]), center[1] + rho[i] * np.sin(phi[i]), z[i]), sizes[i], rot, col)
    for _ in range(int(rng.integers(0, 4))):  # bent rebar sticking out
        rx, ry = rng.uniform(-1.2, 1.2, 2)
        rot = rotation_xyz(rx, ry, rng.uniform(-np.pi, np.pi))
        r = radius * rng.uniform(0, 0.6)
        a = rng.uniform(0, 2 * np.pi)
        builder.add_box(
            (center[0] + r * np.cos(a), center[1] + r * np.sin(a), floor_z + height * 0.6),
            (0.016, 0.016, rng.uniform(0.5, 1.5)),
            cls=SemanticClass.DEBRIS,
            instance=inst,
            material=METAL,
            rotation=rot,
            color=(95, 70, 55),
            story=story,
        )
    return inst


@dataclass(frozen=True, slots=True)
class CrackTruth:
    """A crack: where it is, how long, wide and deep it is, and on which element.

    `polyline` is its centre line (K, 3) in the world (scene) or element frame; `length_m` is measured
    along it; `width_m` is the mean opening, `max_width_m` the widest point; `direction` is the unit
    vector from its first to its last point; `normal` the outward normal of the cracked face.
    """

    element_instance_id: int
    element_class: int
    center: np.ndarray
    direction: np.ndarray
    normal: np.ndarray
    length_m: float
    width_m: float
    max_width_m: float
    depth_m: float
    color: tuple[int, int, int]
    polyline: np.ndarray
    widths: np.ndarray  # (K,) opening at each polyline point


def crack_polyline(
    rng: np.random.Generator,
    center: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    length: float,
    angle: float,
    points: int = 12,
    wander: float = 0.06,
) -> np.ndarray:
    """A wandering crack centre line on the plane spanned by unit vectors u, v, through `center`."""
    d = np.cos(angle) * u + np.sin(angle) * v
    p = np.cos(angle + np.pi / 2) * u + np.sin(angle + np.pi / 2) * v
    s = np.linspace(-0.5, 0.5, points) * length
    walk = np.cumsum(rng.normal(0, wander * length / np.sqrt(points), points))
    walk -= np.linspace(walk[0], walk[-1], points) * 0.5 + walk.mean() * 0.5
    return center[None, :] + s[:, None] * d[None, :] + walk[:, None] * p[None, :]


def crack_widths(rng: np.random.Generator, points: int, width: float) -> np.ndarray:
    """Opening along a crack: widest in the middle, tapering to a hairline at both ends."""
    t = np.linspace(-1, 1, points)
    profile = np.clip(1.15 - 0.85 * t**2, 0.15, None) * rng.uniform(0.85, 1.15, points)
    return width * profile / profile.mean()


def make_crack(
    rng: np.random.Generator,
    element_instance: int,
    element_class: int,
    center: np.ndarray,
    normal: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    length: float,
    angle: float,
    width: float,
    depth: float,
    color: tuple[int, int, int],
) -> CrackTruth:
    poly = crack_polyline(rng, center, u, v, length, angle)
    widths = crack_widths(rng, len(poly), width)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    direction = poly[-1] - poly[0]
    return CrackTruth(
        element_instance_id=element_instance,
        element_class=element_class,
        center=poly.mean(axis=0),
        direction=direction / np.linalg.norm(direction),
        normal=np.asarray(normal, dtype=np.float64),
        length_m=float(seg.sum()),
        width_m=float(widths.mean()),
        max_width_m=float(widths.max()),
        depth_m=float(depth),
        color=color,
        polyline=poly,
        widths=widths,
    )


def random_crack_size(rng: np.random.Generator) -> tuple[float, float, float]:
    """Length, mean width and depth (m) of a crack in damaged concrete: mostly fine, some severe."""
    width = float(np.clip(rng.lognormal(np.log(0.0022), 0.7), 0.0003, 0.012))
    length = float(rng.uniform(0.25, 1.2))
    depth = float(np.clip(width * rng.uniform(4, 12), 0.003, 0.06))
    return length, width, depth


def distance_to_polylines(
    points: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, seg_w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: distance to the nearest segment minus its half opening (<= 0 inside a crack), and its index.

    Brute force over segments in chunks; fine for the few hundred segments a scene or element has.
    """
    n = len(points)
    best = np.full(n, np.inf)
    best_i = np.zeros(n, np.int64)
    ab = seg_b - seg_a
    ab2 = np.maximum((ab * ab).sum(1), 1e-18)
    chunk = max(1, 4_000_000 // max(len(seg_a), 1))
    for start in range(0, n, chunk):
        p = points[start : start + chunk]
        ap = p[:, None, :] - seg_a[None, :, :]
        t = np.clip((ap * ab[None]).sum(-1) / ab2[None], 0, 1)
        d = np.linalg.norm(ap - t[..., None] * ab[None], axis=-1)
        # half opening interpolated along the segment
        d = d - 0.5 * seg_w[None, :, 0] * (1 - t) - 0.5 * seg_w[None, :, 1] * t
        i = d.argmin(axis=1)
        best[start : start + chunk] = d[np.arange(len(p)), i]
        best_i[start : start + chunk] = i
    return best, best_i


def crack_segments(cracks: list[CrackTruth]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flattened segments of all cracks: starts, ends, (opening at start, at end), crack index."""
    if not cracks:
        z = np.zeros((0, 3))
        return z, z, np.zeros((0, 2)), np.zeros(0, np.int64)
    a = np.concatenate([c.polyline[:-1] for c in cracks])
    b = np.concatenate([c.polyline[1:] for c in cracks])
    w = np.concatenate([np.c_[c.widths[:-1], c.widths[1:]] for c in cracks])
    idx = np.concatenate([np.full(len(c.polyline) - 1, i) for i, c in enumerate(cracks)])
    return a, b, w, idx
