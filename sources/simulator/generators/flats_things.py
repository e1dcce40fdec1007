"""The `flats` generator's own pieces: furniture and fittings as lists of boxes, doors and windows in wall
openings, and its damage (breached partitions with block piles, fallen plaster, a sagging ceiling piece,
overturned furniture, grit). Nothing here comes from the other generators' furniture, doors or wreckage.

A `Thing` is drawn in its own frame: footprint centred on the origin, standing on z = 0, back to -y.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.generators.parts import Footprints, Opening
from aftershock.sources.simulator.meshes import (
    CONCRETE,
    FABRIC,
    GLASS,
    METAL,
    PLASTER,
    RUBBLE,
    TILE,
    WHITEBOARD,
    WOOD,
    Material,
    MeshBuilder,
    rotation_xyz,
    rotation_z,
)

Color = tuple[int, int, int]
Rect = tuple[float, float, float, float]
Point = tuple[float, float]

UPHOLSTERY: Final = ((120, 130, 140), (150, 60, 55), (70, 95, 70), (190, 175, 150), (60, 70, 100), (90, 80, 75))
VENEERS: Final = ((196, 160, 118), (120, 80, 50), (230, 225, 215), (80, 60, 45), (170, 140, 100), (60, 60, 62))
APPLIANCE: Final = ((238, 238, 236), (190, 192, 195), (40, 40, 42))
LINEN: Final = ((235, 235, 230), (200, 210, 225), (225, 205, 200), (180, 190, 170))
PLANT: Final = ((60, 110, 50), (80, 130, 60), (45, 90, 55))
_CORNERS: Final = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])


@dataclass(slots=True)
class Thing:
    """Boxes in the thing's frame (centre, size, material, colour, local rotation) and its class."""

    cls: C
    boxes: list[tuple[tuple[float, float, float], tuple[float, float, float], Material, Color, np.ndarray | None]] = (
        field(default_factory=list)
    )

    def box(
        self,
        c: tuple[float, float, float],
        s: tuple[float, float, float],
        mat: Material,
        col: Color,
        rot: np.ndarray | None = None,
    ) -> Thing:
        self.boxes.append((c, s, mat, col, rot))
        return self

    def corners(self, rot: np.ndarray) -> np.ndarray:
        """All box corners (8 n, 3) turned by `rot` (about the thing's origin)."""
        out = []
        for c, s, _m, _col, r in self.boxes:
            local = _CORNERS * np.asarray(s)
            if r is not None:
                local = local @ r.T
            out.append((local + np.asarray(c)) @ rot.T)
        return np.concatenate(out)


def pick(rng: np.random.Generator, tones: tuple[Color, ...]) -> Color:
    return tones[int(rng.integers(len(tones)))]


def draw(b: MeshBuilder, thing: Thing, x: float, y: float, rot: np.ndarray, z: float = 0.0) -> int:
    """Put a thing's boxes in the world: turned by `rot`, its lowest point at `z` (it rests on what is
    below), its footprint centred on (x, y)."""
    pts = thing.corners(rot)
    lo, hi = pts.min(0), pts.max(0)
    shift = np.array([x - (lo[0] + hi[0]) / 2, y - (lo[1] + hi[1]) / 2, z - lo[2]])
    inst = b.new_instance(thing.cls)
    for c, s, mat, col, r in thing.boxes:
        b.add_box(rot @ np.asarray(c) + shift, s, cls=thing.cls, instance=inst, material=mat, color=col,
                  rotation=rot if r is None else rot @ r)  # fmt: skip
    return inst


def footprint_of(thing: Thing, x: float, y: float, rot: np.ndarray, pad: float) -> Rect:
    pts = thing.corners(rot)
    ex, ey = (pts[:, 0].max() - pts[:, 0].min()) / 2 + pad, (pts[:, 1].max() - pts[:, 1].min()) / 2 + pad
    return (x - ex, y - ey, x + ex, y + ey)


def try_place(
    b: MeshBuilder,
    taken: Footprints,
    room: Rect,
    thing: Thing,
    x: float,
    y: float,
    rot: np.ndarray,
    *,
    pad: float = 0.05,
    z: float = 0.0,
    reserve: bool = True,
) -> bool:
    fp = footprint_of(thing, x, y, rot, pad)
    if not taken.fits(fp, room, margin=0.0):
        return False
    draw(b, thing, x, y, rot, z)
    if reserve:
        taken.take(fp)
    return True


def size_of(thing: Thing) -> tuple[float, float, float]:
    pts = thing.corners(np.eye(3))
    return tuple(float(v) for v in pts.max(0) - pts.min(0))  # type: ignore[return-value]


def by_wall(
    b: MeshBuilder,
    taken: Footprints,
    room: Rect,
    thing: Thing,
    rng: np.random.Generator,
    *,
    sides: tuple[int, ...] = (0, 1, 2, 3),
    tries: int = 10,
    skew: float = 0.0,
    z: float = 0.0,
    reserve: bool = True,
) -> tuple[float, float, int] | None:
    """A thing with its back to a wall of the room (0 south, 1 north, 2 west, 3 east), `skew` radians of
    random yaw off square (slid furniture). Returns where it went."""
    x0, y0, x1, y1 = room
    for _ in range(tries):
        side = sides[int(rng.integers(len(sides)))]
        yaw = (0.0, np.pi, -np.pi / 2, np.pi / 2)[side] + float(rng.uniform(-skew, skew))
        rot = rotation_z(yaw)
        fp = footprint_of(thing, 0.0, 0.0, rot, 0.0)
        ex, ey = fp[2], fp[3]
        if x1 - x0 < 2 * ex + 0.1 or y1 - y0 < 2 * ey + 0.1:
            continue
        gap = 0.03 + (0.25 * skew if skew else 0.0)
        if side < 2:
            x = float(rng.uniform(x0 + ex + 0.03, x1 - ex - 0.03))
            y = y0 + ey + gap if side == 0 else y1 - ey - gap
        else:
            y = float(rng.uniform(y0 + ey + 0.03, y1 - ey - 0.03))
            x = x0 + ex + gap if side == 2 else x1 - ex - gap
        if try_place(b, taken, room, thing, x, y, rot, pad=0.02, z=z, reserve=reserve):
            return x, y, side
    return None


