"""`flats`: one floor of a residential block, hotel or dormitory, built independently of the other generators.

The plan is a tiling of the floor by rectangular cells (corridor, lift lobby, stair, lift shafts, and in each
apartment an entrance hall, an inner passage, a bathroom, a kitchen, a living room and bedrooms); walls stand on
the edges shared by two cells, doors and wide openings where the plan links them, and no wall where a hall runs
into its passage or a living room into it (L- and T-shaped spaces). By seed the corridor is straight and
double-loaded, an access gallery along the south facade, or a dogleg whose joint is the lift lobby.
Structure: party and stair walls of concrete (0.2-0.25 m), partitions of drywall or block (0.08-0.15 m) painted
per room (tiled in bathrooms), columns in the party walls and free-standing in the lobby (square or round),
downstand beams and dropped bulkheads, 45-degree chamfered room corners, windows with sills and mullions or
full-height balcony doors, a dog-leg concrete stair with a handrail rising through a hole in the ceiling.

Labels: walls (stair walls included) WALL; steps, the half landing and the handrail CLUTTER (the landing at
floor level is the floor slab, FLOOR); beams BEAM; bulkheads, dropped ceilings and a sagging ceiling piece
CEILING (instances of their own); dining, coffee and bedside tables, desks and kitchen worktops TABLE; dining
and desk chairs and bar stools CHAIR; sofas, armchairs and beds SOFA; wardrobes, shelving, shoe cabinets and
kitchen wall units BOOKCASE; TV screens, pictures, pin boards and whiteboards BOARD; appliances, boxes, bins,
lamps, plants, radiators, toilets, basins and tubs CLUTTER; fallen blocks, plaster and grit DEBRIS.
Damage (about 60 % of seeds): a partition breached with a block pile, fallen plaster, a sagging ceiling piece,
furniture overturned or slid, grit; routes and doorways stay drivable.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from aftershock.pipeline.classes import SemanticClass as C
from aftershock.sources.simulator.generators import flats_things as th
from aftershock.sources.simulator.generators.parts import Footprints, Opening, finish, slab, wall
from aftershock.sources.simulator.meshes import (
    CONCRETE,
    FABRIC,
    METAL,
    PLASTER,
    TILE,
    WOOD,
    Material,
    MeshBuilder,
    rotation_z,
)
from aftershock.sources.simulator.scene import Room, Scene

NAME: Final = "flats"
OUTER_M: Final = 0.3
EPS: Final = 1e-6
DOOR_MIN_M: Final = 0.92  # every doorway on a route: a 0.6 m robot passes with its margin
WALLPAPER: Final = ((236, 228, 210), (214, 222, 214), (226, 214, 200), (200, 212, 228), (240, 238, 232),
                    (232, 206, 196), (206, 200, 186), (246, 240, 220), (190, 205, 190))  # fmt: skip
TILES: Final = ((228, 230, 232), (190, 200, 205), (215, 205, 185), (120, 140, 150), (245, 245, 245))
WOOD_FLOORS: Final = ((186, 140, 92), (150, 105, 65), (205, 170, 125), (110, 80, 55), (170, 150, 120))
CARPETS: Final = ((120, 120, 125), (90, 100, 130), (160, 145, 120), (110, 125, 100), (140, 90, 90))
COMMON_FLOORS: Final = ((170, 165, 155), (120, 110, 100), (150, 160, 165), (95, 105, 95), (185, 175, 150))
DOOR_COLORS: Final = ((245, 245, 242), (170, 125, 85), (120, 85, 60), (90, 100, 120), (200, 185, 160))
FRAMES: Final = ((245, 245, 245), (70, 70, 72), (140, 100, 70))
CEILINGS: Final = ((248, 248, 245), (238, 236, 230))
ROOM_KIND: Final = {"corridor": "corridor", "lobby": "open"}


@dataclass(slots=True)
class Cell:
    rect: tuple[float, float, float, float]
    kind: str  # corridor lobby stair shaft hall passage bath kitchen living bed store
    apt: int  # -1: common parts
    paint: tuple[int, int, int] = (240, 240, 240)
    skin: Material = PLASTER
    floor: tuple[Material, tuple[int, int, int]] = (TILE, (180, 180, 180))
    drop: float = 0.0  # a suspended ceiling this far below the slab
    chamfer: tuple[str, float] | None = None  # facade corner ("sw", "se", "nw", "ne") and leg length
    stair_low: bool = True  # a stair's landing is at its low-y end


@dataclass(slots=True)
class Link:
    kind: str  # door | open | none | lift
    width: float = 0.95
    style: str = "flush"
    angle: float = 90.0
    into: int = -1  # the cell a door swings into


@dataclass(slots=True)
class Plan:
    cells: list[Cell] = field(default_factory=list)
    links: dict[tuple[int, int], Link] = field(default_factory=dict)
    apts: int = 0

    def add(self, rect: tuple[float, float, float, float], kind: str, apt: int = -1) -> int:
        self.cells.append(Cell(tuple(round(v, 4) for v in rect), kind, apt))  # type: ignore[arg-type]
        return len(self.cells) - 1

    def link(self, a: int, c: int, link: Link) -> None:
        self.links[(min(a, c), max(a, c))] = link


def build(seed: int) -> Scene:
    root = np.random.SeedSequence([int(seed), sum(map(ord, NAME)), 4])
    r_plan, r_furn, r_damage, r_look, r_struct = (np.random.default_rng(s) for s in root.spawn(5))
    b = MeshBuilder(r_struct)
    hc = round(float(r_plan.uniform(2.4, 2.9)), 2)
    layout = str(r_plan.choice(["double", "gallery", "dogleg"]))
    plan, w, d = _plan(r_plan, layout)
    _dress(plan, r_plan, w, d)
    part_t = float(r_plan.choice([0.08, 0.1, 0.12, 0.15]))
    party_t = float(r_plan.choice([0.2, 0.22, 0.25]))
    outer_paint = WALLPAPER[int(r_plan.integers(len(WALLPAPER)))]
    door_col = DOOR_COLORS[int(r_plan.integers(len(DOOR_COLORS)))]
    frame_col = FRAMES[int(r_plan.integers(len(FRAMES)))]
    ceil_col = CEILINGS[int(r_plan.integers(len(CEILINGS)))]
    floor_inst, ceil_inst = b.new_instance(C.FLOOR), b.new_instance(C.CEILING)
    cap = hc + 0.1 + hc  # the stair shaft's roof: the next floor's ceiling

    # ---- floors and ceilings, cell by cell (a hole over the stair flights)
    for cell in plan.cells:
        mat, col = cell.floor
        slab(b, cell.rect, 0.0, floor=floor_inst, ceiling=0, floor_color=col, ceiling_color=(0, 0, 0),
             floor_material=mat, ceiling_material=PLASTER)  # fmt: skip
        if cell.kind == "stair":
            land = _stair(b, r_plan, cell, hc, cap, frame_col)
            slab(b, land, hc + 0.2, floor=0, ceiling=ceil_inst, floor_color=(0, 0, 0), ceiling_color=ceil_col,
                 floor_material=CONCRETE, ceiling_material=PLASTER, thickness=0.2)  # fmt: skip
            continue
        slab(b, cell.rect, hc + 0.2, floor=0, ceiling=ceil_inst, floor_color=(0, 0, 0), ceiling_color=ceil_col,
             floor_material=CONCRETE, ceiling_material=PLASTER, thickness=0.2)  # fmt: skip
        if cell.drop:
            x0, y0, x1, y1 = cell.rect
            b.add_box(((x0 + x1) / 2, (y0 + y1) / 2, hc - cell.drop + 0.01), (x1 - x0, y1 - y0, 0.02), cls=C.CEILING,
                      instance=b.new_instance(C.CEILING), material=PLASTER, color=ceil_col)  # fmt: skip

    # ---- which walls stand where, with their doors; damage may breach a partition
    taken = Footprints()
    segments = _segments(plan)
    breaches = _pick_breaches(plan, segments, r_damage)
    piles: list[list[tuple[float, float, float, float]]] = []
    hung: list[tuple[tuple[float, float], tuple[float, float], Opening, float, Link, int, str]] = []
    for (i, j), segs in segments.items():
        link = plan.links.get((i, j))
        if link is not None and link.kind in ("none", "open"):  # keep the way through clear of furniture
            for axis, lo, hi, at in segs:
                start = (lo, at) if axis == "x" else (at, lo)
                _reserve(taken, start, start, Opening(0.0, hi - lo, 0.0, hc), axis, depth=1.0)
        if link is not None and link.kind == "none":
            continue
        a, c = plan.cells[i], plan.cells[j]
        stair = "stair" in (a.kind, c.kind) or "shaft" in (a.kind, c.kind)
        t = party_t if (a.apt != c.apt or stair) else part_t
        if a.apt == c.apt and a.apt >= 0 and r_plan.random() < 0.3:
            t = float(r_plan.choice([0.08, 0.1, 0.12, 0.15]))
        top = cap if stair else hc
        main = max(range(len(segs)), key=lambda k: segs[k][2] - segs[k][1])
        inst = b.new_instance(C.WALL)
        for k, (axis, lo, hi, at) in enumerate(segs):
            start, end = ((lo, at), (hi, at)) if axis == "x" else ((at, lo), (at, hi))
            left, right = (j, i) if _is_left(plan.cells[j].rect, axis, at) else (i, j)
            ops: list[Opening] = []
            fills: list[tuple[Opening, Link]] = []
            if k == main and link is not None:
                ops, fills = _openings(link, hi - lo, min(hc - a.drop, hc - c.drop), r_plan)
            if (i, j, k) in breaches:
                ops += _breach(hi - lo, ops, hc, r_damage, piles, start, end, axis)
            _layers(b, start, end, t, top, ops, plan.cells[left], plan.cells[right], inst)
            for o, lk in fills:
                hung.append((start, end, o, t, lk, left, axis))
                _reserve(taken, start, end, o, axis)
            if a.apt != c.apt:
                _column_ends(b, r_plan, start, end, w, d, hc, outer_paint)
    zones = [_zone(h[0], h[6], h[2], 0.95) for h in hung]
    for k, (start, end, o, t, lk, left, axis) in enumerate(hung):
        side = 1.0 if lk.into == left else -1.0
        others = zones[:k] + zones[k + 1 :]
        free = [lo for lo in (True, False) if not any(_overlap(_leaf(start, axis, o, t, side, lo), z) for z in others)]
        if lk.kind == "door" and lk.style != "sliding" and not free:
            lk = Link("door", lk.width, "sliding", 90.0, lk.into)  # no wall to fold back against: it slides
        hinge = None if len(free) != 1 else ("lo" if free[0] else "hi")
        _fill(b, r_plan, start, end, o, t, lk, left, door_col, frame_col, hinge)
    _outer(b, r_plan, plan, w, d, hc, cap, outer_paint, frame_col, taken)
    _chamfers(b, plan, hc, taken)
    _structure(b, r_plan, plan, hc, outer_paint, taken)
    for spots in piles:  # each breach offers places on both sides of its wall for its pile
        for x0, y0, x1, y1 in spots:
            if taken.fits((x0, y0, x1, y1), (0, 0, w, d), margin=0.0):
                th.block_pile(b, r_damage, (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2, outer_paint)
                taken.take((x0, y0, x1, y1))
                break

    # ---- contents, then the rest of the damage
    damaged = bool(breaches) or r_damage.random() < 0.25
    for idx in range(len(plan.cells)):
        _furnish(b, r_furn, plan, idx, taken, damaged)
    if damaged:
        _damage(b, r_damage, plan, hc, taken, ceil_col, outer_paint)
    rooms = [
        Room(0, *_inner(c.rect, w, d), ROOM_KIND.get(c.kind, "room"))
        for c in plan.cells
        if c.kind not in ("shaft", "stair")
    ]
    for c in plan.cells:  # the stair's landing is where the robot goes
        if c.kind == "stair":
            x0, y0, x1, y1 = _inner(c.rect, w, d)
            ya, yb = (y0, y0 + 1.3) if c.stair_low else (y1 - 1.3, y1)
            rooms.append(Room(0, x0, ya, x1, yb, "room"))
    corridors = [r for r in rooms if r.kind == "corridor"]
    rooms = corridors + [r for r in rooms if r.kind != "corridor"]
    return finish(NAME, seed, b, (w, d), 0.0, hc, rooms, floor_inst, ceil_inst, r_look)


# ================================================================================================ plan


def _plan(rng: np.random.Generator, layout: str) -> tuple[Plan, float, float]:
    """Cells tiling [0, w] x [0, d] and the links between them."""
    p = Plan()
    cw = round(float(rng.uniform(1.5, 2.1)), 2)
    if layout == "gallery":
        w, d = round(float(rng.uniform(18, 30)), 2), round(float(rng.uniform(11.5, 14)), 2)
        corr = p.add((0, 0, w, cw), "corridor")
        core_w = float(rng.uniform(5.4, 6.6))
        west = rng.random() < 0.5
        cx0, cx1 = (0.0, core_w) if west else (w - core_w, w)
        _core(p, rng, cx0, cx1, cw, d, True, corr)
        _band(p, rng, (cx1, w) if west else (0.0, cx0), cw, d, True, corr)
        return p, w, d
    if layout == "double":
        w, d = round(float(rng.uniform(18, 30)), 2), round(float(rng.uniform(12.5, 19)), 2)
        yc = round(float(rng.uniform(0.42, 0.55)) * (d - cw), 2)
        corr = p.add((0, yc, w, yc + cw), "corridor")
        core_w = float(rng.uniform(5.4, 6.6))
        cx0 = round(float(rng.uniform(0.2, 0.8)) * (w - core_w), 2)
        north = rng.random() < 0.5
        if north:
            _core(p, rng, cx0, cx0 + core_w, yc + cw, d, True, corr)
            _band(p, rng, (0.0, w), 0.0, yc, False, corr)
            for xa, xb in ((0.0, cx0), (cx0 + core_w, w)):
                _band(p, rng, (xa, xb), yc + cw, d, True, corr)
        else:
            _core(p, rng, cx0, cx0 + core_w, 0.0, yc, False, corr)
            _band(p, rng, (0.0, w), yc + cw, d, True, corr)
            for xa, xb in ((0.0, cx0), (cx0 + core_w, w)):
                _band(p, rng, (xa, xb), 0.0, yc, False, corr)
        return p, w, d
    # dogleg: two corridors offset in y, joined by the lift lobby between them
    w, d = round(float(rng.uniform(21, 30)), 2), round(float(rng.uniform(15, 19.5)), 2)
    off = float(rng.uniform(2.4, 3.4))
    ylo = round(float(rng.uniform(4.5, d - 4.5 - off - cw)), 2)
    yhi = round(ylo + off + cw, 2)
    mw = float(rng.uniform(5.6, 6.6))
    xj = round(float(rng.uniform(0.35, 0.55)) * (w - mw), 2)
    xk = round(xj + mw, 2)
    west_low = rng.random() < 0.5
    yw, ye = (ylo, round(ylo + off, 2)) if west_low else (round(ylo + off, 2), ylo)
    cwest = p.add((0, yw, xj, yw + cw), "corridor")
    ceast = p.add((xk, ye, w, ye + cw), "corridor")
    lobby = p.add((xj, ylo, xk, yhi), "lobby")
    p.link(cwest, lobby, Link("none"))
    p.link(ceast, lobby, Link("none"))
    sw = float(rng.uniform(2.7, 3.0))
    stair_south = ylo >= d - yhi
    ys0, ys1 = (0.0, ylo) if stair_south else (yhi, d)
    st = p.add((xj, ys0, xj + sw, ys1), "stair")
    p.cells[st].stair_low = not stair_south
    p.link(st, lobby, _door(rng, 1.1, 1.5, "double", lobby_side=lobby, into=st))
    shaft = p.add((xj + sw, ys0, xk, ys1), "shaft")
    p.link(shaft, lobby, Link("lift", width=float(rng.uniform(0.9, 1.1))))
    _band(p, rng, (xj, xk), *((yhi, d) if stair_south else (0.0, ylo)), stair_south, lobby)
    for (xa, xb), corr, y0c in (((0.0, xj), cwest, yw), ((xk, w), ceast, ye)):
        _band(p, rng, (xa, xb), 0.0, y0c, False, corr)
        _band(p, rng, (xa, xb), y0c + cw, d, True, corr)
    return p, w, d


def _door(rng: np.random.Generator, lo: float, hi: float, style: str | None = None, *, lobby_side: int = -1,
          into: int = -1) -> Link:  # fmt: skip
    style = style or str(rng.choice(["flush", "panelled", "panelled", "sliding", "flush"]))
    width = max(float(rng.uniform(lo, hi)), DOOR_MIN_M)
    if style == "double" and width < 1.2:
        style = "flush"
    angle = float(rng.uniform(86, 100)) if style != "sliding" else float(rng.uniform(86, 90))
    return Link("door", width=width, style=style, angle=angle, into=into)


def _core(p: Plan, rng: np.random.Generator, x0: float, x1: float, y0: float, y1: float, low: bool, corr: int) -> None:
    """Lift lobby (open to the corridor, lift doors at its back) beside a stair entered from the corridor."""
    sw = float(rng.uniform(2.7, 3.0))
    stair_west = rng.random() < 0.5
    sx0, sx1 = (x0, x0 + sw) if stair_west else (x1 - sw, x1)
    lx0, lx1 = (sx1, x1) if stair_west else (x0, sx0)
    st = p.add((sx0, y0, sx1, y1), "stair")
    p.cells[st].stair_low = low
    p.link(st, corr, _door(rng, 1.0, 1.5, "double" if rng.random() < 0.5 else "flush", into=st))
    depth = y1 - y0
    shaft_d = float(rng.uniform(1.8, 2.2))
    if depth - shaft_d >= 2.6:
        ly0, ly1, sy0, sy1 = (y0, y1 - shaft_d, y1 - shaft_d, y1) if low else (y0 + shaft_d, y1, y0, y0 + shaft_d)
        lobby = p.add((lx0, ly0, lx1, ly1), "lobby")
        shaft = p.add((lx0, sy0, lx1, sy1), "shaft")
        p.link(shaft, lobby, Link("lift", width=float(rng.uniform(0.9, 1.1))))
    else:
        lobby = p.add((lx0, y0, lx1, y1), "lobby")
    p.link(lobby, corr, Link("none") if rng.random() < 0.5 else Link("open"))


def _band(
    p: Plan, rng: np.random.Generator, xs: tuple[float, float], ya: float, yb: float, low: bool, corr: int
) -> None:
    """A strip of apartments between x0 and x1, its corridor edge at ya (low) or yb."""
    x0, x1 = xs
    if x1 - x0 < 1.0 or yb - ya < 1.0:
        return
    lo, hi = (5.8, 9.2) if yb - ya >= 6.6 else (3.4, 4.8)  # flats, or hotel rooms in a shallow strip
    cuts = [x0]
    while x1 - cuts[-1] > hi + 0.3:
        cuts.append(round(cuts[-1] + float(rng.uniform(lo, hi)), 2))
    if x1 - cuts[-1] < 3.2 and len(cuts) > 1:
        cuts.pop()
    cuts.append(x1)
    for a, c in itertools.pairwise(cuts):
        _apartment(p, rng, a, c, ya, yb, low, corr)


def _apartment(
    p: Plan, rng: np.random.Generator, x0: float, x1: float, ya: float, yb: float, low: bool, corr: int
) -> None:
    """Entrance zone on the corridor side (hall, bathroom, kitchen), an inner passage, then living room and
    bedrooms on the facade; narrow or shallow plots become studios or store rooms."""
    apt = p.apts
    p.apts += 1
    width, depth = x1 - x0, yb - ya

    def rect(u0: float, u1: float, v0: float, v1: float) -> tuple[float, float, float, float]:
        return (x0 + u0, ya + v0, x0 + u1, ya + v1) if low else (x0 + u0, yb - v1, x0 + u1, yb - v0)

    if width < 3.2 or depth < 3.5:
        s = p.add(rect(0, width, 0, depth), "store", apt)
        p.link(s, corr, _door(rng, 0.95, 1.05, into=s))
        return
    e = float(rng.uniform(2.1, 2.7))
    if width < 5.8 or depth < 6.6:  # a studio
        hw = float(rng.uniform(1.55, 1.9))
        hall_left = rng.random() < 0.5
        hu = (0.0, hw) if hall_left else (width - hw, width)
        hall = p.add(rect(*hu, 0, e), "hall", apt)
        p.link(hall, corr, _door(rng, 0.95, 1.05, "panelled", into=hall))
        if width - hw >= 2.0:
            bath = p.add(rect(hw, width, 0, e) if hall_left else rect(0, width - hw, 0, e), "bath", apt)
            p.link(bath, hall, _door(rng, 0.92, 0.95, into=bath))
        else:
            p.cells[hall].rect = rect(0, width, 0, e)
        liv = p.add(rect(0, width, e, depth), "living", apt)
        p.link(liv, hall, Link("none") if rng.random() < 0.5 else Link("open"))
        return
    pw = float(rng.uniform(1.15, 1.4))
    hw, bw = float(rng.uniform(1.55, 1.95)), float(rng.uniform(2.1, 2.6))
    rest = width - hw - bw
    front = [("hall", hw), ("bath", bw)]
    if rest >= 2.3:
        if rest > 4.4:
            front += [("kitchen", rest - 1.9), ("store", 1.9)]
        else:
            front.append(("kitchen", rest))
    else:
        front[1] = ("bath", bw + rest)
    order = rng.permutation(len(front))
    u = 0.0
    passage = p.add(rect(0, width, e, e + pw), "passage", apt)
    for k in order:
        kind, wk = front[int(k)]
        c = p.add(rect(u, u + wk, 0, e), kind, apt)
        u += wk
        if kind == "hall":
            p.link(c, corr, _door(rng, 0.95, 1.05, "panelled" if rng.random() < 0.6 else "flush", into=c))
            p.link(c, passage, Link("none"))
        elif kind == "kitchen" and rng.random() < 0.5:
            p.link(c, passage, Link("open"))
        else:
            p.link(c, passage, _door(rng, 0.92, 1.0, into=c))
    nbed = 2 if width >= 8.6 and rng.random() < 0.7 else 1
    beds = [float(rng.uniform(2.6, 3.4)) for _ in range(nbed)]
    if width - sum(beds) < 3.2:
        beds = [max(2.6, (width - 3.2) / nbed)] * nbed
    rooms = [("living", width - sum(beds)), *(("bed", bw_) for bw_ in beds)]
    if rng.random() < 0.5:
        rooms = rooms[::-1]
    u = 0.0
    for kind, wk in rooms:
        c = p.add(rect(u, u + wk, e + pw, depth), kind, apt)
        u += wk
        if kind == "living":
            r = rng.random()
            p.link(c, passage, Link("none") if r < 0.35 else Link("open") if r < 0.7 else _door(
                rng, 1.3, 1.6, "double" if rng.random() < 0.5 else "sliding", into=c))  # fmt: skip
        else:
            p.link(c, passage, _door(rng, 0.92, 1.0, into=c))


def _dress(plan: Plan, rng: np.random.Generator, w: float, d: float) -> None:
    """Paint, floor finish, suspended ceilings and chamfered corners, per cell."""
    wood = WOOD_FLOORS[int(rng.integers(len(WOOD_FLOORS)))]
    common = COMMON_FLOORS[int(rng.integers(len(COMMON_FLOORS)))]
    carpet = CARPETS[int(rng.integers(len(CARPETS)))]
    hotel = rng.random() < 0.3
    for c in plan.cells:
        c.paint = WALLPAPER[int(rng.integers(len(WALLPAPER)))]
        if c.kind in ("bath", "kitchen"):
            c.floor = (TILE, TILES[int(rng.integers(len(TILES)))])
            c.skin = TILE if c.kind == "bath" else PLASTER
            if c.kind == "bath":
                c.paint = TILES[int(rng.integers(len(TILES)))]
        elif c.kind in ("corridor", "lobby"):
            c.floor = (FABRIC, carpet) if hotel else (TILE, common)
        elif c.kind in ("stair", "shaft", "store"):
            c.floor = (CONCRETE, (165, 160, 152))
            c.skin = CONCRETE
        elif c.kind == "bed" and rng.random() < 0.5:
            c.floor = (FABRIC, CARPETS[int(rng.integers(len(CARPETS)))])
        else:
            c.floor = (WOOD, wood)
        if c.kind in ("bath", "hall", "passage") and rng.random() < 0.5:
            c.drop = round(float(rng.uniform(0.15, 0.3)), 2)
        x0, y0, x1, y1 = c.rect
        facade = [f for f, on in (("s", y0 < 0.01), ("n", y1 > d - 0.01)) if on]
        if c.kind in ("living", "bed") and facade and min(x1 - x0, y1 - y0) > 3.0 and rng.random() < 0.35:
            c.chamfer = (facade[0] + str(rng.choice(["w", "e"])), float(rng.uniform(0.8, 1.2)))


# ================================================================================================ walls


def _is_left(rect: tuple[float, float, float, float], axis: str, at: float) -> bool:
    """Is the cell to the left of a wall running in +x (then left is north) or +y (left is west) at `at`?"""
    return abs(rect[1] - at) < 1e-3 if axis == "x" else abs(rect[2] - at) < 1e-3


def _segments(plan: Plan) -> dict[tuple[int, int], list[tuple[str, float, float, float]]]:
    """Edges shared by two cells: (axis the wall runs along, from, to, the other coordinate)."""
    out: dict[tuple[int, int], list[tuple[str, float, float, float]]] = {}
    cells = plan.cells
    for i, j in itertools.combinations(range(len(cells)), 2):
        a, c = cells[i].rect, cells[j].rect
        segs = []
        for xa, xc in ((a[2], c[0]), (a[0], c[2])):
            if abs(xa - xc) < 1e-3:
                lo, hi = max(a[1], c[1]), min(a[3], c[3])
                if hi - lo > 0.05:
                    segs.append(("y", lo, hi, xa))
        for ya, yc in ((a[3], c[1]), (a[1], c[3])):
            if abs(ya - yc) < 1e-3:
                lo, hi = max(a[0], c[0]), min(a[2], c[2])
                if hi - lo > 0.05:
                    segs.append(("x", lo, hi, ya))
        if segs:
            out[(i, j)] = segs
    return out


def _openings(link: Link, length: float, head_max: float, rng: np.random.Generator
              ) -> tuple[list[Opening], list[tuple[Opening, Link]]]:  # fmt: skip
    """The holes a link cuts in its wall, and which of them get a door or lift door."""
    if link.kind == "open":
        nib = float(rng.uniform(0.25, 0.6))
        if length - 2 * nib < 1.2:
            nib = max((length - 1.2) / 2, 0.0)
        head = min(head_max, float(rng.uniform(2.1, 2.4)) if rng.random() < 0.6 else head_max)
        return [Opening(nib, length - nib, 0.0, head)], []
    if link.kind == "lift":
        n = 2 if length > 2 * link.width + 1.2 else 1
        ops = []
        for k in range(n):
            u = length * (k + 1) / (n + 1) - link.width / 2
            ops.append(Opening(u, u + link.width, 0.0, 2.1))
        return ops, [(o, Link("lift", o.u1 - o.u0, "double", 0.0)) for o in ops]
    wd = min(link.width, length - 0.6)
    if wd < DOOR_MIN_M - 0.02:
        wd = max(length - 0.4, 0.85)
    margin = min(0.3, (length - wd) / 2)
    u = float(rng.uniform(margin, max(margin, length - wd - margin)))
    if link.style == "sliding":  # the leaf needs a wall to slide along
        u = margin
    o = Opening(u, u + wd, 0.0, min(float(rng.uniform(2.0, 2.1)), head_max - 0.1))
    return [o], [(o, link)]


def _layers(
    b: MeshBuilder,
    start: tuple[float, float],
    end: tuple[float, float],
    t: float,
    top: float,
    ops: list[Opening],
    left: Cell,
    right: Cell,
    inst: int,
) -> None:
    """A wall as two half-thick layers, each finished like the room it faces; stretched by t/2 at both ends so
    corners close."""
    along_x = abs(end[1] - start[1]) < EPS
    ext = t / 2
    s2 = (start[0] - ext, start[1]) if along_x else (start[0], start[1] - ext)
    e2 = (end[0] + ext, end[1]) if along_x else (end[0], end[1] + ext)
    shifted = [Opening(o.u0 + ext, o.u1 + ext, o.z0, o.z1) for o in ops]
    for cell, sign in ((left, 1.0), (right, -1.0)):
        off = sign * t / 4
        a = (s2[0], s2[1] + off) if along_x else (s2[0] - off, s2[1])
        c = (e2[0], e2[1] + off) if along_x else (e2[0] - off, e2[1])
        wall(b, a, c, 0.0, top, t / 2, shifted, instance=inst, color=cell.paint, material=cell.skin)


def _fill(
    b: MeshBuilder,
    rng: np.random.Generator,
    start: tuple[float, float],
    end: tuple[float, float],
    o: Opening,
    t: float,
    link: Link,
    left: int,
    door_col: tuple[int, int, int],
    frame_col: tuple[int, int, int],
    hinge: str | None = None,
) -> None:
    if link.kind == "lift":
        th.door(b, start, end, o, t, rng, style="double", angle_deg=0.0, side=1.0, color=(170, 172, 176),
                frame=(120, 122, 126), leaf=METAL)  # fmt: skip
        along_x = abs(end[1] - start[1]) < EPS
        u = o.u1 + 0.2
        x, y = (start[0] + u, start[1]) if along_x else (start[0], start[1] + u)
        b.add_box((x, y, 1.1), (0.08, t + 0.04, 0.14) if along_x else (t + 0.04, 0.08, 0.14), cls=C.CLUTTER,
                  instance=b.new_instance(C.CLUTTER), material=METAL, color=(150, 150, 155))  # fmt: skip
        return
    side = 1.0 if link.into == left else -1.0
    th.door(b, start, end, o, t, rng, style=link.style, angle_deg=link.angle, side=side, color=door_col,
            frame=frame_col, hinge=hinge)  # fmt: skip


def _zone(start: tuple[float, float], axis: str, o: Opening, depth: float) -> tuple[float, float, float, float]:
    """The floor on both sides of a doorway that a leaf must not cover."""
    if axis == "x":
        return (start[0] + o.u0, start[1] - depth, start[0] + o.u1, start[1] + depth)
    return (start[0] - depth, start[1] + o.u0, start[0] + depth, start[1] + o.u1)


def _leaf(start: tuple[float, float], axis: str, o: Opening, t: float, side: float, lo: bool
          ) -> tuple[float, float, float, float]:  # fmt: skip
    """Where a leaf opened square lies: hinged at the low or high jamb, on the wall's left (side +1) or right."""
    u = o.u0 + 0.03 if lo else o.u1 - 0.03
    reach = t / 2 + (o.u1 - o.u0)
    if axis == "x":
        x, y = start[0] + u, start[1]
        return (x - 0.04, min(y, y + side * reach), x + 0.04, max(y, y + side * reach))
    x, y = start[0], start[1] + u
    return (min(x, x - side * reach), y - 0.04, max(x, x - side * reach), y + 0.04)


