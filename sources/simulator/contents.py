"""Furnishing a room: bookcases, sofas and boards along the walls, tables with chairs, things on the tables
and on the floor, clear of columns and door swings; in damaged buildings thrown about or tipped over."""

from __future__ import annotations

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator import furniture as fur
from aftershock.sources.simulator.layout import OUTER_WALL_M, Plan
from aftershock.sources.simulator.meshes import (
    MeshBuilder,
    rotation_xyz,
    rotation_z,
)
from aftershock.sources.simulator.scene import Room


class _Free:
    """Axis-aligned footprints already taken in a room."""

    def __init__(self, room: Room, taken: list[tuple[float, float, float, float]]) -> None:
        self.room = room
        self.rects = list(taken)

    def fits(self, x0: float, y0: float, x1: float, y1: float, margin: float = 0.05) -> bool:
        r = self.room
        if x0 < r.x0 + margin or y0 < r.y0 + margin or x1 > r.x1 - margin or y1 > r.y1 - margin:
            return False
        return all(x1 <= a or x0 >= c or y1 <= bb or y0 >= d for a, bb, c, d in self.rects)

    def take(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.rects.append((x0, y0, x1, y1))


def _footprint(piece: fur.Piece, x: float, y: float, yaw: float, pad: float = 0.0) -> tuple[float, ...]:
    hx, hy = piece.half_extent
    c, s = abs(np.cos(yaw)), abs(np.sin(yaw))
    ex, ey = hx * c + hy * s + pad, hx * s + hy * c + pad
    return (x - ex, y - ey, x + ex, y + ey)


def furnish(plan: Plan, room: Room, b: MeshBuilder, rng: np.random.Generator, r_damage: np.random.Generator) -> None:
    spec = plan.spec
    k = room.story
    z0 = plan.floor_z[k]
    cw = plan.column_w / 2 + 0.05
    taken = [(x - cw, y - cw, x + cw, y + cw) for x in plan.xs for y in plan.ys]
    taken += plan.door_zones.get(k, [])
    free = _Free(room, taken)
    shade = float(rng.uniform(0.8, 1.15))
    area = (room.x1 - room.x0) * (room.y1 - room.y0)
    messy = spec.tip_prob

    def put(
        piece: fur.Piece, x: float, y: float, yaw: float, z: float = 0.0, check: bool = True, pad: float = 0.05
    ) -> bool:
        fp = _footprint(piece, x, y, yaw, pad)
        if check and not free.fits(*fp):
            return False
        rot = rotation_z(yaw)
        zz = z0 + z
        if messy and r_damage.random() < messy and z == 0.0:
            # thrown about: shifted, turned, some tipped over onto a side
            yaw2 = yaw + r_damage.normal(0, 0.5)
            if piece.cls in (C.CHAIR, C.TABLE, C.BOOKCASE, C.CLUTTER) and r_damage.random() < 0.5:
                hy = piece.half_extent[1]
                tip = rotation_z(yaw2) @ rotation_xyz(np.pi / 2 * r_damage.choice([-1, 1]), 0, 0)
                rot, zz = tip, z0 + hy
            else:
                rot = rotation_z(yaw2)
        fur.place(b, piece, fur.pose(x, y, zz, rot), story=k, shade=shade)
        free.take(*fp)
        return True

    def along_wall(piece: fur.Piece, tries: int = 20) -> bool:
        for _ in range(tries):
            side = int(rng.integers(4))
            hx, hy = piece.half_extent
            if (room.x1 - room.x0 if side < 2 else room.y1 - room.y0) < 2 * hx + 0.02:
                continue
            if side == 0:
                x, y, yaw = rng.uniform(room.x0 + hx, room.x1 - hx), room.y0 + hy + 0.06, 0.0
            elif side == 1:
                x, y, yaw = rng.uniform(room.x0 + hx, room.x1 - hx), room.y1 - hy - 0.06, np.pi
            elif side == 2:
                x, y, yaw = room.x0 + hy + 0.06, rng.uniform(room.y0 + hx, room.y1 - hx), -np.pi / 2
            else:
                x, y, yaw = room.x1 - hy - 0.06, rng.uniform(room.y0 + hx, room.y1 - hx), np.pi / 2
            if put(piece, x, y, yaw, pad=0.0):
                return True
        return False

    f = spec.furniture
    tables: list[tuple[float, float, float, fur.Piece]] = []
    if room.kind == "corridor":
        for _ in range(rng.poisson(0.1 * area * spec.clutter / 4)):
            along_wall(fur.clutter(rng))
        if rng.random() < 0.3 * f:
            along_wall(fur.bookcase(rng))
        if rng.random() < 0.2 * f:
            along_wall(fur.sofa(rng))
        return
    for _ in range(rng.poisson(area / 22 * f)):
        along_wall(fur.bookcase(rng))
    if rng.random() < 0.6:
        _board(plan, room, b, rng, shade)
    if rng.random() < 0.35 * f:
        along_wall(fur.sofa(rng))
    n_tables = rng.poisson(area / (7 if room.kind == "open" else 9) * f)
    for _ in range(n_tables):
        piece = fur.table(rng)
        for _try in range(15):
            yaw = float(rng.choice([0.0, np.pi / 2]) + rng.normal(0, 0.05))
            x = rng.uniform(room.x0 + 0.9, room.x1 - 0.9)
            y = rng.uniform(room.y0 + 0.9, room.y1 - 0.9)
            if put(piece, x, y, yaw, pad=0.55):  # room for the chairs and to walk around
                tables.append((x, y, yaw, piece))
                break
    for x, y, yaw, piece in tables:
        hx, hy = piece.half_extent
        rot = rotation_z(yaw)
        for side in (-1, 1):
            for _ in range(int(rng.integers(0, 3))):
                local = np.array([rng.uniform(-hx + 0.3, hx - 0.3), side * (hy + rng.uniform(0.2, 0.35)), 0])
                cx, cy = (rot @ local)[:2] + np.array([x, y])
                chair_yaw = yaw + (0 if side < 0 else np.pi) + rng.normal(0, 0.3)
                put(fur.chair(rng), float(cx), float(cy), float(chair_yaw), check=False)
        for _ in range(rng.poisson(1.2 * spec.clutter)):  # things on the table
            item = fur.clutter(rng)
            if item.height > 0.8 or item.half_extent[0] > hx or item.half_extent[1] > hy:
                continue
            local = np.array(
                [
                    rng.uniform(-hx + item.half_extent[0], hx - item.half_extent[0]),
                    rng.uniform(-hy + item.half_extent[1], hy - item.half_extent[1]),
                    0,
                ]
            )
            cx, cy = (rot @ local)[:2] + np.array([x, y])
            zt = max(p.center[2] + p.size[2] / 2 for p in piece.parts)
            fur.place(
                b,
                item,
                fur.pose(float(cx), float(cy), z0 + zt, rotation_z(yaw + rng.normal(0, 0.4))),
                story=k,
                shade=shade,
            )
    for _ in range(rng.poisson(area / 10 * spec.clutter)):
        along_wall(fur.clutter(rng), tries=6)


def _board(plan: Plan, room: Room, b: MeshBuilder, rng: np.random.Generator, shade: float) -> None:
    """A board on an inside wall, clear of the doors."""
    piece = fur.board(rng)
    hx = piece.half_extent[0]
    zones = plan.door_zones.get(room.story, [])
    for _ in range(10):
        side = int(rng.integers(4))
        horizontal = side < 2
        lo, hi = (room.x0, room.x1) if horizontal else (room.y0, room.y1)
        if hi - lo < 2 * hx + 0.4:
            continue
        u = rng.uniform(lo + hx + 0.2, hi - hx - 0.2)
        if side == 0:
            x, y, yaw = u, room.y0, 0.0
        elif side == 1:
            x, y, yaw = u, room.y1, np.pi
        elif side == 2:
            x, y, yaw = room.x0, u, -np.pi / 2
        else:
            x, y, yaw = room.x1, u, np.pi / 2
        edge = (x, y)
        if _near_outer(plan, edge) or any(a - hx <= x <= c + hx and bb - hx <= y <= d + hx for a, bb, c, d in zones):
            continue
        fur.place(b, piece, fur.pose(x, y, plan.floor_z[room.story], rotation_z(yaw)), story=room.story, shade=shade)
        return


def _near_outer(plan: Plan, xy: tuple[float, float]) -> bool:
    x, y = xy
    m = OUTER_WALL_M
    return x < m or y < m or x > plan.width - m or y > plan.depth - m