def free_standing(
    b: MeshBuilder,
    taken: Footprints,
    room: Rect,
    thing: Thing,
    rng: np.random.Generator,
    *,
    pad: float = 0.25,
    tries: int = 10,
    square: bool = False,
) -> tuple[float, float, float] | None:
    """A thing anywhere in the room at an arbitrary yaw (or square to the walls), clear of the others by `pad`."""
    for _ in range(tries):
        yaw = float(rng.choice([0.0, np.pi / 2])) if square else float(rng.uniform(-np.pi, np.pi))
        x = float(rng.uniform(room[0] + 0.3, room[2] - 0.3))
        y = float(rng.uniform(room[1] + 0.3, room[3] - 0.3))
        if try_place(b, taken, room, thing, x, y, rotation_z(yaw), pad=pad):
            return x, y, yaw
    return None


# ---------------------------------------------------------------------------------------------------- tables


def dining_table(rng: np.random.Generator) -> Thing:
    """On a pedestal (column and cross feet), on two trestles, or on four square legs."""
    t = Thing(C.TABLE)
    wx, wy, h = float(rng.uniform(0.8, 1.8)), float(rng.uniform(0.75, 1.0)), float(rng.uniform(0.72, 0.77))
    col, top_t = pick(rng, VENEERS), float(rng.uniform(0.025, 0.05))
    t.box((0, 0, h - top_t / 2), (wx, wy, top_t), WOOD, col)
    style = int(rng.integers(3))
    if style == 0 and wx < 1.2:
        t.box((0, 0, h / 2), (0.1, 0.1, h - top_t), METAL, (50, 50, 52))
        for a in (np.pi / 4, -np.pi / 4):
            t.box((0, 0, 0.02), (0.7 * min(wx, wy), 0.07, 0.04), METAL, (50, 50, 52), rotation_z(a))
    elif style <= 1:
        for sx in (-1, 1):
            xx = sx * (wx / 2 - 0.15)
            t.box((xx, 0, 0.03), (0.08, wy * 0.85, 0.06), WOOD, col)
            t.box((xx, 0, h / 2), (0.06, 0.06, h - top_t), WOOD, col)
            t.box((xx, 0, h - top_t - 0.04), (0.08, wy * 0.8, 0.06), WOOD, col)
        t.box((0, 0, h * 0.35), (wx - 0.3, 0.04, 0.08), WOOD, col)
    else:
        leg = float(rng.uniform(0.04, 0.07))
        for sx in (-1, 1):
            for sy in (-1, 1):
                t.box((sx * (wx / 2 - 0.06), sy * (wy / 2 - 0.06), (h - top_t) / 2), (leg, leg, h - top_t), WOOD, col)
        t.box((0, 0, h - top_t - 0.05), (wx - 0.12, wy - 0.12, 0.08), WOOD, col)
    return t


def coffee_table(rng: np.random.Generator) -> Thing:
    t = Thing(C.TABLE)
    wx, wy, h = float(rng.uniform(0.7, 1.3)), float(rng.uniform(0.45, 0.7)), float(rng.uniform(0.35, 0.45))
    col = pick(rng, VENEERS)
    glass = rng.random() < 0.3
    t.box((0, 0, h - 0.015), (wx, wy, 0.03), GLASS if glass else WOOD, col)
    t.box((0, 0, 0.1), (wx - 0.1, wy - 0.1, 0.02), WOOD, col)
    for sx in (-1, 1):
        t.box((sx * (wx / 2 - 0.04), 0, h / 2), (0.04, wy - 0.02, h - 0.03), WOOD if not glass else METAL, col)
    return t


def desk(rng: np.random.Generator) -> Thing:
    """A top on a drawer pedestal and a side panel."""
    t = Thing(C.TABLE)
    wx, wy, h = float(rng.uniform(1.0, 1.6)), float(rng.uniform(0.55, 0.75)), 0.74
    col = pick(rng, VENEERS)
    t.box((0, 0, h - 0.015), (wx, wy, 0.03), WOOD, col)
    side = float(rng.choice([-1.0, 1.0]))
    t.box((side * (wx / 2 - 0.22), 0, (h - 0.03) / 2), (0.4, wy - 0.06, h - 0.03), WOOD, col)
    for k in range(3):
        t.box((side * (wx / 2 - 0.22), wy / 2 - 0.025, 0.15 + 0.22 * k), (0.36, 0.01, 0.18), WOOD, col)
    t.box((-side * (wx / 2 - 0.02), 0, (h - 0.03) / 2), (0.03, wy - 0.06, h - 0.03), WOOD, col)
    t.box((0, -wy / 2 + 0.05, h * 0.6), (wx - 0.1, 0.02, h * 0.5), WOOD, col)
    return t


