"""`hall`: one tall open space (warehouse, gym, workshop, atrium) on a grid of round or steel columns, often
with a mezzanine along one side (a deck on its own columns, a parapet, stairs up), clerestory glazing,
roller doors, a glass site office or a mirror wall; racks in rows, workbenches with stools, benches along
the walls, crates, drums and pallets; sometimes damaged (fallen roof sheets, a beam down, racks toppled).
"""

from __future__ import annotations

from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.furniture import place, pose
from aftershock.sources.simulator.generators import things
from aftershock.sources.simulator.generators.parts import (
    Footprints,
    Opening,
    Rect,
    against_wall,
    door_leaf,
    finish,
    glazing,
    mirror,
    put,
    slab,
    wall,
)
from aftershock.sources.simulator.generators.wreck import fallen_beam, fallen_panels, rubble_strip, toppled
from aftershock.sources.simulator.meshes import CONCRETE, METAL, PLASTER, TILE, WOOD, MeshBuilder, rotation_z
from aftershock.sources.simulator.scene import Room, Scene

NAME: Final = "hall"
WALL_M: Final = 0.3
WALLS: Final = ((205, 200, 190), (150, 155, 160), (190, 170, 140), (225, 225, 225), (120, 130, 120))
FLOORS: Final = ((120, 120, 118), (170, 120, 70), (70, 110, 80), (150, 60, 50), (200, 195, 185))
ROOFS: Final = ((210, 210, 205), (160, 165, 170), (90, 95, 100))
STEEL: Final = ((60, 80, 120), (200, 90, 40), (110, 110, 115), (220, 200, 60))