def _overlap(a: tuple[float, float, float, float], c: tuple[float, float, float, float]) -> bool:
    return a[0] < c[2] - 1e-6 and c[0] < a[2] - 1e-6 and a[1] < c[3] - 1e-6 and c[1] < a[3] - 1e-6


def _reserve(
    taken: Footprints, start: tuple[float, float], end: tuple[float, float], o: Opening, axis: str, depth: float = 1.15
) -> None:
    """Keep the floor clear on both sides of a doorway (the leaf's swing and the way through)."""
    if axis == "x":
        x0, x1 = start[0] + o.u0 - 0.15, start[0] + o.u1 + 0.15
        taken.take((x0, start[1] - depth, x1, start[1] + depth))
    else:
        y0, y1 = start[1] + o.u0 - 0.15, start[1] + o.u1 + 0.15
        taken.take((start[0] - depth, y0, start[0] + depth, y1))


def _pick_breaches(
    plan: Plan, segments: dict[tuple[int, int], list[tuple[str, float, float, float]]], rng: np.random.Generator
) -> set[tuple[int, int, int]]:
    """Partitions inside apartments that partly collapse (about half the seeds)."""
    if rng.random() > 0.5:
        return set()
    cand = []
    for (i, j), segs in segments.items():
        a, c = plan.cells[i], plan.cells[j]
        link = plan.links.get((i, j))
        if a.apt != c.apt or a.apt < 0 or (link is not None and link.kind in ("none", "open")):
            continue
        if {a.kind, c.kind} & {"bath", "store"}:
            continue
        for k, (_axis, lo, hi, _at) in enumerate(segs):
            if hi - lo > 2.6:
                cand.append((i, j, k))
    if not cand:
        return set()
    n = min(len(cand), int(rng.integers(1, 4)))
    return {cand[int(q)] for q in rng.choice(len(cand), n, replace=False)}