def bedside(rng: np.random.Generator) -> Thing:
    t = Thing(C.TABLE)
    s, h = float(rng.uniform(0.38, 0.5)), float(rng.uniform(0.45, 0.6))
    col = pick(rng, VENEERS)
    t.box((0, 0, 0.04), (s - 0.04, s - 0.06, 0.08), WOOD, col)
    t.box((0, 0, (h + 0.08) / 2), (s, s - 0.02, h - 0.08), WOOD, col)
    t.box((0, s / 2 - 0.005, h * 0.7), (s - 0.06, 0.012, h * 0.25), WOOD, col)
    return t


def worktop(rng: np.random.Generator, length: float) -> Thing:
    """A run of kitchen base units on a plinth under an overhanging top, a sink bowl and hob in it."""
    t = Thing(C.TABLE)
    body, top = pick(rng, ((240, 240, 238), (60, 70, 90), (150, 110, 75), (120, 130, 120))), pick(rng, VENEERS)
    t.box((0, -0.02, 0.05), (length, 0.5, 0.1), WOOD, (40, 40, 40))
    t.box((0, 0, 0.48), (length, 0.58, 0.76), WOOD, body)
    n = max(int(length / 0.6), 1)
    for k in range(n):
        t.box((-length / 2 + (k + 0.5) * length / n, 0.295, 0.48), (length / n - 0.01, 0.01, 0.72), WOOD, body)
    t.box((0, 0.01, 0.88), (length + 0.02, 0.62, 0.04), WOOD, top)
    u = float(rng.uniform(-length / 2 + 0.4, length / 2 - 0.4))
    t.box((u, 0.05, 0.9), (0.5, 0.4, 0.01), METAL, (180, 182, 186))
    t.box((u, -0.22, 1.02), (0.03, 0.03, 0.26), METAL, (180, 182, 186))
    return t


# ---------------------------------------------------------------------------------------------------- chairs


def dining_chair(rng: np.random.Generator) -> Thing:
    t = Thing(C.CHAIR)
    s, seat, back = float(rng.uniform(0.4, 0.48)), float(rng.uniform(0.43, 0.47)), float(rng.uniform(0.35, 0.5))
    col = pick(rng, VENEERS)
    for sx in (-1, 1):
        for sy in (-1, 1):
            t.box((sx * (s / 2 - 0.025), sy * (s / 2 - 0.025), seat / 2), (0.035, 0.035, seat), WOOD, col)
    t.box((0, 0, seat), (s, s, 0.04), FABRIC if rng.random() < 0.5 else WOOD, pick(rng, UPHOLSTERY))
    for sx in (-1, 1):
        t.box((sx * (s / 2 - 0.025), -s / 2 + 0.02, seat + back / 2), (0.035, 0.035, back), WOOD, col)
    n = int(rng.integers(1, 4))
    for k in range(n):
        t.box((0, -s / 2 + 0.02, seat + back * (k + 1) / (n + 0.5)), (s - 0.05, 0.02, 0.06), WOOD, col)
    return t


def desk_chair(rng: np.random.Generator) -> Thing:
    """Five-star base on castors, a gas column, a seat and a back on a stem."""
    t = Thing(C.CHAIR)
    col = pick(rng, UPHOLSTERY)
    r = float(rng.uniform(0.28, 0.34))
    for k in range(5):
        a = 2 * np.pi * k / 5
        t.box((r / 2 * np.cos(a), r / 2 * np.sin(a), 0.07), (r, 0.05, 0.03), METAL, (30, 30, 32), rotation_z(a))
        t.box((r * np.cos(a), r * np.sin(a), 0.03), (0.05, 0.05, 0.06), METAL, (20, 20, 20))
    seat = float(rng.uniform(0.44, 0.52))
    t.box((0, 0, (seat + 0.08) / 2), (0.05, 0.05, seat - 0.08), METAL, (120, 120, 125))
    t.box((0, 0, seat), (0.48, 0.46, 0.08), FABRIC, col)
    t.box((0, -0.25, seat + 0.12), (0.05, 0.04, 0.22), METAL, (30, 30, 32))
    t.box((0, -0.26, seat + 0.42), (0.44, 0.06, float(rng.uniform(0.35, 0.55))), FABRIC, col)
    return t


def bar_stool(rng: np.random.Generator) -> Thing:
    t = Thing(C.CHAIR)
    h = float(rng.uniform(0.62, 0.78))
    col = pick(rng, UPHOLSTERY)
    for a in (0.0, np.pi / 4):
        t.box((0, 0, h), (0.36, 0.36, 0.05), FABRIC, col, rotation_z(a))
        t.box((0, 0, 0.015), (0.42, 0.42, 0.03), METAL, (60, 60, 62), rotation_z(a))
    t.box((0, 0, h / 2), (0.05, 0.05, h), METAL, (170, 170, 175))
    t.box((0, 0, h * 0.35), (0.3, 0.03, 0.02), METAL, (170, 170, 175))
    t.box((0, 0, h * 0.35), (0.03, 0.3, 0.02), METAL, (170, 170, 175))
    return t


# ---------------------------------------------------------------------------------------------------- sofas, beds


