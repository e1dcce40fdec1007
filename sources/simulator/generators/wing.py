"""`wing`: a low-ceilinged wing of a school, clinic or office block: a corridor that turns (L) or branches (T),
doors along it, rooms of drywall or block between pilasters, many of them L-shaped round a closet or a
washroom (with a mirror), glass partitions to the corridor; desks in an L, pedestal tables, stools and
armchairs, cabinets and lockers, waiting benches, screens; sometimes damaged (ceiling tiles down, panels
hanging, cabinets toppled, rubble strewn).
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
from aftershock.sources.simulator.generators.wreck import fallen_panels, hanging_panel, rubble_strip, toppled
from aftershock.sources.simulator.meshes import CONCRETE, PLASTER, TILE, WOOD, MeshBuilder, rotation_z
from aftershock.sources.simulator.scene import Room, Scene

NAME: Final = "wing"
OUTER_M: Final = 0.3
WALLS: Final = ((240, 236, 220), (200, 220, 235), (235, 215, 200), (210, 230, 205), (250, 250, 250), (180, 180, 190))
FLOORS: Final = ((180, 170, 150), (90, 120, 150), (140, 60, 60), (60, 60, 70), (200, 200, 195), (120, 150, 110))
CEILINGS: Final = ((245, 245, 240), (225, 225, 225))
DOORS: Final = ((170, 120, 80), (230, 230, 230), (90, 110, 150), (160, 40, 40))


def build(seed: int) -> Scene:
    root = np.random.SeedSequence([int(seed), sum(map(ord, NAME)), 2])
    r_plan, r_furn, r_damage, r_look, r_struct = (np.random.default_rng(s) for s in root.spawn(5))
    b = MeshBuilder(r_struct)
    w, d = round(float(r_plan.uniform(20, 32)), 2), round(float(r_plan.uniform(13, 19)), 2)
    hc = round(float(r_plan.uniform(2.5, 3.0)), 2)  # suspended ceiling
    part_t = 0.12 if r_plan.random() < 0.6 else 0.2  # drywall or block
    part_mat = PLASTER if part_t < 0.15 else CONCRETE
    wall_col = WALLS[int(r_plan.integers(len(WALLS)))]
    door_col = DOORS[int(r_plan.integers(len(DOORS)))]
    floor_inst, ceil_inst = b.new_instance(C.FLOOR), b.new_instance(C.CEILING)
    ceil_col = CEILINGS[int(r_plan.integers(len(CEILINGS)))]
    slab(b, (0, 0, w, d), 0.0, floor=floor_inst, ceiling=0, floor_color=FLOORS[int(r_plan.integers(len(FLOORS)))],
         ceiling_color=(0, 0, 0), floor_material=TILE, ceiling_material=PLASTER)  # fmt: skip
    slab(b, (0, 0, w, d), hc + 0.1, floor=0, ceiling=ceil_inst, floor_color=(0, 0, 0), ceiling_color=ceil_col,
         floor_material=CONCRETE, ceiling_material=PLASTER, thickness=0.2)  # fmt: skip
    # The corridor: along x, turning north at the east end (L) or branching north in the middle (T).
    cw = float(r_plan.uniform(1.7, 2.5))
    yc = float(r_plan.uniform(d * 0.33, d * 0.45))
    el = r_plan.random() < 0.5
    bw = float(r_plan.uniform(1.7, 2.4))
    xb = w - OUTER_M / 2 - bw if el else float(r_plan.uniform(w * 0.35, w * 0.6))
    h = part_t / 2
    corridors = [Room(0, OUTER_M / 2, yc + h, w - OUTER_M / 2, yc + cw - h, "corridor"),
                 Room(0, xb + h, yc + cw + h, xb + bw - h, d - OUTER_M / 2, "corridor")]  # fmt: skip
    rooms: list[Room] = list(corridors)
    taken = Footprints()
    south_wall: list[Opening] = []
    north_west: list[Opening] = []
    north_east: list[Opening] = []
    branch_w: list[Opening] = []
    branch_e: list[Opening] = []
    bands = [("south", 0.0, w, OUTER_M / 2, yc), ("north-west", 0.0, xb, yc + cw, d - OUTER_M / 2)]
    if not el and w - (xb + bw) > 3.0:
        bands.append(("north-east", xb + bw, w, yc + cw, d - OUTER_M / 2))
    kinds: list[tuple[Rect, str]] = []
    for band, xa, xz, ya, yz in bands:
        cuts = [xa]
        while cuts[-1] + 2 * 3.2 < xz:
            cuts.append(cuts[-1] + float(r_plan.uniform(3.2, 6.5)))
        cuts.append(xz)
        if cuts[-1] - cuts[-2] < 3.0 and len(cuts) > 2:
            cuts.pop(-2)
        for i in range(len(cuts) - 1):
            x0, x1 = (
                cuts[i] + (OUTER_M / 2 if i == 0 and xa == 0 else h),
                cuts[i + 1] - (OUTER_M / 2 if cuts[i + 1] == w else h),
            )
            y0, y1 = (ya, yz - h) if band == "south" else (ya + h, yz)
            if i > 0:  # a partition between rooms
                wall(b, (cuts[i], ya), (cuts[i], yz), 0.0, hc, part_t, [], instance=b.new_instance(C.WALL),
                     color=wall_col, material=part_mat)  # fmt: skip
            # the door to the corridor, and sometimes a glazed strip beside it
            dw = float(r_plan.uniform(1.0, 1.3))
            u = float(r_plan.uniform(x0 + 0.4, max(x0 + 0.41, x1 - dw - 0.4)))
            door = Opening(u, u + dw, 0.0, 2.1)
            ops = [door]
            if r_plan.random() < 0.3 and x1 - (u + dw) > 2.0:
                ops.append(Opening(u + dw + 0.4, x1 - 0.3, 0.9, 2.2))
            target = south_wall if band == "south" else north_west if band == "north-west" else north_east
            target.extend(ops)
            # rooms on the branch get a second door onto it
            if band == "north-west" and abs(cuts[i + 1] - xb) < 1e-6 and r_plan.random() < 0.5:
                v = float(r_plan.uniform(0.5, max(0.6, yz - ya - 1.6)))
                branch_w.append(Opening(v, v + 0.95, 0.0, 2.1))
            if band == "north-east" and i == 0 and r_plan.random() < 0.5:
                v = float(r_plan.uniform(0.5, max(0.6, yz - ya - 1.6)))
                branch_e.append(Opening(v, v + 0.95, 0.0, 2.1))
            # inside of the corridor door stays clear
            yd = y1 if band == "south" else y0
            taken.take((u - 0.3, yd - 1.3, u + dw + 0.3, yd + 1.3))
            rect = (x0, y0, x1, y1)
            rooms.extend(_room(b, r_plan, taken, rect, band, hc, part_t, part_mat, wall_col, door_col))
            kinds.append((rect, str(r_plan.choice(["office", "meeting", "store", "waiting"]))))
    # corridor walls with their doors (the branch leaves a gap in the north wall)
    inst = b.new_instance(C.WALL)
    wall(b, (0, yc), (w, yc), 0.0, hc, part_t, south_wall, instance=inst, color=wall_col, material=part_mat)
    for o in south_wall:  # doors swing into the rooms, never across the corridor
        _opening_fill(b, r_plan, (0, yc), (w, yc), o, part_t, door_col, -1.0)
    inst = b.new_instance(C.WALL)
    north = [*north_west, Opening(xb, xb + bw, 0.0, hc), *north_east]
    wall(b, (0, yc + cw), (w, yc + cw), 0.0, hc, part_t, north, instance=inst, color=wall_col, material=part_mat)
    for o in [*north_west, *north_east]:
        _opening_fill(b, r_plan, (0, yc + cw), (w, yc + cw), o, part_t, door_col, 1.0)
    for x, ops, swing in ((xb, branch_w, 1.0), (xb + bw, branch_e, -1.0)):
        if x >= w - OUTER_M:
            continue
        wall(b, (x, yc + cw), (x, d), 0.0, hc, part_t, ops, instance=b.new_instance(C.WALL), color=wall_col,
             material=part_mat)  # fmt: skip
        for o in ops:
            door_leaf(b, (x, yc + cw), (x, d), o, 0.0, part_t, r_plan, color=door_col, material=WOOD,
                      frame_color=(90, 90, 90), swing=swing)  # fmt: skip
    _outer(b, r_plan, w, d, hc, wall_col)
    for rect, kind in kinds:
        _furnish(b, r_furn, taken, rect, kind)
    for c, long_sides in zip(corridors, ((0, 1), (2, 3)), strict=True):  # never across the corridor
        crect = (c.x0, c.y0, c.x1, c.y1)
        for _ in range(int(r_furn.integers(0, 3))):
            piece = things.bench(r_furn) if r_furn.random() < 0.5 else things.cabinet(r_furn)
            if against_wall(b, taken, crect, piece, r_furn, sides=long_sides):
                # nothing opposite it: the corridor keeps one side free
                x0, y0, x1, y1 = taken.taken[-1]
                across = (
                    (x0 - 0.8, crect[1], x1 + 0.8, crect[3])
                    if long_sides[0] == 0
                    else (crect[0], y0 - 0.8, crect[2], y1 + 0.8)
                )
                taken.take(across)
    if r_damage.random() < 0.6:
        for r in rooms:
            rect = (r.x0, r.y0, r.x1, r.y1)
            if r.kind != "corridor" and r_damage.random() < 0.35:  # corridors stay passable
                fallen_panels(b, r_damage, rect, int(r_damage.integers(1, 5)), ceil_col)
            if r.kind != "corridor" and r_damage.random() < 0.2 and r.x1 - r.x0 > 2.5 and r.y1 - r.y0 > 2.5:
                hanging_panel(b, r_damage, rect, hc, ceil_col, ceil_inst)
            if r.kind != "corridor" and r_damage.random() < 0.25:
                toppled(b, taken, rect, things.cabinet(r_damage), r_damage)
            if r.kind != "corridor" and r_damage.random() < 0.15:
                rubble_strip(b, r_damage, rect, wall_col)
    return finish(NAME, seed, b, (w, d), 0.0, hc, rooms, floor_inst, ceil_inst, r_look)


def _opening_fill(
    b: MeshBuilder,
    rng: np.random.Generator,
    a: tuple,
    c: tuple,
    o: Opening,
    t: float,
    door_col: tuple[int, int, int],
    swing: float,
) -> None:
    if o.z0 > 0:  # a glazed strip
        glazing(b, a, c, o, 0.0, frame_color=(80, 80, 85), mullions=1.0)
    else:
        door_leaf(b, a, c, o, 0.0, t, rng, color=door_col, material=WOOD, frame_color=(90, 90, 90), swing=swing)


def _room(
    b: MeshBuilder,
    rng: np.random.Generator,
    taken: Footprints,
    rect: Rect,
    band: str,
    hc: float,
    t: float,
    mat,
    wall_col: tuple[int, int, int],
    door_col: tuple[int, int, int],
) -> list[Room]:
    """A room; often L-shaped round a closet or washroom carved out of its corner away from the corridor."""
    x0, y0, x1, y1 = rect
    if rng.random() < 0.55 and x1 - x0 > 3.4 and y1 - y0 > 3.4:
        cw_, cd = float(rng.uniform(1.6, min(2.6, x1 - x0 - 1.8))), float(rng.uniform(1.6, min(2.6, y1 - y0 - 1.8)))
        west = rng.random() < 0.5
        far_y = y0 if band == "south" else y1  # the closet sits against the outer wall
        cx0, cx1 = (x0, x0 + cw_) if west else (x1 - cw_, x1)
        cy0, cy1 = (far_y, far_y + cd) if band == "south" else (far_y - cd, far_y)
        edge_y = cy1 if band == "south" else cy0
        edge_x = cx1 if west else cx0
        door_u = float(rng.uniform(0.2, max(0.25, cw_ - 1.0)))
        inst = b.new_instance(C.WALL)
        ops = [Opening(door_u, door_u + 0.8, 0.0, 2.05)]
        wall(b, (cx0, edge_y), (cx1, edge_y), 0.0, hc, t, ops, instance=inst, color=wall_col, material=mat)
        door_leaf(b, (cx0, edge_y), (cx1, edge_y), ops[0], 0.0, t, rng, color=door_col, material=WOOD,
                  frame_color=(90, 90, 90))  # fmt: skip
        wall(b, (edge_x, cy0), (edge_x, cy1), 0.0, hc, t, [], instance=inst, color=wall_col, material=mat)
        closet: Rect = (cx0 + t / 2, cy0 + t / 2, cx1 - t / 2, cy1 - t / 2)
        taken.take((cx0 - 0.2, cy0 - 1.2, cx1 + 0.2, cy1 + 1.2))  # the closet and its door swing
        if rng.random() < 0.6:  # a washroom: a mirror over where the basin would be
            mx = (closet[0] + closet[2]) / 2
            my, yaw = (closet[1] + 0.01, 0.0) if band == "south" else (closet[3] - 0.01, np.pi)
            mirror(b, (mx, my, 1.5), min(1.2, closet[2] - closet[0] - 0.2), 0.9, yaw)
            against_wall(b, Footprints(), closet, things.thing(rng), rng)
        else:
            against_wall(b, Footprints(), closet, things.rack(rng), rng)
        # the L: the strip beside the closet and the strip in front of it
        side = Room(0, cx1 + t / 2, cy0, x1, cy1, "room") if west else Room(0, x0, cy0, cx0 - t / 2, cy1, "room")
        front = (
            Room(0, x0, y0, x1, cy0 - t / 2, "room") if band != "south" else Room(0, x0, cy1 + t / 2, x1, y1, "room")
        )
        return [front, side, Room(0, *closet, "room")]
    return [Room(0, x0, y0, x1, y1, "room")]


def _outer(
    b: MeshBuilder, rng: np.random.Generator, w: float, d: float, hc: float, wall_col: tuple[int, int, int]
) -> None:
    """Outer walls with a window every few metres, and pilasters (columns standing proud of the wall)."""
    sill, head = float(rng.uniform(0.8, 1.1)), min(hc - 0.25, float(rng.uniform(2.0, 2.4)))
    frame = (240, 240, 240) if rng.random() < 0.5 else (60, 60, 60)
    pil = float(rng.uniform(4.5, 7.0))
    for a, c, length, inward in (((0, 0), (w, 0), w, (0, 1)), ((w, d), (0, d), w, (0, -1)),
                                 ((0, d), (0, 0), d, (1, 0)), ((w, 0), (w, d), d, (-1, 0))):  # fmt: skip
        ops = []
        for u in np.arange(1.2, length - 2.4, float(rng.uniform(2.6, 4.0))):
            ops.append(Opening(float(u), float(u) + float(rng.uniform(1.0, 1.8)), sill, head))
        wall(b, a, c, 0.0, hc, OUTER_M, ops, instance=b.new_instance(C.WALL), color=wall_col, material=CONCRETE)
        for o in ops:
            glazing(b, a, c, o, 0.0, frame_color=frame, mullions=0.9)
        from aftershock.sources.simulator.generators.parts import wall_point

        for u in np.arange(pil, length - 1.0, pil):
            if any(o.u0 - 0.3 < u < o.u1 + 0.3 for o in ops):
                continue
            x, y = wall_point(a, c, float(u))
            x, y = x + inward[0] * (OUTER_M / 2 + 0.12), y + inward[1] * (OUTER_M / 2 + 0.12)
            size = (0.45, 0.24, hc) if inward[1] else (0.24, 0.45, hc)
            b.add_box((x, y, hc / 2), size, cls=C.COLUMN, instance=b.new_instance(C.COLUMN), material=CONCRETE,
                      color=wall_col, span=True)  # fmt: skip


def _furnish(b: MeshBuilder, rng: np.random.Generator, taken: Footprints, rect: Rect, kind: str) -> None:
    area = (rect[2] - rect[0]) * (rect[3] - rect[1])
    if kind == "office":
        for _ in range(max(1, int(area / 12))):
            desk = things.l_desk(rng)
            if against_wall(b, taken, rect, desk, rng):
                pass
        for _ in range(int(rng.integers(1, 4))):
            piece = things.armchair(rng) if rng.random() < 0.4 else things.stool(rng)
            _anywhere(b, taken, rect, piece, rng)
        for _ in range(int(rng.integers(0, 3))):
            against_wall(b, taken, rect, things.cabinet(rng), rng)
    elif kind == "meeting":
        for _ in range(max(1, int(area / 10))):
            table = things.round_table(rng)
            for _t in range(10):
                x, y = rng.uniform(rect[0] + 1, rect[2] - 1), rng.uniform(rect[1] + 1, rect[3] - 1)
                if put(b, taken, rect, table, float(x), float(y), 0.0, pad=0.6):
                    for k in range(int(rng.integers(2, 5))):
                        a = k * 2 * np.pi / 4 + rng.normal(0, 0.2)
                        r = table.half_extent[0] + 0.35
                        chair = things.stool(rng) if rng.random() < 0.5 else things.armchair(rng)
                        place(b, chair, pose(x + r * np.cos(a), y + r * np.sin(a), 0.0, rotation_z(a + np.pi / 2)),
                              story=0)  # fmt: skip
                    break
    elif kind == "store":
        for _ in range(max(1, int(area / 8))):
            against_wall(b, taken, rect, things.rack(rng) if rng.random() < 0.6 else things.cabinet(rng), rng)
    else:  # waiting
        for _ in range(int(rng.integers(1, 4))):
            against_wall(b, taken, rect, things.bench(rng), rng)
        for _ in range(int(rng.integers(0, 3))):
            _anywhere(b, taken, rect, things.armchair(rng), rng)
    if rng.random() < 0.6:
        against_wall(b, taken, rect, things.screen(rng), rng)
    for _ in range(int(rng.poisson(area / 12))):
        _anywhere(b, taken, rect, things.thing(rng), rng)


def _anywhere(b: MeshBuilder, taken: Footprints, rect: Rect, piece, rng: np.random.Generator) -> bool:
    for _ in range(8):
        x, y = rng.uniform(rect[0] + 0.4, rect[2] - 0.4), rng.uniform(rect[1] + 0.4, rect[3] - 0.4)
        if put(b, taken, rect, piece, float(x), float(y), float(rng.uniform(-np.pi, np.pi)), pad=0.15):
            return True
    return False