def _breach(
    length: float,
    ops: list[Opening],
    hc: float,
    rng: np.random.Generator,
    piles: list[list[tuple[float, float, float, float]]],
    start: tuple[float, float],
    end: tuple[float, float],
    axis: str,
) -> list[Opening]:
    """A ragged hole in a partition, clear of its doorway: strips broken off at different heights (the middle
    ones down to the floor or to a stub), and a pile of what fell beside it."""
    edges = sorted([(0.0, 0.3), (length - 0.3, length)] + [(o.u0 - 0.25, o.u1 + 0.25) for o in ops])
    gaps = [(a[1], c[0]) for a, c in itertools.pairwise(edges) if c[0] - a[1] >= 0.8]
    if not gaps:
        return []
    g0, g1 = gaps[int(rng.integers(len(gaps)))]
    span = float(rng.uniform(0.8, min(1.9, g1 - g0)))
    u0 = float(rng.uniform(g0, g1 - span))
    n = int(rng.integers(4, 8))
    edges = np.linspace(u0, u0 + span, n + 1)
    out = []
    for k in range(n):
        mid = 1 - abs((k + 0.5) / n - 0.5) * 2
        z0 = float(rng.uniform(0.0, 0.5)) if mid > 0.5 else float(rng.uniform(0.6, 1.8))
        if rng.random() < 0.3:
            z0 = 0.0 if mid > 0.5 else z0
        out.append(Opening(float(edges[k]), float(edges[k + 1]), z0, hc + 0.01))
    first = float(rng.choice([-1.0, 1.0]))
    dep = float(rng.uniform(0.45, 0.8))
    spots = []
    for side, (ua, ub), dd in itertools.product((first, -first), ((u0, u0 + span), (u0, u0 + span / 2),
                                                (u0 + span / 2, u0 + span)), (dep, 0.6 * dep)):  # fmt: skip
        if axis == "x":
            y = start[1] + side * 0.08
            spots.append((start[0] + ua, min(y, y + side * dd), start[0] + ub, max(y, y + side * dd)))
        else:
            x = start[0] + side * 0.08
            spots.append((min(x, x + side * dd), start[1] + ua, max(x, x + side * dd), start[1] + ub))
    piles.append(spots)
    return out