def sofa(rng: np.random.Generator, seats: int | None = None) -> Thing:
    """A sofa (2-3 seats) or, with one seat, an armchair: plinth or feet, cushions, back, arms."""
    t = Thing(C.SOFA)
    n = int(rng.integers(2, 4)) if seats is None else seats
    sw = float(rng.uniform(0.55, 0.7))
    arm, depth = float(rng.uniform(0.1, 0.22)), float(rng.uniform(0.8, 0.95))
    wx = n * sw + 2 * arm
    col = pick(rng, UPHOLSTERY)
    feet = rng.random() < 0.5
    base = 0.12 if feet else 0.0
    if feet:
        for sx in (-1, 1):
            for sy in (-1, 1):
                t.box((sx * (wx / 2 - 0.06), sy * (depth / 2 - 0.06), 0.06), (0.05, 0.05, 0.12), WOOD, (70, 50, 35))
    t.box((0, 0, base + 0.13), (wx, depth, 0.26), FABRIC, col)
    for k in range(n):
        t.box((-wx / 2 + arm + (k + 0.5) * sw, 0.08, base + 0.33), (sw - 0.02, depth - 0.2, 0.14), FABRIC, col)
    back_h = float(rng.uniform(0.4, 0.6))
    t.box((0, -depth / 2 + 0.1, base + 0.26 + back_h / 2), (wx, 0.2, back_h), FABRIC, col)
    arm_h = float(rng.uniform(0.2, 0.35))
    for sx in (-1, 1):
        t.box((sx * (wx / 2 - arm / 2), 0, base + 0.26 + arm_h / 2), (arm, depth, arm_h), FABRIC, col)
    return t


def bed(rng: np.random.Generator, double: bool) -> Thing:
    """Frame on legs, mattress, duvet, pillows and a headboard at the back (-y)."""
    t = Thing(C.SOFA)
    wx = float(rng.uniform(1.35, 1.8)) if double else float(rng.uniform(0.85, 1.0))
    ly = float(rng.uniform(1.95, 2.15))
    frame = pick(rng, VENEERS)
    h = float(rng.uniform(0.25, 0.35))
    t.box((0, 0, h - 0.08), (wx, ly, 0.16), WOOD, frame)
    for sx in (-1, 1):
        for sy in (-1, 1):
            t.box((sx * (wx / 2 - 0.05), sy * (ly / 2 - 0.05), (h - 0.16) / 2), (0.06, 0.06, h - 0.16), WOOD, frame)
    t.box((0, 0, h + 0.1), (wx - 0.04, ly - 0.04, 0.2), FABRIC, (235, 235, 232))
    t.box((0, 0.2, h + 0.23), (wx + 0.02, ly - 0.5, 0.06), FABRIC, pick(rng, LINEN))
    for k in range(2 if double else 1):
        px = (k - 0.5) * wx / 2 if double else 0.0
        t.box((px, -ly / 2 + 0.25, h + 0.26), (min(0.6, wx / 2 - 0.05) if double else 0.6, 0.35, 0.12), FABRIC,
              pick(rng, LINEN))  # fmt: skip
    hb = float(rng.uniform(0.9, 1.25))
    t.box((0, -ly / 2 - 0.04, hb / 2), (wx + 0.06, 0.07, hb), FABRIC if rng.random() < 0.5 else WOOD,
          pick(rng, UPHOLSTERY))  # fmt: skip
    return t


# ---------------------------------------------------------------------------------------------------- storage


def wardrobe(rng: np.random.Generator) -> Thing:
    """A tall carcass on a plinth, doors with handles and a cornice."""
    t = Thing(C.BOOKCASE)
    wx, dy, h = float(rng.uniform(0.8, 2.0)), float(rng.uniform(0.55, 0.62)), float(rng.uniform(1.9, 2.25))
    col = pick(rng, VENEERS)
    t.box((0, 0.0, 0.05), (wx - 0.04, dy - 0.06, 0.1), WOOD, (50, 45, 40))
    t.box((0, 0, 0.1 + (h - 0.14) / 2), (wx, dy, h - 0.14), WOOD, col)
    t.box((0, 0.01, h - 0.02), (wx + 0.04, dy + 0.04, 0.04), WOOD, col)
    n = max(round(wx / 0.5), 2)
    for k in range(n):
        u = -wx / 2 + (k + 0.5) * wx / n
        t.box((u, dy / 2 + 0.005, 0.1 + (h - 0.14) / 2), (wx / n - 0.008, 0.012, h - 0.16), WOOD, col)
        t.box((u + (0.18 if k % 2 == 0 else -0.18) * wx / n, dy / 2 + 0.025, 1.05), (0.02, 0.025, 0.25), METAL,
              (150, 150, 155))  # fmt: skip
    return t


def shelving(rng: np.random.Generator) -> Thing:
    """Open shelves between two sides with books (boxes of book colours) on some of them."""
    t = Thing(C.BOOKCASE)
    wx, dy, h = float(rng.uniform(0.6, 1.6)), float(rng.uniform(0.28, 0.4)), float(rng.uniform(0.9, 2.2))
    col = pick(rng, VENEERS)
    for sx in (-1, 1):
        t.box((sx * (wx / 2 - 0.01), 0, h / 2), (0.02, dy, h), WOOD, col)
    t.box((0, -dy / 2 + 0.005, h / 2), (wx, 0.01, h), WOOD, col)
    n = max(int(h / 0.35), 2)
    for k in range(n + 1):
        z = 0.04 + k * (h - 0.06) / n
        t.box((0, 0, z), (wx - 0.04, dy, 0.02), WOOD, col)
        if k < n and rng.random() < 0.7:
            fill = float(rng.uniform(0.3, 0.95)) * (wx - 0.06)
            bh = float(rng.uniform(0.18, 0.28))
            t.box((-wx / 2 + 0.03 + fill / 2, -0.01, z + 0.01 + bh / 2), (fill, dy - 0.06, bh), FABRIC,
                  pick(rng, UPHOLSTERY))  # fmt: skip
    return t


