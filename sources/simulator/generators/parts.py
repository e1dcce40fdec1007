"""Building blocks of the independent scene generators (`hall`, `wing`): slabs, walls cut by openings, doors,
glazing and mirrors, a footprint book-keeper for furniture, and the finished `Scene` with its truth. `flats`
takes only the walls, slabs, openings, footprints and `finish` from here (its doors and glazing are its own).

None of this goes through the families' plan (`layout.py`, `building.py`): the generators draw their
shapes themselves, so that a network trained on one cannot learn the other's habits.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.damage import LevelMotion
from aftershock.sources.simulator.furniture import Piece, place, pose
from aftershock.sources.simulator.meshes import GLASS, METAL, MIRROR, Material, MeshBuilder, rotation_z
from aftershock.sources.simulator.raycast import Raycaster
from aftershock.sources.simulator.scene import Room, Scene, SceneTruth, StoryTruth, plane_of

Color = tuple[int, int, int]
Rect = tuple[float, float, float, float]  # x0, y0, x1, y1

SLAB_M: Final = 0.25


@dataclass(slots=True)
class Opening:
    """A hole in a wall: from u0 to u1 along it, from z0 to z1 above its foot (relative)."""

    u0: float
    u1: float
    z0: float
    z1: float


def wall(
    b: MeshBuilder,
    start: tuple[float, float],
    end: tuple[float, float],
    z0: float,
    z1: float,
    thickness: float,
    openings: list[Opening],
    *,
    instance: int,
    color: Color,
    material: Material,
    story: int = 0,
    cls: C = C.WALL,
) -> None:
    """An axis-aligned wall from `start` to `end`, minus its openings: cut into vertical strips at every
    opening edge, each strip keeping what no opening covers."""
    (xa, ya), (xb, yb) = start, end
    along_x = abs(yb - ya) < 1e-9
    length = abs(xb - xa) + abs(yb - ya)
    sign = np.sign((xb - xa) + (yb - ya)) or 1.0
    cuts = sorted(
        {0.0, length, *(min(max(o.u0, 0.0), length) for o in openings)}
        | {min(max(o.u1, 0.0), length) for o in openings}
    )
    h = z1 - z0
    for ua, ub in itertools.pairwise(cuts):
        if ub - ua < 1e-3:
            continue
        gaps = sorted((o.z0, o.z1) for o in openings if o.u0 <= ua + 1e-9 and o.u1 >= ub - 1e-9)
        lo = 0.0
        spans = []
        for g0, g1 in gaps:
            if g0 > lo:
                spans.append((lo, g0))
            lo = max(lo, g1)
        if lo < h:
            spans.append((lo, h))
        um = (ua + ub) / 2 * sign
        cx, cy = (xa + um, ya) if along_x else (xa, ya + um)
        for s0, s1 in spans:
            if s1 - s0 < 1e-3:
                continue
            size = (ub - ua, thickness, s1 - s0) if along_x else (thickness, ub - ua, s1 - s0)
            b.add_box(
                (cx, cy, z0 + (s0 + s1) / 2),
                size,
                cls=cls,
                instance=instance,
                material=material,
                color=color,
                story=story,
                span=True,
                jitter_color=0.0,
            )


def wall_point(start: tuple[float, float], end: tuple[float, float], u: float) -> tuple[float, float]:
    (xa, ya), (xb, yb) = start, end
    length = abs(xb - xa) + abs(yb - ya)
    f = u / length
    return (xa + f * (xb - xa), ya + f * (yb - ya))


def slab(
    b: MeshBuilder,
    rect: Rect,
    top: float,
    *,
    floor: int,
    ceiling: int,
    floor_color: Color,
    ceiling_color: Color,
    floor_material: Material,
    ceiling_material: Material,
    thickness: float = SLAB_M,
    story: int = 0,
) -> None:
    """A slab: its upper half is the floor above (instance `floor`), its lower half the ceiling below (`ceiling`,
    0 for none)."""
    x0, y0, x1, y1 = rect
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    if floor:
        b.add_box(
            (cx, cy, top - thickness / 4),
            (x1 - x0, y1 - y0, thickness / 2),
            cls=C.FLOOR,
            instance=floor,
            material=floor_material,
            color=floor_color,
            story=story,
        )
    if ceiling:
        b.add_box(
            (cx, cy, top - 3 * thickness / 4),
            (x1 - x0, y1 - y0, thickness / 2),
            cls=C.CEILING,
            instance=ceiling,
            material=ceiling_material,
            color=ceiling_color,
            story=story,
        )


def door_leaf(
    b: MeshBuilder,
    start: tuple[float, float],
    end: tuple[float, float],
    o: Opening,
    z0: float,
    thickness: float,
    rng: np.random.Generator,
    *,
    color: Color,
    material: Material,
    frame_color: Color,
    story: int = 0,
    swing: float | None = None,
) -> int:
    """A door in opening `o`: a thin frame and one leaf swung open by 65-110 degrees, to the left of the wall's
    direction (`swing` +1), to its right (-1) or either way (None)."""
    inst = b.new_instance(C.DOOR)
    (xa, ya), (xb, yb) = start, end
    along_x = abs(yb - ya) < 1e-9
    f = 0.04
    for uu, su, zc, sz in ((o.u0 + f / 2, f, o.z1 / 2, o.z1), (o.u1 - f / 2, f, o.z1 / 2, o.z1)):
        x, y = wall_point(start, end, uu)
        size = (su, thickness + 0.03, sz) if along_x else (thickness + 0.03, su, sz)
        b.add_box((x, y, z0 + zc), size, cls=C.DOOR, instance=inst, material=METAL, color=frame_color, story=story)
    leaf_w = o.u1 - o.u0 - 2 * f
    hx, hy = wall_point(start, end, o.u0 + f)
    base = np.arctan2(yb - ya, xb - xa)
    ang = base + np.deg2rad(rng.uniform(65, 110)) * (rng.choice([-1, 1]) if swing is None else swing)
    rot = rotation_z(ang)
    center = np.array([hx, hy, z0 + (o.z1 - 0.02) / 2]) + rot @ np.array([leaf_w / 2, 0.0, 0.0])
    b.add_box(
        center, (leaf_w, 0.045, o.z1 - 0.03), cls=C.DOOR, instance=inst, material=material, color=color,
        story=story, rotation=rot,
    )  # fmt: skip
    return inst


def glazing(
    b: MeshBuilder,
    start: tuple[float, float],
    end: tuple[float, float],
    o: Opening,
    z0: float,
    *,
    frame_color: Color,
    mullions: float,
    story: int = 0,
    glass: bool = True,
) -> int:
    """Glass in an opening (a window, or a glass partition), with mullions every `mullions` metres."""
    inst = b.new_instance(C.WINDOW)
    (_xa, ya), (_xb, yb) = start, end
    along_x = abs(yb - ya) < 1e-9
    n = max(round((o.u1 - o.u0) / mullions), 1)
    for u in np.linspace(o.u0, o.u1, n + 1):
        x, y = wall_point(start, end, float(u))
        size = (0.05, 0.07, o.z1 - o.z0) if along_x else (0.07, 0.05, o.z1 - o.z0)
        b.add_box((x, y, z0 + (o.z0 + o.z1) / 2), size, cls=C.WINDOW, instance=inst, material=METAL,
                  color=frame_color, story=story)  # fmt: skip
    for zz in (o.z0 + 0.025, o.z1 - 0.025):
        x, y = wall_point(start, end, (o.u0 + o.u1) / 2)
        size = (o.u1 - o.u0, 0.07, 0.05) if along_x else (0.07, o.u1 - o.u0, 0.05)
        b.add_box((x, y, z0 + zz), size, cls=C.WINDOW, instance=inst, material=METAL, color=frame_color, story=story)
    if glass:
        x, y = wall_point(start, end, (o.u0 + o.u1) / 2)
        size = (o.u1 - o.u0, 0.012, o.z1 - o.z0) if along_x else (0.012, o.u1 - o.u0, o.z1 - o.z0)
        b.add_box((x, y, z0 + (o.z0 + o.z1) / 2), size, cls=C.WINDOW, instance=inst, material=GLASS, story=story)
    return inst


def mirror(
    b: MeshBuilder, center: tuple[float, float, float], width: float, height: float, yaw: float, story: int = 0
) -> int:
    """A mirror hung flat on a wall (a board to the class table; to the laser a surface that folds the beam)."""
    inst = b.new_instance(C.BOARD)
    b.add_box(center, (width, 0.01, height), cls=C.BOARD, instance=inst, material=MIRROR, story=story,
              rotation=rotation_z(yaw), jitter_color=0.0)  # fmt: skip
    return inst


@dataclass(slots=True)
class Footprints:
    """Floor rectangles already taken; a piece goes where it fits inside its room and clear of the others."""

    taken: list[Rect] = field(default_factory=list)

    def fits(self, r: Rect, room: Rect, margin: float = 0.05) -> bool:
        x0, y0, x1, y1 = r
        if x0 < room[0] + margin or y0 < room[1] + margin or x1 > room[2] - margin or y1 > room[3] - margin:
            return False
        return all(x1 <= a or x0 >= c or y1 <= bb or y0 >= d for a, bb, c, d in self.taken)

    def take(self, r: Rect) -> None:
        self.taken.append(r)


def footprint(piece: Piece, x: float, y: float, yaw: float, pad: float = 0.0) -> Rect:
    hx, hy = piece.half_extent
    c, s = abs(np.cos(yaw)), abs(np.sin(yaw))
    ex, ey = hx * c + hy * s + pad, hx * s + hy * c + pad
    return (x - ex, y - ey, x + ex, y + ey)


def put(
    b: MeshBuilder,
    taken: Footprints,
    room: Rect,
    piece: Piece,
    x: float,
    y: float,
    yaw: float,
    *,
    z: float = 0.0,
    pad: float = 0.05,
    rotation: np.ndarray | None = None,
    lift: float = 0.0,
) -> bool:
    """Place a piece if its padded footprint is free; `rotation` (if given) replaces the upright yaw pose,
    `lift` raises it (a toppled piece lies on its side)."""
    fp = footprint(piece, x, y, yaw, pad)
    if not taken.fits(fp, room):
        return False
    rot = rotation_z(yaw) if rotation is None else rotation
    place(b, piece, pose(x, y, z + lift, rot), story=0)
    taken.take(fp)
    return True


def against_wall(
    b: MeshBuilder,
    taken: Footprints,
    room: Rect,
    piece: Piece,
    rng: np.random.Generator,
    tries: int = 12,
    sides: tuple[int, ...] = (0, 1, 2, 3),
) -> bool:
    """A piece with its back to one of the room's walls (the piece's -y side); sides 0-3 are south, north,
    west, east."""
    hx, hy = piece.half_extent
    for _ in range(tries):
        side = sides[int(rng.integers(len(sides)))]
        x0, y0, x1, y1 = room
        if (x1 - x0 if side < 2 else y1 - y0) < 2 * hx + 0.2:
            continue
        if side == 0:
            x, y, yaw = rng.uniform(x0 + hx + 0.1, x1 - hx - 0.1), y0 + hy + 0.08, 0.0
        elif side == 1:
            x, y, yaw = rng.uniform(x0 + hx + 0.1, x1 - hx - 0.1), y1 - hy - 0.08, np.pi
        elif side == 2:
            x, y, yaw = x0 + hy + 0.08, rng.uniform(y0 + hx + 0.1, y1 - hx - 0.1), -np.pi / 2
        else:
            x, y, yaw = x1 - hy - 0.08, rng.uniform(y0 + hx + 0.1, y1 - hx - 0.1), np.pi / 2
        if put(b, taken, room, piece, float(x), float(y), float(yaw), pad=0.0):
            return True
    return False


def finish(
    name: str,
    seed: int,
    b: MeshBuilder,
    footprint_m: tuple[float, float],
    floor_z: float,
    ceiling_z: float,
    rooms: list[Room],
    floor_instance: int,
    ceiling_instance: int,
    r_look: np.random.Generator,
) -> Scene:
    """The one-story scene with its truth (an undamaged frame: no drift, no tilt, no cracks)."""
    mesh, _, _ = b.build()
    cx, cy = footprint_m[0] / 2, footprint_m[1] / 2
    levels = tuple(
        LevelMotion(j, z, 0.0, 0.0, 0.0, 0.0, (cx, cy, z)) for j, z in enumerate((floor_z, ceiling_z + SLAB_M))
    )
    story = StoryTruth(
        index=0,
        floor_z_m=floor_z,
        ceiling_z_m=ceiling_z,
        drift_x_mm=0.0,
        drift_y_mm=0.0,
        tilt_x_deg=0.0,
        tilt_y_deg=0.0,
        inter_story_drift_x_mm=0.0,
        inter_story_drift_y_mm=0.0,
        floor_plane=plane_of(np.eye(4), floor_z),
        ceiling_plane=plane_of(np.eye(4), ceiling_z),
        floor_instance_id=floor_instance,
        ceiling_instance_id=ceiling_instance,
    )
    truth = SceneTruth(
        family=name,
        seed=int(seed),
        footprint_m=footprint_m,
        stories=(story,),
        levels=levels,
        cracks=(),
        instance_classes=dict(b.instance_class),
    )
    waves = np.c_[
        r_look.normal(0, 1, (4, 3)) * np.array([[7.0], [3.0], [1.0], [18.0]]), r_look.uniform(0, 2 * np.pi, 4)
    ]
    return Scene(
        family=name,
        seed=int(seed),
        mesh=mesh,
        truth=truth,
        rooms=tuple(rooms),
        floor_z=(floor_z,),
        ceiling_z=(ceiling_z,),
        light=float(r_look.uniform(0.7, 1.2)),
        _waves=waves,
        _raycaster=Raycaster(mesh),
    )