def _column_ends(
    b: MeshBuilder,
    rng: np.random.Generator,
    start: tuple[float, float],
    end: tuple[float, float],
    w: float,
    d: float,
    hc: float,
    col: tuple[int, int, int],
) -> None:
    """Concrete columns built into a party wall where it meets the facade."""
    for x, y in (start, end):
        on_facade = x < 0.01 or y < 0.01 or x > w - 0.01 or y > d - 0.01
        if not on_facade or rng.random() < 0.3:
            continue
        s = float(rng.uniform(0.3, 0.45))
        cx = min(max(x, OUTER_M / 2 + s / 2 - 0.05), w - OUTER_M / 2 - s / 2 + 0.05)
        cy = min(max(y, OUTER_M / 2 + s / 2 - 0.05), d - OUTER_M / 2 - s / 2 + 0.05)
        b.add_box((cx, cy, hc / 2), (s, s, hc), cls=C.COLUMN, instance=b.new_instance(C.COLUMN), material=CONCRETE,
                  color=col, span=True)  # fmt: skip


def _outer(
    b: MeshBuilder,
    rng: np.random.Generator,
    plan: Plan,
    w: float,
    d: float,
    hc: float,
    cap: float,
    paint: tuple[int, int, int],
    frame: tuple[int, int, int],
    taken: Footprints,
) -> None:
    """The four facades, with each room's windows (or a balcony door) where it meets them; radiators below."""
    sill_col = (230, 228, 222) if rng.random() < 0.5 else (150, 110, 80)
    sides = (((0.0, 0.0), (w, 0.0), "x", 0.0), ((w, 0.0), (w, d), "y", w),
             ((w, d), (0.0, d), "x", d), ((0.0, d), (0.0, 0.0), "y", 0.0))  # fmt: skip
    for start, end, axis, at in sides:
        length = w if axis == "x" else d
        rev = (end[0] - start[0]) + (end[1] - start[1]) < 0
        ops: list[Opening] = []
        kinds: list[str] = []
        for c in plan.cells:
            x0, y0, x1, y1 = c.rect
            if axis == "x" and abs((y0 if at == 0.0 else y1) - at) < 1e-3:
                lo, hi = x0, x1
            elif axis == "y" and abs((x0 if at == 0.0 else x1) - at) < 1e-3:
                lo, hi = y0, y1
            else:
                continue
            if c.kind == "stair":  # the stair shaft's wall goes on up
                u_a, u_b = sorted(((length - hi) if rev else lo, (length - lo) if rev else hi))
                mid = (u_a + u_b) / 2
                x, y = (start[0] + (-mid if rev else mid), start[1]) if axis == "x" else (start[0], start[1] + (
                    -mid if rev else mid))  # fmt: skip
                size = (u_b - u_a, OUTER_M, cap - hc) if axis == "x" else (OUTER_M, u_b - u_a, cap - hc)
                b.add_box((x, y, (hc + cap) / 2), size, cls=C.WALL, instance=b.new_instance(C.WALL),
                          material=CONCRETE, color=paint)  # fmt: skip
            lo, hi = _shrink_for_chamfer(c, axis, at, lo, hi)
            for a, z in _window_spans(c.kind, hi - lo, hc, rng):
                u0 = (length - (lo + a[1])) if rev else lo + a[0]
                ops.append(Opening(u0, u0 + a[1] - a[0], z[0], z[1]))
                kinds.append(c.kind)
        ext = OUTER_M / 2
        along = (np.array(end) - np.array(start)) / length
        s2 = tuple(np.array(start) - along * ext)
        e2 = tuple(np.array(end) + along * ext)
        shifted = [Opening(o.u0 + ext, o.u1 + ext, o.z0, o.z1) for o in ops]
        wall(b, s2, e2, 0.0, hc, OUTER_M, shifted, instance=b.new_instance(C.WALL), color=paint,
             material=CONCRETE)  # fmt: skip
        for o, kind in zip(ops, kinds, strict=True):
            th.window(b, start, end, o, OUTER_M, rng, inside=1.0, frame=frame, sill=sill_col)
            mid = start + along * ((o.u0 + o.u1) / 2)
            inward = np.array([-along[1], along[0]])
            if o.z0 < 0.05:  # balcony door: keep its inside clear
                p = mid + inward * 0.7
                hx = (o.u1 - o.u0) / 2 + 0.1
                taken.take((p[0] - (hx if axis == "x" else 0.6), p[1] - (0.6 if axis == "x" else hx),
                            p[0] + (hx if axis == "x" else 0.6), p[1] + (0.6 if axis == "x" else hx)))  # fmt: skip
            elif kind in ("living", "bed") and o.z0 > 0.6 and rng.random() < 0.8:
                rad = th.radiator(rng, min(o.u1 - o.u0, 1.6))
                p = mid + inward * (OUTER_M / 2 + 0.08)
                rot = rotation_z(float(np.arctan2(along[1], along[0])))
                th.draw(b, rad, float(p[0]), float(p[1]), rot, 0.14)
                taken.take(th.footprint_of(rad, float(p[0]), float(p[1]), rot, 0.03))