def shoe_cabinet(rng: np.random.Generator) -> Thing:
    t = Thing(C.BOOKCASE)
    wx, dy, h = float(rng.uniform(0.6, 1.1)), float(rng.uniform(0.25, 0.35)), float(rng.uniform(0.8, 1.1))
    col = pick(rng, VENEERS)
    t.box((0, 0, 0.03), (wx - 0.05, dy - 0.03, 0.06), WOOD, (40, 40, 40))
    t.box((0, 0, 0.06 + (h - 0.06) / 2), (wx, dy, h - 0.06), WOOD, col)
    for k in range(2):
        t.box((0, dy / 2 + 0.005, 0.06 + (k + 0.5) * (h - 0.06) / 2), (wx - 0.02, 0.01, (h - 0.06) / 2 - 0.01),
              WOOD, col)  # fmt: skip
    return t


def wall_units(rng: np.random.Generator, length: float) -> Thing:
    """Kitchen wall cupboards: hung at 1.45-1.55 m (place with z), 0.33 deep."""
    t = Thing(C.BOOKCASE)
    col, h = pick(rng, ((240, 240, 238), (200, 60, 50), (60, 70, 90), (150, 110, 75))), float(rng.uniform(0.6, 0.8))
    t.box((0, 0, h / 2), (length, 0.33, h), WOOD, col)
    n = max(int(length / 0.6), 1)
    for k in range(n):
        t.box((-length / 2 + (k + 0.5) * length / n, 0.17, h / 2), (length / n - 0.01, 0.012, h - 0.02), WOOD, col)
    return t


# ---------------------------------------------------------------------------------------------------- boards


def screen(rng: np.random.Generator) -> Thing:
    """A flat TV on the wall: a thin black slab (hung with z)."""
    t = Thing(C.BOARD)
    wx = float(rng.uniform(0.8, 1.5))
    t.box((0, 0, wx * 0.28), (wx, 0.05, wx * 0.56), METAL, (20, 20, 22))
    return t


def picture(rng: np.random.Generator) -> Thing:
    """A framed picture, a pin board or a whiteboard (hung with z)."""
    t = Thing(C.BOARD)
    wx, h = float(rng.uniform(0.4, 1.2)), float(rng.uniform(0.3, 0.9))
    kind = int(rng.integers(3))
    face = (
        (WOOD, (150, 120, 80))
        if kind == 1
        else (WHITEBOARD, (238, 240, 242))
        if kind == 2
        else (PLASTER, pick(rng, UPHOLSTERY))
    )
    t.box((0, 0, h / 2), (wx, 0.03, h), METAL if kind == 2 else WOOD, (40, 40, 40) if kind != 2 else (200, 200, 200))
    t.box((0, 0.01, h / 2), (wx - 0.06, 0.02, h - 0.06), face[0], face[1])
    return t


# ---------------------------------------------------------------------------------------------------- clutter


def appliance(rng: np.random.Generator, kind: str) -> Thing:
    """Fridge (tall), washing machine (a porthole), cooker (hob and oven door)."""
    t = Thing(C.CLUTTER)
    col = pick(rng, APPLIANCE)
    if kind == "fridge":
        h = float(rng.uniform(1.4, 1.9))
        t.box((0, 0, h / 2), (0.6, 0.62, h), METAL, col)
        t.box((0.22, 0.32, h * 0.6), (0.03, 0.03, 0.4), METAL, (120, 120, 125))
        t.box((0, 0.315, h * 0.38), (0.58, 0.01, 0.01), METAL, (90, 90, 90))
    elif kind == "washer":
        t.box((0, 0, 0.42), (0.6, 0.58, 0.84), METAL, col)
        for a in (0.0, np.pi / 4):
            t.box((0, 0.29, 0.4), (0.3, 0.02, 0.3), GLASS, (60, 60, 70), rotation_xyz(0.0, a, 0.0))
    else:
        t.box((0, 0, 0.45), (0.6, 0.6, 0.9), METAL, col)
        t.box((0, 0.305, 0.42), (0.5, 0.01, 0.45), GLASS, (30, 30, 30))
        t.box((0, 0.0, 0.905), (0.55, 0.55, 0.01), METAL, (30, 30, 32))
    return t


def clutter(rng: np.random.Generator) -> Thing:
    """A box or a stack of boxes, a bin, a floor lamp, a potted plant."""
    t = Thing(C.CLUTTER)
    k = int(rng.integers(4))
    if k == 0:
        z = 0.0
        for _ in range(int(rng.integers(1, 4))):
            s = (float(rng.uniform(0.25, 0.6)), float(rng.uniform(0.25, 0.5)), float(rng.uniform(0.15, 0.4)))
            t.box((float(rng.normal(0, 0.03)), float(rng.normal(0, 0.03)), z + s[2] / 2), s, WOOD, (175, 140, 95),
                  rotation_z(float(rng.normal(0, 0.2))))  # fmt: skip
            z += s[2]
    elif k == 1:
        h = float(rng.uniform(0.3, 0.7))
        for a in (0.0, np.pi / 4):
            t.box((0, 0, h / 2), (0.3, 0.3, h), METAL, pick(rng, APPLIANCE), rotation_z(a))
    elif k == 2:
        h = float(rng.uniform(1.4, 1.8))
        t.box((0, 0, 0.015), (0.3, 0.3, 0.03), METAL, (40, 40, 40))
        t.box((0, 0, h / 2), (0.025, 0.025, h), METAL, (160, 160, 160))
        for a in (0.0, np.pi / 4):
            t.box((0, 0, h), (0.35, 0.35, 0.25), FABRIC, pick(rng, LINEN), rotation_z(a))
    else:
        pot = float(rng.uniform(0.25, 0.45))
        t.box((0, 0, pot / 2), (pot, pot, pot), TILE, (160, 90, 60))
        top = pot + float(rng.uniform(0.3, 1.1))
        for _ in range(int(rng.integers(3, 7))):
            s = float(rng.uniform(0.2, 0.4))
            zz = float(rng.uniform(pot + s / 2, top))
            t.box((float(rng.normal(0, pot / 3)), float(rng.normal(0, pot / 3)), zz), (s, s, s * 0.8), FABRIC,
                  pick(rng, PLANT), rotation_xyz(*rng.uniform(-0.6, 0.6, 3)))  # fmt: skip
    return t


