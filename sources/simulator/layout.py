"""The floor plan of a building: column grid, story heights, corridor, rooms, walls with their doors and
windows. Pure layout, no geometry: `building.py` turns it into labelled boxes, `contents.py` furnishes it."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from aftershock.sources.simulator.families import FamilySpec
from aftershock.sources.simulator.scene import Room

OUTER_WALL_M: Final = 0.25
PARTITION_M: Final = 0.12
DOOR_W: Final = (0.9, 1.05)
DOOR_H: Final = 2.1


@dataclass(slots=True)
class Opening:
    u0: float
    u1: float
    z0: float
    z1: float
    kind: str  # door | window | gap


@dataclass(slots=True)
class Wall:
    """A straight wall from (x0, y0) to (x1, y1) (axis aligned) with openings along it."""

    story: int
    x0: float
    y0: float
    x1: float
    y1: float
    thickness: float
    outer: bool
    openings: list[Opening] = field(default_factory=list)
    broken: bool = False

    @property
    def along_x(self) -> bool:
        return abs(self.y1 - self.y0) < 1e-9

    @property
    def length(self) -> float:
        return abs(self.x1 - self.x0) + abs(self.y1 - self.y0)

    def point(self, u: float) -> tuple[float, float]:
        return (self.x0 + u, self.y0) if self.along_x else (self.x0, self.y0 + u)


@dataclass(slots=True)
class Plan:
    spec: FamilySpec
    xs: np.ndarray  # column lines along x
    ys: np.ndarray
    story_h: list[float]
    slab_t: float
    beam_d: float
    column_w: float
    corridor: tuple[float, float]  # y0, y1
    floor_z: list[float]
    ceiling_z: list[float]
    walls: list[Wall] = field(default_factory=list)
    rooms: list[Room] = field(default_factory=list)
    door_zones: dict[int, list[tuple[float, float, float, float]]] = field(default_factory=dict)
    floor_instances: dict[int, int] = field(default_factory=dict)  # level -> instance of its floor half
    ceiling_instances: dict[int, int] = field(default_factory=dict)

    @property
    def width(self) -> float:
        return float(self.xs[-1])

    @property
    def depth(self) -> float:
        return float(self.ys[-1])


def _bays(rng: np.random.Generator, lo_hi: tuple[int, int], bay: tuple[float, float]) -> np.ndarray:
    n = int(rng.integers(lo_hi[0], lo_hi[1] + 1))
    return np.r_[0.0, np.cumsum(np.round(rng.uniform(*bay, n), 2))]


def make_plan(spec: FamilySpec, rng: np.random.Generator) -> Plan:
    xs, ys = _bays(rng, spec.bays_x, spec.bay_m), _bays(rng, spec.bays_y, spec.bay_m)
    n_st = int(rng.integers(spec.stories[0], spec.stories[1] + 1))
    slab_t = round(float(rng.uniform(0.2, 0.28)), 3)
    h = round(float(rng.uniform(*spec.story_height_m)), 2)
    story_h = [h] * n_st
    floor_z = [k * h for k in range(n_st)]
    ceiling_z = [(k + 1) * h - slab_t for k in range(n_st)]
    depth = ys[-1]
    cw = float(rng.uniform(*spec.corridor_width_m))
    yc = float(np.clip(depth * rng.uniform(0.4, 0.6), 3.2 + cw / 2, depth - 3.2 - cw / 2))
    plan = Plan(
        spec=spec,
        xs=xs,
        ys=ys,
        story_h=story_h,
        slab_t=slab_t,
        beam_d=round(float(rng.uniform(0.35, 0.55)), 2),
        column_w=round(float(rng.uniform(0.4, 0.6)), 2),
        corridor=(yc - cw / 2, yc + cw / 2),
        floor_z=floor_z,
        ceiling_z=ceiling_z,
    )
    for k in range(n_st):
        _story_walls(plan, k, rng)
    return plan


def _story_walls(plan: Plan, k: int, rng: np.random.Generator) -> None:
    spec, w, d = plan.spec, plan.width, plan.depth
    ch = plan.ceiling_z[k] - plan.floor_z[k]
    zones = plan.door_zones.setdefault(k, [])
    # Outer walls with a window per bay.
    for x0, y0, x1, y1, lines in (
        (0, 0, w, 0, plan.xs),
        (0, d, w, d, plan.xs),
        (0, 0, 0, d, plan.ys),
        (w, 0, w, d, plan.ys),
    ):
        wall = Wall(k, x0, y0, x1, y1, OUTER_WALL_M, True)
        for a, c in itertools.pairwise(lines):
            width = min(c - a - 1.2, rng.uniform(1.2, 2.6))
            mid = (a + c) / 2 + rng.uniform(-0.2, 0.2)
            sill = rng.uniform(0.8, 1.0)
            wall.openings.append(Opening(mid - width / 2, mid + width / 2, sill, min(2.4, ch - 0.3), "window"))
        plan.walls.append(wall)
    c0, c1 = plan.corridor
    half = PARTITION_M / 2 + 0.01
    plan.rooms.append(Room(k, OUTER_WALL_M / 2, c0 + half, w - OUTER_WALL_M / 2, c1 - half, "corridor"))
    for side in ("south", "north"):
        ya, yb = (OUTER_WALL_M / 2, c0) if side == "south" else (c1, d - OUTER_WALL_M / 2)
        y_wall = c0 if side == "south" else c1
        y_in = ya if side == "north" else yb  # the room side of the corridor wall
        if rng.random() < spec.open_plan_prob:
            plan.rooms.append(
                Room(
                    k,
                    OUTER_WALL_M / 2,
                    ya + (half if side == "north" else 0),
                    w - OUTER_WALL_M / 2,
                    yb - (half if side == "south" else 0),
                    "open",
                )
            )
            # a low wall stub at each end keeps the corridor readable; the middle is open
            cw = Wall(k, 0, y_wall, w, y_wall, PARTITION_M, False)
            cw.openings.append(Opening(1.5, w - 1.5, 0.0, ch, "gap"))
            plan.walls.append(cw)
            continue
        bounds = [0.0]
        while bounds[-1] + spec.room_width_m[0] * 2 < w:
            bounds.append(bounds[-1] + float(rng.uniform(*spec.room_width_m)))
        bounds.append(w)
        if bounds[-1] - bounds[-2] < spec.room_width_m[0]:
            bounds.pop(-2)
        corridor_wall = Wall(k, 0, y_wall, w, y_wall, PARTITION_M, False)
        for i, (a, c) in enumerate(itertools.pairwise(bounds)):
            x0 = a + (OUTER_WALL_M / 2 if i == 0 else half)
            x1 = c - (OUTER_WALL_M / 2 if i == len(bounds) - 2 else half)
            y0 = ya + (half if side == "north" else 0)
            y1 = yb - (half if side == "south" else 0)
            plan.rooms.append(Room(k, x0, y0, x1, y1, "room"))
            dw = float(rng.uniform(*DOOR_W))
            u = float(rng.uniform(x0 + 0.3, max(x0 + 0.31, x1 - dw - 0.3)))
            corridor_wall.openings.append(Opening(u, u + dw, 0.0, DOOR_H, "door"))
            sgn = 1.0 if side == "north" else -1.0
            zones.append((u - 0.2, min(y_in, y_in + sgn * 1.4), u + dw + 0.2, max(y_in, y_in + sgn * 1.4)))
            zones.append((u - 0.2, min(y_in, y_in - sgn * 1.0), u + dw + 0.2, max(y_in, y_in - sgn * 1.0)))
            if i > 0:
                part = Wall(k, a, ya, a, yb, PARTITION_M, False)
                if rng.random() < 0.3 and yb - ya > 2.5:  # a door to the neighbouring room
                    v = float(rng.uniform(0.4, yb - ya - 1.5))
                    part.openings.append(Opening(v, v + 0.95, 0.0, DOOR_H, "door"))
                    zones.append((a - 1.2, ya + v - 0.2, a + 1.2, ya + v + 1.15))
                part.broken = rng.random() < spec.broken_wall_prob
                plan.walls.append(part)
        plan.walls.append(corridor_wall)