def _window_spans(kind: str, length: float, hc: float, rng: np.random.Generator
                  ) -> list[tuple[tuple[float, float], tuple[float, float]]]:  # fmt: skip
    """(u range, z range) of the windows of a room along a facade stretch of `length`."""
    head = min(hc - 0.2, float(rng.uniform(2.0, 2.3)))
    if length < 1.4 or kind in ("hall", "passage", "shaft", "store"):
        return []
    if kind == "bath":
        if rng.random() < 0.6 and length > 1.2:
            u = float(rng.uniform(0.4, length - 1.0))
            return [((u, u + 0.6), (1.5, min(head, 2.0)))]
        return []
    if kind == "stair":
        u = (length - 1.0) / 2
        return [((u, u + 1.0), (1.0, head))]
    if kind == "corridor":
        if length < 3.0:
            u = (length - 1.2) / 2
            return [((u, u + 1.2), (0.0 if rng.random() < 0.5 else 0.9, head))]
        # the gallery: wide windows all along
        out = []
        ww, pier = float(rng.uniform(1.4, 2.4)), float(rng.uniform(0.6, 1.2))
        u = pier
        while u + ww < length - pier:
            out.append(((u, u + ww), (0.9, head)))
            u += ww + pier
        return out
    if kind == "living" and rng.random() < 0.45 and length > 2.8:  # a balcony door and a window
        dw = float(rng.uniform(0.9, 1.6))
        u = float(rng.uniform(0.5, length - dw - 0.5))
        out = [((u, u + dw), (0.0, head))]
        if length - (u + dw) > 2.0:
            out.append(((u + dw + 0.5, min(length - 0.5, u + dw + 0.5 + float(rng.uniform(1.0, 1.8)))),
                        (0.9, head)))  # fmt: skip
        return out
    ww = min(float(rng.uniform(1.0, 2.2)), length - 0.9)
    u = float(rng.uniform(0.45, max(0.45, length - ww - 0.45)))
    sill = float(rng.uniform(0.85, 1.1)) if kind != "kitchen" else float(rng.uniform(1.0, 1.15))
    return [((u, u + ww), (sill, head))]