def build(seed: int) -> Scene:
    root = np.random.SeedSequence([int(seed), sum(map(ord, NAME)), 1])
    r_plan, r_furn, r_damage, r_look, r_struct = (np.random.default_rng(s) for s in root.spawn(5))
    b = MeshBuilder(r_struct)
    w, d = round(float(r_plan.uniform(16, 28)), 2), round(float(r_plan.uniform(11, 18)), 2)
    height = round(float(r_plan.uniform(4.5, 7.0)), 2)
    wall_col = WALLS[int(r_plan.integers(len(WALLS)))]
    steel_col = STEEL[int(r_plan.integers(len(STEEL)))]
    floor_inst, roof_inst = b.new_instance(C.FLOOR), b.new_instance(C.CEILING)
    slab(b, (0, 0, w, d), 0.0, floor=floor_inst, ceiling=0, floor_color=FLOORS[int(r_plan.integers(len(FLOORS)))],
         ceiling_color=(0, 0, 0), floor_material=TILE, ceiling_material=CONCRETE)  # fmt: skip
    roof_col = ROOFS[int(r_plan.integers(len(ROOFS)))]
    slab(b, (0, 0, w, d), height + 0.25, floor=0, ceiling=roof_inst, floor_color=(0, 0, 0), ceiling_color=roof_col,
         floor_material=CONCRETE, ceiling_material=METAL)  # fmt: skip
    # Columns on a grid; steel I-sections or round concrete, and steel roof beams along the column lines.
    nx, ny = max(round(w / r_plan.uniform(5.5, 8.0)), 2), max(round(d / r_plan.uniform(5.5, 8.0)), 2)
    xs, ys = np.linspace(0, w, nx + 1)[1:-1], np.linspace(0, d, ny + 1)[1:-1]
    steel = r_plan.random() < 0.5
    cols: list[Rect] = []
    for x in xs:
        for y in ys:
            _column(b, float(x), float(y), 0.0, height, steel, steel_col if steel else wall_col)
            cols.append((x - 0.45, y - 0.45, x + 0.45, y + 0.45))
    beam_d = float(r_plan.uniform(0.4, 0.8))
    for x in xs:
        b.add_box((x, d / 2, height - beam_d / 2), (0.25, d, beam_d), cls=C.BEAM, instance=b.new_instance(C.BEAM),
                  material=METAL, color=steel_col)  # fmt: skip
    # Outer walls: clerestory glazing high up, roller doors and a personnel door at floor level.
    taken = Footprints(list(cols))
    sides = (((0, 0), (w, 0)), ((w, d), (0, d)), ((0, d), (0, 0)), ((w, 0), (w, d)))
    for i, (a, c) in enumerate(sides):
        length = w if i < 2 else d
        ops: list[Opening] = []
        band = (height - float(r_plan.uniform(1.2, 2.0)), height - 0.4)
        for u in np.arange(1.0, length - 2.0, float(r_plan.uniform(3.0, 5.0))):
            ops.append(Opening(float(u), float(u) + 2.0, band[0] - 0.0, band[1]))
        doors = []
        if i < 2 and r_plan.random() < 0.8:
            u = float(r_plan.uniform(2.0, length - 6.0))
            doors.append(Opening(u, u + float(r_plan.uniform(3.0, 4.0)), 0.0, float(r_plan.uniform(3.0, 3.8))))
        if r_plan.random() < 0.6:
            u = float(r_plan.uniform(1.0, length - 2.5))
            if all(u + 1.2 < o.u0 or u > o.u1 for o in doors):
                doors.append(Opening(u, u + 1.0, 0.0, 2.1))
        inst = b.new_instance(C.WALL)
        wall(b, a, c, 0.0, height, WALL_M, ops + doors, instance=inst, color=wall_col, material=CONCRETE)
        frame = (225, 225, 225) if r_plan.random() < 0.5 else (60, 60, 65)
        for o in ops:
            glazing(b, a, c, o, 0.0, frame_color=frame, mullions=1.0)
        for o in doors:
            if o.u1 - o.u0 > 2.0:  # a roller door, shut: a ribbed steel curtain in the opening
                _roller_door(b, a, c, o, steel_col)
            else:
                door_leaf(b, a, c, o, 0.0, WALL_M, r_plan, color=steel_col, material=METAL, frame_color=(80, 80, 80))
        # keep the inside of doors clear
        for o in doors:
            taken.take(_inside_of(a, c, o, 1.6))
    rooms = [Room(0, WALL_M / 2, WALL_M / 2, w - WALL_M / 2, d - WALL_M / 2, "open")]
    inner: Rect = (WALL_M / 2 + 0.02, WALL_M / 2 + 0.02, w - WALL_M / 2 - 0.02, d - WALL_M / 2 - 0.02)
    if r_plan.random() < 0.7:
        _mezzanine(b, r_plan, taken, w, d, height, wall_col, steel_col, roof_col)
    if r_plan.random() < 0.5:
        _site_office(b, r_plan, taken, inner, wall_col)
    if r_plan.random() < 0.5:  # a gym's mirror wall along the west side
        y0 = float(r_plan.uniform(1.0, d / 3))
        for k in range(int(r_plan.integers(2, 5))):
            mirror(b, (WALL_M / 2 + 0.01, y0 + 1.0 + k * 1.05, 1.25), 1.0, 1.9, np.pi / 2)
        taken.take((0.0, y0, 1.2, y0 + 1.0 + 4 * 1.05))
    _contents(b, r_furn, taken, inner, w, d)
    if r_damage.random() < 0.5:
        fallen_panels(b, r_damage, inner, int(r_damage.integers(2, 7)), roof_col)
        if r_damage.random() < 0.6:
            fallen_beam(b, r_damage, inner, height, steel_col)
        for _ in range(int(r_damage.integers(1, 4))):
            rubble_strip(b, r_damage, inner, wall_col)
        for _ in range(int(r_damage.integers(0, 3))):
            toppled(b, taken, inner, things.rack(r_damage), r_damage)
    return finish(NAME, seed, b, (w, d), 0.0, height, rooms, floor_inst, roof_inst, r_look)


def _column(b: MeshBuilder, x: float, y: float, z0: float, z1: float, steel: bool, color: tuple[int, int, int]) -> int:
    inst = b.new_instance(C.COLUMN)
    h = z1 - z0
    if steel:  # I-section: two flanges and a web
        for dy in (-0.14, 0.14):
            b.add_box((x, y + dy, z0 + h / 2), (0.3, 0.025, h), cls=C.COLUMN, instance=inst, material=METAL,
                      color=color, span=True)  # fmt: skip
        b.add_box(
            (x, y, z0 + h / 2), (0.02, 0.28, h), cls=C.COLUMN, instance=inst, material=METAL, color=color, span=True
        )
    else:  # round concrete: an octagon of two square boxes
        dia = 0.5
        for yaw in (0.0, np.pi / 4):
            b.add_box((x, y, z0 + h / 2), (dia * 0.83, dia * 0.83, h), cls=C.COLUMN, instance=inst, material=CONCRETE,
                      color=color, span=True, rotation=rotation_z(yaw))  # fmt: skip
    return inst