def radiator(rng: np.random.Generator, length: float) -> Thing:
    """A panel radiator with fins (hung with z ~ 0.12)."""
    t = Thing(C.CLUTTER)
    h = float(rng.uniform(0.45, 0.65))
    t.box((0, 0, h / 2), (length, 0.06, h), METAL, (236, 236, 232))
    for k in range(max(int(length / 0.15), 2)):
        t.box((-length / 2 + 0.06 + k * 0.15, 0.035, h / 2), (0.03, 0.02, h - 0.06), METAL, (230, 230, 226))
    return t


def sanitary(rng: np.random.Generator, kind: str) -> Thing:
    """A toilet (pan and cistern), a basin on a pedestal, or a bath tub."""
    t = Thing(C.CLUTTER)
    white = (245, 245, 243)
    if kind == "toilet":
        t.box((0, 0.12, 0.2), (0.36, 0.5, 0.4), TILE, white)
        t.box((0, -0.14, 0.55), (0.4, 0.18, 0.38), TILE, white)
        t.box((0, 0.1, 0.42), (0.38, 0.46, 0.03), TILE, white)
    elif kind == "basin":
        t.box((0, -0.05, 0.38), (0.18, 0.16, 0.76), TILE, white)
        t.box((0, 0.0, 0.8), (float(rng.uniform(0.45, 0.6)), 0.42, 0.14), TILE, white)
        t.box((0, -0.16, 0.93), (0.04, 0.08, 0.12), METAL, (180, 182, 186))
    else:
        ln = float(rng.uniform(1.5, 1.7))
        t.box((0, 0, 0.28), (ln, 0.72, 0.56), TILE, white)
        t.box((0, 0, 0.5), (ln - 0.16, 0.56, 0.1), TILE, (225, 230, 232))
    return t


# ---------------------------------------------------------------------------------------------------- doors, windows


def _axis(start: Point, end: Point) -> tuple[np.ndarray, np.ndarray]:
    d = np.array([end[0] - start[0], end[1] - start[1]], dtype=np.float64)
    d /= np.linalg.norm(d)
    return d, np.array([-d[1], d[0]])


def _at(start: Point, d: np.ndarray, u: float, n: np.ndarray, off: float) -> np.ndarray:
    return np.asarray(start) + d * u + n * off