def _shrink_for_chamfer(c: Cell, axis: str, at: float, lo: float, hi: float) -> tuple[float, float]:
    if c.chamfer is None:
        return lo, hi
    corner, leg = c.chamfer
    x0, y0, x1, y1 = c.rect
    ny = "s" if abs(at - y0) < 1e-3 else "n" if abs(at - y1) < 1e-3 else ""
    nx = "w" if abs(at - x0) < 1e-3 else "e" if abs(at - x1) < 1e-3 else ""
    if axis == "x" and corner[0] == ny:
        return (lo + leg + 0.3, hi) if corner[1] == "w" else (lo, hi - leg - 0.3)
    if axis == "y" and corner[1] == nx:
        return (lo + leg + 0.3, hi) if corner[0] == "s" else (lo, hi - leg - 0.3)
    return lo, hi


def _chamfers(b: MeshBuilder, plan: Plan, hc: float, taken: Footprints) -> None:
    """45-degree walls across room corners (the triangle behind them is a duct)."""
    for c in plan.cells:
        if c.chamfer is None:
            continue
        corner, leg = c.chamfer
        x0, y0, x1, y1 = c.rect
        cx, sx = (x0 + 0.12, 1.0) if corner[1] == "w" else (x1 - 0.12, -1.0)
        cy, sy = (y0 + 0.12, 1.0) if corner[0] == "s" else (y1 - 0.12, -1.0)
        a = np.array([cx + sx * leg, cy])
        e = np.array([cx, cy + sy * leg])
        mid = (a + e) / 2
        yaw = float(np.arctan2(e[1] - a[1], e[0] - a[0]))
        b.add_box((mid[0], mid[1], hc / 2), (float(np.linalg.norm(e - a)) + 0.1, 0.1, hc), cls=C.WALL,
                  instance=b.new_instance(C.WALL), material=c.skin, color=c.paint, rotation=rotation_z(yaw),
                  span=True)  # fmt: skip
        taken.take((min(cx, cx + sx * (leg + 0.1)), min(cy, cy + sy * (leg + 0.1)),
                    max(cx, cx + sx * (leg + 0.1)), max(cy, cy + sy * (leg + 0.1))))  # fmt: skip


# ================================================================================================ structure


def _stair(
    b: MeshBuilder, rng: np.random.Generator, cell: Cell, hc: float, cap: float, rail_col: tuple[int, int, int]
) -> tuple[float, float, float, float]:
    """A dog-leg stair: the floor landing at the door end, flight one up the west or east side to a half landing,
    flight two back up to the floor above through the ceiling; a handrail on the well side of both flights.
    Returns the rectangle over the landing that keeps its ceiling."""
    x0, y0, x1, y1 = cell.rect
    ix0, iy0, ix1, iy1 = x0 + 0.1, y0 + 0.1, x1 - 0.1, y1 - 0.1
    width, depth = ix1 - ix0, iy1 - iy0
    total = hc + 0.1
    n = int(np.ceil(total / 0.18 / 2)) * 2
    rise, m = total / n, n // 2
    gap = float(rng.uniform(0.1, 0.3))
    fw = (width - gap) / 2
    half = max(1.0, min(fw, 1.3))
    going = min(0.28, (depth - 1.3 - half) / m)
    land = depth - half - m * going
    inst = b.new_instance(C.CLUTTER)
    west_first = rng.random() < 0.5
    mat, col = (CONCRETE, (175, 170, 160))
    s = 1.0 if cell.stair_low else -1.0
    v0 = iy0 if cell.stair_low else iy1

    def y_at(v: float) -> float:
        return v0 + s * v

    ua = (ix0, ix0 + fw) if west_first else (ix1 - fw, ix1)
    ub = (ix1 - fw, ix1) if west_first else (ix0, ix0 + fw)
    for k in range(m):  # flight one, solid
        va, vb = land + k * going, land + (k + 1) * going
        z = (k + 1) * rise
        b.add_box(((ua[0] + ua[1]) / 2, (y_at(va) + y_at(vb)) / 2, z / 2), (fw, going + 0.02, z), cls=C.CLUTTER,
                  instance=inst, material=mat, color=col)  # fmt: skip
    vh = land + m * going
    zh = m * rise
    b.add_box(((ix0 + ix1) / 2, (y_at(vh) + y_at(depth)) / 2, zh - 0.1), (width, depth - vh, 0.2), cls=C.CLUTTER,
              instance=inst, material=mat, color=col)  # fmt: skip
    for k in range(m):  # flight two: stepped slab on its way back up
        va, vb = vh - (k + 1) * going, vh - k * going
        z = zh + (k + 1) * rise
        b.add_box(((ub[0] + ub[1]) / 2, (y_at(va) + y_at(vb)) / 2, z - 0.2), (fw, going + 0.02, 0.4), cls=C.CLUTTER,
                  instance=inst, material=mat, color=col)  # fmt: skip
    rail = b.new_instance(C.CLUTTER)
    for (u_lo, u_hi), z0, z1, first in ((ua, 0.0, zh, True), (ub, zh, total, False)):
        u = u_hi - 0.03 if (u_lo < (ix0 + ix1) / 2) else u_lo + 0.03
        va, vb = (land, vh) if first else (vh, land)
        pa = np.array([u, y_at(va), z0 + 0.9])
        pb = np.array([u, y_at(vb), z1 + 0.9])
        length = float(np.linalg.norm(pb - pa))
        pitch = float(np.arctan2(pb[2] - pa[2], abs(pb[1] - pa[1])))
        dirn = 1.0 if pb[1] > pa[1] else -1.0
        rot = rotation_z(np.pi / 2 * dirn) @ np.array(
            [[np.cos(pitch), 0, -np.sin(pitch)], [0, 1, 0], [np.sin(pitch), 0, np.cos(pitch)]]
        )
        b.add_box((pa + pb) / 2, (length, 0.05, 0.05), cls=C.CLUTTER, instance=rail, material=METAL, color=rail_col,
                  rotation=rot)  # fmt: skip
        for f in np.linspace(0.05, 0.95, max(int(length / 0.6), 2)):
            p = pa + f * (pb - pa)
            b.add_box((p[0], p[1], p[2] - 0.45), (0.03, 0.03, 0.9), cls=C.CLUTTER, instance=rail, material=METAL,
                      color=rail_col)  # fmt: skip
    b.add_box(((x0 + x1) / 2, (y0 + y1) / 2, cap + 0.1), (x1 - x0, y1 - y0, 0.2), cls=C.CEILING,
              instance=b.new_instance(C.CEILING), material=CONCRETE, color=(200, 198, 192))  # fmt: skip
    ly0, ly1 = sorted((y_at(-0.1), y_at(land)))
    return (x0, ly0, x1, ly1)