def _roller_door(b: MeshBuilder, a: tuple, c: tuple, o: Opening, color: tuple[int, int, int]) -> None:
    from aftershock.sources.simulator.generators.parts import wall_point

    inst = b.new_instance(C.DOOR)
    along_x = abs(c[1] - a[1]) < 1e-9
    x, y = wall_point(a, c, (o.u0 + o.u1) / 2)
    for z in np.arange(o.z0, o.z1 - 0.1, 0.1):
        size = (o.u1 - o.u0, 0.05, 0.09) if along_x else (0.05, o.u1 - o.u0, 0.09)
        b.add_box((x, y, z + 0.05), size, cls=C.DOOR, instance=inst, material=METAL, color=color, jitter_color=0.0)


def _inside_of(a: tuple, c: tuple, o: Opening, depth: float) -> Rect:
    from aftershock.sources.simulator.generators.parts import wall_point

    p0, p1 = wall_point(a, c, o.u0), wall_point(a, c, o.u1)
    x0, x1 = min(p0[0], p1[0]) - 0.3, max(p0[0], p1[0]) + 0.3
    y0, y1 = min(p0[1], p1[1]) - 0.3, max(p0[1], p1[1]) + 0.3
    return (x0 - depth, y0 - depth, x1 + depth, y1 + depth)


def _mezzanine(
    b: MeshBuilder,
    rng: np.random.Generator,
    taken: Footprints,
    w: float,
    d: float,
    height: float,
    wall_col: tuple[int, int, int],
    steel_col: tuple[int, int, int],
    roof_col: tuple[int, int, int],
) -> None:
    """A deck along the north wall: floor on top, ceiling underneath, an edge beam, a parapet, posts, stairs."""
    md = float(rng.uniform(3.5, min(6.0, d / 2.5)))
    zt = float(rng.uniform(2.7, min(3.4, height - 1.8)))
    steps = int(np.ceil(zt / 0.18))
    run = steps * 0.28
    # the deck leaves room for the stairs at its east end, inside the hall
    x0 = float(rng.uniform(0.0, w / 4))
    x1 = min(float(rng.uniform(3 * w / 4, w)), w - WALL_M - 1.0 - run)
    y0 = d - md
    slab(b, (x0, y0, x1, d), zt, floor=b.new_instance(C.FLOOR), ceiling=b.new_instance(C.CEILING),
         floor_color=(150, 150, 150), ceiling_color=roof_col, floor_material=METAL, ceiling_material=PLASTER,
         thickness=0.2)  # fmt: skip
    b.add_box(((x0 + x1) / 2, y0 + 0.1, zt - 0.35), (x1 - x0, 0.2, 0.3), cls=C.BEAM, instance=b.new_instance(C.BEAM),
              material=METAL, color=steel_col)  # fmt: skip
    wall(b, (x0, y0 + 0.05), (x1, y0 + 0.05), zt, zt + 1.05, 0.1, [], instance=b.new_instance(C.WALL), color=wall_col,
         material=PLASTER)  # fmt: skip
    n = max(int((x1 - x0) / 4.0), 1)
    for x in np.linspace(x0 + 0.3, x1 - 0.3, n + 1):
        _column(b, float(x), y0 + 0.15, 0.0, zt - 0.5, True, steel_col)
        taken.take((x - 0.5, y0 - 0.35, x + 0.5, y0 + 0.65))
    # stairs beside the deck, rising towards it along x
    inst = b.new_instance(C.FLOOR)
    for k in range(steps):
        back = (steps - 1 - k + 0.5) * 0.28  # the top step is next to the deck
        x = x1 + 0.3 + back
        zz = (k + 1) * zt / steps
        b.add_box((x, y0 + 0.7, zz / 2), (0.28, 1.1, zz), cls=C.FLOOR, instance=inst, material=CONCRETE,
                  color=(160, 160, 160))  # fmt: skip
    taken.take((x1 - 0.3, y0 - 0.4, x1 + 0.9 + run, d))