def door(
    b: MeshBuilder,
    start: Point,
    end: Point,
    o: Opening,
    t: float,
    rng: np.random.Generator,
    *,
    style: str,
    angle_deg: float,
    side: float,
    color: Color,
    frame: Color,
    leaf: Material = WOOD,
    hinge: str | None = None,
) -> int:
    """A door in opening `o` of the axis-aligned wall start -> end (thickness t): linings and architraves, and a
    flush, panelled, double or sliding leaf. Hinged leaves open by `angle_deg` to the wall's left (`side` +1)
    or right (-1), hinged at the low (`hinge` "lo") or high jamb (random if None); 0 is shut. A sliding leaf
    runs on a track on the `side` face and is parked clear of the opening (from 85 degrees on) or covers the
    share 1 - angle_deg / 90 of it."""
    inst = b.new_instance(C.DOOR)
    d, n = _axis(start, end)
    yaw = float(np.arctan2(d[1], d[0]))
    rw = rotation_z(yaw)
    h, lin, arch = o.z1, 0.025, 0.07
    for u in (o.u0 + lin / 2, o.u1 - lin / 2):  # linings in the jambs and the head, architraves on both faces
        c = _at(start, d, u, n, 0.0)
        b.add_box((c[0], c[1], h / 2), (lin, t + 0.02, h), cls=C.DOOR, instance=inst, material=WOOD, color=frame,
                  rotation=rw)  # fmt: skip
        for s in (-1, 1):
            c2 = _at(start, d, u + (-1 if u < (o.u0 + o.u1) / 2 else 1) * (arch / 2 - lin / 2), n, s * (t / 2 + 0.01))
            b.add_box((c2[0], c2[1], (h + arch) / 2), (arch, 0.02, h + arch), cls=C.DOOR, instance=inst,
                      material=WOOD, color=frame, rotation=rw)  # fmt: skip
    c = _at(start, d, (o.u0 + o.u1) / 2, n, 0.0)
    b.add_box((c[0], c[1], h - lin / 2), (o.u1 - o.u0, t + 0.02, lin), cls=C.DOOR, instance=inst, material=WOOD,
              color=frame, rotation=rw)  # fmt: skip
    for s in (-1, 1):
        c2 = _at(start, d, (o.u0 + o.u1) / 2, n, s * (t / 2 + 0.01))
        b.add_box((c2[0], c2[1], h + arch / 2), (o.u1 - o.u0 + 2 * arch, 0.02, arch), cls=C.DOOR, instance=inst,
                  material=WOOD, color=frame, rotation=rw)  # fmt: skip
    clear = o.u1 - o.u0 - 2 * lin
    lh, lt = h - lin - 0.01, 0.04
    if style == "sliding":
        share = 1.0 if angle_deg >= 85.0 else min(max(angle_deg / 90.0, 0.0), 1.0)
        off = side * (t / 2 + 0.04)
        c = _at(start, d, o.u0 + lin + clear / 2 + share * (clear + 0.03), n, off)
        b.add_box((c[0], c[1], lh / 2 + 0.005), (clear + 0.05, lt, lh), cls=C.DOOR, instance=inst, material=leaf,
                  color=color, rotation=rw)  # fmt: skip
        c = _at(start, d, o.u0 + lin + clear, n, off)
        b.add_box((c[0], c[1], h + 0.05), (2 * clear + 0.2, 0.06, 0.06), cls=C.DOOR, instance=inst, material=METAL,
                  color=(150, 150, 150), rotation=rw)  # fmt: skip
        return inst
    hinges = [(o.u0 + lin, 1.0, clear / 2), (o.u1 - lin, -1.0, clear / 2)] if style == "double" else []
    if not hinges:
        left = rng.random() < 0.5 if hinge is None else hinge == "lo"
        hinges = [(o.u0 + lin, 1.0, clear) if left else (o.u1 - lin, -1.0, clear)]
    a = np.deg2rad(angle_deg)
    for u, sgn, width in hinges:
        face = side * (t / 2 - lt / 2) if angle_deg > 1 else 0.0
        hinge = _at(start, d, u, n, face)
        along = sgn * d * np.cos(a) + side * n * np.sin(a)
        across = np.array([-along[1], along[0]])
        lyaw = float(np.arctan2(along[1], along[0]))
        rl = rotation_z(lyaw)
        mid = hinge + along * (width / 2 - 0.003) - across * 0.0
        b.add_box((mid[0], mid[1], lh / 2 + 0.005), (width - 0.006, lt, lh), cls=C.DOOR, instance=inst,
                  material=leaf, color=color, rotation=rl)  # fmt: skip
        if style == "panelled":  # raised panels on both faces
            for zc, zh in ((lh * 0.27, lh * 0.38), (lh * 0.72, lh * 0.38)):
                for s in (-1, 1):
                    p = mid + across * s * (lt / 2 + 0.006)
                    b.add_box((p[0], p[1], zc), (width * 0.62, 0.012, zh), cls=C.DOOR, instance=inst, material=WOOD,
                              color=tuple(int(v * 0.92) for v in color), rotation=rl)  # fmt: skip
        knob = hinge + along * (width - 0.07)
        for s in (-1, 1):
            p = knob + across * s * (lt / 2 + 0.03)
            b.add_box((p[0], p[1], 1.02), (0.12, 0.025, 0.025), cls=C.DOOR, instance=inst, material=METAL,
                      color=(170, 170, 175), rotation=rl)  # fmt: skip
    return inst


def window(
    b: MeshBuilder,
    start: Point,
    end: Point,
    o: Opening,
    t: float,
    rng: np.random.Generator,
    *,
    inside: float,
    frame: Color,
    sill: Color,
) -> int:
    """Glazing in an outer-wall opening: frame, mullions every 0.6-1.2 m, sometimes a transom, a pane, an inner
    sill board (not for a full-height balcony door, which gets a threshold) and an outer drip sill; all
    WINDOW. `inside` is +1 if the building is to the wall's left."""
    inst = b.new_instance(C.WINDOW)
    d, n = _axis(start, end)
    rw = rotation_z(float(np.arctan2(d[1], d[0])))
    fw, fd = 0.06, 0.08
    w, hgt = o.u1 - o.u0, o.z1 - o.z0

    def bar(u: float, z: float, su: float, sz: float, off: float = 0.0, sd: float = fd, mat: Material = METAL,
            col: Color = frame) -> None:  # fmt: skip
        c = _at(start, d, u, n, off)
        b.add_box((c[0], c[1], z), (su, sd, sz), cls=C.WINDOW, instance=inst, material=mat, color=col, rotation=rw)

    um, zm = (o.u0 + o.u1) / 2, (o.z0 + o.z1) / 2
    bar(o.u0 + fw / 2, zm, fw, hgt)
    bar(o.u1 - fw / 2, zm, fw, hgt)
    bar(um, o.z1 - fw / 2, w, fw)
    bar(um, o.z0 + fw / 2, w, fw)
    panes = max(round(w / float(rng.uniform(0.6, 1.2))), 1)
    for k in range(1, panes):
        bar(o.u0 + k * w / panes, zm, 0.05, hgt)
    if hgt > 1.3 and rng.random() < 0.5:
        bar(um, o.z1 - float(rng.uniform(0.35, 0.5)), w, 0.05)
    if o.z0 < 0.05:
        bar(um, 1.0, w, 0.08)  # the rail of a balcony door
    bar(um, zm, w - 2 * fw, hgt - 2 * fw, 0.0, 0.012, GLASS, (130, 170, 190))
    if o.z0 > 0.05:
        bar(um, o.z0 - 0.015, w + 0.1, 0.03, inside * (t / 2 - 0.05 + 0.03), t / 2 + 0.06, WOOD, sill)
    bar(um, o.z0 - 0.02, w + 0.06, 0.04, -inside * (t / 2 + 0.02), 0.08, METAL, (150, 150, 150))
    return inst