def _structure(
    b: MeshBuilder, rng: np.random.Generator, plan: Plan, hc: float, col: tuple[int, int, int], taken: Footprints
) -> None:
    """Free-standing lobby columns, downstand beams across rooms or the corridor, dropped bulkheads."""
    for c in plan.cells:
        x0, y0, x1, y1 = c.rect
        if c.kind == "lobby" and min(x1 - x0, y1 - y0) > 2.9 and rng.random() < 0.7:
            s = float(rng.uniform(0.35, 0.5))
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            inst = b.new_instance(C.COLUMN)
            turns = (0.0, np.pi / 6, np.pi / 3) if rng.random() < 0.5 else (0.0,)
            for a in turns:
                b.add_box((cx, cy, hc / 2), (s, s, hc), cls=C.COLUMN, instance=inst, material=CONCRETE, color=col,
                          rotation=rotation_z(a), span=True)  # fmt: skip
            taken.take((cx - s / 2 - 0.05, cy - s / 2 - 0.05, cx + s / 2 + 0.05, cy + s / 2 + 0.05))
        if c.kind in ("living", "corridor", "lobby", "bed") and hc > 2.5 and rng.random() < 0.2:
            bw, bd = float(rng.uniform(0.25, 0.35)), float(rng.uniform(0.3, min(0.45, hc - 2.15)))
            if (x1 - x0) > (y1 - y0):  # across the long direction
                bx = float(rng.uniform(x0 + 1.0, x1 - 1.0))
                b.add_box((bx, (y0 + y1) / 2, hc - bd / 2), (bw, y1 - y0, bd), cls=C.BEAM,
                          instance=b.new_instance(C.BEAM), material=CONCRETE, color=col)  # fmt: skip
            else:
                by = float(rng.uniform(y0 + 1.0, y1 - 1.0))
                b.add_box(((x0 + x1) / 2, by, hc - bd / 2), (x1 - x0, bw, bd), cls=C.BEAM,
                          instance=b.new_instance(C.BEAM), material=CONCRETE, color=col)  # fmt: skip
        if c.kind in ("corridor", "kitchen", "living") and hc > 2.45 and rng.random() < 0.2:
            bw, bd = float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.2, min(0.35, hc - 2.2)))
            if (x1 - x0) > (y1 - y0):
                y = y0 + bw / 2 if rng.random() < 0.5 else y1 - bw / 2
                center, size = ((x0 + x1) / 2, y, hc - bd / 2), (x1 - x0, bw, bd)
            else:
                x = x0 + bw / 2 if rng.random() < 0.5 else x1 - bw / 2
                center, size = (x, (y0 + y1) / 2, hc - bd / 2), (bw, y1 - y0, bd)
            b.add_box(center, size, cls=C.CEILING, instance=b.new_instance(C.CEILING), material=PLASTER,
                      color=c.paint)  # fmt: skip


# ================================================================================================ contents


def _inner(rect: tuple[float, float, float, float], w: float, d: float) -> tuple[float, float, float, float]:
    """A cell inside its walls (outer walls are thicker)."""
    x0, y0, x1, y1 = rect
    return (
        x0 + (OUTER_M / 2 if x0 < 0.01 else 0.11),
        y0 + (OUTER_M / 2 if y0 < 0.01 else 0.11),
        x1 - (OUTER_M / 2 if x1 > w - 0.01 else 0.11),
        y1 - (OUTER_M / 2 if y1 > d - 0.01 else 0.11),
    )


def _walls_free(plan: Plan, idx: int) -> tuple[int, ...]:
    """The sides (0 S, 1 N, 2 W, 3 E) of a cell with no link to a neighbour along them."""
    x0, y0, x1, y1 = plan.cells[idx].rect
    busy = set()
    for (i, j), _link in plan.links.items():
        if idx not in (i, j):
            continue
        o = plan.cells[j if i == idx else i].rect
        if abs(o[3] - y0) < 1e-3:
            busy.add(0)
        if abs(o[1] - y1) < 1e-3:
            busy.add(1)
        if abs(o[2] - x0) < 1e-3:
            busy.add(2)
        if abs(o[0] - x1) < 1e-3:
            busy.add(3)
    return tuple(s for s in range(4) if s not in busy) or (0, 1, 2, 3)


def _furnish(b: MeshBuilder, rng: np.random.Generator, plan: Plan, idx: int, taken: Footprints, damaged: bool) -> None:
    cell = plan.cells[idx]
    w = max(c.rect[2] for c in plan.cells)
    d = max(c.rect[3] for c in plan.cells)
    room = _inner(cell.rect, w, d)
    x0, y0, x1, y1 = room
    area = (x1 - x0) * (y1 - y0)
    skew = 0.35 if damaged else 0.0
    quiet = _walls_free(plan, idx)
    facade = {s for s, on in enumerate((y0 < 0.2, y1 > d - 0.2, x0 < 0.2, x1 > w - 0.2)) if on}
    hang = tuple(s for s in quiet if s not in facade) or tuple(s for s in range(4) if s not in facade)
    kind = cell.kind
    if kind == "passage" or kind == "shaft" or kind == "stair":
        return
    if kind in ("corridor", "lobby"):
        long_sides = tuple(s for s in ((0, 1) if (x1 - x0) > (y1 - y0) else (2, 3)) if s not in facade) or (0,)
        for _ in range(int(rng.integers(1, 4))):
            th.by_wall(b, taken, room, th.picture(rng), rng, sides=long_sides, z=float(rng.uniform(1.2, 1.5)),
                       reserve=False)  # fmt: skip
        if rng.random() < 0.5:
            th.by_wall(b, taken, room, th.clutter(rng), rng, sides=long_sides)
        return
    if kind == "hall":
        if min(x1 - x0, y1 - y0) >= 1.75:
            th.by_wall(b, taken, room, th.shoe_cabinet(rng), rng, sides=quiet)
        th.by_wall(b, taken, room, th.picture(rng), rng, sides=hang, z=1.4, reserve=False)
        return
    if kind == "bath":
        th.by_wall(b, taken, room, th.sanitary(rng, "toilet"), rng, sides=quiet, tries=16)
        th.by_wall(b, taken, room, th.sanitary(rng, "basin"), rng, tries=16)
        if max(x1 - x0, y1 - y0) > 2.4 and area > 6.0 and rng.random() < 0.5:
            th.by_wall(b, taken, room, th.sanitary(rng, "tub"), rng, sides=quiet, tries=16)
        if area > 5.0 and rng.random() < 0.4:
            th.by_wall(b, taken, room, th.appliance(rng, "washer"), rng, tries=8)
        return
    if kind == "store":
        for _ in range(max(1, int(area / 3))):
            th.by_wall(b, taken, room, th.shelving(rng) if rng.random() < 0.6 else th.clutter(rng), rng, skew=skew)
        return
    kitchen = any(c.kind == "kitchen" and c.apt == cell.apt for c in plan.cells)
    if kind == "kitchen" or (kind == "living" and not kitchen):
        _kitchen(b, rng, taken, room, hang, kind == "kitchen")
        if kind == "kitchen":
            if area > 6 and rng.random() < 0.7:
                _table_set(b, rng, taken, room, small=True)
            th.by_wall(b, taken, room, th.clutter(rng), rng, skew=skew)
            return
    if kind == "living":
        sofa = th.sofa(rng)
        spot = th.by_wall(b, taken, room, sofa, rng, sides=quiet, skew=skew, tries=14)
        if spot is not None:
            sx, sy, side = spot
            face = np.array([(0, 1), (0, -1), (1, 0), (-1, 0)][side], dtype=float)
            depth = th.size_of(sofa)[1]
            p = np.array([sx, sy]) + face * (depth / 2 + 0.65)
            th.try_place(b, taken, room, th.coffee_table(rng), float(p[0]), float(p[1]),
                         rotation_z((0.0, np.pi, -np.pi / 2, np.pi / 2)[side] + float(rng.normal(0, 0.1))),
                         pad=0.1)  # fmt: skip
            opposite = {0: 1, 1: 0, 2: 3, 3: 2}[side]
            th.by_wall(b, taken, room, th.screen(rng), rng, sides=(opposite,) if opposite not in facade else hang,
                       z=1.0, reserve=False)  # fmt: skip
        for _ in range(int(rng.integers(0, 3))):
            th.free_standing(b, taken, room, th.sofa(rng, 1), rng, pad=0.3)
        if area > 10:
            _table_set(b, rng, taken, room, small=area < 14)
        elif rng.random() < 0.7 and th.by_wall(b, taken, room, th.desk(rng), rng, tries=10) is not None:
            th.free_standing(b, taken, room, th.desk_chair(rng), rng, pad=0.1)  # a studio or hotel room's desk
        for _ in range(int(rng.integers(1, 3))):
            th.by_wall(b, taken, room, th.shelving(rng), rng, skew=skew)
        for _ in range(int(rng.integers(1, 4))):
            th.by_wall(b, taken, room, th.clutter(rng), rng)
        th.by_wall(b, taken, room, th.picture(rng), rng, sides=hang, z=float(rng.uniform(1.3, 1.6)), reserve=False)
        return
    if kind == "bed":
        double = min(x1 - x0, y1 - y0) > 3.0 and area > 10.0 and rng.random() < 0.7
        bed = th.bed(rng, double)
        spot = th.by_wall(b, taken, room, bed, rng, sides=quiet, skew=skew / 3, tries=16)
        if spot is not None:
            bx, by, side = spot
            yaw = (0.0, np.pi, -np.pi / 2, np.pi / 2)[side]
            rot = rotation_z(yaw)
            bwx, bly, _ = th.size_of(bed)
            for sgn in (-1, 1):
                stand = th.bedside(rng)
                s = th.size_of(stand)[0]
                off = rot @ np.array([sgn * (bwx / 2 + s / 2 + 0.05), -bly / 2 + s / 2 + 0.02, 0.0])
                th.try_place(b, taken, room, stand, bx + float(off[0]), by + float(off[1]), rot, pad=0.01)
        th.by_wall(b, taken, room, th.wardrobe(rng), rng, skew=skew, tries=14)
        if area > 8.0 and rng.random() < 0.6:
            spot = th.by_wall(b, taken, room, th.desk(rng), rng, tries=10)
            if spot is not None:
                th.free_standing(b, taken, room, th.desk_chair(rng), rng, pad=0.1)
        th.by_wall(b, taken, room, th.picture(rng), rng, sides=hang, z=float(rng.uniform(1.3, 1.6)), reserve=False)
        if rng.random() < 0.5:
            th.by_wall(b, taken, room, th.clutter(rng), rng)