def _site_office(
    b: MeshBuilder, rng: np.random.Generator, taken: Footprints, inner: Rect, wall_col: tuple[int, int, int]
) -> None:
    """A glass-walled office box in the south-east corner: glass from 1 m up, a door, a desk inside."""
    ow, od, oh = float(rng.uniform(3.0, 4.5)), float(rng.uniform(2.5, 3.5)), 2.6
    x1, y0 = inner[2], inner[1]
    x0, y1 = x1 - ow, y0 + od
    inst = b.new_instance(C.WALL)
    north = [Opening(0.3, ow - 1.5, 1.0, oh - 0.15), Opening(ow - 1.3, ow - 0.3, 0.0, 2.1)]
    west = [Opening(0.3, od - 0.3, 1.0, oh - 0.15)]
    wall(b, (x0, y1), (x1, y1), 0.0, oh, 0.1, north, instance=inst, color=wall_col, material=PLASTER)
    wall(b, (x0, y0), (x0, y1), 0.0, oh, 0.1, west, instance=inst, color=wall_col, material=PLASTER)
    glazing(b, (x0, y1), (x1, y1), north[0], 0.0, frame_color=(70, 70, 70), mullions=1.2)
    glazing(b, (x0, y0), (x0, y1), west[0], 0.0, frame_color=(70, 70, 70), mullions=1.2)
    door_leaf(b, (x0, y1), (x1, y1), north[1], 0.0, 0.1, rng, color=(200, 200, 200), material=WOOD,
              frame_color=(70, 70, 70))  # fmt: skip
    b.add_box(((x0 + x1) / 2, (y0 + y1) / 2, oh + 0.03), (ow, od, 0.06), cls=C.CEILING,
              instance=b.new_instance(C.CEILING), material=PLASTER, color=(230, 230, 230))  # fmt: skip
    desk = things.l_desk(rng)
    put(b, Footprints(), (x0, y0, x1, y1), desk, x0 + ow / 2, y0 + 0.9, 0.0)
    taken.take((x0 - 1.4, y0 - 0.2, x1 + 0.2, y1 + 1.6))


def _contents(b: MeshBuilder, rng: np.random.Generator, taken: Footprints, inner: Rect, w: float, d: float) -> None:
    # Rack rows across a part of the hall, aisles wide enough to drive.
    if rng.random() < 0.75:
        n_rows = int(rng.integers(2, 5))
        y = inner[1] + float(rng.uniform(1.5, 3.0))
        x0 = inner[0] + float(rng.uniform(1.5, 4.0))
        for _ in range(n_rows):
            x = x0
            piece = things.rack(rng)
            while x + 2 * piece.half_extent[0] < inner[2] - 2.0 and rng.random() < 0.85:
                if put(b, taken, inner, piece, x + piece.half_extent[0], y, 0.0, pad=0.03):
                    x += 2 * piece.half_extent[0] + 0.05
                    piece = things.rack(rng)
                else:
                    x += 0.5
            y += 2 * piece.half_extent[1] + float(rng.uniform(2.2, 3.2))
            if y > inner[1] + d / 2:
                break
    for _ in range(int(rng.integers(1, 4))):  # workbenches with stools
        bench_piece = things.workbench(rng)
        for _t in range(15):
            x, y = rng.uniform(inner[0] + 1.5, inner[2] - 1.5), rng.uniform(inner[1] + 1.5, inner[3] - 1.5)
            yaw = float(rng.choice([0.0, np.pi / 2]))
            if put(b, taken, inner, bench_piece, float(x), float(y), yaw, pad=0.7):
                for k in range(int(rng.integers(0, 4))):
                    off = rotation_z(yaw) @ np.array([(k - 1.5) * 0.5, -(bench_piece.half_extent[1] + 0.35), 0.0])
                    place(
                        b, things.stool(rng), pose(x + off[0], y + off[1], 0.0, rotation_z(rng.uniform(0, 6))), story=0
                    )
                break
    for _ in range(int(rng.integers(1, 4))):
        against_wall(b, taken, inner, things.bench(rng), rng)
    for _ in range(int(rng.integers(0, 3))):
        against_wall(b, taken, inner, things.cabinet(rng), rng)
    for _ in range(int(rng.integers(1, 3))):
        piece = things.screen(rng)
        side = int(rng.integers(2))
        x = float(rng.uniform(inner[0] + 2, inner[2] - 2))
        y, yaw = (inner[1], 0.0) if side == 0 else (inner[3], np.pi)
        place(b, piece, pose(x, y, 0.0, rotation_z(yaw)), story=0)
    for _ in range(int(rng.poisson(w * d / 25))):
        piece = things.thing(rng)
        for _t in range(8):
            x, y = rng.uniform(inner[0] + 0.5, inner[2] - 0.5), rng.uniform(inner[1] + 0.5, inner[3] - 0.5)
            if put(b, taken, inner, piece, float(x), float(y), float(rng.uniform(0, np.pi)), pad=0.1):
                break