# ---------------------------------------------------------------------------------------------------- damage


def block_pile(b: MeshBuilder, rng: np.random.Generator, cx: float, cy: float, rx: float, ry: float,
               color: Color) -> int:  # fmt: skip
    """A heap of broken blocks and plaster, highest in the middle (DEBRIS)."""
    inst = b.new_instance(C.DEBRIS)
    n = int(rng.integers(12, 30))
    u = rng.uniform(-1, 1, (n, 2))
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1.0)
    r = np.hypot(u[:, 0], u[:, 1])
    for k in range(n):
        s = (float(rng.uniform(0.12, 0.45)), float(rng.uniform(0.08, 0.25)), float(rng.uniform(0.05, 0.14)))
        z = float((1 - r[k]) * rng.uniform(0.05, 0.45)) + s[2] / 2
        col = color if rng.random() < 0.5 else (150, 145, 135)
        b.add_box((cx + u[k, 0] * rx, cy + u[k, 1] * ry, z), s, cls=C.DEBRIS, instance=inst,
                  material=RUBBLE if rng.random() < 0.6 else PLASTER, color=col,
                  rotation=rotation_xyz(*rng.uniform(-0.5, 0.5, 2), float(rng.uniform(-np.pi, np.pi))))  # fmt: skip
    return inst


def fallen_plaster(b: MeshBuilder, rng: np.random.Generator, rect: Rect, n: int, color: Color) -> int:
    """Slabs of ceiling plaster lying on the floor, one edge propped up now and then (low: drivable over)."""
    inst = b.new_instance(C.DEBRIS)
    x0, y0, x1, y1 = rect
    for _ in range(n):
        sx, sy = float(rng.uniform(0.3, 1.1)), float(rng.uniform(0.25, 0.8))
        tilt = float(rng.uniform(0, 0.06 / sx)) if rng.random() < 0.5 else 0.0  # a propped edge stays under 0.1 m
        b.add_box((float(rng.uniform(x0 + 0.3, x1 - 0.3)), float(rng.uniform(y0 + 0.3, y1 - 0.3)),
                   0.015 + tilt * sx / 2), (sx, sy, 0.025), cls=C.DEBRIS, instance=inst, material=PLASTER,
                  color=color, rotation=rotation_xyz(tilt, 0.0, float(rng.uniform(-np.pi, np.pi))))  # fmt: skip
    return inst


def sagging_ceiling(b: MeshBuilder, rng: np.random.Generator, rect: Rect, hc: float, color: Color) -> int:
    """A piece of ceiling torn loose along three sides, hanging from the fourth (CEILING, its own instance):
    its low edge stays above 1.9 m. A dark patch above shows the bare slab."""
    inst = b.new_instance(C.CEILING)
    x0, y0, x1, y1 = rect
    lx, ly = float(rng.uniform(0.8, min(1.6, x1 - x0 - 0.4))), float(rng.uniform(0.6, min(1.2, y1 - y0 - 0.4)))
    cx = float(rng.uniform(x0 + lx / 2 + 0.2, x1 - lx / 2 - 0.2))
    cy = float(rng.uniform(y0 + ly / 2 + 0.2, y1 - ly / 2 - 0.2))
    drop = min(float(rng.uniform(0.2, 0.7)), hc - 1.95)
    ang = float(np.arcsin(min(drop / ly, 0.9)))
    sgn = float(rng.choice([-1.0, 1.0]))
    hinge_y = cy - sgn * ly / 2
    b.add_box((cx, cy, hc - 0.004), (lx, ly, 0.006), cls=C.CEILING, instance=inst, material=CONCRETE,
              color=(110, 108, 104))  # fmt: skip
    mid = (cx, hinge_y + sgn * np.cos(ang) * ly / 2, hc - 0.02 - np.sin(ang) * ly / 2)
    b.add_box(mid, (lx, ly, 0.02), cls=C.CEILING, instance=inst, material=PLASTER, color=color,
              rotation=rotation_xyz(-sgn * ang, 0.0, 0.0))  # fmt: skip
    return inst


def grit(b: MeshBuilder, rng: np.random.Generator, rect: Rect, n: int, color: Color) -> int:
    """Small chunks strewn on the floor (under 0.1 m: a robot drives over them)."""
    inst = b.new_instance(C.DEBRIS)
    x0, y0, x1, y1 = rect
    xy = np.c_[rng.uniform(x0 + 0.1, x1 - 0.1, n), rng.uniform(y0 + 0.1, y1 - 0.1, n)]
    for k in range(n):
        s = rng.uniform(0.03, 0.12, 3) * np.array([1.0, 1.0, 0.6])
        b.add_box((xy[k, 0], xy[k, 1], s[2] / 2), s, cls=C.DEBRIS, instance=inst, material=RUBBLE, color=color,
                  rotation=rotation_z(float(rng.uniform(-np.pi, np.pi))))  # fmt: skip
    return inst


def overturned(thing: Thing, rng: np.random.Generator, yaw: float) -> np.ndarray:
    """The rotation of a thing fallen on its face or side (to place with `try_place`)."""
    fall = float(rng.choice([np.pi / 2, -np.pi / 2]))
    return rotation_z(yaw) @ (rotation_xyz(fall, 0.0, 0.0) if rng.random() < 0.6 else rotation_xyz(0.0, fall, 0.0))