def _kitchen(b: MeshBuilder, rng: np.random.Generator, taken: Footprints, room: tuple[float, float, float, float],
             quiet: tuple[int, ...], closed: bool) -> None:  # fmt: skip
    """A worktop run on a quiet wall, wall units over it, the fridge at one end, a cooker or a hob."""
    x0, y0, x1, y1 = room
    for _ in range(6):
        side = quiet[int(rng.integers(len(quiet)))]
        wall_len = (x1 - x0) if side < 2 else (y1 - y0)
        length = min(float(rng.uniform(1.6, 3.6)), wall_len - 0.9)
        if length < 1.2:
            continue
        top = th.worktop(rng, length)
        spot = th.by_wall(b, taken, room, top, rng, sides=(side,), tries=4)
        if spot is None:
            continue
        tx, ty, _ = spot
        yaw = (0.0, np.pi, -np.pi / 2, np.pi / 2)[side]
        rot = rotation_z(yaw)
        if rng.random() < 0.8:
            units = th.wall_units(rng, length)
            off = rot @ np.array([0.0, -0.3 + 0.165, 0.0])
            th.draw(b, units, tx + float(off[0]), ty + float(off[1]), rot, float(rng.uniform(1.45, 1.55)))
        fridge = th.appliance(rng, "fridge")
        for sgn in (1, -1):
            off = rot @ np.array([sgn * (length / 2 + 0.33), 0.0, 0.0])
            if th.try_place(b, taken, room, fridge, tx + float(off[0]), ty + float(off[1]), rot, pad=0.01):
                break
        if closed and rng.random() < 0.5:
            th.by_wall(b, taken, room, th.appliance(rng, "cooker"), rng, sides=quiet, tries=6)
        if not closed and rng.random() < 0.5:  # bar stools along the worktop's front
            for k in range(int(rng.integers(1, 4))):
                off = rot @ np.array([(k - 1) * 0.5, 0.75, 0.0])
                th.try_place(b, taken, room, th.bar_stool(rng), tx + float(off[0]), ty + float(off[1]),
                             rotation_z(float(rng.uniform(-np.pi, np.pi))), pad=0.02)  # fmt: skip
        return


def _table_set(b: MeshBuilder, rng: np.random.Generator, taken: Footprints, room: tuple[float, float, float, float],
               small: bool) -> None:  # fmt: skip
    """A dining table free in the room with chairs round it (pulled out at odd angles)."""
    table = th.dining_table(rng)
    if small and th.size_of(table)[0] > 1.2:
        table = th.dining_table(rng)
    spot = th.free_standing(b, taken, room, table, rng, pad=0.55, tries=25, square=rng.random() < 0.6)
    if spot is None:
        return
    tx, ty, yaw = spot
    sx, sy, _ = th.size_of(table)
    rot = rotation_z(yaw)
    seats = [(0.0, sy / 2 + 0.32), (0.0, -sy / 2 - 0.32)]
    if sx > 1.3:
        seats = [(u, v) for u in (-sx / 4, sx / 4) for (_, v) in seats]
    seats += [(sx / 2 + 0.32, 0.0), (-sx / 2 - 0.32, 0.0)]
    for u, v in seats:
        if rng.random() < 0.25:
            continue
        p = rot @ np.array([u, v, 0.0])
        f = -p[:2] / max(float(np.linalg.norm(p[:2])), 1e-6)  # the chair faces the table, pulled out askew
        face = float(np.arctan2(-f[0], f[1])) + float(rng.normal(0, 0.25))
        th.draw(b, th.dining_chair(rng), tx + float(p[0]), ty + float(p[1]), rotation_z(face))


# ================================================================================================ damage


def _damage(
    b: MeshBuilder,
    rng: np.random.Generator,
    plan: Plan,
    hc: float,
    taken: Footprints,
    ceil_col: tuple[int, int, int],
    rubble_col: tuple[int, int, int],
) -> None:
    """Fallen plaster, a sagging piece of ceiling, furniture overturned, grit; corridors keep their width."""
    w = max(c.rect[2] for c in plan.cells)
    d = max(c.rect[3] for c in plan.cells)
    sag = 0
    for c in plan.cells:
        if c.kind in ("shaft", "stair"):
            continue
        room = _inner(c.rect, w, d)
        if min(room[2] - room[0], room[3] - room[1]) < 1.2:
            continue
        if rng.random() < 0.45:
            th.fallen_plaster(b, rng, room, int(rng.integers(1, 6)), ceil_col)
        if rng.random() < 0.6:
            th.grit(b, rng, room, int(rng.integers(10, 40)), rubble_col)
        if c.kind in ("living", "bed", "kitchen") and sag < 2 and rng.random() < 0.25 and min(
                room[2] - room[0], room[3] - room[1]) > 2.4:  # fmt: skip
            th.sagging_ceiling(b, rng, room, hc - c.drop, ceil_col)
            sag += 1
        if c.kind in ("living", "bed", "store") and rng.random() < 0.35:
            piece = [th.shelving, th.wardrobe, th.dining_chair, lambda r: th.sofa(r, 1)][int(rng.integers(4))](rng)
            for _ in range(8):
                x = float(rng.uniform(room[0] + 0.5, room[2] - 0.5))
                y = float(rng.uniform(room[1] + 0.5, room[3] - 0.5))
                rot = th.overturned(piece, rng, float(rng.uniform(-np.pi, np.pi)))
                if th.try_place(b, taken, room, piece, x, y, rot, pad=0.2):
                    break
